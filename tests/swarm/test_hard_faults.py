"""Hard faults a swarm run meets on a real machine (issue 43): files in the way of --out, a second agent
for a live UAV, a stalled world, a full disk.

Real `truav-swarm up` runs (a small city, loopback) where a process is needed; every process is tracked
by PID and none may outlive its test.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.support.runs import run_to_end
from tests.support.swarm_up import SMALL, learners, up  # noqa: F401  (the fixture: `up` runs, each closed at the end)
from truav.cli import swarm as swarm_cli
from truav.swarm.children import free_loopback_endpoint
from truav.swarm.outdir import MARKER_FILE


def _up_argv(out: Path, *extra: str) -> list[str]:
    return ["up", *learners(extra), "--run", "hf", "--agents", "2", "--steps", "10", "--episodes", "1", "--lockstep", *SMALL,
            "--out", str(out), "-l", free_loopback_endpoint(), "--quiet", "--no-plot", *extra]


# -- nothing outside the run is touched --------------------------------------------------------
def test_users_own_files_in_out_are_refused_and_force_removes_only_what_a_run_writes(tmp_path, capsys):
    out = tmp_path / "mine"
    out.mkdir()
    mine = {"summary.json": '{"my": "results"}', "scenario.toml": "# my own scenario\n", "notes.txt": "mine"}
    for name, text in mine.items():
        (out / name).write_text(text)
    assert swarm_cli.main(_up_argv(out)) == 2  # no earlier run's marker: refused before anything starts
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "not a TRUAV swarm run's" in err and "--force" in err and str(out) in err
    assert {p.name for p in out.iterdir()} == set(mine)
    assert all((out / name).read_text() == text for name, text in mine.items())

    assert swarm_cli.main(_up_argv(out, "--force")) == 0
    assert (out / "notes.txt").read_text() == "mine"  # not a run's name: left alone
    assert (out / MARKER_FILE).is_file() and (out / "agent0.npz").is_file()
    capsys.readouterr()
    assert swarm_cli.main(_up_argv(out)) == 2  # now an earlier run: the usual refusal
    assert "holds an earlier run" in capsys.readouterr().err


# -- one process per identity -------------------------------------------------------------------
def test_a_second_agent_for_a_live_uav_is_refused_before_it_flies(up, tmp_path):
    u = up("dup", "--agents", "2", "--steps", "100", "--episodes", "20")  # real time: minutes, ended by close()
    endpoint = u.wait_ticking()
    dup = subprocess.run(  # by hand, as a user would: its own checkpoint path, the run's UAV 1
[sys.executable, "-m", "truav.cli.swarm", "agent", "--run", "dup", "--id", "1", "-e",
                          endpoint, "--scenario", str(u.out / "scenario.toml"), "--checkpoint",
                          str(tmp_path / "dup1.npz")], capture_output=True, text=True, timeout=120)
    assert dup.returncode == 2, dup.stderr[-3000:]
    lines = dup.stderr.strip().splitlines()
    assert "already has a live agent" in lines[-1] and "--id 1" in lines[-1] and "Traceback" not in dup.stderr
    assert not (tmp_path / "dup1.npz").exists() and u.proc.poll() is None  # refused before it flew; the run flies on


# -- a stall is a fault -------------------------------------------------------------------------
STALL_S = 12.0
"""Longer than Zenoh's 10 s lease: the router drops the paused world's session, and on waking the world sees
every agent's token vanish and come back (no agent left)."""


def test_a_stalled_world_resumes_without_a_burst_and_the_run_says_so(up):
    u = up("stall", "--agents", "2", "--steps", "60", "--episodes", "3")  # real time, 10 Hz: 183 ticks
    u.wait_ticking()
    world = u.pids["world"]
    os.kill(world, signal.SIGSTOP)
    try:
        time.sleep(STALL_S)  # the stall itself: the world's clock jumps this far
    finally:
        os.kill(world, signal.SIGCONT)
    rc = u.wait(timeout=180)
    summary = json.loads((u.out / "summary.json").read_text())
    w = summary["world"]
    assert rc == 1 and summary["outcome"]["result"] == "failed", u.output()[-3000:]
    assert len(w["stalls"]) == 1 and w["stalls"][0]["s"] >= STALL_S - 0.5, w["stalls"]
    assert w["stalls"][0]["ticks_skipped"] >= 10 * (STALL_S - 0.5)  # 10 Hz
    assert w["ticks"] == 3 * 61  # no simulated step lost: the run took longer instead
    # No burst: only the tick after the stall started late, not the ~25 that were due during it.
    assert w["tick_lateness_ms"]["p99"] < 1000, w["tick_lateness_ms"]
    assert w["losses"] == []  # no agent left (the run said "agent losses seen 3")
    out = u.output()
    assert "the world stalled 1 time(s)" in out and "tick(s) skipped" in out and "result: FAILED" in out


# -- disks fill up ------------------------------------------------------------------------------
@pytest.fixture
def small_disk(tmp_path):
    """A 1 MiB tmpfs (a checkpoint of the small city is 2 MB): mounted for the test, unmounted after."""
    disk = tmp_path / "disk"
    disk.mkdir()
    try:
        subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(disk)], check=True,
                       capture_output=True, timeout=30)
    except (OSError, subprocess.SubprocessError) as exc:
        pytest.skip(f"cannot mount a small tmpfs here ({exc})")
    try:
        yield disk
    finally:
        subprocess.run(["umount", "-l", str(disk)], capture_output=True, timeout=30)


def test_up_on_a_full_disk_ends_failed_with_a_summary_that_says_so(small_disk, tmp_path):
    out = small_disk / "swarm"
    rc = run_to_end([sys.executable, "-m", "truav.cli.swarm", *_up_argv(out)], tmp_path / "up.log", 240)
    text = (tmp_path / "up.log").read_text(errors="replace")
    assert rc == 1, text[-3000:]
    assert "Traceback" not in text and "no space left on" in text and "result: FAILED" in text
    summary = json.loads((out / "summary.json").read_text())  # small: it fits, and is whole
    assert any("no space left on" in f for f in summary["outcome"]["failures"]), summary["outcome"]
    assert not list(out.glob("agent*.npz")) and not list(out.glob("*.tmp"))  # no partial file, no temporary
    for i in (0, 1):
        log = (out / "logs" / f"agent{i}.log").read_text(errors="replace")
        assert log.count("no space left on") == 1 and "Traceback" not in log, log[-2000:]


# -- ranges that hold ---------------------------------------------------------------------------
def test_a_run_without_packets_reports_pdr_as_no_data(tmp_path, capsys):
    out = tmp_path / "quiet-roads"
    assert swarm_cli.main(_up_argv(out, "--set", "traffic.packet_rate_hz=0")) == 0
    text = capsys.readouterr().out
    assert "PDR no data" in text and not re.search(r"\bnan\b", text, re.IGNORECASE), text[-2000:]
    assert "pdr no data" in (out / "logs" / "world.log").read_text()
