"""A first run on a fresh machine: the compiled kernels are built before the first tick.

With an empty numba cache, compiling the world's step and the agents' reward took seconds. Done
at tick 0 it made the world 3.5 s late and the agents miss their first six ticks (every UAV
hovering), which skewed the first episode of the quick start on every fresh machine. The world
and the agents now compile on a throwaway step before they join.
"""

from __future__ import annotations

import json

from tests.test_swarm_outcomes import Up


def test_a_cold_kernel_cache_costs_no_tick(tmp_path, monkeypatch) -> None:
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "empty-numba-cache"))  # inherited by every process `up` starts
    up = Up(tmp_path, "cold", "--agents", "2", "--steps", "20", "--episodes", "1", "--rate", "10")
    try:
        assert up.wait(timeout=200) == 0, up.output()
    finally:
        up.close()
    assert any((tmp_path / "empty-numba-cache").rglob("*.nbi")), "the test did not use the empty cache"
    world = json.loads((up.out / "world.json").read_text())
    summary = json.loads((up.out / "summary.json").read_text())
    # A tick compiled in place was seconds late; a loaded CI machine is tens of milliseconds late.
    assert world["tick_lateness_ms"]["max"] < 500.0, world["tick_lateness_ms"]
    all_hovering = [tick for tick, hovering in summary["timeline"]["hovering"] if hovering >= 2]
    assert not all_hovering, f"ticks where every UAV hovered: {all_hovering}"
