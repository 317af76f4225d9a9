"""bench/bench_bridges.py: it refuses to measure on a loaded machine (one line, exit 2), and a tiny run of the
three settings (no bridge, MAVLink, ROS 2) prints each run, a HEARTBEAT from every UAV and the table."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("pymavlink", reason="the MAVLink bridge is the optional extra 'mavlink'")
pytest.importorskip("rosbags", reason="the ROS 2 bridge is the optional extra 'ros2'")

BENCH = Path(__file__).resolve().parents[2] / "bench" / "bench_bridges.py"


def _bench(*args: str, timeout: float = 240.0) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(BENCH), *args], capture_output=True, text=True, timeout=timeout)


def test_it_refuses_a_loaded_machine_in_one_line() -> None:
    r = _bench("--max-load", "0")  # any load average is >= 0
    assert r.returncode == 2 and r.stdout == "" and r.stderr.count("\n") == 1, r
    assert "load average" in r.stderr and "--max-load 0" in r.stderr and "--anyway" in r.stderr


def test_a_tiny_run_of_each_setting_prints_the_runs_heartbeats_and_the_table(tmp_path) -> None:
    rows = tmp_path / "rows.json"
    r = _bench("--agents", "2", "--seconds", "3", "--repeat", "1", "--anyway", "--load-wait", "0",
               "--json", str(rows))
    assert r.returncode == 0, r.stdout + r.stderr
    for setting in ("none", "mavlink", "ros2"):
        assert f"| {setting} | 1 |" in r.stdout, r.stdout
    assert "HEARTBEAT from 2/2 UAVs" in r.stdout and "| 2/2 |" in r.stdout, r.stdout
    got = json.loads(rows.read_text())
    assert [g["setting"] for g in got] == ["none", "mavlink", "ros2"] and all(g["ticks"] >= 30 for g in got)
    assert all(g["exit_code"] == 0 for g in got), got
