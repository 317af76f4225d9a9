"""A first run on a fresh machine: the compiled kernels are built before the first tick.

With an empty numba cache, compiling the world's step and the agents' reward took seconds. Done
at tick 0 it made the world 3.5 s late and the agents miss their first six ticks (every UAV
hovering), which skewed the first episode of the quick start on every fresh machine. The world
and the agents now compile on a throwaway step before they join.
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from tests.support.swarm_up import Up


def _cold_run(tmp_path, name: str, scheme: str) -> tuple[Up, dict, dict]:
    up = Up(tmp_path, name, "--agents", "2", "--steps", "20", "--episodes", "1", "--rate", "10",
            "--scheme", scheme,
            "--max-missed", "1")  # a busy host's missed actions: bounded below where they matter here
    try:
        assert up.wait(timeout=300) == 0, up.output()
    finally:
        up.close()
    world = json.loads((up.out / "world.json").read_text())
    summary = json.loads((up.out / "summary.json").read_text())
    # A tick compiled in place was seconds late; a loaded CI machine is tens of milliseconds late.
    assert world["tick_lateness_ms"]["max"] < 500.0, world["tick_lateness_ms"]
    # Agents compiling at their first observation missed seconds of ticks; a busy host may cost every
    # agent a tick or two, never a run of ticks.
    all_hovering = [tick for tick, hovering in summary["timeline"]["hovering"] if hovering >= 2]
    runs = [t for t in all_hovering if all(t - k in all_hovering for k in range(1, 4))]
    assert not runs, f"ticks where every UAV hovered: {all_hovering}"
    return up, world, summary


def test_a_cold_machine_compiles_once_and_no_tick_pays_for_it(tmp_path, monkeypatch) -> None:
    """The quick start on a fresh machine compiles every kernel once, before anything starts, saying so;
    `truav train` after it compiles nothing; the central scheme's own kernels (the world's control-plane
    model, the controller's learner) compile before they join too (they once compiled in tick 0: the world
    0.9 s late, 80% of a short run's actions missed)."""
    cache = tmp_path / "empty-numba-cache"
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(cache))  # inherited by every process `up` starts
    up, _, _ = _cold_run(tmp_path, "cold", "truav")
    assert any(cache.rglob("*.nbi")), "the test did not use the empty cache"
    assert up.output().count("compiling the numba kernels once for this machine") == 1, up.output()
    train = subprocess.run([sys.executable, "-m", "truav.cli", "train", "--seeds", "1", "--episodes", "2", "--quiet",
                            "--set", "scenario.n_vehicles=60", "--out", str(tmp_path / "train")],
                           capture_output=True, text=True, timeout=300)
    assert train.returncode == 0, train.stderr
    assert "compiling" not in train.stdout + train.stderr, train.stdout  # the demo compiled what training runs
    (tmp_path / "central").mkdir()
    central, _, _ = _cold_run(tmp_path / "central", "cold-central", "central")
    assert "compiling the numba kernels once" not in central.output(), central.output()


def test_the_cold_cache_check_finds_what_numba_cached(tmp_path, monkeypatch) -> None:
    """uncached() mirrors numba's cache layout: after a warm-up (compiled or loaded) it finds the kernels."""
    import numba

    from truav import kernel_cache
    from truav.config import Config
    from world.process.world_process import warm_up_kernels
    warm_up_kernels(Config().replace(scenario={"n_uavs": 2}))
    monkeypatch.setenv("NUMBA_CACHE_DIR", numba.config.CACHE_DIR)
    assert kernel_cache.uncached(["world/step.py"]) == []
    assert kernel_cache.cold_start_note(["world/step.py"]) is None
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    assert kernel_cache.uncached(["world/step.py", "agents/fused.py"]) == ["world/step.py", "agents/fused.py"]
