"""A plain (no --secure) real-time swarm under the floods of issue 14, measured.

    python bench/bench_flood.py                          # 5 agents, 30 s at 10 Hz; 100k garbage per live key,
                                                         # 300 x 1 MB, a million unique sender names
    python bench/bench_flood.py --malformed 2000 --large 300 --unique-senders 20000   # a quick look (~45 s)

Starts `truav-swarm up` (its own loopback router) for a run of --duration seconds
of ticks, waits --flood-at seconds after tick 0, floods it from a bare zenoh
session (bench/hostile.py), one phase after the other with --gap seconds
between, and lets the run end by itself. It prints, per phase: messages sent
and how long that took, every swarm process's CPU seconds and resident memory
(before / peak / after), the actions missed from the phase's start to the next
one's, and how long the disruption lasted (first to last tick with a missed
action). Then: every process alive, missed actions of the whole run (target
<= 1%) and outside the floods, the world's rejections by reason. The per-tick
misses come from the world's step metrics (`hovering_uavs`), heard through a
ring channel (a step metric lost under the flood shows as a tick not heard).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

import zenoh  # noqa: E402

from bench.hostile import flood  # noqa: E402
from truav import jsonio  # noqa: E402
from truav.bus import transport
from truav.wire import schema  # noqa: E402

CLK_TCK = os.sysconf("SC_CLK_TCK")


def rss_mb(pid: int) -> float:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return float("nan")


def cpu_s(pid: int) -> float:
    """User + system CPU seconds of a process so far (NaN once it is gone)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / CLK_TCK
    except (OSError, IndexError, ValueError):
        return float("nan")


