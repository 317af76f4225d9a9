"""`truav-swarm` commands run to their end as OS processes (swarm tier)."""

from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

from truav.config import Config, to_toml
from tests.support.swarm_up import learners


def run_to_end(cmd: list[str], log_path: Path, timeout_s: float, *, env: dict | None = None,
               term_wait_s: float = 30.0) -> int:
    """Run a `truav-swarm` command to its end, output in ``log_path``; its exit code. If it outlives
    ``timeout_s`` (the wait raises) it gets SIGTERM (the supervisor stops every process it started),
    then SIGKILL after ``term_wait_s``."""
    with open(log_path, "wb") as log:
        proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=env)
    try:
        return proc.wait(timeout=timeout_s)
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(timeout=term_wait_s)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=10)


def up_to_end(tmp: Path, name: str, cfg: Config, *args: str, timeout_s: float = 300.0) -> Path:
    """`truav-swarm up` of scenario ``cfg`` (written to ``tmp/<name>.toml``) with ``args``, run to its end;
    asserts exit 0 (the log in the message otherwise) and returns its --out directory."""
    scenario = tmp / f"{name}.toml"
    scenario.write_text(to_toml(cfg))
    out = tmp / name
    cmd = [sys.executable, "-m", "truav.cli.swarm", "up", *learners(args), "--run", name, "--scenario", str(scenario),
           "--out", str(out), "--quiet", "--no-plot", *args]
    rc = run_to_end(cmd, tmp / f"{name}.log", timeout_s, term_wait_s=60)
    assert rc == 0, (tmp / f"{name}.log").read_text(errors="replace")
    return out
