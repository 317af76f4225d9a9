"""What beacon send slots cost a receiver: one agent's CPU per beacon, beacons spread over the tick or in one burst.

    python bench/bench_beacon_burst.py               # 49 peers at 10 Hz for 10 s: spread, then burst, then spread ...
    python bench/bench_beacon_burst.py --peers 99 --repeat 3

Three processes on loopback (scouting off): a Zenoh router, a publisher putting one valid beacon of each
of N peers per 100 ms tick (``spread``: evenly over 60% of the tick, as one send slot per UAV did;
``burst``: all at once, as ``--beacon-slots 1`` does), and a receiver with a real-time agent's Inbox and
guard that drains once per tick. Printed per delivered beacon: the receiver's CPU (every thread, from
getrusage), its context switches, and the CPU of its threads by name (Zenoh's rx-0/net-0/app-0, Python's).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

RUN = "bench-burst"
ENDPOINT = "tcp/127.0.0.1:7491"
CLK_TCK = os.sysconf("SC_CLK_TCK")


def router(seconds: float) -> None:
    from truav.bus import transport
    session = transport.open_router([ENDPOINT])
    time.sleep(seconds)
    session.close()


def publisher(n: int, spread: bool, seconds: float) -> None:
    import zenoh

    from truav.bus import transport
    from truav.wire import keys, schema
    session = transport.open_session(transport.make_config("client", [ENDPOINT]))
    pubs = [session.declare_publisher(keys.uav_beacon(RUN, j), congestion_control=zenoh.CongestionControl.DROP)
            for j in range(1, n + 1)]
    seqs = [schema.Sequencer(f"uav/{j}") for j in range(1, n + 1)]
    time.sleep(1.0)
    t0, tick = time.monotonic(), 0
    while time.monotonic() - t0 < seconds:
        start = t0 + tick * 0.1
        for j in range(n):
            if spread:
                wait = start + 0.03 + 0.06 * j / n - time.monotonic()
                if wait > 0:
                    time.sleep(wait)
            pubs[j].put(schema.encode(seqs[j].stamp(schema.Beacon(uav=j + 1, tick=tick, pos=(100.0, 200.0),
                                                                  vel=(1.0, 2.0)))))
        tick += 1
        wait = t0 + tick * 0.1 - time.monotonic()
        if wait > 0:
            time.sleep(wait)
    session.close()


def _threads() -> dict[str, int]:
    out: dict[str, int] = {}
    for tid in os.listdir("/proc/self/task"):
        try:
            with open(f"/proc/self/task/{tid}/stat") as f:
                st = f.read()
        except OSError:
            continue
        name = st[st.index("(") + 1:st.rindex(")")]
        fields = st[st.rindex(")") + 2:].split()
        out[name] = out.get(name, 0) + int(fields[11]) + int(fields[12])
    return out


def receiver(n: int, seconds: float) -> None:
    from truav.bus import transport
    from truav.wire import keys
    from truav.wire.guard import Bounds, Guard
    bus = transport.Bus("uav/0", RUN, transport.make_config("client", [ENDPOINT]))
    bus.guard = Guard(Bounds(n_uavs=n + 1, area_m=5000.0, max_count=100, max_packets=1000, max_speed=30.0,
                             max_energy_j=1e5))
    bus.receive_ring = 256
    box = bus.inbox(keys.all_beacons(RUN), capacity=4 * n, compact=False)
    time.sleep(2.0)
    box.drain()
    th0, r0, t0, got = _threads(), resource.getrusage(resource.RUSAGE_SELF), time.monotonic(), 0
    while time.monotonic() - t0 < seconds:
        time.sleep(0.1)
        got += len(box.drain())
    r1, th1 = resource.getrusage(resource.RUSAGE_SELF), _threads()
    bus.close()
    cpu = r1.ru_utime - r0.ru_utime + r1.ru_stime - r0.ru_stime
    per = max(got, 1)
    print(json.dumps({"beacons": got, "cpu_us": 1e6 * cpu / per,
                      "switches": (r1.ru_nvcsw - r0.ru_nvcsw + r1.ru_nivcsw - r0.ru_nivcsw) / per,
                      "threads_us": {k: round(1e6 * (v - th0.get(k, 0)) / CLK_TCK / per, 1) for k, v in th1.items()
                                     if v > th0.get(k, 0)}}))


def one(n: int, mode: str, seconds: float) -> dict:
    me, py = os.path.abspath(__file__), sys.executable
    procs = [subprocess.Popen([py, me, "--role", "router", "--seconds", str(seconds + 8)])]
    try:
        time.sleep(1.0)
        procs.append(subprocess.Popen([py, me, "--role", "pub", "--peers", str(n), "--mode", mode,
                                       "--seconds", str(seconds + 4)]))
        out = subprocess.run([py, me, "--role", "rx", "--peers", str(n), "--seconds", str(seconds)],
                             capture_output=True, text=True, timeout=seconds + 60).stdout
        return json.loads(out.strip().splitlines()[-1])
    finally:
        for p in procs:
            p.terminate()
        for p in procs:
            p.wait(10)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--peers", type=int, default=49)
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--repeat", type=int, default=2, help="pairs of runs (spread, burst), alternated")
    ap.add_argument("--role", choices=("router", "pub", "rx"), help=argparse.SUPPRESS)
    ap.add_argument("--mode", choices=("spread", "burst"), default="burst", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.role == "router":
        return router(args.seconds)
    if args.role == "pub":
        return publisher(args.peers, args.mode == "spread", args.seconds)
    if args.role == "rx":
        return receiver(args.peers, args.seconds)
    runs: dict[str, list[dict]] = {"spread": [], "burst": []}
    for _ in range(args.repeat):
        for mode in ("spread", "burst"):
            r = one(args.peers, mode, args.seconds)
            runs[mode].append(r)
            print(f"{mode:6s}: {r['beacons']} beacons, {r['cpu_us']:.1f} us CPU and {r['switches']:.2f} context "
                  f"switches per beacon; by thread (us/beacon): {r['threads_us']}", flush=True)
    med = {m: sorted(r["cpu_us"] for r in rs)[len(rs) // 2] for m, rs in runs.items()}
    print(f"burst / spread, receiver CPU per beacon (medians): x{med['burst'] / med['spread']:.2f}")


if __name__ == "__main__":
    main()
