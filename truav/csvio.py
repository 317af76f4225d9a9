"""CSV cells for every file the project writes: a missing or non-finite number is an empty field, the cell CSV
readers (pandas, spreadsheets, R) take as missing, never ``nan`` or ``inf`` (which some read as text and others
as a number). The JSON counterpart is :mod:`truav.jsonio` (``null``)."""

from __future__ import annotations

import math
from typing import Any, Iterable

import numpy as np


def cell(value: Any, spec: str | None = None) -> Any:
    """``value`` as a CSV cell: "" for None and for a NaN or infinite float (Python or numpy); a number
    formatted by ``spec`` when given; anything else unchanged."""
    if value is None:
        return ""
    if isinstance(value, (float, np.floating)):
        if not math.isfinite(value):
            return ""
        return format(float(value), spec) if spec else float(value)
    if isinstance(value, np.integer):
        value = int(value)
    return format(value, spec) if spec and isinstance(value, (int, float)) and not isinstance(value, bool) else value


def cells(values: Iterable[Any], spec: str | None = None) -> list[Any]:
    """:func:`cell` of each value."""
    return [cell(v, spec) for v in values]


def row_cells(row: dict[str, Any]) -> dict[str, Any]:
    """A csv.DictWriter row with :func:`cell` of each value."""
    return {k: cell(v) for k, v in row.items()}


__all__ = ["cell", "cells", "row_cells"]
