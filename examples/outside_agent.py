"""A minimal outside agent for a TRUAV swarm: flies one UAV by the wire protocol (docs/reference/protocol.md).

Only zenoh (pip install eclipse-zenoh) and msgpack; nothing of TRUAV is imported. Its policy is a seeded
random heading, the same sequence in every run with the same --seed and --id. Run it beside a world:

    python examples/outside_agent.py --id 2 --run demo --lockstep -e tcp/127.0.0.1:7447
    python examples/outside_agent.py --id 2 --run demo -c creds/uav-2.json5        # a --secure swarm
"""
import argparse
import json
import math
import queue
import random
import time

import msgpack
import zenoh

HALF, FULL, N_ACTIONS = 0.5, 1.0, 16  # actions 0-7 at half speed, 8-15 at full; heading 45 deg x (a % 8)


def velocity(action: int, speed_max: float) -> list[float]:
    """The velocity (m/s) the world flies for an action: heading 45 deg x (a % 8) counterclockwise from east."""
    angle = math.radians(45.0 * (action % 8))
    v = (HALF if action < 8 else FULL) * speed_max
    return [v * math.cos(angle), v * math.sin(angle)]


class Sender:
    """Stamps the envelope: v, kind, src, seq (per kind, from 0), t (ns since the epoch), inc."""

    def __init__(self, session: zenoh.Session, uav: int):
        self.session, self.src, self.seq = session, f"uav/{uav}", {}
        self.inc = random.SystemRandom().getrandbits(63) or 1  # this start's incarnation

    def send(self, key: str, kind: str, **body) -> None:
        seq = self.seq.get(kind, 0)
        self.seq[kind] = seq + 1
        msg = {"v": 1, "kind": kind, "src": self.src, "seq": seq, "t": time.time_ns(), "inc": self.inc, **body}
        self.session.put(key, msgpack.packb(msg))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--id", type=int, required=True, help="UAV id in [0, n_uavs)")
    ap.add_argument("--run", default="demo", help="run name: keys live under truav/<run>/")
    ap.add_argument("--lockstep", action="store_true", help="the world runs in lock-step (answer done too)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the random policy")
    ap.add_argument("-e", "--connect", action="append", default=[], help="router endpoint (default tcp/127.0.0.1:7447)")
    ap.add_argument("-c", "--config", help="zenoh JSON5 config (a --secure swarm: uav-<id>.json5 of its credentials)")
    ap.add_argument("--timeout", type=float, default=3600.0, help="give up after this many seconds")
    ap.add_argument("--bad-action", type=int, help="(to see a rejection) send this action at the first tick")
    args = ap.parse_args()
    if args.id < 0:
        ap.error(f"--id {args.id}: UAV ids start at 0")
    try:  # a missing config, a bad endpoint, no router there: one line, not a traceback
        conf = zenoh.Config.from_file(args.config) if args.config else zenoh.Config()
        conf.insert_json5("mode", '"client"')
        conf.insert_json5("scouting/multicast/enabled", "false")
        if args.connect or not args.config:
            conf.insert_json5("connect/endpoints", json.dumps(args.connect or ["tcp/127.0.0.1:7447"]))
        session = zenoh.open(conf)
    except zenoh.ZError as exc:
        ap.error(f"-e/-c: no zenoh session ({str(exc).split(' at /')[0]}); is the swarm's router up?")
    base, me = f"truav/{args.run}", args.id
    rng = random.Random(args.seed * 1024 + me)
    inbox: queue.Queue = queue.Queue()
    answered = 0
    try:
        out = Sender(session, me)

        def on_obs(sample: zenoh.Sample) -> None:
            inbox.put(msgpack.unpackb(sample.payload.to_bytes()))

        def on_control(sample: zenoh.Sample) -> None:
            msg = msgpack.unpackb(sample.payload.to_bytes())
            if isinstance(msg, dict) and msg.get("src") in ("world", "supervisor") and msg.get("command") == "shutdown":
                inbox.put(None)  # the world's at the run's end; the supervisor's (`truav-swarm down`) before it

        def on_rejected(sample: zenoh.Sample) -> None:  # what the world refused of ours (at most 10 a second)
            r = msgpack.unpackb(sample.payload.to_bytes())
            print(f"uav {me}: the world refused {r['refused_kind']} on {r['key']} at tick {r['at_tick']}: "
                  f"{r['reason']} ({r['detail']}); since the last notice: {r['counts']}", flush=True)

        subs = [session.declare_subscriber(f"{base}/uav/{me}/obs", on_obs),
                session.declare_subscriber(f"{base}/control/shutdown", on_control),
                session.declare_subscriber(f"{base}/uav/{me}/rejected", on_rejected)]
        token = session.liveliness().declare_token(f"{base}/alive/uav/{me}")  # the world waits for it
        vel, last_tick, end = [0.0, 0.0], -1, time.monotonic() + args.timeout
        while time.monotonic() < end:
            try:
                obs = inbox.get(timeout=1.0)
            except queue.Empty:
                continue
            while obs is not None and not args.lockstep and not inbox.empty():
                obs = inbox.get_nowait()  # real time: only the newest observation matters
            if obs is None:
                break
            if obs.get("kind") != "obs" or obs.get("uav") != me or obs["tick"] <= last_tick:
                continue
            tick, last_tick = obs["tick"], obs["tick"]
            if obs["done"] and not args.lockstep:
                continue  # real time: neither beacon nor answer for `done` (an answer would count as late)
            # Lock-step: every observation, `done` included, gets a beacon (the peers wait for it), then an action.
            out.send(f"{base}/uav/{me}/beacon", "beacon", uav=me, tick=tick, pos=obs["pos"], vel=vel)
            if obs["done"]:  # the acknowledgement the world waits for; its action is ignored
                out.send(f"{base}/uav/{me}/action", "action", uav=me, tick=tick, action=0)
                continue
            action = rng.randrange(N_ACTIONS)
            sent = args.bad_action if args.bad_action is not None and answered == 0 else action
            out.send(f"{base}/uav/{me}/action", "action", uav=me, tick=tick, action=sent)
            vel = velocity(sent, obs["speed_max"]) if 0 <= sent < N_ACTIONS else [0.0, 0.0]  # refused: it hovers
            answered += 1
        print(f"uav {me}: answered {answered} observations, last tick {last_tick}", flush=True)
        token.undeclare()
        for sub in subs:
            sub.undeclare()
    finally:
        session.close()  # always: a session left open after its router vanished can hang at exit
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
