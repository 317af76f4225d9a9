"""Interrupting a command part-way: start it as a process, wait for a file it writes, send a signal, and see
that it ended as it should (its exit code, one line, no traceback, no process of its own left)."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
from pathlib import Path
from typing import Callable

from tests.support.waits import wait_until

ROOT = Path(__file__).resolve().parents[2]


def descendants(pid: int) -> set[int]:
    """Every live process below ``pid`` (children in sessions of their own included), from /proc."""
    parent_of = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                parent_of[int(entry.name)] = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, ValueError, IndexError):
                continue
    found, frontier = set(), {pid}
    while frontier:
        frontier = {child for child, parent in parent_of.items() if parent in frontier} - found
        found |= frontier
    return found


def alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def _as_at_a_terminal() -> None:
    # A suite started in the background (`cmd &` without job control, as a CI script may) ignores SIGINT, and
    # its children inherit that: the command stopped here is one a user runs at a terminal, where Ctrl-C counts.
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def start(code: str, args: list[str], cwd: Path) -> subprocess.Popen:
    """``python -c code args...`` in ``cwd``, its output in pipes (text), SIGINT as at a terminal."""
    env = {**os.environ, "PYTHONPATH": f"{ROOT}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    return subprocess.Popen([sys.executable, "-c", code, *args], cwd=cwd, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, preexec_fn=_as_at_a_terminal)


def stop_when(proc: subprocess.Popen, ready: Callable[[], bool], signum: int, timeout_s: float,
              end_timeout_s: float = 120.0) -> tuple[int, str, str, set[int]]:
    """Send ``signum`` to ``proc`` once ``ready()`` holds (within ``timeout_s``); its exit code, stdout,
    stderr, and which of the processes it had started just before the signal are still alive after it ended."""
    if not wait_until(lambda: ready() or proc.poll() is not None, timeout_s, poll_s=0.05) or proc.poll() is not None:
        proc.kill()
        out, err = proc.communicate(timeout=30)
        raise AssertionError(f"never ready to be stopped (exit {proc.returncode}):\n{out}\n{err}")
    below = descendants(proc.pid)
    proc.send_signal(signum)
    out, err = _ended(proc, end_timeout_s, f"did not end {end_timeout_s:.0f} s after signal {signum}")
    wait_until(lambda: not any(alive(p) for p in below), 15.0, poll_s=0.1)  # reaped by init, if orphaned
    return proc.returncode, out, err, {p for p in below if alive(p)}


def finish(proc: subprocess.Popen, timeout_s: float = 300.0) -> tuple[int, str, str]:
    out, err = _ended(proc, timeout_s, f"did not end in {timeout_s:.0f} s")
    return proc.returncode, out, err


def _ended(proc: subprocess.Popen, timeout_s: float, late: str) -> tuple[str, str]:
    """``proc``'s stdout and stderr once it ended within ``timeout_s``; else killed, and an AssertionError
    saying ``late`` with what it wrote."""
    try:
        return proc.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate(timeout=30)
        raise AssertionError(f"{late}:\n{out}\n{err}") from None


def stopped_quietly(rc: int, out: str, err: str, code: int, line_re: str) -> None:
    """The command exited ``code`` with exactly one line on stderr, matching ``line_re``, and no traceback."""
    assert rc == code, f"exit {rc}, not {code}:\n{out}\n{err}"
    assert "Traceback" not in out + err, out + err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and re.fullmatch(line_re, lines[0]), err

