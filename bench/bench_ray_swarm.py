"""A real-time swarm across three Ray nodes against the same swarm on one host: missed actions and CPU,
runs alternated.

    python bench/bench_ray_swarm.py                   # 100 UAVs, 10 per process, 10 Hz, 60 s a run, 2 rounds
    python bench/bench_ray_swarm.py --repeat 3        # more rounds: the run-to-run spread
    python bench/bench_ray_swarm.py --quick           # a smoke run: 6 UAVs, 2 per process, 3 s, 1 round, any load

The benchmark starts a Ray cluster of three nodes on this machine (ray.cluster_utils.Cluster: a raylet per node,
each on loopback, the nodes' routers on consecutive ports, as tests/swarm/test_ray_swarm.py does) and shuts it
down at its end. Each round runs ``truav-swarm up`` of this checkout twice, in turn: on one host (``one-host``:
one router, every process a child of ``up``) and with ``--ray ADDRESS`` (``ray``: a router per node linked to
the first, the agent processes dealt to the three nodes, each started by a Ray actor). Both run one episode of
``--seconds x --rate`` ticks at ``--rate`` Hz with ``--agents-per-process`` UAVs per process and
``--share-beacons`` (the setting docs/results/benchmarks.md measured 100 UAVs with on one host).

Figures, from the run's world.json and from /proc over the ticking window (the world's first to last tick):
the share of actions missed (UAVs x ticks without an action in time, per_uav's ``missed``), the world's tick
lateness p99, the CPU of the swarm's own processes in cores (the supervisor, routers, world, agents: found by
the run's unique name or its routers' endpoints on their command lines, wherever Ray started them), and the
machine's busy cores (/proc/stat: Ray's raylets and workers included, and anything else running). The end
prints, per setting, the medians and the ray run's ratios to the one-host run.

A figure measured beside other jobs is noise: the benchmark refuses to start (exit 2) while the 1-minute load
average is at or above ``--max-load`` (default 1); ``--anyway`` (and ``--quick``) runs regardless and marks every
line and the table LOADED. Before each run it waits up to ``--load-wait`` seconds for the load to fall.
"""

from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_common  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SETTINGS = ("one-host", "ray")
CLK_TCK = bench_common.CLK_TCK
SAMPLE_S = 0.5
START_WAIT_S = 300.0
"""For the swarm's first tick (100 UAVs' processes, or Ray actors' workers, start slowly on 2 cores)."""
NODES = 3
NODE = {"num_cpus": 1, "object_store_memory": 80 * 1024 ** 2, "node_ip_address": "127.0.0.1"}
LOOPBACK_DRIVER = {"RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0"}
"""Ray resolves a loopback head address to the machine's address unless told the cluster is this machine's."""


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _machine_busy_s() -> float:
    """Busy CPU seconds of the whole machine so far (/proc/stat: all but idle and iowait)."""
    fields = [int(x) for x in Path("/proc/stat").read_text().splitlines()[0].split()[1:]]
    return (sum(fields) - fields[3] - fields[4]) / CLK_TCK


class Sampler:
    """CPU seconds of the swarm's processes (its supervisor, and every TRUAV process whose command line names
    the run or one of its routers' endpoints) and of the machine, every SAMPLE_S, in a thread."""

    def __init__(self, up_pid: int, marks: list[str]) -> None:
        self.up_pid, self.marks = str(up_pid), [m.encode() for m in marks]
        self.samples: list[tuple[float, float, dict[str, float]]] = []  # (wall s, machine busy s, {pid: cpu s})
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, daemon=True)
        self._thread.start()

    def _ours(self, pid: str) -> bool:
        if pid == self.up_pid:
            return True
        try:
            cmd = Path(f"/proc/{pid}/cmdline").read_bytes()
        except OSError:
            return False
        return (b"truav.cli.swarm" in cmd or b"recorder.process" in cmd) and any(m in cmd for m in self.marks)

    def _loop(self) -> None:
        known: set[str] = set()
        while not self._stop.is_set():
            for p in os.listdir("/proc"):
                if p.isdigit() and p not in known and self._ours(p):
                    known.add(p)
            cpu = {p: c for p in known if (c := bench_common.cpu_s(p)) is not None}
            self.samples.append((time.time(), _machine_busy_s(), cpu))
            self._stop.wait(SAMPLE_S)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=10)

    def cores(self, t0: float, t1: float) -> tuple[float, float]:
        """(swarm cores, machine busy cores) between the samples nearest inside [t0, t1] (wall clock)."""
        inside = [s for s in self.samples if t0 <= s[0] <= t1]
        if len(inside) < 2:
            return float("nan"), float("nan")
        (w0, m0, c0), (w1, m1, c1) = inside[0], inside[-1]
        swarm = sum(c - c0.get(p, c) for p, c in c1.items())  # a process not yet seen at t0 counts from its start
        return swarm / (w1 - w0), (m1 - m0) / (w1 - w0)


