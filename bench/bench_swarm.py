"""Real-time swarm benchmark: router + world + N agent processes at a tick rate.

    python bench/bench_swarm.py                  # 20 agents, 10 Hz, 200 ticks
    python bench/bench_swarm.py --agents 5 --ticks 100
    python bench/bench_swarm.py --repeat 3       # the run-to-run spread
    python bench/bench_swarm.py --secure         # plain and --secure (mutual TLS + ACL) in turn: the cost of TLS
    python bench/bench_swarm.py --sweep 5,10,20,50,100 --modes realtime,lockstep --variants base,hz1,cells,k10
                                                 # the scale table: every N x mode x variant, CSV + JSON + plot
    python bench/bench_swarm.py --sweep 20,50 --modes realtime --compare ../old-checkout --repeat 2 --max-load 1
                                                 # this code against another checkout's, runs alternated, each
                                                 # after the load average fell below 1; ratios printed at the end

A sweep writes runs/bench-swarm/sweep.csv, sweep.json and sweep.png (``--sweep-out``), one row per
run: tick lateness, beacon latency (all receptions, first and last receiver of each beacon),
missed actions, messages delivered per second, CPU and peak memory per agent (sampled from /proc
over the ticking window), lock-step ticks/s and real-time factor (ticks/s over --rate), and the
load average before and after (the reference machine is shared: read the numbers beside it).
Variants (joined with '+'): base (all-to-all, every tick, one process per agent), hz1 (beacons at
1 Hz, the Remote ID rate), cells (range-limited beacons, 500 m cells), k<K> (K agents per
process), shared (with k<K>: one beacon subscription per process), batch (with k<K>: one beacon
message per process and tick), slots<N> (beacons in N send slots per tick).  Real-time-only options
are skipped in lock-step.

With ``--compare DIR[,DIR...]`` every run goes through bench/swarm_runs.py: ``truav-swarm up`` of
this checkout and of each DIR (another checkout, e.g. a ``git worktree`` of an older commit) in
turn, measured the same way from outside; rows carry the code's commit and the end prints, per
configuration, the median of each figure per code and the ratio of this code's to the other's.

Prints world tick lateness p50/p99 (target p99 < 20 ms), one-way beacon
latency p50/p99 over every beacon every agent heard (target p99 < 5 ms),
missed actions, and the control-plane traffic measured on the bus.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import sys
import tempfile
import threading
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from truav.config import Config  # noqa: E402
from truav.swarm.supervisor import SwarmOptions, run_swarm  # noqa: E402
from truav import jsonio  # noqa: E402
from truav.csvio import row_cells  # noqa: E402
import swarm_runs  # noqa: E402


def _cpu_s() -> float:
    """CPU seconds of this process and of its reaped children (router, world, agents)."""
    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


CLK_TCK = os.sysconf("SC_CLK_TCK")
SAMPLE_S = 0.25
PSS_EVERY = 8
"""Proportional set size (shared pages split among their users) every this many samples: it costs a
page-table walk per process, RSS (which counts each shared library once per process) every sample."""
CELL_M = 500.0
"""The variant `cells`: map cells of this side (10 x 10 over the 5 km city)."""


class ProcSampler:
    """CPU seconds and memory of every process in a swarm's pids.json, sampled from /proc in a thread."""

    def __init__(self, pid_file: Path) -> None:
        self.pid_file = pid_file
        self.samples: list[dict[str, tuple[float, float]]] = []  # {name: (wall s when read, cumulative CPU s)}
        self.rss_kb: dict[str, int] = {}  # peak per process name
        self.pss_kb: dict[str, int] = {}  # peak per process name
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="proc-sampler", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join()

    def _loop(self) -> None:
        n = 0
        while not self._stop.wait(SAMPLE_S):
            try:
                pids = json.loads(self.pid_file.read_text())
            except (OSError, ValueError):
                continue
            pids["supervisor"] = os.getpid()
            cpu = {}
            for name, pid in pids.items():
                try:
                    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
                    # Each read is timed on its own: on a loaded machine one pass over 100 processes takes a while.
                    cpu[name] = (time.time(), (int(fields[11]) + int(fields[12])) / CLK_TCK)
                    self.rss_kb[name] = max(self.rss_kb.get(name, 0), _proc_kb(f"/proc/{pid}/status", "VmRSS:"))
                    if n % PSS_EVERY == 0 or name not in self.pss_kb:
                        self.pss_kb[name] = max(self.pss_kb.get(name, 0), _proc_kb(f"/proc/{pid}/smaps_rollup", "Pss:"))
                except (OSError, IndexError, ValueError):
                    continue
            self.samples.append(cpu)
            n += 1

    def cpu_rates(self, t0: float, t1: float) -> dict[str, float]:
        """Mean CPU (cores) of each process between its first reading after t0 and its last before t1."""
        out = {}
        for name in {n for s in self.samples for n in s}:
            inside = [s[name] for s in self.samples if name in s and t0 <= s[name][0] <= t1]
            if len(inside) >= 2 and inside[-1][0] > inside[0][0]:
                (ta, ca), (tb, cb) = inside[0], inside[-1]
                out[name] = (cb - ca) / (tb - ta)
        return out


