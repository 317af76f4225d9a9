"""bench/bench_ray_swarm.py: it refuses a loaded machine and a bad size in one line (exit 2) before it starts a
Ray cluster; its --quick smoke run is the command the lead's quiet-machine run shortens."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[2] / "bench" / "bench_ray_swarm.py"


def _bench(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(BENCH), *args], capture_output=True, text=True, timeout=120)


def test_it_refuses_a_loaded_machine_and_a_bad_size_in_one_line() -> None:
    pytest.importorskip("ray", reason="the benchmark needs the ray extra")
    r = _bench("--max-load", "0")  # any load average is >= 0
    assert r.returncode == 2 and r.stdout == "" and r.stderr.count("\n") == 1, r
    assert "load average" in r.stderr and "--max-load 0" in r.stderr and "--anyway" in r.stderr
    r = _bench("--agents", "0")
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "--agents" in r.stderr, r


def test_its_help_names_the_quick_run() -> None:
    r = _bench("--help")
    assert r.returncode == 0 and "--quick" in r.stdout and "--per-process" in r.stdout, r
