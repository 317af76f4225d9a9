"""What the bridges cost a real-time swarm: missed actions without a bridge, with `truav-swarm mavlink`,
with `truav-swarm ros2`, runs alternated; and a pymavlink listener counting a HEARTBEAT from every UAV.

    python bench/bench_bridges.py                     # 20 UAVs, 10 Hz, 60 s a run, 2 rounds of the 3 runs
    python bench/bench_bridges.py --repeat 3          # more rounds: the run-to-run spread
    python bench/bench_bridges.py --agents 2 --seconds 5 --repeat 1 --anyway   # a smoke run on a busy machine

Each run is ``truav-swarm up`` of this checkout (one episode of ``--seconds x --rate`` ticks at ``--rate``
Hz, every UAV an agent process), and, once the world ticks, the bridge under test beside it: ``mavlink``
sending to a pymavlink listener on loopback (which counts the systems it heard a HEARTBEAT from), or
``ros2`` (publishing every pose, the markers and the metrics on the run's router). The figures come from
the run's world.json: the share of actions missed (UAVs x ticks that had no action in time, per_uav's
``missed``), the world's tick lateness p99; and the bridge's own CPU (from /proc, over its life, start-up
included). The end
prints, per setting, the median of each figure and the ratio of each bridge's missed share to the runs
without a bridge.

A figure measured beside other jobs is noise, not the bridges' cost: the benchmark refuses to start
(exit 2) while the 1-minute load average is at or above ``--max-load`` (default 1); ``--anyway`` runs
regardless and marks every line and the table LOADED. Before each run it waits up to ``--load-wait``
seconds for the load to fall below ``--max-load`` and records the load each run started at.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
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
SETTINGS = ("none", "mavlink", "ros2")
START_WAIT_S = 120.0  # for the swarm's swarm.json (it writes it once the world runs)


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class HeartbeatCounter:
    """A pymavlink listener on a loopback UDP port, in a thread: the system ids it heard a HEARTBEAT from."""

    def __init__(self, port: int) -> None:
        os.environ.setdefault("MAVLINK20", "1")
        from pymavlink import mavutil
        self.conn = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=255)
        self.systems: set[int] = set()
        self.heartbeats = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, daemon=True)
        self._thread.start()

    def _loop(self) -> None:
        while not self._stop.is_set():
            msg = self.conn.recv_match(type="HEARTBEAT", blocking=True, timeout=0.5)
            if msg is not None:
                self.heartbeats += 1
                self.systems.add(msg.get_srcSystem())

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        self.conn.close()


def run_once(setting: str, agents: int, rate: float, seconds: float, loaded: bool) -> dict:
    """One real-time run with ``setting``'s bridge (or none); its figures."""
    tmp = Path(tempfile.mkdtemp(prefix="truav-bench-bridges-"))
    out, ticks = tmp / "run", max(1, int(round(seconds * rate)))
    run = f"bench-{setting}"
    load0 = os.getloadavg()[0]
    cli = [sys.executable, "-m", "truav.cli.swarm"]
    up_log = open(tmp / "up.log", "wb")
    up = subprocess.Popen([*cli, "up", "--scheme", "truav", "--run", run, "--agents", str(agents), "--episodes", "1", "--steps", str(ticks),
                           "--rate", f"{rate:g}", "--out", str(out), "--quiet", "--no-plot", "--max-missed", "1",
                           *(["--force-agents"] if agents > 50 else [])],
                          cwd=ROOT, stdout=up_log, stderr=subprocess.STDOUT, start_new_session=True)
    up_log.close()
    bridge = listener = None
    bridge_cpu = bridge_wall = float("nan")
    try:
        deadline = time.monotonic() + START_WAIT_S
        while not (out / "swarm.json").is_file() and up.poll() is None and time.monotonic() < deadline:
            time.sleep(0.1)
        if setting != "none" and up.poll() is None:
            extra: list[str] = []
            if setting == "mavlink":
                port = _free_udp_port()
                listener = HeartbeatCounter(port)
                extra = ["--udp-out", f"127.0.0.1:{port}"]
            log = open(tmp / f"{setting}.log", "wb")
            bridge = subprocess.Popen([*cli, setting, "--out", str(out), *extra], cwd=ROOT, stdout=log,
                                      stderr=subprocess.STDOUT, start_new_session=True)
            log.close()
            started = time.monotonic()
        code = up.wait(timeout=seconds * 4 + START_WAIT_S + 120)
        if bridge is not None:
            cpu = bench_common.cpu_s(bridge.pid)
            bridge_cpu, bridge_wall = (float("nan") if cpu is None else cpu), time.monotonic() - started
    finally:
        if bridge is not None:
            bench_common.stop_group(bridge, signal.SIGTERM, 15)
        if listener is not None:
            listener.close()
        if up.poll() is None:
            bench_common.stop_group(up, signal.SIGINT, 15)
    try:
        world = json.loads((out / "world.json").read_text())
    except (OSError, ValueError):
        tail = (tmp / "up.log").read_text(errors="replace")[-2000:]
        shutil.rmtree(tmp, ignore_errors=True)
        raise RuntimeError(f"{setting}: the swarm wrote no world.json (exit {code}); its log ends:\n{tail}")
    shutil.rmtree(tmp, ignore_errors=True)
    n_ticks = int(world.get("ticks", ticks))
    missed = bench_common.missed(world)
    return {"setting": setting, "agents": agents, "rate_hz": rate, "ticks": n_ticks, "exit_code": code,
            "load_before": load0, "load_after": os.getloadavg()[0], "loaded": loaded,
            "missed_pct": 100.0 * missed / max(agents * n_ticks, 1),
            "tick_p99_ms": bench_common.tick_p99_ms(world),
            "bridge_cores": bridge_cpu / bridge_wall if bridge_wall > 0 else float("nan"),
            "heartbeat_systems": len(listener.systems) if listener is not None else None,
            "heartbeats": listener.heartbeats if listener is not None else None}


