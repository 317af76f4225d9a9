"""One ``truav-swarm up`` of a scheme under ``--preset paper`` with 1.5 km sensing, its agent processes
sampled from /proc: what bench_policy_memory.py and bench_policy_realtime.py share.

A scheme is ``truav`` (the Q-learning agents, ``--scheme truav``) or the name of an agent class (``ppo``,
``spread``: flown with ``--agent NAME``). The agent processes are the run's ``pids.json`` entries named
``agent<i>`` (one UAV) or ``agents<a>-<b>`` (several, ``--agents-per-process``), read again at each sample
(a restarted agent has a new pid). Memory per process: RSS, its peak (``VmHWM``), PSS (each shared page
divided among the processes that map it: the sum over processes is what they take together) and USS (the
pages only it maps: what stopping it would free), from ``/proc/<pid>/smaps_rollup``; CPU from
``/proc/<pid>/stat``.
"""

from __future__ import annotations

import json
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import bench_common

ROOT = Path(__file__).resolve().parents[1]
SENSE_RANGE_M = 1500  # the sensing the shipped `ppo` weights were trained with (docs/results/learned-policy.md)
MAX_PROCESSES = 50  # up's limit without --force-agents
MEMORY_KEYS = ("rss_kb", "hwm_kb", "pss_kb", "uss_kb")


def run_name(scheme: str) -> str:
    """The swarm's run name for ``scheme``: a class path (``pkg.mod:Class``) has characters a run name may not."""
    return "bench-" + re.sub(r"[^A-Za-z0-9_-]", "-", scheme)[-58:]


def scheme_args(scheme: str) -> list[str]:
    """``up``'s flags that fly ``scheme``: ``--scheme truav`` (the Q-learning agents), else ``--agent NAME``."""
    return ["--scheme", "truav"] if scheme == "truav" else ["--agent", scheme]


def flown_as(scheme: str) -> str:
    """The scheme the run's summary.json names when it flew ``scheme``."""
    return "truav" if scheme == "truav" else f"agent:{scheme}"


def add_speed_option(ap) -> None:
    """--speed, the scenario's UAV speed (ppo-disc flies its own network below 10 m/s, ppo-claim's from it)."""
    ap.add_argument("--speed", type=float, metavar="M/S", help="UAV speed, m/s (default: the paper preset's)")


def write_scenario(path: Path, speed: float | None = None) -> Path:
    """``truav config show --preset paper --set learner.sense_range_m=1500`` (and the UAV ``speed``) into ``path``."""
    sets = [f"learner.sense_range_m={SENSE_RANGE_M}", *([f"scenario.uav_speed_mps={speed:g}"] if speed else [])]
    text = subprocess.run([sys.executable, "-m", "truav.cli", "config", "show", "--preset", "paper",
                           *(a for s in sets for a in ("--set", s))], cwd=ROOT, capture_output=True, text=True,
                          check=True).stdout
    path.write_text(text)
    return path


def memory_kb(pid: int) -> dict[str, int] | None:
    """:data:`MEMORY_KEYS` of process ``pid`` in kB (None once it is gone)."""
    try:
        rollup = Path(f"/proc/{pid}/smaps_rollup").read_text()
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return None
    fields: dict[str, int] = {}
    for text in (rollup, status):
        for row in text.splitlines():
            parts = row.split()
            if len(parts) >= 2 and parts[0].endswith(":") and parts[1].isdigit():
                fields[parts[0][:-1]] = int(parts[1])
    # VmHWM comes from the kernel's lazily synced per-thread counters, Rss from a walk of the page tables: the
    # peak can read a few pages below the Rss of the same moment, and a peak is at least what is resident now
    peak = max(fields.get("VmHWM", 0), fields.get("Rss", 0))
    return {"rss_kb": fields.get("Rss", 0), "hwm_kb": peak, "pss_kb": fields.get("Pss", 0),
            "uss_kb": fields.get("Private_Clean", 0) + fields.get("Private_Dirty", 0)}


def uavs_of(name: str) -> int:
    """How many UAVs the process named ``name`` in pids.json hosts (0: not an agent process)."""
    if name.startswith("agents"):
        ids = name[len("agents"):]
        if "-" in ids:
            a, b = ids.split("-", 1)
            return int(b) - int(a) + 1
        return len(ids.split(","))
    return 1 if name.startswith("agent") and name[len("agent"):].isdigit() else 0


