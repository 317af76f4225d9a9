"""Standalone `truav log record` / `truav-swarm record` (no supervisor): it says what it records and where as it
starts, and ends by itself when the run it records ends (the world's shutdown message, or the world's
liveliness token gone), finishing the file. A loopback router; the recorder is a child killed by PID."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from recorder.check import check
from recorder.process.recorder import RUN_END_MAX_WAIT_S, wait_until_recording
from truav.lifecycle import SUPERVISOR_PID_ENV
from truav.wire import keys, schema

REPO = Path(__file__).resolve().parents[2]
RUN = "alone"
READY_S = 20.0
EXIT_S = RUN_END_MAX_WAIT_S - 2.0  # it ends when the run's processes have left, before the cap


@pytest.fixture
def recorder_proc(tmp_path: Path, endpoint: str):
    procs: list[subprocess.Popen] = []

    def start(out: Path) -> tuple[subprocess.Popen, list[str]]:
        env = {k: v for k, v in os.environ.items() if k != SUPERVISOR_PID_ENV}  # as a user starts it
        env["PYTHONPATH"] = os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])
        proc = subprocess.Popen([sys.executable, "-m", "truav.cli", "log", "record", "--run", RUN, "--out", str(out),
                                 "-e", endpoint], cwd=REPO, env=env, stdin=subprocess.DEVNULL,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        procs.append(proc)
        err: list[str] = []
        threading.Thread(target=lambda: err.extend(proc.stderr), daemon=True).start()  # read as it comes
        return proc, err

    yield start
    for proc in procs:  # by PID, reaped
        if proc.poll() is None:
            proc.kill()
        proc.wait(timeout=EXIT_S)


def _world(bus_factory, proc: subprocess.Popen):
    world = bus_factory("world")
    if not wait_until_recording(world, RUN, READY_S):
        raise AssertionError("the recorder never became ready")
    token = world.declare_liveliness(keys.alive_world(RUN))
    for tick in range(5):
        world.publish(keys.world_tick(RUN), schema.Tick(tick=tick, episode=0, sim_time=float(tick), deadline_ms=80.0,
                                                        n_uavs=1))
    return world, token


@pytest.mark.parametrize("end", ["shutdown", "world gone"])
def test_standalone_record_says_what_it_records_and_ends_with_the_run(tmp_path: Path, bus_factory, recorder_proc,
                                                                      end: str) -> None:
    out = tmp_path / "run.mcap"
    proc, err = recorder_proc(out)
    world, token = _world(bus_factory, proc)
    deadline = time.monotonic() + READY_S
    while not any("recording run" in line for line in err) and time.monotonic() < deadline:
        time.sleep(0.05)
    start_line = next(line for line in err if "recording run" in line)  # printed while it records
    assert f"recording run {RUN}" in start_line and str(out) in start_line, start_line
    time.sleep(0.5)  # the ticks reached the recorder
    if end == "shutdown":  # what the world publishes at a run's end (and `truav-swarm down`)
        world.publish(keys.control(RUN, "shutdown"), schema.Control(command="shutdown", args={}))
        time.sleep(0.5)
        assert proc.poll() is None  # its processes have not left yet: it records on
        token.close()  # the world leaves after its shutdown
    else:
        token.close()  # the world died: its liveliness token is gone
    try:
        proc.wait(timeout=EXIT_S)  # by itself: no signal, no stop command
    except subprocess.TimeoutExpired:
        raise AssertionError(f"the recorder kept running after the run ended: {''.join(err)}") from None
    stdout = proc.stdout.read()  # a summary's few lines: the pipe never filled
    reason = "the run ended (shutdown from world)" if end == "shutdown" else "the world left"
    finishing = f"{reason}: finishing once its processes have left"
    deadline = time.monotonic() + READY_S  # stderr is the fixture's thread's alone: it reads to the end
    while not any(finishing in line for line in err) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert proc.returncode == 0, stdout + "".join(err)
    assert f"({reason})" in stdout.splitlines()[0], stdout
    assert any(finishing in line for line in err), err
    report = check(out)
    assert report.finished and report.messages >= 5 and not report.problems
