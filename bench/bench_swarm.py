"""Real-time swarm benchmark: router + world + N agent processes at a tick rate.

    python bench/bench_swarm.py                  # 20 agents, 10 Hz, 200 ticks
    python bench/bench_swarm.py --agents 5 --ticks 100
    python bench/bench_swarm.py --repeat 3       # the run-to-run spread
    python bench/bench_swarm.py --secure         # plain and --secure (mutual TLS + ACL) in turn: the cost of TLS

Prints world tick lateness p50/p99 (target p99 < 20 ms), one-way beacon
latency p50/p99 over every beacon every agent heard (target p99 < 5 ms),
missed actions, and the control-plane traffic measured on the bus.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from truav.config import Config  # noqa: E402
from truav.swarm.supervisor import SwarmOptions, run_swarm  # noqa: E402


def _cpu_s() -> float:
    """CPU seconds of this process and of its reaped children (router, world, agents)."""
    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


def run_once(agents: int, rate: float, ticks: int, secure: bool = False) -> dict:
    """One swarm run; prints its figures and returns the headline ones."""
    cfg = Config().replace(scenario={"n_uavs": agents, "steps_per_episode": ticks})
    out = Path(tempfile.mkdtemp(prefix="truav-bench-swarm-"))
    t0, cpu0 = time.perf_counter(), _cpu_s()
    run_swarm(cfg, SwarmOptions(run="bench", episodes=1, rate_hz=rate, out=str(out), plot=False, quiet=True,
                                wait_agents_s=120.0, secure=secure))
    wall, cpu = time.perf_counter() - t0, _cpu_s() - cpu0
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
    tl = world["tick_lateness_ms"]
    cp = json.loads((out / "summary.json").read_text())["control_plane"]
    result = {"tick_p50": tl["p50"], "tick_p99": tl["p99"], "beacon_p50": float("nan"), "beacon_p99": float("nan"),
              "last_receiver_p50": float("nan"), "cpu_s": cpu}
    print(f"\n{agents} agents at {rate:g} Hz{' --secure (mutual TLS + ACL)' if secure else ''}, {world['ticks']} "
          f"ticks, {wall:.1f} s wall (incl. start-up), {cpu:.1f} CPU-s over every process")
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
        result.update(beacon_p50=float(p50), beacon_p99=float(p99), last_receiver_p50=float(np.percentile(last, 50)))
    n_act = agents * ticks
    print(f"missed actions: {world['deadline_misses']} of {n_act} ({100 * world['deadline_misses'] / n_act:.2f}%)")
    print(f"control plane: {cp['bytes_per_beacon']:.0f} B/beacon, {cp['beacons_per_s_per_uav']:.1f} beacons/s/UAV, "
          f"{cp['beacon_bytes_per_s_total'] / 1e3:.1f} kB/s total")
    print(f"(details in {out})")
    return result


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--agents", type=int, default=20)
    ap.add_argument("--rate", type=float, default=10.0)
    ap.add_argument("--ticks", type=int, default=200)
    ap.add_argument("--repeat", type=int, default=1, help="runs (the tail moves from run to run on a shared VM)")
    ap.add_argument("--secure", action="store_true",
                    help="each repeat runs plain, then --secure, and prints the secure/plain ratios")
    args = ap.parse_args()
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
