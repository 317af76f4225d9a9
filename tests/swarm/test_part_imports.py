"""A swarm part's command imports what that part needs, no more: the CPU a process spends importing is paid by
every `truav-swarm up` (once per world, agent and controller process) and by the suite's hundreds of swarms.

`--help` of a part (and building its parser, which every start of the part does) imports no numba, and no other
part's runtime; the modules of the agent API that compute nothing with kernels import no numba either; a module
with kernels still sets numba's cache up (truav.kernel_cache) before numba compiles or loads any of them.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]

_HELP = """
import contextlib, io, json, sys
from truav.cli import swarm
with contextlib.redirect_stdout(io.StringIO()):
    try:
        swarm.main([sys.argv[1], "--help"])
    except SystemExit:
        pass
print(json.dumps(sorted(sys.modules)))
"""
_IMPORT = "import json, sys, importlib; importlib.import_module(sys.argv[1]); print(json.dumps(sorted(sys.modules)))"


def _modules(code: str, arg: str) -> set[str]:
    done = subprocess.run([sys.executable, "-c", code, arg], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-3000:]
    return set(json.loads(done.stdout.strip().splitlines()[-1]))


def _under(modules: set[str], *prefixes: str) -> list[str]:
    return sorted(m for m in modules if any(m == p or m.startswith(p + ".") for p in prefixes))


FOREIGN = {
    "agent": ("world.process", "agents.process.central_process", "agents.process.controller_host", "recorder",
              "truav.cli.swarm_router", "truav.cli.swarm_up", "truav.swarm.supervisor"),
    "world": ("agents.process", "recorder", "truav.cli.swarm_router", "truav.cli.swarm_up", "truav.swarm.supervisor"),
    "controller": ("world.process", "agents.process.agent_host", "agents.process.agent_process", "recorder",
                   "truav.cli.swarm_router", "truav.cli.swarm_up", "truav.swarm.supervisor"),
    "router": ("world", "agents", "recorder", "truav.cli.swarm_up", "truav.swarm.supervisor"),
}


@pytest.mark.parametrize("part", sorted(FOREIGN))
def test_a_parts_help_imports_no_numba_and_no_other_parts_runtime(part: str) -> None:
    modules = _modules(_HELP, part)
    assert not _under(modules, "numba", "llvmlite"), f"`{part} --help` imported numba"
    assert not _under(modules, "torch"), f"`{part} --help` imported torch"
    assert not _under(modules, *FOREIGN[part]), f"`{part} --help` imported {_under(modules, *FOREIGN[part])}"


@pytest.mark.parametrize("module", ["agents.api", "agents.spread_agent", "agents.claim_agent", "agents.ppo_agent",
                                    "agents.process.agent_options", "world.process.world_options"])
def test_modules_without_kernels_import_no_numba(module: str) -> None:
    assert not _under(_modules(_IMPORT, module), "numba", "llvmlite"), f"{module} imported numba"


def test_every_kernel_module_sets_the_cache_up_before_numba() -> None:
    """Read from the sources: a module that imports numba imports truav.kernel_cache first (its package no
    longer does it for every module beneath it)."""
    for package in ("world", "agents"):
        for path in sorted((REPO / package).rglob("*.py")):
            lines = path.read_text().splitlines()
            numba_at = [i for i, line in enumerate(lines) if line.startswith(("import numba", "from numba"))]
            if not numba_at:
                continue
            cache_at = [i for i, line in enumerate(lines) if line.startswith("from truav import kernel_cache")]
            assert cache_at and cache_at[0] < numba_at[0], f"{path.relative_to(REPO)} imports numba before " \
                                                           f"truav.kernel_cache"


def test_a_process_loading_kernels_imports_no_scipy_linalg() -> None:
    """numba's BLAS probe (scipy.linalg, ~0.3 CPU-s at every world and agent start) is answered "no": it only
    picks np.correlate's and np.convolve's inner product, which no kernel calls (so no number changes)."""
    code = ("import json, sys; from world.channel import fspl_db; fspl_db(100.0, 2.4e9); "
            "from agents.reward import Reward; print(json.dumps(sorted(sys.modules)))")
    modules = _modules(code, "")
    assert "world.channel" in modules and "numba.np.arraymath" in modules
    assert not _under(modules, "scipy.linalg"), "loading a kernel imported scipy.linalg (numba's BLAS probe)"
    from truav.kernel_cache import NO_BLAS_FUNCTIONS, kernel_sources
    for path in kernel_sources():
        text = path.read_text()
        used = [name for name in NO_BLAS_FUNCTIONS if name + "(" in text or name.split(".")[1] + "(" in text]
        assert not used, f"{path.relative_to(REPO)} calls {used}: numba's BLAS probe decides how they compile"