def run_once(setting: str, address: str | None, args, k: int, loaded: bool) -> dict:
    """One real-time run on one host or across the Ray nodes; its figures."""
    tmp = Path(tempfile.mkdtemp(prefix="truav-bench-ray-"))
    out, ticks = tmp / "run", max(1, int(round(args.seconds * args.rate)))
    run, port = f"bench-ray-{os.getpid()}-{k}", _free_port()
    where = ["-l", f"tcp/127.0.0.1:{port}"] if setting == "one-host" else ["--ray", address, "--ray-port", str(port)]
    load0 = os.getloadavg()[0]
    argv = [sys.executable, "-m", "truav.cli.swarm", "up", "--run", run, "--scheme", "truav",
            "--agents", str(args.agents), "--agents-per-process", str(args.per_process), "--share-beacons",
            "--episodes", "1", "--steps", str(ticks), "--rate", f"{args.rate:g}", "--out", str(out), "--quiet",
            "--no-plot", "--no-references", "--max-missed", "1", "--force-agents", "--wait-agents", f"{START_WAIT_S:g}",
            *where]  # tick 0 once every agent is up: the figures are those of a swarm ticking, not of its start
    with open(tmp / "up.log", "wb") as log:
        up = subprocess.Popen(argv, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT, start_new_session=True,
                              env={**os.environ, **LOOPBACK_DRIVER})
    sampler = Sampler(up.pid, [run, *(f"127.0.0.1:{port + n}" for n in range(NODES))])
    try:
        code = up.wait(timeout=args.seconds * 4 + START_WAIT_S + 180)
    except subprocess.TimeoutExpired:
        code = bench_common.stop_group(up)
    finally:
        sampler.close()
        if up.poll() is None:
            bench_common.stop_group(up)
    try:
        world = json.loads((out / "world.json").read_text())
    except (OSError, ValueError):
        tail = (tmp / "up.log").read_text(errors="replace")[-2000:]
        shutil.rmtree(tmp, ignore_errors=True)
        raise RuntimeError(f"{setting}: the swarm wrote no world.json (exit {code}); its log ends:\n{tail}") from None
    shutil.rmtree(tmp, ignore_errors=True)
    n_ticks = int(world.get("ticks", ticks))
    missed = bench_common.missed(world)
    swarm, machine = sampler.cores(float(world.get("first_tick_wall_s") or 0),
                                   float(world.get("last_tick_wall_s") or 0))
    return {"setting": setting, "agents": args.agents, "per_process": args.per_process, "rate_hz": args.rate,
            "ticks": n_ticks, "exit_code": code, "load_before": load0, "load_after": os.getloadavg()[0],
            "loaded": loaded, "missed": missed, "missed_pct": 100.0 * missed / max(args.agents * n_ticks, 1),
            "tick_p99_ms": bench_common.tick_p99_ms(world),
            "swarm_cores": swarm, "machine_cores": machine}


def line(r: dict) -> str:
    return (f"{'LOADED ' if r['loaded'] else ''}{r['setting']:>8s} {r['agents']} UAVs ({r['per_process']} per process) "
            f"{r['ticks']} ticks at {r['rate_hz']:g} Hz, load {r['load_before']:.2f}: missed {r['missed']} "
            f"({r['missed_pct']:.3f}%) of actions, tick lateness p99 {r['tick_p99_ms']:.1f} ms, swarm "
            f"{r['swarm_cores']:.2f} cores, machine {r['machine_cores']:.2f} cores, exit {r['exit_code']}")


