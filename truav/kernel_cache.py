"""Where numba caches the compiled kernels: a directory keyed by a hash of
every kernel source file.

numba checks a cached function against its own file's timestamp only, so a
kernel that calls another file's kernel (the world step calls mobility and
relay; the fused trainer calls the world and the learners) would keep stale
machine code after an edit of the callee, and silently compute the old
numbers. Keyed by all kernel sources, any edit recompiles every kernel once.
Imported by each module of `world` and `agents` that has kernels, before it imports numba (not by the
packages: a module without kernels, and a process without any, imports no numba, ~0.4 CPU-s at each start);
NUMBA_CACHE_DIR, if set, wins.

Shared by every checkout on the machine: numba files a kernel under a hash of its source directory's
absolute path, so a second clone of the same sources compiled everything again. The locator below files
TRUAV's kernels under their place in the project (``world``, ``agents``) and stamps them with their source's
content, so every clone with the same kernel sources loads what the first compiled.
"""

from __future__ import annotations

import functools
import hashlib
import os
import sys
from pathlib import Path

import numba
from numba.core.caching import CacheImpl, UserProvidedCacheLocator

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


def project_subpath(py_file: str | os.PathLike) -> str | None:
    """The subdirectory of the cache a kernel of ``py_file`` is filed in: its directory inside the project
    (``world``, ``agents``, ``world/process``) with ``/`` as ``.``, the same in every checkout; None for a file
    outside TRUAV's kernel packages (numba's own locators file it)."""
    try:
        rel = Path(py_file).resolve().parent.relative_to(_ROOT)
    except ValueError:
        return None
    if not rel.parts or rel.parts[0] not in KERNEL_PACKAGES:
        return None
    return "truav-" + ".".join(rel.parts)


@functools.lru_cache(maxsize=None)
def _content_stamp(path: str, mtime_ns: int, size: int) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


class SharedKernelLocator(UserProvidedCacheLocator):
    """numba's NUMBA_CACHE_DIR locator for TRUAV's kernels, keyed by :func:`project_subpath` instead of the
    checkout's absolute path and stamped by the source's content instead of its modification time (a fresh
    clone's files are all new): every checkout of the same sources shares one compiled copy."""

    @classmethod
    def get_suitable_cache_subpath(cls, py_file):
        return project_subpath(py_file) or super().get_suitable_cache_subpath(py_file)

    def get_source_stamp(self):
        st = os.stat(self._py_file)
        return _content_stamp(str(self._py_file), st.st_mtime_ns, st.st_size)

    @classmethod
    def from_function(cls, py_func, py_file):
        if project_subpath(py_file) is None:
            return None
        return super().from_function(py_func, py_file)


def uncached(files: list[str]) -> list[str]:
    """Those kernel source files (repository paths, e.g. "world/step.py") of which numba's cache holds
    no compiled kernel yet: their kernels compile on first use (a fresh machine, or after any kernel
    edit, which changes :func:`cache_dir`). Mirrors the cache's layout (:class:`SharedKernelLocator`), so
    that asking costs no compilation."""
    root = Path(os.environ.get("NUMBA_CACHE_DIR") or cache_dir())
    missing = []
    for name in files:
        sub = root / SharedKernelLocator.get_suitable_cache_subpath(str(_ROOT / name))
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
    return (f"compiling the numba kernels first (nothing cached yet on this machine for these kernel sources, in "
            f"{os.environ.get('NUMBA_CACHE_DIR') or cache_dir()}): about {lo}-{hi} s on 2 busy cores, once; "
            f"later starts load them in about a second")


if not os.environ.get("NUMBA_CACHE_DIR"):
    # The environment too: numba re-reads its config from it, and the swarm's
    # processes inherit it.
    os.environ["NUMBA_CACHE_DIR"] = str(cache_dir())
    numba.config.CACHE_DIR = os.environ["NUMBA_CACHE_DIR"]
if SharedKernelLocator not in CacheImpl._locator_classes:  # numba's list of locators, tried in order
    CacheImpl._locator_classes.insert(0, SharedKernelLocator)


NO_BLAS_FUNCTIONS = ("np.correlate", "np.convolve")
"""The only numba functions whose compiled code depends on numba's start-up BLAS probe (below): no kernel calls
them (tests/swarm/test_part_imports.py reads the kernel sources)."""


def _skip_blas_probe() -> None:
    """numba's numba.np.arraymath, which every process loads with its first kernel, probes for BLAS at import by
    importing scipy.linalg (~0.3 CPU-s, on every start of the world and of each agent) only to pick the inner
    product of np.correlate and np.convolve (NO_BLAS_FUNCTIONS). The probe is answered "no" while that module
    loads; numba's np.dot and np.linalg still import scipy when a kernel using them compiles."""
    if "numba.np.arraymath" in sys.modules:
        return
    from numba.np import linalg
    probe = getattr(linalg, "ensure_blas", None)
    if probe is None:  # another numba: its probe is left alone
        return

    def no_blas() -> None:
        raise ImportError("TRUAV's kernels call no BLAS-backed np.correlate or np.convolve")

    linalg.ensure_blas = no_blas
    try:
        import numba.np.arraymath  # noqa: F401
    finally:
        linalg.ensure_blas = probe


_skip_blas_probe()