def _proc_kb(path: str, field: str) -> int:
    for line in Path(path).read_text().splitlines():
        if line.startswith(field):
            return int(line.split()[1])
    return 0


def variant_options(variant: str, rate: float, lockstep: bool) -> dict:
    """SwarmOptions of a variant (see the module docstring); real-time-only parts are dropped in lock-step."""
    opts: dict = {}
    for part in variant.split("+"):
        if part == "base":
            continue
        if part == "hz1":
            opts["beacon_every"] = int(round(rate))
        elif part.startswith("cells"):
            opts["beacon_cell_m"] = float(part[5:] or CELL_M)
        elif part == "shared":
            opts["share_beacons"] = True
        elif part == "batch":
            opts["batch_beacons"] = True
        elif part.startswith("slots") and part[5:].isdigit():
            opts["beacon_slots"] = int(part[5:])
        elif part[:1] == "k" and part[1:].isdigit():
            opts["agents_per_process"] = int(part[1:])
        else:
            raise SystemExit(f"bench_swarm: error: --variants: unknown part {part!r} (base, hz1, cells[M], k<K>, shared, "
                             f"batch, slots<N>)")
    if lockstep:
        for real_time_only in ("beacon_every", "beacon_cell_m", "beacon_slots"):
            opts.pop(real_time_only, None)
    return opts


UP_FLAGS = {"beacon_every": "--beacon-every", "beacon_cell_m": "--beacon-cell", "share_beacons": "--share-beacons",
            "batch_beacons": "--batch-beacons", "agents_per_process": "--agents-per-process",
            "beacon_slots": "--beacon-slots"}


def up_flags(opts: dict) -> list[str]:
    """The `truav-swarm up` flags of a variant's options (for --compare, which runs the command line)."""
    out: list[str] = []
    for name, value in opts.items():
        out += [UP_FLAGS[name]] if value is True else [UP_FLAGS[name], f"{value:g}" if isinstance(value, float)
                                                       else str(value)]
    return out


def realtime_only(variant: str) -> bool:
    return any(p == "hz1" or p.startswith("cells") or p.startswith("slots") for p in variant.split("+"))


