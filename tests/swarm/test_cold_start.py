"""A first run on a fresh machine: the compiled kernels are built before the first tick.

With an empty numba cache, compiling the world's step and the agents' reward took seconds. Done
at tick 0 it made the world 3.5 s late and the agents miss their first six ticks (every UAV
hovering), which skewed the first episode of the quick start on every fresh machine. The world
and the agents now compile on a throwaway step before they join.
"""

from __future__ import annotations

import json

import pytest

from tests.support.swarm_up import Up


@pytest.mark.parametrize("scheme", ["truav", "central"])
def test_a_cold_kernel_cache_costs_no_tick(tmp_path, monkeypatch, scheme) -> None:
    """Under central the world's control-plane model and the controller's learner compile before they join
    too (they once compiled in tick 0: the world 0.9 s late, 80% of a short run's actions missed)."""
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "empty-numba-cache"))  # inherited by every process `up` starts
    up = Up(tmp_path, "cold", "--agents", "2", "--steps", "20", "--episodes", "1", "--rate", "10",
            "--scheme", scheme,
            "--max-missed", "1")  # a busy host's missed actions: bounded below where they matter here
    try:
        assert up.wait(timeout=200) == 0, up.output()
    finally:
        up.close()
    assert any((tmp_path / "empty-numba-cache").rglob("*.nbi")), "the test did not use the empty cache"
    world = json.loads((up.out / "world.json").read_text())
    summary = json.loads((up.out / "summary.json").read_text())
    # The user is told why tick 0 takes so long, once.
    assert up.output().count("compiling the numba kernels first") == 1, up.output()
    # A tick compiled in place was seconds late; a loaded CI machine is tens of milliseconds late.
    assert world["tick_lateness_ms"]["max"] < 500.0, world["tick_lateness_ms"]
    # Agents compiling at their first observation missed seconds of ticks; a busy host may cost every
    # agent a tick or two, never a run of ticks.
    all_hovering = [tick for tick, hovering in summary["timeline"]["hovering"] if hovering >= 2]
    runs = [t for t in all_hovering if all(t - k in all_hovering for k in range(1, 4))]
    assert not runs, f"ticks where every UAV hovered: {all_hovering}"


def test_the_cold_cache_check_finds_what_numba_cached(tmp_path, monkeypatch) -> None:
    """uncached() mirrors numba's cache layout: after a warm-up (compiled or loaded) it finds the kernels."""
    import numba

    from truav import kernel_cache
    from truav.config import Config
    from world.world_process import warm_up_kernels
    warm_up_kernels(Config().replace(scenario={"n_uavs": 2}))
    monkeypatch.setenv("NUMBA_CACHE_DIR", numba.config.CACHE_DIR)
    assert kernel_cache.uncached(["world/step.py"]) == []
    assert kernel_cache.cold_start_note(["world/step.py"]) is None
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    assert kernel_cache.uncached(["world/step.py", "agents/fused.py"]) == ["world/step.py", "agents/fused.py"]
