"""Hostile traffic for a running swarm, as an attacker with a bare zenoh session would send it.

Used by tests/swarm/test_security.py (small floods) and, run as a script, to measure
the full-size floods of issue 14 against a `truav-swarm up` on loopback:

    python bench/hostile.py --endpoint tcp/127.0.0.1:7447 --run demo --agents 5 \\
        --malformed 100000 --large 300 --unique-senders 1000000

Every flood is built with the project's own schema (valid-looking envelopes)
or from plain garbage; nothing here is needed by the swarm itself.
"""

from __future__ import annotations

import argparse
import itertools
import time

import msgpack
import zenoh

from truav.wire import keys, schema

GARBAGE = (b"", b"\xc1", b"\x00" * 7, b"\xde\xff\xff", msgpack.packb([1, 2, 3]), msgpack.packb({"v": 1}),
           msgpack.packb({"v": 1, "kind": "obs"}), msgpack.packb({"v": 2, "kind": "beacon"}),
           b"\x92\xc0" * 50, msgpack.packb("x" * 300))


def live_keys(run: str, n_uavs: int) -> list[str]:
    """Every key a swarm process listens on."""
    out = [keys.world_tick(run), keys.world_positions(run), keys.metrics_step(run), keys.metrics_episode(run),
           keys.control(run, "shutdown"), keys.control(run, "faults"), keys.control(run, "recorder"),
           keys.fault(run, "loss")]
    for i in range(n_uavs):
        out += [keys.uav_obs(run, i), keys.uav_beacon(run, i), keys.uav_action(run, i)]
    return out


def forged(run: str, n_uavs: int, seq: int = 0) -> list[tuple[str, bytes]]:
    """Schema-valid messages with forged senders or impossible values, one per attack of issue 14."""
    def stamp(src, msg):
        m = schema.Sequencer(src).stamp(msg)
        object.__setattr__(m, "seq", seq)
        return schema.encode(m)
    out = [
        (keys.control(run, "shutdown"), stamp("mallory", schema.Control(command="shutdown", args={}))),
        (keys.control(run, "recorder"), stamp("mallory", schema.Control(command="stop", args={}))),
        (keys.control(run, "faults"), stamp("mallory", schema.Control(command="faults", args={
            "seed": 0, "fault": [{"kind": "loss", "probability": 1.0, "start": 0.0, "duration": 1e6}]}))),
    ]
    for i in range(n_uavs):
        out.append((keys.uav_obs(run, i), stamp("mallory", schema.Obs(
            tick=1, episode=0, uav=i, pos=(1.0, 1.0), vehicles_in_range=10 ** 15, queued_packets=0,
            relayed=10 ** 15, covered=10 ** 15, energy_j=0.0, speed_max=15.0, done=False))))
        out.append((keys.uav_action(run, i), stamp("replay", schema.Action(uav=i, tick=1, action=3))))
        out.append((keys.uav_beacon(run, i), stamp(keys.uav_identity(i), schema.Beacon(
            uav=i, tick=2 ** 62, pos=(1.0, 1.0), vel=(0.0, 0.0)))))
    return out


def large_obs_payload(run: str, uav: int, size: int = 1 << 20) -> bytes:
    """~``size`` bytes that start like a valid observation and carry many extra keys."""
    body = {"v": 1, "kind": "obs", "src": "world", "seq": 0, "t": time.time_ns(), "tick": 0, "episode": 0,
            "uav": uav, "pos": [0.0, 0.0], "vehicles_in_range": 0, "queued_packets": 0, "relayed": 0,
            "covered": 0, "energy_j": 0.0, "speed_max": 1.0, "done": False, "densest_sector": 0}
    n = 0
    while True:
        chunk = {f"x{n + k}": k for k in range(10_000)}
        body.update(chunk)
        n += len(chunk)
        data = msgpack.packb(body)
        if len(data) >= size - 100_000:
            return data[:size] if len(data) > size else data


def flood(session: zenoh.Session, run: str, n_uavs: int, *, malformed: int = 0, large: int = 0,
          unique_senders: int = 0, pace_every: int = 2000, pace_s: float = 0.002,
          large_pace_s: float = 0.0) -> dict[str, int]:
    """Send the floods; returns how many messages of each kind were put.

    ``malformed`` garbage payloads per live key (cycling :data:`GARBAGE`) plus
    the forged ones; ``large`` 1 MB pseudo-observations spread over the agents;
    ``unique_senders`` valid-looking beacons, each from a new sender name.
    A short pause every ``pace_every`` puts keeps the attacker from owning both
    cores of a small test machine (the point is what the swarm survives);
    ``large_pace_s`` spaces the 1 MB payloads."""
    sent = {"malformed": 0, "forged": 0, "large": 0, "unique_senders": 0}
    counter = itertools.count()

    def put(key: str, data: bytes, what: str) -> None:
        session.put(key, data, congestion_control=zenoh.CongestionControl.BLOCK)
        sent[what] += 1
        if next(counter) % pace_every == pace_every - 1:
            time.sleep(pace_s)

    live = live_keys(run, n_uavs)
    for n in range(malformed):
        for key in live:
            put(key, GARBAGE[n % len(GARBAGE)], "malformed")
        if n % 50 == 0:
            for key, data in forged(run, n_uavs, n):
                put(key, data, "forged")
    if large:
        blob = [large_obs_payload(run, i % n_uavs) for i in range(min(n_uavs, 4))]
        for n in range(large):
            put(keys.uav_obs(run, n % n_uavs), blob[n % len(blob)], "large")
            if large_pace_s:
                time.sleep(large_pace_s)
    for n in range(unique_senders):
        i = n % n_uavs
        raw = msgpack.packb({"v": 1, "kind": "beacon", "src": f"m{n}", "seq": n, "t": time.time_ns(), "uav": i,
                             "tick": 0, "pos": [0.0, 0.0], "vel": [0.0, 0.0]})
        put(keys.uav_beacon(run, i), raw, "unique_senders")
    return sent


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--endpoint", required=True)
    ap.add_argument("--run", default="demo")
    ap.add_argument("--agents", type=int, default=5)
    ap.add_argument("--malformed", type=int, default=0, help="garbage messages per live key")
    ap.add_argument("--large", type=int, default=0, help="1 MB hostile observations")
    ap.add_argument("--unique-senders", type=int, default=0, help="beacons from this many distinct sender names")
    args = ap.parse_args()
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", f'["{args.endpoint}"]')
    conf.insert_json5("scouting/multicast/enabled", "false")
    t0 = time.monotonic()
    with zenoh.open(conf) as session:
        sent = flood(session, args.run, args.agents, malformed=args.malformed, large=args.large,
                     unique_senders=args.unique_senders)
    print(f"sent {sent} in {time.monotonic() - t0:.1f} s")


if __name__ == "__main__":
    main()