def window_figures(out: Path, world: dict, agents: int, sampler: ProcSampler, started_wall_s: float) -> dict:
    """Rates over the ticking window (tick 0 to the last tick): ticks/s, messages/s, CPU and memory."""
    t0, t1 = world.get("first_tick_wall_s"), world.get("last_tick_wall_s")
    ticking = (t1 - t0) if t0 and t1 else float("nan")
    received = 0
    for i in range(agents):
        try:
            received += json.loads((out / f"agent{i}.json").read_text())["bus"]["received"]
        except (OSError, ValueError, KeyError):
            pass
    received += world.get("actions_received", 0)
    rates = sampler.cpu_rates(t0, t1) if t0 and t1 else {}
    agent_names = [n for n in sampler.rss_kb if n.startswith("agent")]
    agent_cpu = sum(v for n, v in rates.items() if n.startswith("agent"))
    total = sum(rates.values())
    msgs = received / ticking if ticking > 0 else float("nan")
    ticks_per_s = world["ticks"] / ticking if ticking > 0 else float("nan")
    return {"ticking_s": ticking, "startup_s": (t0 - started_wall_s) if t0 else float("nan"),
            "ticks_per_s": ticks_per_s, "msgs_per_s": msgs, "msgs_received": received,
            "agent_processes": len(agent_names),
            "cpu_pct_per_agent": 100 * agent_cpu / agents if rates else float("nan"),
            "cpu_cores_total": total if rates else float("nan"),
            "cpu_cores": {n: round(v, 4) for n, v in rates.items()},
            "cpu_us_per_msg": 1e6 * total / msgs if rates and msgs > 0 else float("nan"),
            "agent_cpu_us_per_msg": 1e6 * agent_cpu / msgs if rates and msgs > 0 else float("nan"),
            "rss_mb_per_agent": sum(sampler.rss_kb[n] for n in agent_names) / 1024 / agents,
            "pss_mb_per_agent": sum(sampler.pss_kb.get(n, 0) for n in agent_names) / 1024 / agents}


