"""Compile every numba kernel the commands run, once per machine, before any of them needs it.

numba compiles a kernel on its first call and caches it (truav.kernel_cache). Left to that, each command
met its own kernels cold: the demo compiled the swarm's, then `truav train` the fused trainer's for
another minute, `truav evaluate` the step-by-step driver's in silence, and a progress bar counted the
compile into its ETA. Instead, the first command on a machine (or after a kernel edit) runs one tiny
episode of every in-process path here, in the foreground, saying so in one line; every command after it
loads the compiled kernels in about a second. The central SAC's kernels (torch, an optional extra)
compile on their first use, with their own line.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable

from truav import kernel_cache

WARM_KERNELS = ["world/step.py", "world/draws.py", "agents/fused.py", "agents/state.py", "agents/reward.py",
                "agents/qlearning.py"]
"""Kernel files that :func:`compile_kernels` leaves compiled: one of them uncached means a compile."""

_PATHS = (("truav", True), ("truav", False), ("patrol", False), ("random", False), ("hover", False))
"""The in-process paths, (controller, learning): TRUAV's fused training and greedy episodes, the patrol's
fused episodes, and the step-by-step driver (random, hover) that the swarm's kernels share."""


def needs_compile() -> bool:
    return bool(kernel_cache.uncached(WARM_KERNELS))


def compile_kernels() -> None:
    """One short episode of each path in :data:`_PATHS` (nothing written): numba compiles and caches."""
    from truav.analysis.trainer import run_chunk
    from truav.config import Config
    cfg = Config().replace(scenario={"n_vehicles": 40, "steps_per_episode": 3}, roads={"warmup_steps": 3})
    trained = run_chunk("truav", cfg, [0], 1, train=True)
    for kind, learn in _PATHS[1:]:
        run_chunk(kind, cfg, [0], 1, train=learn, q=trained.q if kind == "truav" else None)


def ensure_compiled(say: Callable[[str], None] = print) -> float:
    """Compile the kernels if this machine has not yet (one line before, one after); the seconds it took."""
    if not needs_compile():
        return 0.0
    lo, hi = kernel_cache.COLD_COMPILE_S
    say(f"compiling the numba kernels once for this machine (about {lo}-{hi} s on 2 cores; cached in "
        f"{os.environ.get('NUMBA_CACHE_DIR') or kernel_cache.cache_dir()}); every later command loads them "
        f"in about a second")
    t0 = time.perf_counter()
    compile_kernels()
    elapsed = time.perf_counter() - t0
    say(f"compiled in {elapsed:.0f} s")
    return elapsed