def line(r: dict) -> str:
    hb = "" if r["heartbeat_systems"] is None else \
        f", HEARTBEAT from {r['heartbeat_systems']}/{r['agents']} UAVs ({r['heartbeats']} heartbeats)"
    return (f"{'LOADED ' if r['loaded'] else ''}{r['setting']:>7s} {r['agents']} UAVs {r['ticks']} ticks at "
            f"{r['rate_hz']:g} Hz, load {r['load_before']:.2f}: missed {r['missed_pct']:.3f}% of actions, tick "
            f"lateness p99 {r['tick_p99_ms']:.1f} ms"
            + ("" if r["setting"] == "none" else f", bridge {r['bridge_cores']:.3f} cores")
            + f"{hb}, exit {r['exit_code']}")


def table(rows: list[dict]) -> str:
    """Per setting: runs, the medians, and the missed share over the runs without a bridge."""
    med = {s: {k: float(np.median([r[k] for r in rows if r["setting"] == s]))
               for k in ("missed_pct", "tick_p99_ms", "bridge_cores", "load_before")}
           for s in SETTINGS if any(r["setting"] == s for r in rows)}
    base = med.get("none", {}).get("missed_pct")
    out = [("LOADED (measured beside other jobs: not the bridges' cost)\n" if any(r["loaded"] for r in rows) else "")
           + "| setting | runs | load | missed % | x missed of none | tick lateness p99 ms | bridge cores | "
             "HEARTBEAT systems (min) |", "|---|---|---|---|---|---|---|---|"]
    for s, m in med.items():
        runs = [r for r in rows if r["setting"] == s]
        hb = [r["heartbeat_systems"] for r in runs if r["heartbeat_systems"] is not None]
        ratio = "-" if s == "none" or base is None else bench_common.ratio(m["missed_pct"], base, "inf (none missed 0)")
        systems = f"{min(hb)}/{runs[0]['agents']}" if hb else "-"
        out.append(f"| {s} | {len(runs)} | {m['load_before']:.2f} | {m['missed_pct']:.3f} | {ratio} | "
                   f"{m['tick_p99_ms']:.1f} | {'-' if s == 'none' else format(m['bridge_cores'], '.3f')} | {systems} |")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    ap = bench_common.parser(__doc__)
    ap.add_argument("--agents", type=int, default=20, help="UAVs, each an agent process (default 20)")
    bench_common.add_tick_options(ap)
    ap.add_argument("--repeat", type=int, default=2, help="rounds of none, mavlink, ros2 (default 2)")
    ap.add_argument("--settings", default=",".join(SETTINGS), help="which of none,mavlink,ros2 (default all three)")
    bench_common.add_load_options(ap)
    ap.add_argument("--json", type=Path, metavar="FILE", help="also write the rows as JSON")
    args = ap.parse_args(argv)
    settings = [s for s in args.settings.split(",") if s]
    if not settings or any(s not in SETTINGS for s in settings):
        print(f"bench_bridges: error: --settings: choose among {','.join(SETTINGS)}, got {args.settings!r}",
              file=sys.stderr)
        return 2
    if bench_common.refuse_nonpositive("bench_bridges", args, ("--agents", "--seconds", "--rate", "--repeat")):
        return 2
    for module in ("pymavlink", "rosbags"):
        needed = {"pymavlink": "mavlink", "rosbags": "ros2"}[module]
        if needed in settings:
            try:
                __import__(module)
            except ImportError:
                print(f"bench_bridges: error: the {needed} bridge needs {module}: pip install -e "
                      f"'.[{needed}]' -c constraints.txt", file=sys.stderr)
                return 2
    if bench_common.refuse_loaded("bench_bridges", args):
        return 2
    rows: list[dict] = []
    for _ in range(args.repeat):
        for s in settings:
            loaded = bench_common.wait_for_load(args)
            r = run_once(s, args.agents, args.rate, args.seconds, loaded)
            rows.append(r)
            print(line(r), flush=True)
    print(table(rows))
    bench_common.write_rows(args.json, rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
