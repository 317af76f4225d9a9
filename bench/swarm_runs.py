"""One swarm run of any checkout of this project, measured from outside: for old-versus-new comparisons.

``bench_swarm.py --sweep ... --compare DIR`` runs every configuration with this checkout's code and with
DIR's, alternated, through :func:`run_checkout`: ``truav-swarm up`` of that checkout (its own command line,
``PYTHONPATH`` set to it) in a subprocess, every process of the swarm sampled from /proc, the figures read
from the run's files that every version since 0cd7060 writes (``world.json``: ticks, deadline misses, tick
lateness; ``agent<i>.json``: beacon latency samples, messages received). So both sides are measured the
same way, whatever their benchmark code was.

The agents' CPU is also split by thread (main, other Python threads, Zenoh's rx/tx/app threads: what
:func:`thread_class` says) and printed per agent and tick, with each class's wake-ups (voluntary context
switches), to show where a one-process-per-agent swarm's cost goes. The ticking window (for rates and CPU) is the world's first to last tick when its stats say (8cffba7 on);
otherwise the last ``ticks / rate`` seconds the world lived (real time only).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import bench_common

CLK_TCK = os.sysconf("SC_CLK_TCK")
SAMPLE_S = 0.25
THREAD_CLASSES = ("main", "python", "zenoh-rx", "zenoh-tx", "zenoh-app", "zenoh-other")
"""Where an agent process's CPU goes, by thread: its main thread (decisions, draining beacons, publishing),
its other Python threads (receive pumps, health; Python 3.11 names no OS thread, so they show as the
interpreter), and Zenoh's runtime threads by their names (rx-N receive, tx-N send, app-N, the rest)."""


def thread_class(pid: int, tid: int, comm: str) -> str:
    """The :data:`THREAD_CLASSES` entry of thread ``tid`` (OS name ``comm``) of process ``pid``."""
    if tid == pid:
        return "main"
    for prefix, name in (("rx-", "zenoh-rx"), ("tx-", "zenoh-tx"), ("app-", "zenoh-app")):
        if comm.startswith(prefix):
            return name
    return "python" if comm.startswith("python") else "zenoh-other"


def agent_thread_cpu(pids: set[int]) -> dict[str, float]:
    """Cumulative CPU seconds of the agent processes ``pids``, by :func:`thread_class` (exited threads not
    counted: an agent's threads live as long as it does)."""
    return agent_thread_totals(pids)[0]


def agent_thread_totals(pids: set[int]) -> tuple[dict[str, float], dict[str, float]]:
    """Cumulative CPU seconds and wake-ups (voluntary context switches: each time a thread blocked and was
    woken again) of the agent processes ``pids``, by :func:`thread_class`."""
    cpu, wakes = dict.fromkeys(THREAD_CLASSES, 0.0), dict.fromkeys(THREAD_CLASSES, 0.0)
    for pid in pids:
        try:
            tids = os.listdir(f"/proc/{pid}/task")
        except OSError:
            continue
        for tid in tids:
            try:
                with open(f"/proc/{pid}/task/{tid}/stat") as f:
                    head, rest = f.read().rsplit(")", 1)
                with open(f"/proc/{pid}/task/{tid}/status") as f:
                    status = f.read()
            except OSError:
                continue
            fields = rest.split()
            cls = thread_class(pid, int(tid), head.split("(", 1)[1])
            cpu[cls] += (int(fields[11]) + int(fields[12])) / CLK_TCK
            wakes[cls] += _voluntary_switches(status)
    return cpu, wakes


def _voluntary_switches(status: str) -> int:
    """``voluntary_ctxt_switches`` of a /proc task status text (0 if absent)."""
    for line in status.splitlines():
        if line.startswith("voluntary_ctxt_switches:"):
            return int(line.split()[1])
    return 0


def cli_module(code: Path) -> str:
    """The module of ``truav-swarm`` in checkout ``code`` (it moved in the swarm package's history)."""
    if (code / "truav" / "cli" / "swarm.py").exists():
        return "truav.cli.swarm"
    # older checkouts (historical layouts, not this tree's): truav/swarm/cli.py, before it truav/swarm_cli.py
    return "truav.swarm.cli" if (code / "truav" / "swarm" / "cli.py").exists() else "truav.swarm_cli"


def accepts(code: Path, flag: str) -> bool:
    """Whether checkout ``code``'s `up` has ``flag`` (older ones had no --force-agents limit to lift, and
    flew TRUAV's agents without a --scheme)."""
    sources = [*(code / "truav" / "cli").glob("swarm*.py"), *(code / "truav" / "swarm").glob("cli*.py"),
               code / "truav" / "swarm_cli.py"]
    return any(p.exists() and f'"{flag}"' in p.read_text() for p in sources)


