"""`truav-swarm up --external IDS`: up starts everything but those UAVs' agents, prints the command that flies
them, waits (bounded) for their liveliness tokens and reports on them like any other agent.

The test reads up's output until the printed command appears and runs it exactly as printed (from the repo
root): the run must end ``result: ok`` with every action of the external UAV applied (world.json's per_uav).
An external UAV that never comes fails the run within --external-wait; bad values are one line, exit 2.
Loopback only; every process started here is stopped at the end, bounded in time."""

from __future__ import annotations

import json
import shlex
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.support.waits import free_port
from truav.lifecycle import child_env
from tests.support.swarm_up import learners

REPO = Path(__file__).resolve().parents[2]
CLI = [sys.executable, "-m", "truav.cli.swarm"]
STEPS = 10
RUN_TIMEOUT_S = 240.0


def _up(tmp: Path, *args: str) -> tuple[subprocess.Popen, Path]:
    log = tmp / "up.log"
    proc = subprocess.Popen([*CLI, "up", *learners(args), "--agents", "3", "--episodes", "1", "--steps", str(STEPS), "--no-plot",
                             "--out", str(tmp / "out"), "-l", f"tcp/127.0.0.1:{free_port()}",
                             "--set", "scenario.n_vehicles=60", "--set", "roads.warmup_steps=10", *args],
                            cwd=REPO, env=child_env(), stdout=log.open("w"), stderr=subprocess.STDOUT)
    return proc, log


def _printed_command(log: Path, proc: subprocess.Popen, timeout_s: float = 120.0) -> list[str]:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and proc.poll() is None:
        for line in log.read_text().splitlines():
            if line.strip().startswith("command:"):
                return shlex.split(line.split("command:", 1)[1])
        time.sleep(0.2)
    raise AssertionError(f"up printed no command for the external UAV:\n{log.read_text()}")


def _stop(*procs: subprocess.Popen) -> None:
    for p in procs:
        if p.poll() is None:
            p.terminate()
    for p in procs:
        try:
            p.wait(30)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


@pytest.mark.parametrize("mode", ["lockstep", "realtime", "secure-lockstep"])
def test_external_agent_from_the_printed_command_flies_to_result_ok(tmp_path, mode):
    extra = {"lockstep": ["--lockstep"], "secure-lockstep": ["--lockstep", "--secure"],
             "realtime": ["--rate", "5", "--max-missed", "1"]}  # real time: a busy host's misses are not this test's
    up, log = _up(tmp_path, "--external", "2", *extra[mode])
    agent = None
    try:
        cmd = _printed_command(log, up)
        assert cmd[:2] == ["python", "examples/outside_agent.py"] and ("--lockstep" in cmd) == ("lockstep" in mode)
        if mode == "secure-lockstep":  # its identity's credentials: a config that holds them, loadable anywhere
            assert cmd[cmd.index("-c") + 1].endswith("creds/uav-2.json5") and "-e" not in cmd
        agent = subprocess.Popen([sys.executable, *cmd[1:]], cwd=REPO, stdout=subprocess.DEVNULL,
                                 stderr=subprocess.STDOUT)
        rc = up.wait(RUN_TIMEOUT_S)
        agent.wait(60)
    finally:
        _stop(up, *([agent] if agent else []))
    text = log.read_text()
    assert rc == 0 and "result: ok" in text, text
    assert "external uav/2: joined" in text
    world = json.loads((tmp_path / "out" / "world.json").read_text())
    ext = world["per_uav"][2]
    if "lockstep" in mode:  # every action of the outside agent applied
        assert ext["applied"] == STEPS and ext["missed"] == 0 and ext["rejected"] == {}
    else:  # real time on a busy machine: it flew, nothing refused
        assert ext["applied"] > 0 and ext["rejected"] == {}
    assert not (tmp_path / "out" / "agent2.json").exists()  # no project agent was started for UAV 2


def test_external_uav_that_never_joins_fails_within_the_wait(tmp_path):
    up, log = _up(tmp_path, "--external", "1", "--lockstep", "--external-wait", "3")
    try:
        rc = up.wait(RUN_TIMEOUT_S)
    finally:
        _stop(up)
    text = log.read_text()
    assert rc != 0 and "never joined" in text and "result: ok" not in text, text


@pytest.mark.parametrize("args, flag", [
    (["--external", "5"], "--external"),
    (["--external", "1,1"], "--external"),
    (["--external", "x"], "--external"),
    (["--external", "1", "--scheme", "patrol"], "--external"),
    (["--external-wait", "10"], "--external-wait"),
])
def test_bad_external_values_are_one_line_exit_2(tmp_path, args, flag):
    r = subprocess.run([*CLI, "up", *learners(args), "--agents", "3", "--out", str(tmp_path / "out"), *args], cwd=REPO,
                       env=child_env(), capture_output=True, text=True, timeout=60)
    assert r.returncode == 2, r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and flag in lines[0] and "Traceback" not in r.stderr, r.stderr
    assert not (tmp_path / "out").exists()  # nothing started
