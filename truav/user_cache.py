"""Where TRUAV keeps what it can rebuild: one directory per user, outside any checkout."""

from __future__ import annotations

import os
from pathlib import Path


def truav_cache_dir() -> Path:
    """``$XDG_CACHE_HOME/truav`` (``~/.cache/truav`` without it): the compiled numba kernels, SUMO's traces
    and the test suite's bytecode, each in a subdirectory."""
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "truav"
