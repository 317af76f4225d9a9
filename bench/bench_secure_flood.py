"""A `--secure` real-time swarm while agent 1's identity floods its own beacon key, measured.

    python bench/bench_secure_flood.py                    # 5 agents, 40 s at 10 Hz, a 20 s flood from second 10
    python bench/bench_secure_flood.py --duration 20 --flood-s 8

Starts `truav-swarm up --secure` (its own loopback router, the rate caps of truav.bus.security.rate_caps
in its config), waits --flood-at seconds, then opens a second session with agent 1's certificate (a
compromised agent: the ACL lets it put only on its own keys) and puts on uav/1/beacon as fast as it can
for --flood-s seconds: garbage (bench/hostile.py's) and schema-valid beacons stamped uav/1, which pass
every receiver's checks and are decoded. Prints the puts sent, the actions the world missed (all agents;
agent 1's own process is not slowed by the flooder's session) and the machine's load. Real-time
figures on a shared machine are noise unless the load is low: read them with the load printed.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

import zenoh  # noqa: E402

from bench.hostile import GARBAGE  # noqa: E402
from truav.bus import security
from truav.wire import keys, schema  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--agents", type=int, default=5)
    ap.add_argument("--duration", type=float, default=40.0, help="seconds of ticks (default 40)")
    ap.add_argument("--flood-at", type=float, default=10.0)
    ap.add_argument("--flood-s", type=float, default=20.0)
    ap.add_argument("--rate", type=float, default=10.0)
    ap.add_argument("--pace-s", type=float, default=0.0,
                    help="sleep this long after each put (on one machine the attacker's own CPU is part of the cost)")
    args = ap.parse_args()
    run = "secflood"
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "swarm"
        steps = int(args.duration * args.rate)
        cmd = [sys.executable, "-m", "truav.cli.swarm", "up", "--scheme", "truav", "--secure", "--run", run, "--agents", str(args.agents),
               "--steps", str(steps), "--episodes", "1", "--rate", str(args.rate), "--out", str(out),
               "--quiet", "--no-plot"]
        log = open(Path(tmp) / "up.log", "wb")
        proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT)
        try:
            deadline = time.monotonic() + 120
            while not (out / "creds" / security.MANIFEST).is_file() or not (out / "world.json").parent.is_dir():
                if time.monotonic() > deadline or proc.poll() is not None:
                    raise SystemExit("the swarm did not start: " + (Path(tmp) / "up.log").read_text())
                time.sleep(0.2)
            time.sleep(args.flood_at)
            creds = security.load(out / "creds", run)
            sent = 0
            with zenoh.open(zenoh.Config.from_file(str(creds.config_file("uav/1")))) as attacker:
                seq = schema.Sequencer("uav/1")
                key = keys.uav_beacon(run, 1)
                t0 = time.monotonic()
                while time.monotonic() - t0 < args.flood_s and proc.poll() is None:
                    if sent % 2:
                        data = GARBAGE[sent % len(GARBAGE)]
                    else:
                        data = schema.encode(seq.stamp(schema.Beacon(uav=1, tick=0, pos=(100.0, 100.0),
                                                                     vel=(0.0, 0.0))))
                    attacker.put(key, data, congestion_control=zenoh.CongestionControl.BLOCK)
                    sent += 1
                    if args.pace_s:
                        time.sleep(args.pace_s)
                flood_s = time.monotonic() - t0
            load = Path("/proc/loadavg").read_text().split()[:3]
            rc = proc.wait(timeout=args.duration + 180)
        finally:
            if proc.poll() is None:
                proc.terminate()
                proc.wait(timeout=60)
            log.close()
        world = json.loads((out / "world.json").read_text())
        summary = json.loads((out / "summary.json").read_text())
        expected = (world["ticks"] - 1) * args.agents
        missed = expected - world["actions_received"]
        caps = "downsampling" in json.loads((out / "creds" / security.ROUTER_CONFIG).read_text())
        print(f"exit {rc} ({summary['outcome']['result']}); router rate caps: {'on' if caps else 'OFF'}")
        print(f"flood: {sent} puts on {keys.uav_beacon(run, 1)} in {flood_s:.1f} s ({sent / flood_s:.0f}/s)")
        print(f"actions missed: {missed} of {expected} ({100 * missed / max(expected, 1):.2f}%), "
              f"ticks {world['ticks']}; load during the flood {' '.join(load)}")
        rejected = {}
        for i in range(args.agents):
            a = json.loads((out / f"agent{i}.json").read_text())
            for reason, by in (a["bus"]["rejected"] or {}).items():
                rejected[reason] = rejected.get(reason, 0) + sum(by.values())
        print(f"rejected by the agents: {rejected}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
