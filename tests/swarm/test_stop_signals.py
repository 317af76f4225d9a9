"""Schedulers stop jobs with SIGTERM (Slurm, systemd, `timeout`, container runtimes), a closed terminal
with SIGHUP: `truav train` stops as on Ctrl-C (checkpoint, a line naming --resume, exit 128 + signal),
and no worker outlives it, even when it is SIGKILLed."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

LONG_TRAIN = ["--seeds", "2", "--workers", "2", "--checkpoint-every", "0.5", "--episodes", "200000", "--quiet",
              "--set", "scenario.n_vehicles=60", "--set", "scenario.steps_per_episode=10",
              "--set", "roads.warmup_steps=10"]


def children_of(pid: int) -> list[int]:
    """PIDs whose parent is ``pid`` (from /proc: no psutil needed)."""
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                found.append(int(entry.name))
    return found


def alive(pid: int) -> bool:
    try:
        return (Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]) != "Z"
    except OSError:
        return False


def start_training(out: Path, log: Path) -> tuple[subprocess.Popen, list[int]]:
    with open(log, "wb") as f:
        proc = subprocess.Popen([sys.executable, "-m", "truav.cli", "train", *LONG_TRAIN, "--out", str(out)],
                                stdout=f, stderr=subprocess.STDOUT, start_new_session=True)
    deadline = time.monotonic() + 240  # a cold kernel cache compiles first
    workers: list[int] = []
    while time.monotonic() < deadline and proc.poll() is None:
        workers = children_of(proc.pid)
        # both workers started, and past their first episodes: each has checkpointed once
        if len(workers) >= 2 and len(list((out / "resume").glob("chunk*.pkl"))) >= 2:
            break
        time.sleep(0.2)
    assert proc.poll() is None and len(workers) >= 2, log.read_text(errors="replace")
    return proc, workers


def finish(proc: subprocess.Popen, workers: list[int]) -> None:
    if proc.poll() is None:
        proc.kill()
        proc.wait()
    for pid in workers:  # only our own, should the test have failed
        if alive(pid):
            os.kill(pid, signal.SIGKILL)


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGHUP], ids=["sigterm", "sighup"])
def test_train_stops_on_sigterm_as_on_ctrl_c(tmp_path: Path, signum: int) -> None:
    out, log = tmp_path / "run", tmp_path / "train.log"
    proc, workers = start_training(out, log)
    try:
        proc.send_signal(signum)
        rc = proc.wait(timeout=120)
        text = log.read_text(errors="replace")
        assert rc == 128 + signum, text
        assert "--resume" in text and "Traceback" not in text, text
        deadline = time.monotonic() + 10
        while any(alive(p) for p in workers) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not [p for p in workers if alive(p)], "workers outlived `truav train`"
        assert len(list((out / "resume").glob("chunk*.pkl"))) == 2  # resumable
        again = subprocess.run([sys.executable, "-m", "truav.cli", "train", *LONG_TRAIN, "--out", str(out)],
                               capture_output=True, text=True, timeout=120)
        assert again.returncode == 2 and "--resume" in again.stderr  # not restarted silently
    finally:
        finish(proc, workers)


def test_workers_die_with_a_sigkilled_train(tmp_path: Path) -> None:
    proc, workers = start_training(tmp_path / "run", tmp_path / "train.log")
    try:
        proc.kill()
        proc.wait(timeout=30)
        deadline = time.monotonic() + 10
        while any(alive(p) for p in workers) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not [p for p in workers if alive(p)], "workers outlived a SIGKILLed `truav train`"
    finally:
        finish(proc, workers)
