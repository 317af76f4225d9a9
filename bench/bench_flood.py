"""A plain (no --secure) real-time swarm under the floods of issue 14, measured.

    python bench/bench_flood.py                          # 5 agents; 100k garbage per live key, 300 x 1 MB,
                                                         # a million unique sender names
    python bench/bench_flood.py --malformed 1000 --large 20 --unique-senders 20000   # a quick look

Starts `truav-swarm up` (its own loopback router), waits for the first ticks,
floods it from a bare zenoh session (bench/hostile.py), samples every swarm
process's resident memory while it does, then lets the run finish and prints:
per-process memory before / peak / after, whether every process lived,
missed actions (target <= 1%), and the world's rejections by reason.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

import zenoh  # noqa: E402

from bench.hostile import flood  # noqa: E402
from truav.bus import transport  # noqa: E402


def rss_mb(pid: int) -> float:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return float("nan")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--agents", type=int, default=5)
    ap.add_argument("--malformed", type=int, default=100_000, help="garbage messages per live key")
    ap.add_argument("--large", type=int, default=300, help="1 MB hostile observations")
    ap.add_argument("--unique-senders", type=int, default=1_000_000)
    ap.add_argument("--large-pace-ms", type=float, default=0.0, help="pause between 1 MB payloads")
    ap.add_argument("--steps", type=int, default=20_000, help="steps of the run (it is stopped after the flood)")
    args = ap.parse_args()
    out = Path(tempfile.mkdtemp(prefix="truav-bench-flood-"))
    run = "flood"
    log = open(out / "up.log", "wb")
    up = subprocess.Popen([sys.executable, "-m", "truav.swarm.cli", "up", "--run", run, "--agents", str(args.agents),
                           "--steps", str(args.steps), "--episodes", "1", "--out", str(out / "swarm"), "--quiet",
                           "--no-plot"], stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        while "world +" not in (out / "up.log").read_text():
            time.sleep(0.2)
            if up.poll() is not None:
                raise SystemExit((out / "up.log").read_text())
        endpoint = (out / "up.log").read_text().split("router ", 1)[1].split(",", 1)[0]
        pids = json.loads((out / "swarm" / "pids.json").read_text())
        with zenoh.open(transport.make_config("client", connect=[endpoint])) as s:
            ticks = []
            s.declare_subscriber(f"truav/{run}/metrics/step", lambda sample: ticks.append(1))
            while len(ticks) < 20:
                time.sleep(0.1)
            time.sleep(2.0)  # settled
            phases = []
            alive = {}
            for name, kw in (("malformed", {"malformed": args.malformed}),
                             ("large", {"large": args.large, "large_pace_s": args.large_pace_ms / 1e3}),
                             ("unique-senders", {"unique_senders": args.unique_senders})):
                if not next(iter(kw.values())):  # the flood's size
                    continue
                before = {n: rss_mb(p) for n, p in pids.items()}
                peak = dict(before)
                done = threading.Event()

                def sample() -> None:
                    while not done.wait(0.5):
                        for n, p in pids.items():
                            peak[n] = max(peak[n], rss_mb(p))

                threading.Thread(target=sample, daemon=True).start()
                t0 = time.monotonic()
                sent = flood(s, run, args.agents, **kw)
                took = time.monotonic() - t0
                time.sleep(3.0)  # the receivers work off what is queued
                done.set()
                after = {n: rss_mb(p) for n, p in pids.items()}
                alive = {n: Path(f"/proc/{p}").exists() for n, p in pids.items()}
                phases.append((name, sent, took, before, peak, after))
        up.send_signal(signal.SIGTERM)  # ends the run like Ctrl-C: summary, statistics
        up.wait(120)
    finally:
        if up.poll() is None:
            up.kill()
            up.wait()
        log.close()
    for name, sent, took, before, peak, after in phases:
        print(f"\nflood {name}: {sent} in {took:.1f} s")
        print(f"  {'process':10s} {'before':>8s} {'peak':>8s} {'after':>8s}  MB (growth: peak - before)")
        for n in before:
            print(f"  {n:10s} {before[n]:8.1f} {peak[n]:8.1f} {after[n]:8.1f}  (+{peak[n] - before[n]:.1f})")
    print("every process alive after the floods:", all(alive.values()), {n: a for n, a in alive.items() if not a})
    world = json.loads((out / "swarm" / "world.json").read_text())
    steps = world["ticks"] - 1
    print(f"ticks {world['ticks']}, missed actions {world['deadline_misses']} of {steps * args.agents} "
          f"({100 * world['deadline_misses'] / max(steps * args.agents, 1):.2f}%)")
    print("world rejections by reason:", {r: sum(v.values()) for r, v in world["rejected"].items()})
    print(f"(details in {out})")


if __name__ == "__main__":
    main()