class AgentSampler(bench_common.Poller):
    """A thread sampling the run's agent processes (and its world) every ``period_s`` from /proc."""

    def __init__(self, out: Path, period_s: float) -> None:
        self.out, self.period_s = out, period_s
        self.peak: dict[str, dict[str, int]] = {}  # process name -> the largest of each memory key seen
        self.uavs: dict[str, int] = {}  # agent process name -> UAVs it hosts
        self.pids: dict[str, set[int]] = {}  # process name -> every pid it had
        self.totals: list[tuple[int, int]] = []  # per sample: (agent processes read, the sum of their PSS kB)
        self.cpu: list[tuple[float, float]] = []  # (wall s, the agent processes' cumulative CPU s)
        self._cpu_last: dict[int, float] = {}  # pid -> its last cumulative CPU s (kept after it exits)
        self._start_polling()

    def _loop(self) -> None:
        while not self._stop.is_set():
            self.sample()
            self._stop.wait(self.period_s)

    def sample(self) -> None:
        try:
            names = json.loads((self.out / "pids.json").read_text())
        except (OSError, ValueError):
            return
        now, total, read = time.time(), 0, 0
        for name, pid in names.items():
            n = uavs_of(name)
            if not (n or name == "world") or not isinstance(pid, int):
                continue
            mem = memory_kb(pid)
            if mem is None:
                continue
            self.pids.setdefault(name, set()).add(pid)
            peak = self.peak.setdefault(name, dict.fromkeys(MEMORY_KEYS, 0))
            for k in MEMORY_KEYS:
                peak[k] = max(peak[k], mem[k])
            if n:
                self.uavs[name] = n
                total, read = total + mem["pss_kb"], read + 1
                cpu = bench_common.cpu_s(pid)
                if cpu is not None:
                    self._cpu_last[pid] = cpu
        self.totals.append((read, total))
        self.cpu.append((now, sum(self._cpu_last.values())))

    def total_pss_kb(self, processes: int) -> float:
        """The largest sum of the agent processes' PSS over the samples that read all ``processes`` of them
        (NaN if none did)."""
        return float(max((t for n, t in self.totals if n == processes), default=float("nan")))

    def agent_cores(self, t0: float, t1: float) -> float:
        """The agent processes' mean cores over [t0, t1] (the samples nearest inside; NaN without two)."""
        inside = [(t, c) for t, c in self.cpu if t0 <= t <= t1]
        if len(inside) < 2 or inside[-1][0] <= inside[0][0]:
            return float("nan")
        return (inside[-1][1] - inside[0][1]) / (inside[-1][0] - inside[0][0])


def fly(scheme: str, scenario: Path, agents: int, ticks: int, *, per_process: int = 1, lockstep: bool = False,
        rate: float = 10.0, period_s: float = 1.0,
        timeout_s: float = 1800.0) -> tuple[dict, AgentSampler, int, str]:
    """``truav-swarm up`` of ``scheme`` for one episode of ``ticks`` ticks, sampled: (world.json, the sampler,
    exit code, the last lines of its output when it did not exit 0: why). Raises RuntimeError (with the log's
    end) when the run wrote no world.json, or its summary names another scheme than ``scheme``."""
    tmp = Path(tempfile.mkdtemp(prefix="truav-bench-policy-"))
    out = tmp / "run"
    processes = -(-agents // per_process)
    cmd = [sys.executable, "-m", "truav.cli.swarm", "up", "--run", run_name(scheme), "--scenario", str(scenario),
           *scheme_args(scheme), "--agents", str(agents), "--episodes", "1", "--steps", str(ticks),
           "--out", str(out), "--quiet", "--no-plot", "--no-references", "--max-missed", "1",
           *(["--agents-per-process", str(per_process)] if per_process > 1 else []),
           *(["--force-agents"] if processes > MAX_PROCESSES else []),
           *(["--lockstep"] if lockstep else ["--rate", f"{rate:g}"])]
    with open(tmp / "up.log", "wb") as log:
        up = subprocess.Popen(cmd, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    sampler = AgentSampler(out, period_s)
    try:
        code = up.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        code = -1
    finally:
        sampler.stop()
        bench_common.stop_group(up, signal.SIGINT, 30)
    try:
        world = json.loads((out / "world.json").read_text())
        flown = json.loads((out / "summary.json").read_text()).get("scheme")
    except (OSError, ValueError):
        tail = (tmp / "up.log").read_text(errors="replace")[-2000:]
        shutil.rmtree(tmp, ignore_errors=True)
        raise RuntimeError(f"{scheme}: the swarm wrote no world.json or summary.json (exit {code}); its log "
                           f"ends:\n{tail}") from None
    lines = [ln for ln in (tmp / "up.log").read_text(errors="replace").splitlines() if ln.strip()]
    why = " | ".join(lines[-3:]) if code != 0 else ""
    shutil.rmtree(tmp, ignore_errors=True)
    if flown != flown_as(scheme):
        raise RuntimeError(f"{scheme}: the swarm flew {flown!r}, not {flown_as(scheme)!r}")
    return world, sampler, code, why


def missed_pct(world: dict, agents: int) -> float:
    """The share of actions missed (UAVs x ticks with no action in time: per_uav's ``missed``), in %."""
    return 100.0 * bench_common.missed(world) / max(agents * int(world.get("ticks", 0)), 1)