def run_once(agents: int, rate: float, ticks: int, secure: bool = False, lockstep: bool = False,
             variant: str = "base", keep: bool = True) -> dict:
    """One swarm run; prints its figures and returns the headline ones."""
    cfg = Config().replace(scenario={"n_uavs": agents, "steps_per_episode": ticks})
    out = Path(tempfile.mkdtemp(prefix="truav-bench-swarm-"))
    load0 = os.getloadavg()
    sampler = ProcSampler(out / "pids.json")
    sampler.start()
    t0, cpu0, started = time.perf_counter(), _cpu_s(), time.time()
    try:
        code = run_swarm(cfg, SwarmOptions(run="bench", episodes=1, rate_hz=rate, out=str(out), plot=False,
                                           quiet=True, wait_agents_s=300.0, secure=secure, lockstep=lockstep,
                                           **variant_options(variant, rate, lockstep)))
    finally:
        sampler.stop()
    wall, cpu = time.perf_counter() - t0, _cpu_s() - cpu0
    load1 = os.getloadavg()
    world = json.loads((out / "world.json").read_text())
    samples, by_beacon = [], defaultdict(list)
    for i in range(agents):
        try:
            stats = json.loads((out / f"agent{i}.json").read_text())
        except (OSError, ValueError):
            print(f"agent {i}: no statistics")
            continue
        samples += stats["beacon_latency_samples_ms"]
        for (sender, tick), ms in zip(stats["beacon_latency_from"], stats["beacon_latency_samples_ms"]):
            by_beacon[sender, tick].append(ms)
    lat = np.array(samples)
    tl = world.get("tick_lateness_ms")
    cp = json.loads((out / "summary.json").read_text())["control_plane"]
    tl = tl or {"p50": float("nan"), "p99": float("nan"), "max": float("nan")}  # lock-step: no schedule to be late on
    result = {"tick_p50": tl["p50"], "tick_p99": tl["p99"], "beacon_p50": float("nan"), "beacon_p99": float("nan"),
              "first_receiver_p50": float("nan"), "first_receiver_p99": float("nan"),
              "last_receiver_p50": float("nan"), "last_receiver_p99": float("nan"), "cpu_s": cpu}
    mode = "lock-step" if lockstep else f"{rate:g} Hz"
    print(f"\n{agents} agents, {mode}, variant {variant}{' --secure (mutual TLS + ACL)' if secure else ''}, "
          f"{world['ticks']} ticks, {wall:.1f} s wall (incl. start-up), {cpu:.1f} CPU-s over every process, "
          f"load {load0[0]:.2f} -> {load1[0]:.2f}, exit {code}")
    print(f"tick lateness:  p50 {tl['p50']:6.2f} ms   p99 {tl['p99']:6.2f} ms   max {tl['max']:6.2f} ms"
          f"   (target p99 < 20 ms: x{20 / max(tl['p99'], 1e-9):.1f} headroom)")
    if lat.size:
        p50, p99 = np.percentile(lat, 50), np.percentile(lat, 99)
        print(f"beacon latency: p50 {p50:6.2f} ms   p99 {p99:6.2f} ms   over {lat.size} receptions"
              f"   (target p99 < 5 ms: {'met' if p99 < 5 else 'missed'}, x{5 / max(p99, 1e-9):.2f})")
        first = np.array([min(v) for v in by_beacon.values()])
        last = np.array([max(v) for v in by_beacon.values()])
        print(f"  per beacon:   first receiver p50 {np.percentile(first, 50):5.2f} ms, last receiver p50 "
              f"{np.percentile(last, 50):5.2f} ms over {len(by_beacon)} beacons (the fan-out's own spread)")
        result.update(beacon_p50=float(p50), beacon_p99=float(p99),
                      first_receiver_p50=float(np.percentile(first, 50)),
                      first_receiver_p99=float(np.percentile(first, 99)),
                      last_receiver_p50=float(np.percentile(last, 50)), last_receiver_p99=float(np.percentile(last, 99)))
    n_act = agents * ticks
    print(f"missed actions: {world['deadline_misses']} of {n_act} ({100 * world['deadline_misses'] / n_act:.2f}%)")
    result.update(window_figures(out, world, agents, sampler, started))
    result["realtime_factor"] = result["ticks_per_s"] / rate
    result.update(agents=agents, mode="lockstep" if lockstep else "realtime", variant=variant, rate_hz=rate,
                  ticks=world["ticks"], exit_code=code, wall_s=wall, load_before=load0[0], load_after=load1[0],
                  missed=world["deadline_misses"], missed_pct=100 * world["deadline_misses"] / n_act,
                  beacons_per_s_per_uav=cp.get("beacons_per_s_per_uav", float("nan")))
    print(f"ticking {result['ticking_s']:.1f} s: {result['ticks_per_s']:.1f} ticks/s (x{result['realtime_factor']:.2f}"
          f" of {rate:g} Hz); {result['msgs_per_s']:,.0f} messages/s delivered; per agent "
          f"{result['cpu_pct_per_agent']:.1f}% CPU, {result['rss_mb_per_agent']:.0f} MB; all processes "
          f"{result['cpu_cores_total']:.2f} cores, {result['cpu_us_per_msg']:.0f} us CPU per delivered message "
          f"({result['agent_cpu_us_per_msg']:.0f} us in the agent processes)")
    print(f"control plane: {cp['bytes_per_beacon']:.0f} B/beacon, {cp['beacons_per_s_per_uav']:.1f} beacons/s/UAV, "
          f"{cp['beacon_bytes_per_s_total'] / 1e3:.1f} kB/s total")
    if keep:
        print(f"(details in {out})")
    else:  # a sweep's runs hold ~2 MB of checkpoints per agent: the figures are in its JSON
        shutil.rmtree(out, ignore_errors=True)
    return result


