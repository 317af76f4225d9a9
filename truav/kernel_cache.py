"""Where numba caches the compiled kernels: a directory keyed by a hash of
every kernel source file.

numba checks a cached function against its own file's timestamp only, so a
kernel that calls another file's kernel (the world step calls mobility and
relay; the fused trainer calls the world and the learners) would keep stale
machine code after an edit of the callee, and silently compute the old
numbers. Keyed by all kernel sources, any edit recompiles every kernel once.
Imported by the `world` and `agents` packages before any kernel is defined;
NUMBA_CACHE_DIR, if set, wins.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

from truav.user_cache import truav_cache_dir

_ROOT = Path(__file__).resolve().parent.parent
KERNEL_PACKAGES = ("world", "agents")


def kernel_sources() -> list[Path]:
    files = sorted(p for pkg in KERNEL_PACKAGES for p in (_ROOT / pkg).glob("*.py"))
    return [p for p in files if "@njit" in p.read_text()]


def cache_dir() -> Path:
    digest = hashlib.sha256()
    for path in kernel_sources():
        digest.update(path.name.encode() + b"\0" + path.read_bytes())
    return truav_cache_dir() / "numba" / digest.hexdigest()[:16]


def uncached(files: list[str]) -> list[str]:
    """Those kernel source files (repository paths, e.g. "world/step.py") of which numba's cache holds
    no compiled kernel yet: their kernels compile on first use (a fresh machine, or after any kernel
    edit, which changes :func:`cache_dir`). Mirrors numba's cache layout, a subdirectory per source
    directory (numba.core.caching._CacheLocator), so that asking costs no numba import."""
    root = Path(os.environ.get("NUMBA_CACHE_DIR") or cache_dir())
    missing = []
    for name in files:
        source = (_ROOT / name).resolve().parent
        sub = root / f"{source.name}_{hashlib.sha1(str(source).encode()).hexdigest()}"
        if not any(sub.glob(f"{Path(name).stem}.*.nbi")):
            missing.append(name)
    return missing


SWARM_KERNELS = ["world/step.py", "agents/state.py", "agents/reward.py", "agents/qlearning.py"]
"""What the world and the agents of a swarm compile before they join."""
TRAIN_KERNELS = ["world/step.py", "agents/fused.py"]
"""What `truav train` compiles before its first episode."""
COLD_COMPILE_S = (60, 90)
"""Seconds a first start spends compiling on the 2-core reference machine: measured beside other jobs (load
average 5), `truav-swarm up --steps 5 --episodes 1` took 77 s and `truav train --seeds 1 --episodes 1` 92 s
from an empty cache, seconds of which were the run itself."""


def cold_start_note(files: list[str]) -> str | None:
    """One line for the user when the kernels ``files`` need are not compiled yet, else None."""
    if not uncached(files):
        return None
    lo, hi = COLD_COMPILE_S
    return (f"compiling the numba kernels first (nothing cached yet for this checkout in "
            f"{os.environ.get('NUMBA_CACHE_DIR') or cache_dir()}): about {lo}-{hi} s on 2 busy cores, once; "
            f"later starts load them in about a second")


if not os.environ.get("NUMBA_CACHE_DIR"):
    # The environment too: numba re-reads its config from it, and the swarm's
    # processes inherit it.
    os.environ["NUMBA_CACHE_DIR"] = str(cache_dir())
    import numba

    numba.config.CACHE_DIR = os.environ["NUMBA_CACHE_DIR"]