def label(code: Path) -> str:
    """A checkout's short commit (with ``+`` if its tree has changes)."""
    try:
        rev = subprocess.run(["git", "-C", str(code), "rev-parse", "--short", "HEAD"], capture_output=True,
                             text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(code), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True).stdout.strip()
        return rev + ("+" if dirty else "")
    except (OSError, subprocess.CalledProcessError):
        return code.name


def _role(cmdline: str) -> str:
    for role in ("agent", "world", "router", "recorder", "controller"):
        if f" {role}" in cmdline:
            return role
    return "supervisor"


class TreeSampler(bench_common.Poller):
    """Cumulative CPU seconds of every process under one pid, by role, sampled from /proc in a thread."""

    def __init__(self, root: int) -> None:
        self.root = root
        self.cpu: dict[int, tuple[str, float]] = {}  # pid -> (role, last cumulative CPU s)
        self.timeline: list[tuple[float, dict[str, float]]] = []  # (wall s, {role: cumulative CPU s})
        self.thread_timeline: list[tuple[float, dict[str, float]]] = []  # (wall s, agents' {thread class: CPU s})
        self.wake_timeline: list[tuple[float, dict[str, float]]] = []  # (wall s, agents' {thread class: wake-ups})
        self.world_alive: list[float] = []  # wall times the world process was seen
        self.agent_pids: set[int] = set()
        self._start_polling()

    def _children(self) -> list[int]:
        out, todo = [], [self.root]
        while todo:
            pid = todo.pop()
            out.append(pid)
            try:
                for tid in os.listdir(f"/proc/{pid}/task"):
                    with open(f"/proc/{pid}/task/{tid}/children") as f:
                        todo += [int(c) for c in f.read().split()]
            except OSError:
                pass
        return out

    def _loop(self) -> None:
        while not self._stop.is_set():
            now = time.time()
            for pid in self._children():
                try:
                    with open(f"/proc/{pid}/stat") as f:
                        fields = f.read().rsplit(")", 1)[1].split()
                    role = self.cpu[pid][0] if pid in self.cpu else _role(
                        " " + open(f"/proc/{pid}/cmdline").read().replace("\0", " "))
                except (OSError, IndexError):
                    continue
                self.cpu[pid] = (role, (int(fields[11]) + int(fields[12])) / CLK_TCK)
                if role == "world":
                    self.world_alive.append(now)
                if role == "agent":
                    self.agent_pids.add(pid)
            by_role: dict[str, float] = {}
            for role, cpu in self.cpu.values():
                by_role[role] = by_role.get(role, 0.0) + cpu
            self.timeline.append((now, by_role))
            cpu, wakes = agent_thread_totals(self.agent_pids)
            self.thread_timeline.append((now, cpu))
            self.wake_timeline.append((now, wakes))
            self._stop.wait(SAMPLE_S)

    def cores(self, t0: float, t1: float, timeline: list | None = None) -> dict[str, float]:
        """Mean cores per role (or, of ``thread_timeline``, per agent thread class) over [t0, t1] (from the
        samples nearest inside)."""
        inside = [(t, c) for t, c in (self.timeline if timeline is None else timeline) if t0 <= t <= t1]
        if len(inside) < 2 or inside[-1][0] <= inside[0][0]:
            return {}
        (ta, a), (tb, b) = inside[0], inside[-1]
        return {role: (b.get(role, 0.0) - a.get(role, 0.0)) / (tb - ta) for role in b}