SWEEP_FIELDS = ["code", "agents", "mode", "variant", "rate_hz", "ticks", "exit_code", "load_before", "load_after",
                "wall_s", "startup_s", "ticking_s", "ticks_per_s", "realtime_factor", "tick_p50", "tick_p99",
                "beacon_p50", "beacon_p99", "first_receiver_p50", "first_receiver_p99", "last_receiver_p50",
                "last_receiver_p99", "missed", "missed_pct", "beacons_per_s_per_uav", "msgs_per_s",
                "agent_processes", "cpu_pct_per_agent", "cpu_cores_total", "cpu_us_per_msg", "agent_cpu_us_per_msg",
                "rss_mb_per_agent", "pss_mb_per_agent"]
MEM_PER_AGENT_PROCESS_MB = 120
"""Refuse a run whose agent processes would not fit in the memory available (with this much each)."""


def sweep(args) -> None:
    sizes = [int(x) for x in args.sweep.split(",")]
    modes, variants = args.modes.split(","), args.variants.split(",")
    for m in modes:
        if m not in ("realtime", "lockstep"):
            raise SystemExit(f"bench_swarm: error: --modes: {m!r} is not realtime or lockstep")
    out = Path(args.sweep_out)
    out.mkdir(parents=True, exist_ok=True)
    rows_path = out / "sweep.json"
    rows = json.loads(rows_path.read_text()) if args.append and rows_path.exists() else []
    codes = [Path(__file__).resolve().parent.parent] + [Path(d).resolve() for d in args.compare.split(",")] \
        if args.compare else []
    for _ in range(args.repeat):
        for n in sizes:
            for mode in modes:
                for variant in variants:
                    if mode == "lockstep" and realtime_only(variant):
                        continue
                    per_proc = variant_options(variant, args.rate, False).get("agents_per_process", 1)
                    need = -(-n // per_proc) * MEM_PER_AGENT_PROCESS_MB
                    avail = _proc_kb("/proc/meminfo", "MemAvailable:") / 1024
                    if need > avail:
                        print(f"skip {n} agents {mode} {variant}: ~{need:.0f} MB needed, {avail:.0f} MB available")
                        continue
                    ticks = args.lockstep_ticks if mode == "lockstep" and args.lockstep_ticks else args.ticks
                    for code in codes or [None]:
                        load = swarm_runs.wait_for_quiet(args.max_load, args.load_wait) if args.max_load else None
                        if code is None:
                            r = run_once(n, args.rate, ticks, lockstep=mode == "lockstep", variant=variant,
                                         keep=args.keep_runs)
                        else:
                            r = compared_run(code, n, args.rate, ticks, mode, variant)
                            if r is None:
                                continue
                        if load is not None:
                            r["load_before"] = load
                        rows.append(r)
                        rows_path.write_text(jsonio.dumps(rows, indent=1))
                        write_csv(out / "sweep.csv", rows)
    print(f"\n{len(rows)} runs in {out}/sweep.csv and sweep.json")
    print(table(rows))
    if codes:
        print(ratios(rows, swarm_runs.label(codes[0])))
    fit = cost_fit(rows)
    if fit:
        print(fit)
    print(f"plot: {plot(rows, out / 'sweep.png')}")


def compared_run(code: Path, n: int, rate: float, ticks: int, mode: str, variant: str) -> dict | None:
    """One run of checkout ``code`` through the command line (bench/swarm_runs.py); None if it failed."""
    try:
        r = swarm_runs.run_checkout(code, n, rate, ticks, mode == "lockstep",
                                    up_flags(variant_options(variant, rate, mode == "lockstep")))
    except RuntimeError as exc:
        print(f"skip: {n} agents {mode} {variant} with {code}: {exc}")
        return None
    r["variant"] = variant
    print(f"{r['code']:>9s} {n:4d} agents {mode:8s} {variant:12s} load {r['load_before']:.2f}: missed "
          f"{r['missed_pct']:.2f}%, beacon p99 {r['beacon_p99']:.1f} ms, {r['msgs_per_s']:,.0f} msgs/s, "
          f"{r['cpu_cores_total']:.2f} cores, {r['cpu_us_per_msg']:.1f} us/msg (agents {r['agent_cpu_us_per_msg']:.1f}), "
          f"x{r['realtime_factor']:.2f} real time, exit {r['exit_code']}", flush=True)
    by_thread = r.get("agent_us_per_tick_by_thread") or {}
    if by_thread:
        print("          agent CPU per agent and tick, by thread: " + ", ".join(
            f"{k} {v:.0f} us" for k, v in by_thread.items()) + f" (all {sum(by_thread.values()):.0f} us)", flush=True)
    wakes = r.get("agent_wakes_per_tick_by_thread") or {}
    if wakes:
        print("          wake-ups per agent and tick, by thread: " + ", ".join(
            f"{k} {v:.1f}" for k, v in wakes.items()), flush=True)
    return r


RATIO_FIELDS = (("missed_pct", "missed %"), ("beacon_p99", "beacon p99 ms"), ("cpu_us_per_msg", "us CPU/msg"),
                ("agent_cpu_us_per_msg", "agent us/msg"), ("cpu_cores_total", "cores"),
                ("realtime_factor", "x real time"))


def ratios(rows: list[dict], this: str) -> str:
    """Per configuration: the median of each figure per code, and this code's over each other's."""
    lines = ["| N | mode | variant | code | runs | " + " | ".join(t for _, t in RATIO_FIELDS) + " |",
             "|" + "---|" * (5 + len(RATIO_FIELDS))]
    configs = sorted({(r["agents"], r["mode"], r["variant"]) for r in rows if "code" in r})
    for cfg in configs:
        by_code: dict[str, list[dict]] = {}
        for r in rows:
            if "code" in r and (r["agents"], r["mode"], r["variant"]) == cfg:
                by_code.setdefault(r["code"], []).append(r)
        med = {c: {k: float(np.median([r[k] for r in rs])) for k, _ in RATIO_FIELDS} for c, rs in by_code.items()}
        for c, rs in by_code.items():
            lines.append(f"| {cfg[0]} | {cfg[1]} | {cfg[2]} | {c} | {len(rs)} | "
                         + " | ".join(_f(med[c][k], 2) for k, _ in RATIO_FIELDS) + " |")
        for c in by_code:
            if c != this and this in med:
                lines.append(f"| {cfg[0]} | {cfg[1]} | {cfg[2]} | {this} / {c} | | " + " | ".join(
                    f"x{med[this][k] / med[c][k]:.2f}" if med[c][k] else "-" for k, _ in RATIO_FIELDS) + " |")
    return "\n".join(lines)


def write_csv(path: Path, rows: list[dict]) -> None:
    import csv
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=SWEEP_FIELDS, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow(row_cells({k: (round(v, 4) if isinstance(v, float) else v) for k, v in r.items()}))


def table(rows: list[dict]) -> str:
    """The scale table (markdown): one line per run."""
    head = ("| N | mode | variant | load | tick p99 ms | beacon p99 ms | first / last rcv p50 ms | missed % "
            "| msgs/s | CPU %/agent | MB/agent (PSS) | ticks/s | x real time |")
    lines = [head, "|" + "---|" * head.count("|")[:-1] if False else "|" + "---|" * (head.count("|") - 1)]
    nan = float("nan")
    for r in rows:
        rt = r["mode"] == "realtime"
        g = lambda k: r.get(k, nan)  # noqa: E731  (rows of --compare runs lack the in-process figures)
        lines.append(
            f"| {r['agents']} | {'real time' if rt else 'lock-step'} | {r['variant']}{' @' + r['code'] if 'code' in r else ''} "
            f"| {r['load_before']:.1f} | {_f(g('tick_p99'), 1) if rt else '-'} | {_f(g('beacon_p99'), 1)} "
            f"| {_f(g('first_receiver_p50'), 1)} / {_f(g('last_receiver_p50'), 1)} "
            f"| {_f(g('missed_pct'), 1) if rt else '-'} | {_f(g('msgs_per_s'), 0)} | {_f(g('cpu_pct_per_agent'), 1)} "
            f"| {_f(g('pss_mb_per_agent'), 0)} | {_f(g('ticks_per_s'), 1)} | {_f(g('realtime_factor'), 2)} |")
    return "\n".join(lines)


def _f(v, digits: int) -> str:
    return "-" if v is None or not np.isfinite(v) else f"{v:,.{digits}f}"


def cost_fit(rows: list[dict]) -> str:
    """Least squares over real-time runs: cores (every process) = a * agents + b * messages delivered/s."""
    # Only runs that kept up (a saturated run's CPU is capped by the machine, not set by its traffic), and
    # one process per agent (where every message counted crossed Zenoh).
    pts = [r for r in rows if r["mode"] == "realtime" and np.isfinite(r.get("cpu_cores_total", np.nan))
           and r["missed_pct"] < 5 and "k" not in "".join(p[:1] for p in r["variant"].split("+"))]
    if len(pts) < 3:
        return ""
    a = np.array([[r["agents"], r["msgs_per_s"]] for r in pts])
    y = np.array([r["cpu_cores_total"] for r in pts])
    (per_agent, per_msg), *_ = np.linalg.lstsq(a, y, rcond=None)
    return (f"fit over {len(pts)} real-time runs: cores = {per_agent:.4f} x agents + {per_msg * 1e6:.1f} us x "
            f"messages/s")


def plot(rows: list[dict], path: Path) -> Path:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    panels = [("tick_p99", "tick lateness p99 (ms)", True), ("last_receiver_p99", "beacon, last receiver p99 (ms)", True),
              ("missed_pct", "missed actions (%)", True), ("msgs_per_s", "messages delivered / s", False),
              ("cpu_pct_per_agent", "CPU per agent (% of a core)", False), ("pss_mb_per_agent", "memory per agent, PSS (MB)", False),
              ("realtime_factor", "ticks/s over 10 Hz (x real time)", False), ("cpu_cores_total", "CPU, all processes (cores)", False)]
    fig, axes = plt.subplots(2, 4, figsize=(18, 8))
    series = sorted({(r["mode"], r["variant"]) for r in rows})
    variants = sorted({r["variant"] for r in rows})
    palette = plt.get_cmap("tab10" if len(variants) <= 10 else "tab20").colors  # one colour per variant
    colors = {v: palette[i % len(palette)] for i, v in enumerate(variants)}
    for ax, (key, title, rt_only) in zip(axes.flat, panels):
        for mode, variant in series:
            if rt_only and mode != "realtime":
                continue
            pts = sorted((r["agents"], r[key]) for r in rows if r["mode"] == mode and r["variant"] == variant
                         and np.isfinite(r.get(key, np.nan)))
            if not pts:
                continue
            xs = sorted({x for x, _ in pts})
            med = [np.median([v for x, v in pts if x == n]) for n in xs]
            ax.plot(xs, med, "o-" if mode == "realtime" else "s--", color=colors[variant],
                    label=f"{variant}, {'real time' if mode == 'realtime' else 'lock-step'}")
            ax.plot([x for x, _ in pts], [v for _, v in pts], ".", color=colors[variant], alpha=0.4)
        ax.set_xscale("log")
        ax.set_xticks(sorted({r["agents"] for r in rows}), [str(n) for n in sorted({r["agents"] for r in rows})])
        ax.set_xticks([], minor=True)
        ax.set_title(title, fontsize=10)
        ax.set_xlabel("agents")
        ax.grid(alpha=0.3)
        if key in ("msgs_per_s", "tick_p99", "last_receiver_p99"):
            ax.set_yscale("log")
        if key == "realtime_factor":
            ax.axhline(1.0, color="k", lw=0.8)
    handles, labels = axes.flat[3].get_legend_handles_labels()  # every series shows in that panel
    fig.legend(handles, labels, loc="lower center", ncol=min(5, len(labels)), fontsize=8, frameon=False)
    loads = [r["load_before"] for r in rows]
    fig.suptitle(f"bench_swarm sweep: {len(rows)} runs on {os.cpu_count()} cores (load average {min(loads):.1f}-"
                 f"{max(loads):.1f}; lines: median, dots: each run)")
    fig.tight_layout(rect=(0, 0.04 * ((len(labels) + 4) // 5), 1, 1))
    fig.savefig(path, dpi=90)
    return path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--agents", type=int, default=20)
    ap.add_argument("--rate", type=float, default=10.0)
    ap.add_argument("--ticks", type=int, default=200)
    ap.add_argument("--repeat", type=int, default=1, help="runs (the tail moves from run to run on a shared VM)")
    ap.add_argument("--secure", action="store_true",
                    help="each repeat runs plain, then --secure, and prints the secure/plain ratios")
    ap.add_argument("--sweep", metavar="N,N,...", help="swarm sizes to sweep (e.g. 5,10,20,50,100): the scale table")
    ap.add_argument("--modes", default="realtime,lockstep", help="with --sweep: realtime, lockstep or both")
    ap.add_argument("--variants", default="base", help="with --sweep: comma-separated, parts joined by '+' "
                                                       "(base, hz1, cells[M], k<K>, shared)")
    ap.add_argument("--sweep-out", default="runs/bench-swarm", help="with --sweep: where sweep.csv/json/png go")
    ap.add_argument("--lockstep-ticks", type=int, help="with --sweep: ticks of the lock-step runs (default --ticks)")
    ap.add_argument("--keep-runs", action="store_true", help="with --sweep: keep each run's directory (logs, checkpoints)")
    ap.add_argument("--append", action="store_true", help="with --sweep: add to the runs already in sweep.json")
    ap.add_argument("--compare", metavar="DIR[,DIR]", help="with --sweep: also run each configuration with these "
                    "checkouts' code, alternated with this one's, all through `truav-swarm up` (bench/swarm_runs.py)")
    ap.add_argument("--max-load", type=float, metavar="L", help="with --sweep: before each run wait until the "
                    "1-minute load average is below L (a figure taken beside other jobs is noise)")
    ap.add_argument("--load-wait", type=float, default=600.0, metavar="S",
                    help="with --max-load: wait at most this long per run (default 600)")
    args = ap.parse_args()
    if args.sweep:
        sweep(args)
        return
    if args.secure:
        pairs = [(run_once(args.agents, args.rate, args.ticks), run_once(args.agents, args.rate, args.ticks, True))
                 for _ in range(args.repeat)]
        print(f"\n--secure / plain, {len(pairs)} pair(s) run back to back (ratio per pair):")
        for key, label in (("beacon_p50", "beacon latency p50"), ("beacon_p99", "beacon latency p99"),
                           ("tick_p99", "tick lateness p99"), ("cpu_s", "CPU seconds")):
            ratios = ", ".join(f"{sec[key]:.2f}/{plain[key]:.2f} = x{sec[key] / plain[key]:.2f}" for plain, sec in pairs)
            print(f"  {label:20s} {ratios}")
        return
    runs = [run_once(args.agents, args.rate, args.ticks) for _ in range(args.repeat)]
    if len(runs) > 1:
        print(f"\nover {len(runs)} runs (min / median / max):")
        for key, label in (("tick_p99", "tick lateness p99"), ("beacon_p50", "beacon latency p50"),
                           ("beacon_p99", "beacon latency p99"), ("last_receiver_p50", "last receiver p50")):
            v = np.array([r[key] for r in runs])
            print(f"  {label:20s} {np.min(v):6.2f} / {np.median(v):6.2f} / {np.max(v):6.2f} ms")


if __name__ == "__main__":
    main()
