"""Strict JSON for every file and message the project writes: a non-finite float is written as ``null``.

Python's json writes NaN and Infinity as bare words that strict parsers (browsers, jq, most other languages)
reject. :func:`dumps` converts them to ``None`` first and then encodes with ``allow_nan=False``, so a value
that slipped past the conversion fails loudly here instead of producing a file others cannot read.
Readers of a metric that may be missing use :func:`num` to get NaN back for arithmetic.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np


def strict(value: Any) -> Any:
    """``value`` with every NaN/inf float (Python or numpy, at any depth) replaced by None; numpy values as
    Python ones (a numpy array becomes a list)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: strict(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [strict(v) for v in value]
    if isinstance(value, np.ndarray):
        return strict(value.tolist())
    if isinstance(value, np.generic):
        return strict(value.item())
    return value


def dumps(value: Any, **kwargs: Any) -> str:
    """json.dumps of :func:`strict` ``value``; ``kwargs`` as json.dumps takes them (indent, sort_keys, ...)."""
    return json.dumps(strict(value), allow_nan=False, **kwargs)


def write_json(path: str | Path, value: Any, indent: int | None = 1, newline: bool = False) -> None:
    """Write ``value`` as strict JSON to ``path``."""
    Path(path).write_text(dumps(value, indent=indent) + ("\n" if newline else ""))


def _refuse_constant(name: str) -> Any:
    raise ValueError(f"not strict JSON: bare {name}")


def loads_strict(text: str) -> Any:
    """json.loads that refuses the bare NaN/Infinity words (what a strict parser elsewhere would do)."""
    return json.loads(text, parse_constant=_refuse_constant)


def num(value: Any) -> float:
    """A metric read back from JSON as a float: None (a non-finite value written as null) is NaN again."""
    return math.nan if value is None else float(value)


__all__ = ["dumps", "loads_strict", "num", "strict", "write_json"]
