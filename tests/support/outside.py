"""Processes of a swarm started by hand (router, world, agents, examples/outside_agent.py), each stopped
at the end (swarm tier)."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

from truav.lifecycle import child_env

REPO = Path(__file__).resolve().parents[2]
EXAMPLE = REPO / "examples" / "outside_agent.py"
CLI = [sys.executable, "-m", "truav.cli.swarm"]


class Swarm:
    """The processes of one hand-started swarm in ``d``; all stopped by close()."""

    def __init__(self, d: Path):
        self.d, self.procs = d, {}
        (d / "logs").mkdir(parents=True)

    def start(self, name: str, argv: list[str]) -> subprocess.Popen:
        with open(self.d / "logs" / f"{name}.log", "wb") as log:
            # child_env: the project's processes also stop by themselves if this test process dies
            self.procs[name] = subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT, cwd=self.d,
                                                env=child_env())
        return self.procs[name]

    def log(self, name: str) -> str:
        return (self.d / "logs" / f"{name}.log").read_text(errors="replace")

    def wait_log(self, name: str, text: str, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        while text not in self.log(name):
            assert self.procs[name].poll() is None, f"{name} exited: {self.log(name)[-2000:]}"
            assert time.monotonic() < deadline, f"{name}: no {text!r} within {timeout:g} s"
            time.sleep(0.1)

    def close(self) -> None:
        for proc in self.procs.values():
            if proc.poll() is None:
                proc.terminate()
        for proc in self.procs.values():
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=10)
