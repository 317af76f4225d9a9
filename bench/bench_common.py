"""What the real-time benchmarks share: the load gate (refuse a loaded machine, wait for a quiet one, mark a run
LOADED), the tick options and their check, a process's CPU from /proc, stopping a run's process group, the
figures every run reads from its world.json, and the JSON rows.

A figure measured beside other jobs is noise, not the cost measured: a benchmark with the gate refuses to start
while the 1-minute load average is at or above ``--max-load``, unless ``--anyway``; before each run it waits up to
``--load-wait`` seconds for the load to fall, and a run that still started loaded is marked LOADED.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

CLK_TCK = os.sysconf("SC_CLK_TCK")


def add_tick_options(ap: argparse.ArgumentParser) -> None:
    """--seconds and --rate of a real-time run."""
    ap.add_argument("--seconds", type=float, default=60.0, help="real-time seconds a run ticks (default 60)")
    ap.add_argument("--rate", type=float, default=10.0, help="tick rate in Hz (default 10, up's)")


def refuse_nonpositive(prog: str, args: argparse.Namespace, flags: tuple[str, ...]) -> bool:
    """Whether to refuse the start (the one line said) because one of ``flags`` is not positive."""
    if all(getattr(args, f.lstrip("-").replace("-", "_")) > 0 for f in flags):
        return False
    print(f"{prog}: error: {', '.join(flags[:-1])} and {flags[-1]} must be positive", file=sys.stderr)
    return True


def parser(doc: str) -> argparse.ArgumentParser:
    """A benchmark's parser: its docstring's first paragraph as the description, the line breaks kept."""
    return argparse.ArgumentParser(description=doc.split("\n\n")[0],
                                   formatter_class=argparse.RawDescriptionHelpFormatter)


def add_load_options(ap: argparse.ArgumentParser) -> None:
    """--max-load, --load-wait and --anyway."""
    ap.add_argument("--max-load", type=float, default=1.0, help="refuse to start at or above this 1-minute load "
                    "average (default 1)")
    ap.add_argument("--load-wait", type=float, default=120.0, metavar="S", help="before each run, wait at most "
                    "this long for the load to fall below --max-load (default 120)")
    ap.add_argument("--anyway", action="store_true", help="run above --max-load, every figure marked LOADED")


def refuse_loaded(prog: str, args: argparse.Namespace) -> bool:
    """Whether to refuse the start (the one line said) because the machine is loaded and not ``--anyway``."""
    load = os.getloadavg()[0]
    if load >= args.max_load and not args.anyway:
        print(f"{prog}: error: load average {load:.2f} >= --max-load {args.max_load:g}: other jobs would be measured "
              f"too; run it on a quiet machine (or --anyway, marked LOADED)", file=sys.stderr)
        return True
    return False


def wait_for_load(args: argparse.Namespace) -> bool:
    """Wait up to ``--load-wait`` for the load to fall below ``--max-load``; whether the run starts LOADED (said)."""
    load = os.getloadavg()[0]
    deadline = time.monotonic() + args.load_wait
    while load >= args.max_load and time.monotonic() < deadline:
        time.sleep(5)
        load = os.getloadavg()[0]
    loaded = load >= args.max_load
    if loaded:
        print(f"WARNING: load average {load:.2f} >= {args.max_load:g}: this run is measured beside other jobs "
              f"(LOADED)", flush=True)
    return loaded


def cpu_s(pid: int | str) -> float | None:
    """User + system CPU seconds of process ``pid`` so far (None once it is gone)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None
    return (int(fields[11]) + int(fields[12])) / CLK_TCK


class Poller:
    """A sampler's thread: ``_start_polling()`` runs the sampler's own ``_loop`` in a daemon thread, which ends once
    ``stop()`` sets ``self._stop``."""

    def _start_polling(self) -> None:
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join()


def stop_group(proc: subprocess.Popen, sig: int = signal.SIGINT, timeout_s: float = 60.0) -> int:
    """Stop the process group ``proc`` leads (started with start_new_session): ``sig``, then SIGKILL if it has not
    ended within ``timeout_s``; its exit code."""
    if proc.poll() is None:
        os.killpg(proc.pid, sig)
        try:
            return proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
    return proc.wait()


def ratio(value: float, base: float, over_zero: str) -> str:
    """``value`` over ``base`` as ``x1.23``; over a base of 0: ``x1.00`` when ``value`` is 0 too, else ``over_zero``."""
    if base > 0:
        return f"x{value / base:.2f}"
    return "x1.00" if value == 0 else over_zero


def missed(world: dict) -> int:
    """Actions missed over the run: the UAVs' ``missed`` in world.json's per_uav, summed."""
    return sum(int(u.get("missed", 0)) for u in world.get("per_uav") or [] if isinstance(u, dict))


def tick_p99_ms(world: dict) -> float:
    """world.json's tick lateness p99 in ms (nan when absent)."""
    tl = world.get("tick_lateness_ms") or {}
    return float(tl.get("p99", float("nan"))) if isinstance(tl, dict) else float("nan")


def write_rows(path: Path | None, rows: list[dict]) -> None:
    """``--json FILE``: the rows as JSON (nothing without one)."""
    if path:
        path.write_text(json.dumps(rows, indent=1))
