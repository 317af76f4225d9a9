"""`truav-swarm up` as a subprocess (``Up``) and the ``up`` fixture that starts them and closes each at
the end of its test."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from truav.bus.transport import Bus, make_config
from truav.swarm.children import free_loopback_endpoint
from truav.wire import keys

SMALL = ["--set", "scenario.n_vehicles=40", "--set", "roads.warmup_steps=5"]


def learners(args=()) -> list[str]:
    """``--scheme truav`` (TRUAV's Q-learners, what a test of the swarm's machinery flies) unless ``args`` choose a
    scheme or an agent class: `up` alone flies the demo's learned policy (truav.swarm.swarm_options.DEMO_SCHEME)."""
    return [] if {"--scheme", "--agent"} & set(args) else ["--scheme", "truav"]


def _running(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


class Up:
    """`truav-swarm up` as a subprocess, with everything it started killed at the end should a test fail."""

    def __init__(self, tmp: Path, run: str, *args: str):
        self.out = tmp / "swarm"
        self.log_path = tmp / "up.log"
        self.run = run
        log = open(self.log_path, "wb")
        self.proc = subprocess.Popen([sys.executable, "-m", "truav.cli.swarm", "up", *learners(args), "--run", run,
                                      "--out", str(self.out), "-l", free_loopback_endpoint(), "--quiet", "--no-plot",
                                      *SMALL, *args], stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
        log.close()
        self.pids: dict[str, int] = {}

    def output(self) -> str:
        return self.log_path.read_text(errors="replace")

    def wait_ticking(self, timeout: float = 90.0) -> str:
        """Wait until the world has published a few steps; the router endpoint."""
        deadline = time.monotonic() + timeout
        while not (self.out / "swarm.json").is_file():
            assert self.proc.poll() is None and time.monotonic() < deadline, self.output()
            time.sleep(0.1)
        endpoint = json.loads((self.out / "swarm.json").read_text())["endpoint"]
        steps: list[int] = []
        with Bus("observer", self.run, make_config(connect=[endpoint], connect_timeout_ms=5000)) as bus:
            bus.subscribe(keys.metrics_step(self.run), lambda k, m, r, t: steps.append(m.tick))
            while len(steps) < 3:
                assert self.proc.poll() is None and time.monotonic() < deadline, self.output()
                time.sleep(0.05)
        self.pids = json.loads((self.out / "pids.json").read_text())
        return endpoint

    def wait(self, timeout: float = 120.0) -> int:
        rc = self.proc.wait(timeout=timeout)
        self.pids = json.loads((self.out / "pids.json").read_text())
        return rc

    def left_running(self, grace: float = 5.0) -> list[str]:
        deadline = time.monotonic() + grace
        while any(_running(p) for p in self.pids.values()) and time.monotonic() < deadline:
            time.sleep(0.1)
        return [n for n, p in self.pids.items() if _running(p)]

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()
        for pid in self.pids.values():  # only processes this supervisor started
            if _running(pid) and b"truav" in Path(f"/proc/{pid}/cmdline").read_bytes():
                os.kill(pid, signal.SIGKILL)


@pytest.fixture
def up(tmp_path):
    started: list[Up] = []

    def start(run: str, *args: str) -> Up:
        u = Up(tmp_path, run, *args)
        started.append(u)
        return u

    yield start
    for u in started:
        u.close()