def run_checkout(code: Path, agents: int, rate: float, ticks: int, lockstep: bool, extra: list[str],
                 timeout_s: float = 1800.0) -> dict:
    """``truav-swarm up`` of checkout ``code`` once; its figures (see the module docstring)."""
    out = Path(tempfile.mkdtemp(prefix="truav-bench-cmp-"))
    if agents > 50 and accepts(code, "--force-agents"):
        extra = [*extra, "--force-agents"]  # a benchmark may go past the interactive limit
    if accepts(code, "--scheme"):
        extra = ["--scheme", "truav", *extra]  # TRUAV's agents, whatever the checkout's demo flies by default
    cmd = [sys.executable, "-c", f"import sys; from {cli_module(code)} import main; sys.exit(main())", "up",
           "--agents", str(agents), "--episodes", "1", "--steps", str(ticks), "--rate", f"{rate:g}",
           "--out", str(out / "run"), "--quiet", "--no-plot", *(["--lockstep"] if lockstep else []), *extra]
    env = dict(os.environ, PYTHONPATH=str(code))
    load0 = os.getloadavg()[0]
    started = time.time()
    with open(out / "up.log", "w") as log:
        proc = subprocess.Popen(cmd, cwd=code, env=env, stdout=log, stderr=subprocess.STDOUT,
                                start_new_session=True)
        sampler = TreeSampler(proc.pid)
        try:
            code_rc = proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, 9)
            code_rc = proc.wait()
        finally:
            sampler.stop()
    wall = time.time() - started
    run = out / "run"
    try:
        world = json.loads((run / "world.json").read_text())
    except (OSError, ValueError):
        tail = (out / "up.log").read_text()[-2000:]
        shutil.rmtree(out, ignore_errors=True)
        raise RuntimeError(f"{label(code)}: no world.json (exit {code_rc}); log tail:\n{tail}")
    n_ticks = int(world.get("ticks", ticks))
    t0, t1 = world.get("first_tick_wall_s"), world.get("last_tick_wall_s")
    if not (t0 and t1) and sampler.world_alive and not lockstep:
        t1 = max(sampler.world_alive)
        t0 = t1 - n_ticks / rate
    ticking = (t1 - t0) if t0 and t1 else float("nan")
    lat, received, by_beacon = [], 0, {}
    for i in range(agents):
        try:
            stats = json.loads((run / f"agent{i}.json").read_text())
        except (OSError, ValueError):
            continue
        samples = stats.get("beacon_latency_samples_ms", [])
        lat += samples
        for sender_tick, ms in zip(stats.get("beacon_latency_from", []), samples):
            by_beacon.setdefault(tuple(sender_tick), []).append(ms)
        received += stats.get("bus", {}).get("received", 0)
    first = np.array([min(v) for v in by_beacon.values()] or [np.nan])
    last = np.array([max(v) for v in by_beacon.values()] or [np.nan])
    cores = sampler.cores(t0, t1) if t0 and t1 else {}
    threads = sampler.cores(t0, t1, sampler.thread_timeline) if t0 and t1 else {}
    wakes = sampler.cores(t0, t1, sampler.wake_timeline) if t0 and t1 else {}  # wake-ups per second
    tick_rate = n_ticks / ticking if ticking > 0 else float("nan")
    msgs_per_s = received / ticking if ticking > 0 else float("nan")
    total = sum(cores.values()) if cores else float("nan")
    agent_cores = cores.get("agent", float("nan"))
    lat_a = np.array(lat) if lat else np.array([np.nan])
    tl = world.get("tick_lateness_ms") or {}
    if isinstance(tl, list):  # older worlds wrote the samples
        tl = {"p99": float(np.percentile(tl, 99))} if tl else {}
    misses = int(world.get("deadline_misses", 0))
    shutil.rmtree(out, ignore_errors=True)
    return {
        "code": label(code), "agents": agents, "mode": "lockstep" if lockstep else "realtime", "rate_hz": rate,
        "ticks": n_ticks, "exit_code": code_rc, "wall_s": wall, "load_before": load0,
        "load_after": os.getloadavg()[0], "ticking_s": ticking,
        "ticks_per_s": n_ticks / ticking if ticking > 0 else float("nan"),
        "realtime_factor": n_ticks / ticking / rate if ticking > 0 else float("nan"),
        "missed": misses, "missed_pct": 100 * misses / max(agents * ticks, 1),
        "tick_p99": tl.get("p99", float("nan")) if isinstance(tl, dict) else float("nan"),
        "beacon_p50": float(np.nanpercentile(lat_a, 50)), "beacon_p99": float(np.nanpercentile(lat_a, 99)),
        "first_receiver_p50": float(np.nanpercentile(first, 50)), "first_receiver_p99": float(np.nanpercentile(first, 99)),
        "last_receiver_p50": float(np.nanpercentile(last, 50)), "last_receiver_p99": float(np.nanpercentile(last, 99)),
        "msgs_per_s": msgs_per_s, "cpu_cores_total": total, "cpu_cores": cores,
        "agent_processes": len(sampler.agent_pids),
        "cpu_pct_per_agent": 100 * agent_cores / agents,
        "cpu_us_per_msg": 1e6 * total / msgs_per_s if msgs_per_s > 0 else float("nan"),
        "agent_cpu_us_per_msg": 1e6 * agent_cores / msgs_per_s if msgs_per_s > 0 else float("nan"),
        "agent_us_per_tick_by_thread": {k: round(1e6 * v / agents / tick_rate, 1) for k, v in threads.items()}
        if tick_rate > 0 else {},
        "agent_wakes_per_tick_by_thread": {k: round(v / agents / tick_rate, 2) for k, v in wakes.items()}
        if tick_rate > 0 else {},
    }


def wait_for_quiet(max_load: float, limit_s: float) -> float:
    """Wait (printing) until the 1-minute load average is below ``max_load``, at most ``limit_s``; the load."""
    deadline = time.monotonic() + limit_s
    load = os.getloadavg()[0]
    if load >= max_load:
        print(f"waiting for the load average ({load:.2f}) to fall below {max_load:g} ...", flush=True)
    while load >= max_load and time.monotonic() < deadline:
        time.sleep(5)
        load = os.getloadavg()[0]
    if load >= max_load:
        print(f"load still {load:.2f} after {limit_s:.0f} s: running anyway (the row says so)", flush=True)
    return load
