"""bench/bench_policy_memory.py and bench/bench_policy_realtime.py: a mistake is one line and exit 2 before
anything starts; tiny runs sample every agent process (one UAV each, or hosted two per process) and print
each scheme's figures and the table."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[2] / "bench"


def _bench(name: str, *args: str, timeout: float = 600.0) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(BENCH / name), *args], capture_output=True, text=True,
                          timeout=timeout)


def test_mistakes_are_one_line_and_exit_2() -> None:
    for name, args, says in (("bench_policy_memory.py", ["--per-process", "0"], "--per-process"),
                             ("bench_policy_memory.py", ["--per-process", "x"], "--per-process"),
                             ("bench_policy_realtime.py", ["--max-load", "0"], "--max-load 0"),
                             ("bench_policy_realtime.py", ["--agents", "51", "--anyway"], "--agents"),
                             ("bench_policy_realtime.py", ["--speed", "0", "--anyway"], "--speed"),
                             ("bench_policy_memory.py", ["--speed", "-5"], "--speed")):
        r = _bench(name, *args, timeout=60)
        assert r.returncode == 2 and r.stdout == "" and r.stderr.count("\n") == 1, (name, args, r)
        assert says in r.stderr, r.stderr


@pytest.mark.timeout(900)  # four swarms in turn: minutes on a loaded 2-core host
def test_a_tiny_memory_run_samples_every_agent_process(tmp_path) -> None:
    rows = tmp_path / "rows.json"
    r = _bench("bench_policy_memory.py", "--agents", "2", "--ticks", "20", "--schemes", "ppo,truav",
               "--per-process", "1,2", "--json", str(rows))
    assert r.returncode == 0, r.stdout + r.stderr
    got = json.loads(rows.read_text())
    assert [(g["scheme"], g["per_process"]) for g in got] == [("ppo", 1), ("truav", 1), ("ppo", 2), ("truav", 2)]
    for g in got:
        assert g["processes_seen"] == g["processes_expected"] == (2 if g["per_process"] == 1 else 1), g
        assert g["uavs_seen"] == 2 and g["complete_samples"] >= 1 and g["exit_code"] == 0, g
        assert 0 < g["uss_mb_median"] <= g["rss_mb_median"] <= g["hwm_mb_max"], g
    assert "| ppo | 2 | 1/1 |" in r.stdout and "| truav | 1 | 2/2 |" in r.stdout, r.stdout


@pytest.mark.timeout(900)
def test_a_tiny_realtime_run_of_each_scheme_prints_the_runs_and_the_table(tmp_path) -> None:
    rows = tmp_path / "rows.json"
    r = _bench("bench_policy_realtime.py", "--agents", "2", "--seconds", "3", "--repeat", "1", "--anyway",
               "--load-wait", "0", "--json", str(rows))
    assert r.returncode == 0, r.stdout + r.stderr
    got = json.loads(rows.read_text())
    assert [g["scheme"] for g in got] == ["truav", "ppo"] and all(g["ticks"] >= 30 for g in got), got
    assert all(0.0 <= g["missed_pct"] <= 100.0 and g["exit_code"] == 0 for g in got), got
    assert "| truav | 1 |" in r.stdout and "| ppo | 1 |" in r.stdout, r.stdout


def test_speed_sets_the_scenario_the_policy_flies_in(tmp_path) -> None:
    """--speed 5 flies ppo-disc's own network (it picks by speed): the scenario file says 5 m/s."""
    sys.path.insert(0, str(BENCH))
    try:
        import policy_runs
    finally:
        sys.path.remove(str(BENCH))
    from truav.config import load_config
    cfg = load_config(policy_runs.write_scenario(tmp_path / "s.toml", 5.0))
    assert cfg.scenario.uav_speed_mps == 5.0 and cfg.learner.sense_range_m == 1500.0
    assert load_config(policy_runs.write_scenario(tmp_path / "d.toml")).scenario.uav_speed_mps == 15.0

