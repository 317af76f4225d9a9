"""Throughput of the MCAP recorder: ``python bench/bench_recorder.py [--quick]``.

Measures sustained ``McapLog.write`` calls per second (zstd, default 50 ms
time-based chunk flush, writing a real temp file) for

* beacons only: ~100-byte msgpack payloads from 20 UAVs, with and without
  their JSON mirrors;
* the swarm mix: per tick 20 x (beacon + obs + action) + tick + positions +
  step metrics, with JSON mirrors for beacons, positions and metrics;

and, for reference, mcap's own ``Writer.add_message`` on the same beacons (no
envelope decoding, no stats, no mirrors).  Prints each figure against the
100,000 msgs/s target and against what a 20-agent swarm at 10 Hz needs.
Payloads are built with msgpack directly, with the same fields and sizes as
``truav.wire.schema`` (so the bench does not depend on it).

``--bus`` runs ``bench/bench_recorder_bus.py`` instead: the recorder
*process* fed over Zenoh (router, recorder and publisher processes on
loopback), its sustained rate and losses, and the 20-agent 10 Hz swarm mix.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Callable

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from recorder.mcap_log import McapLog  # noqa: E402
from recorder_payloads import (  # noqa: E402  (bench/ is on sys.path)
    N_UAVS, SWARM_MSGS_PER_TICK, TARGET_MSGS_S, TICK_HZ, WORLD_MSGS_PER_TICK, Batch, beacons, swarm_mix)

SWARM_MSGS_S = SWARM_MSGS_PER_TICK * TICK_HZ


def run_mcaplog(batch: Batch, path: str, mirrors: bool) -> float:
    """msgs/s over the whole life of a log: open, write everything, close."""
    start = time.perf_counter()
    with McapLog(path, mirrors=mirrors) as log:
        write = log.write
        for key, payload, log_time in batch:
            write(key, payload, log_time)
    return len(batch) / (time.perf_counter() - start)


def run_mcap_writer(batch: Batch, path: str) -> float:
    """Reference: the official mcap Writer with one channel per key, nothing else."""
    from mcap.writer import Writer

    start = time.perf_counter()
    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start()
        schema = writer.register_schema("truav.beacon", "jsonschema", b"{}")
        channels: dict[str, int] = {}
        for key, payload, log_time in batch:
            cid = channels.get(key)
            if cid is None:
                cid = channels[key] = writer.register_channel(key, "msgpack", schema)
            writer.add_message(cid, log_time, payload, log_time)
        writer.finish()
    return len(batch) / (time.perf_counter() - start)


def best_of(repeats: int, fn: Callable[[], float]) -> tuple[float, float]:
    runs = [fn() for _ in range(repeats)]
    return max(runs), statistics.median(runs)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="fewer messages (smoke run)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--bus", action="store_true", help="measure the recorder process fed over Zenoh instead")
    args = parser.parse_args(argv)
    if args.bus:
        from bench_recorder_bus import main as bus_main  # bench/ is on sys.path when run as a script

        bus_main(["--quick"] if args.quick else [])
        return
    n = 50_000 if args.quick else 300_000
    beacon_batch = beacons(n)
    mix_batch = swarm_mix(max(1, n // (N_UAVS * 3 + WORLD_MSGS_PER_TICK)))
    sizes = [len(p) for _, p, _ in beacon_batch]
    print(f"beacon payload: {min(sizes)}-{max(sizes)} bytes; mix: {len(mix_batch)} msgs, "
          f"mean {sum(len(p) for _, p, _ in mix_batch) / len(mix_batch):.0f} bytes")
    print(f"target {TARGET_MSGS_S:,} msgs/s; 20-agent 10 Hz swarm needs "
          f"({N_UAVS}x3 + {WORLD_MSGS_PER_TICK}) x {TICK_HZ} = {SWARM_MSGS_S:,} msgs/s")
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "bench.mcap")
        cases = [
            ("McapLog beacons, zstd, no mirrors", lambda: run_mcaplog(beacon_batch, path, mirrors=False)),
            ("McapLog beacons, zstd, + JSON mirrors", lambda: run_mcaplog(beacon_batch, path, mirrors=True)),
            ("McapLog swarm mix, zstd, + JSON mirrors", lambda: run_mcaplog(mix_batch, path, mirrors=True)),
            ("reference: mcap Writer.add_message, beacons", lambda: run_mcap_writer(beacon_batch, path)),
        ]
        print(f"\n{'case':46} {'best msgs/s':>12} {'median':>10} {'vs target':>10} {'vs swarm':>9}")
        for name, fn in cases:
            best, median = best_of(args.repeats, fn)
            print(f"{name:46} {best:12,.0f} {median:10,.0f} {median / TARGET_MSGS_S:9.2f}x "
                  f"{median / SWARM_MSGS_S:8.0f}x")
        run_mcaplog(mix_batch, path, mirrors=True)
        ratio = sum(len(p) for _, p, _ in mix_batch) / os.path.getsize(path)
        print(f"\nswarm mix file: {os.path.getsize(path):,} bytes for "
              f"{sum(len(p) for _, p, _ in mix_batch):,} payload bytes (x{ratio:.2f} incl. mirrors/indexes)")


if __name__ == "__main__":
    main()
