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

_ROOT = Path(__file__).resolve().parent.parent
KERNEL_PACKAGES = ("world", "agents")


def kernel_sources() -> list[Path]:
    files = sorted(p for pkg in KERNEL_PACKAGES for p in (_ROOT / pkg).glob("*.py"))
    return [p for p in files if "@njit" in p.read_text()]


def cache_dir() -> Path:
    digest = hashlib.sha256()
    for path in kernel_sources():
        digest.update(path.name.encode() + b"\0" + path.read_bytes())
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / "truav" / "numba" / digest.hexdigest()[:16]


if not os.environ.get("NUMBA_CACHE_DIR"):
    # The environment too: numba re-reads its config from it, and the swarm's
    # processes inherit it.
    os.environ["NUMBA_CACHE_DIR"] = str(cache_dir())
    import numba

    numba.config.CACHE_DIR = os.environ["NUMBA_CACHE_DIR"]
