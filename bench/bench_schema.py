"""Cost of validating decode for the swarm's hot messages, one process.

    python bench/bench_schema.py

Every agent decodes its 19 neighbours' beacons each tick of a 20-agent swarm,
so decode sits on the real-time path.  Prints, per kind, microseconds per
message for the Bus's checked decode (schema.decode plus the key/sender
placement check), for ``schema.decode`` alone and for a bare
``msgpack.unpackb``, and the ratio of checked decode to bare unpacking (the
price of validation), plus the CPU a 20-agent swarm at 10 Hz spends per
second decoding beacons.
"""

from __future__ import annotations

import argparse
import os
import sys
import timeit

import msgpack

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from truav.bus.placement import check_placement as _check_placement  # noqa: E402
from truav.wire import keys, schema  # noqa: E402


def per_call_us(fn, number: int) -> float:
    """Best of 5 repeats, in microseconds per call."""
    return min(timeit.repeat(fn, number=number, repeat=5)) / number * 1e6


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--number", type=int, default=20_000, help="calls per timing repeat (default 20000)")
    args = ap.parse_args()
    run = "bench"
    cases = [
        ("beacon", keys.uav_beacon(run, 3), schema.Sequencer("uav/3").stamp(
            schema.Beacon(uav=3, tick=1234, pos=(1234.5, 678.25), vel=(10.0, -3.5)))),
        ("obs", keys.uav_obs(run, 3), schema.Sequencer("world").stamp(
            schema.Obs(tick=1234, episode=1, uav=3, pos=(10.5, -2.25), vehicles_in_range=4, queued_packets=12,
                       relayed=3, covered=2, energy_j=0.75, speed_max=20.0, done=False))),
        ("action", keys.uav_action(run, 3), schema.Sequencer("uav/3").stamp(
            schema.Action(uav=3, tick=1234, action=7))),
    ]
    print(f"{'kind':8s} {'bytes':>5s} {'checked decode':>15s} {'schema.decode':>14s} {'msgpack':>8s} {'ratio':>6s}")
    beacon_us = 0.0
    for kind, key, msg in cases:
        raw = schema.encode(msg)

        def checked(raw=raw, key=key):
            _check_placement(key, schema.decode(raw))

        full = per_call_us(checked, args.number)
        dec = per_call_us(lambda raw=raw: schema.decode(raw), args.number)
        bare = per_call_us(lambda raw=raw: msgpack.unpackb(raw, raw=False), args.number)
        print(f"{kind:8s} {len(raw):5d} {full:12.2f} us {dec:11.2f} us {bare:5.2f} us {full / bare:5.1f}x")
        if kind == "beacon":
            beacon_us = full
    per_s = 20 * 19 * 10
    print(f"\n20 agents at 10 Hz decode {per_s} beacons/s: {per_s * beacon_us / 1e3:.1f} ms of CPU per second "
          f"({per_s * beacon_us / 1e4:.2f}% of one core)")


if __name__ == "__main__":
    main()
