"""The compiled numba kernels are shared by every checkout on the machine, as the README says ("once per
machine"): a second clone of the same sources, elsewhere on disk and with fresh file times, loads the
kernels the first one compiled instead of compiling them again (truav.kernel_cache.SharedKernelLocator)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
TINY = "from world.channel import fspl_db; print(fspl_db(100.0, 2.4e9))"
"""One small kernel, compiled (or loaded) and called."""


def _clone(where: Path, touch: float) -> Path:
    """The sources a clone holds (what kernels are made of and the package that files them), with new file
    times, as a fresh `git clone` has."""
    for package in ("truav", "world", "agents"):
        shutil.copytree(REPO / package, where / package, ignore=shutil.ignore_patterns("__pycache__"))
    for path in where.rglob("*.py"):
        os.utime(path, (touch, touch))
    return where


def _run(clone: Path, cache_home: Path) -> str:
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "PYTHONPATH")}
    env.update(XDG_CACHE_HOME=str(cache_home), PYTHONPATH=str(clone), NUMBA_DEBUG_CACHE="1")
    done = subprocess.run([sys.executable, "-c", TINY], cwd=clone, env=env, capture_output=True, text=True,
                          timeout=240)
    assert done.returncode == 0, done.stderr[-3000:]
    return done.stdout + done.stderr


def test_a_second_clone_loads_the_kernels_the_first_compiled(tmp_path: Path) -> None:
    cache_home = tmp_path / "cache"
    first = _run(_clone(tmp_path / "one" / "truav-clone", time.time() - 3600), cache_home)
    assert "data saved" in first and "fspl_db" in first, first[-2000:]
    second = _run(_clone(tmp_path / "two" / "elsewhere", time.time()), cache_home)
    assert "data loaded" in second, second[-2000:]
    assert "data saved" not in second, f"the second clone compiled again:\n{second[-2000:]}"
