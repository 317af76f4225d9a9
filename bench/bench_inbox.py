"""The receive path of one agent's beacons, in one process: CPU per beacon of arrival (the pump) and drain.

    python bench/bench_inbox.py                    # 49 beacons a round (a 50-agent swarm), 300 rounds
    python bench/bench_inbox.py --code ../old      # another checkout's bus, the same rounds (ratio printed)

A peer-mode Zenoh session (loopback, no scouting) puts one valid beacon from each of N peers per round on
their own keys; an Inbox with the guard, as a real-time agent has, receives them through its pump
thread, and the round's beacons are drained at once, as an agent does per decision. Printed per beacon:
the put, the drain (decode, placement, guard, bookkeeping) and the process's whole CPU time over the
round (put, Zenoh's local delivery, the pump's arrival work and the drain). What a swarm adds on top, and
this does not measure, is the cross-process wake-up per burst: see bench/bench_swarm.py.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time


def measure(n: int, rounds: int) -> dict[str, float]:
    from truav.bus import transport
    from truav.wire import keys, schema
    from truav.wire.guard import Bounds, Guard

    run = "bench-inbox"
    bus = transport.Bus("uav/0", run, transport.make_config("peer"))
    try:
        bus.guard = Guard(Bounds(n_uavs=n + 1, area_m=5000.0, max_count=100, max_packets=1000, max_speed=30.0,
                                 max_energy_j=1e5))
        bus.receive_ring = 256
        box = bus.inbox(keys.all_beacons(run), capacity=4 * n, compact=False)
        pubs = [bus._session.declare_publisher(keys.uav_beacon(run, j)) for j in range(1, n + 1)]
        seqs = [schema.Sequencer(f"uav/{j}") for j in range(1, n + 1)]
        time.sleep(0.5)  # the local subscription is declared
        put_s = drain_s = cpu_s = 0.0
        got = 0
        for r in range(rounds):
            raws = [schema.encode(seqs[j].stamp(schema.Beacon(uav=j + 1, tick=r, pos=(100.0, 200.0), vel=(1.0, 2.0))))
                    for j in range(n)]
            c0, t0 = time.process_time(), time.perf_counter()
            for pub, raw in zip(pubs, raws):
                pub.put(raw)
            t1 = time.perf_counter()
            deadline = time.monotonic() + 5.0
            while len(box) < n and time.monotonic() < deadline:
                time.sleep(0.0002)
            time.sleep(0.001)
            t2 = time.perf_counter()
            got += len(box.drain())
            t3 = time.perf_counter()
            cpu_s += time.process_time() - c0
            put_s += t1 - t0
            drain_s += t3 - t2
    finally:
        bus.close()
    per = max(got, 1)
    return {"beacons": got, "put_us": 1e6 * put_s / per, "drain_us": 1e6 * drain_s / per, "cpu_us": 1e6 * cpu_s / per}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--peers", type=int, default=49, help="beacons a round (default 49: a 50-agent swarm)")
    ap.add_argument("--rounds", type=int, default=300)
    ap.add_argument("--repeat", type=int, default=3, help="runs of each code, alternated; the minimum is printed")
    ap.add_argument("--code", metavar="DIR", help="also run another checkout's bus (its truav/ on PYTHONPATH)")
    ap.add_argument("--json", action="store_true", help=argparse.SUPPRESS)  # one run, as JSON (the child's mode)
    args = ap.parse_args()
    if args.json:
        import json
        print(json.dumps(measure(args.peers, args.rounds)))
        return
    here = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    codes = [here] + ([os.path.abspath(args.code)] if args.code else [])
    import json
    best: dict[str, dict[str, float]] = {}
    for _ in range(args.repeat):
        for code in codes:
            out = subprocess.run([sys.executable, os.path.abspath(__file__), "--json", "--peers", str(args.peers),
                                  "--rounds", str(args.rounds)], env=dict(os.environ, PYTHONPATH=code),
                                 capture_output=True, text=True, check=True).stdout
            r = json.loads(out.strip().splitlines()[-1])
            prev = best.get(code)
            best[code] = r if prev is None else {k: min(prev[k], r[k]) for k in r}
    for code, r in best.items():
        print(f"{code}: {r['beacons']:.0f} beacons, per beacon: put {r['put_us']:.1f} us, drain {r['drain_us']:.1f} us, "
              f"process CPU {r['cpu_us']:.1f} us (min of {args.repeat})")
    if len(codes) == 2:
        new, old = best[codes[0]], best[codes[1]]
        print(f"this / {codes[1]}: drain x{new['drain_us'] / old['drain_us']:.2f}, "
              f"process CPU x{new['cpu_us'] / old['cpu_us']:.2f}")


if __name__ == "__main__":
    main()