class StepLog:
    """(tick -> UAVs without an action, wall time heard) from the world's step metrics."""

    def __init__(self, session: zenoh.Session, run: str) -> None:
        self.missed: dict[int, int] = {}
        self.heard_at: dict[int, float] = {}
        self._sub = session.declare_subscriber(f"truav/{run}/metrics/step", zenoh.handlers.RingChannel(1024))
        threading.Thread(target=self._pump, daemon=True).start()

    def _pump(self) -> None:
        handler = self._sub.handler
        while True:
            try:
                sample = handler.recv()
            except zenoh.ZError:
                return
            try:
                msg = schema.decode(sample.payload.to_bytes(), schema.KIND_METRICS)
            except schema.SchemaError:
                continue
            if msg.src == "world":
                self.missed[msg.tick] = int(msg.values.get("hovering_uavs", 0))
                self.heard_at[msg.tick] = time.time()

    def last_tick(self) -> int:
        return max(self.heard_at, default=-1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--agents", type=int, default=5)
    ap.add_argument("--duration", type=float, default=30.0, help="seconds of ticks in the run (at 10 Hz)")
    ap.add_argument("--flood-at", type=float, default=5.0, help="seconds after tick 0 when the first flood starts")
    ap.add_argument("--gap", type=float, default=3.0, help="seconds from the end of one flood to the next")
    ap.add_argument("--malformed", type=int, default=100_000, help="garbage messages per live key")
    ap.add_argument("--large", type=int, default=300, help="1 MB hostile observations")
    ap.add_argument("--unique-senders", type=int, default=1_000_000)
    ap.add_argument("--large-pace-ms", type=float, default=0.0, help="pause between 1 MB payloads")
    ap.add_argument("--json", metavar="FILE", help="also write the figures as JSON")
    args = ap.parse_args()
    rate = 10.0
    out = Path(tempfile.mkdtemp(prefix="truav-bench-flood-"))
    run = "flood"
    log = open(out / "up.log", "wb")
    up = subprocess.Popen([sys.executable, "-m", "truav.cli.swarm", "up", "--scheme", "truav", "--run", run, "--agents", str(args.agents),
                           "--steps", str(int(args.duration * rate)), "--episodes", "1", "--out", str(out / "swarm"),
                           "--quiet", "--no-plot"], stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    phases = []
    try:
        while "world +" not in (out / "up.log").read_text():
            time.sleep(0.2)
            if up.poll() is not None:
                raise SystemExit((out / "up.log").read_text())
        endpoint = (out / "up.log").read_text().split("router ", 1)[1].split(",", 1)[0]
        pids = {"supervisor": up.pid, **json.loads((out / "swarm" / "pids.json").read_text())}
        with zenoh.open(transport.make_config("client", connect=[endpoint])) as s:
            steps = StepLog(s, run)
            while steps.last_tick() < args.flood_at * rate:
                time.sleep(0.05)
                if up.poll() is not None:
                    raise SystemExit((out / "up.log").read_text())
            for name, kw in (("malformed", {"malformed": args.malformed}),
                             ("large", {"large": args.large, "large_pace_s": args.large_pace_ms / 1e3}),
                             ("unique-senders", {"unique_senders": args.unique_senders})):
                if not next(iter(kw.values())):  # the flood's size
                    continue
                before = {n: rss_mb(p) for n, p in pids.items()}
                cpu0 = {n: cpu_s(p) for n, p in pids.items()}
                peak = dict(before)
                done = threading.Event()

                def sample(peak=peak, done=done) -> None:
                    while not done.wait(0.25):
                        for n, p in pids.items():
                            peak[n] = max(peak[n], rss_mb(p))

                threading.Thread(target=sample, daemon=True).start()
                tick0, t0 = steps.last_tick() + 1, time.monotonic()
                sent = flood(s, run, args.agents, **kw)
                took = time.monotonic() - t0
                time.sleep(args.gap)
                done.set()
                after = {n: rss_mb(p) for n, p in pids.items()}
                cpu = {n: cpu_s(p) - cpu0[n] for n, p in pids.items()}
                phases.append({"name": name, "sent": sent, "took_s": took, "first_tick": tick0,
                               "end_tick": steps.last_tick() + 1, "window_s": time.monotonic() - t0,
                               "before": before, "peak": peak, "after": after, "cpu_s": cpu})
            alive = {n: Path(f"/proc/{p}").exists() for n, p in pids.items() if n != "supervisor"}
            up.wait(args.duration + 120)
    finally:
        if up.poll() is None:
            up.kill()
            up.wait()
        log.close()
    world = json.loads((out / "swarm" / "world.json").read_text())
    actions = (world["ticks"] - 1) * args.agents  # the last tick is the episode's done observation
    flood_missed = 0
    for ph in phases:
        ticks = range(ph["first_tick"], ph["end_tick"])
        missed = sum(steps.missed.get(t, 0) for t in ticks)
        unheard = sum(t not in steps.missed for t in ticks)
        bad = [t for t in ticks if steps.missed.get(t, 0)]
        ph.update(missed=missed, actions=len(ticks) * args.agents, ticks_unheard=unheard,
                  disruption_s=(bad[-1] - bad[0] + 1) / rate if bad else 0.0)
        flood_missed += missed
        print(f"\nflood {ph['name']}: {ph['sent']} in {ph['took_s']:.2f} s; ticks {ph['first_tick']}-{ph['end_tick'] - 1}"
              f" ({ph['window_s']:.1f} s): missed {missed} of {ph['actions']} actions, disruption "
              f"{ph['disruption_s']:.1f} s" + (f" ({unheard} ticks' metrics not heard)" if unheard else ""))
        print(f"  {'process':10s} {'CPU s':>6s} {'before':>8s} {'peak':>8s} {'after':>8s}  MB (growth: peak - before)")
        for n in ph["before"]:
            print(f"  {n:10s} {ph['cpu_s'][n]:6.2f} {ph['before'][n]:8.1f} {ph['peak'][n]:8.1f} {ph['after'][n]:8.1f}"
                  f"  (+{ph['peak'][n] - ph['before'][n]:.1f})")
    print("\nevery process alive after the floods:", all(alive.values()), {n: a for n, a in alive.items() if not a})
    total = world["deadline_misses"]
    print(f"run: {world['ticks']} ticks, missed actions {total} of {actions} ({100 * total / max(actions, 1):.2f}%; "
          f"target <= 1%); outside the floods {total - flood_missed}")
    print("world rejections by reason:", {r: sum(v.values()) for r, v in world["rejected"].items()})
    print(f"(details in {out})")
    if args.json:
        Path(args.json).write_text(jsonio.dumps({"phases": phases, "ticks": world["ticks"], "missed": total,
                                               "actions": actions, "alive": alive}, indent=1))


if __name__ == "__main__":
    main()