def table(rows: list[dict]) -> str:
    """Per setting: runs, the medians, and ray's over one-host."""
    keys = ("missed_pct", "tick_p99_ms", "swarm_cores", "machine_cores", "load_before")
    med = {s: {k: float(np.median([r[k] for r in rows if r["setting"] == s])) for k in keys}
           for s in SETTINGS if any(r["setting"] == s for r in rows)}
    base = med.get("one-host")

    def ratio(s: str, k: str) -> str:
        if s == "one-host" or base is None:
            return "-"
        return bench_common.ratio(med[s][k], base[k], "inf (one-host 0)")

    out = [("LOADED (measured beside other jobs: not the cluster's cost)\n" if any(r["loaded"] for r in rows) else "")
           + "| setting | runs | load | missed % | x missed | tick lateness p99 ms | swarm cores | x swarm cores | "
             "machine cores |", "|---|---|---|---|---|---|---|---|---|"]
    for s, m in med.items():
        n = sum(r["setting"] == s for r in rows)
        out.append(f"| {s} | {n} | {m['load_before']:.2f} | {m['missed_pct']:.3f} | {ratio(s, 'missed_pct')} | "
                   f"{m['tick_p99_ms']:.1f} | {m['swarm_cores']:.2f} | {ratio(s, 'swarm_cores')} | "
                   f"{m['machine_cores']:.2f} |")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    ap = bench_common.parser(__doc__)
    ap.add_argument("--agents", type=int, default=100, help="UAVs (default 100)")
    ap.add_argument("--per-process", type=int, default=10, metavar="K",
                    help="UAVs hosted per agent process, `up --agents-per-process` (default 10)")
    bench_common.add_tick_options(ap)
    ap.add_argument("--repeat", type=int, default=2, help="rounds of one-host then ray (default 2)")
    ap.add_argument("--quick", action="store_true", help="a smoke run: 6 UAVs, 2 per process, 3 s, 1 round, at any "
                    "load (figures marked LOADED when loaded)")
    bench_common.add_load_options(ap)
    ap.add_argument("--json", type=Path, metavar="FILE", help="also write the rows as JSON")
    args = ap.parse_args(argv)
    if args.quick:
        args.agents, args.per_process, args.seconds, args.repeat = 6, 2, 3.0, 1
        args.anyway, args.load_wait = True, 0.0
    if bench_common.refuse_nonpositive("bench_ray_swarm", args,
                                       ("--agents", "--per-process", "--seconds", "--rate", "--repeat")):
        return 2
    try:
        from ray import cluster_utils
    except ImportError:
        print("bench_ray_swarm: error: Ray is not installed: pip install -e '.[ray]' -c constraints.txt",
              file=sys.stderr)
        return 2
    if bench_common.refuse_loaded("bench_ray_swarm", args):
        return 2
    cluster = cluster_utils.Cluster(initialize_head=True, head_node_args={**NODE, "include_dashboard": False})
    rows: list[dict] = []
    interrupted = False
    try:
        for _ in range(NODES - 1):
            cluster.add_node(**NODE)
        cluster.wait_for_nodes()
        print(f"Ray cluster {cluster.address}: {NODES} nodes on this machine", flush=True)
        for _ in range(args.repeat):
            for s in SETTINGS:
                loaded = bench_common.wait_for_load(args)
                r = run_once(s, cluster.address, args, len(rows), loaded)
                rows.append(r)
                print(line(r), flush=True)
    except KeyboardInterrupt:
        interrupted = True
        print("interrupted (Ctrl-C): the runs so far", file=sys.stderr)
    finally:
        cluster.shutdown()  # only the raylets it started
    print(table(rows))
    bench_common.write_rows(args.json, rows)
    if interrupted:
        return 130
    return 0 if rows and all(r["exit_code"] == 0 for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
