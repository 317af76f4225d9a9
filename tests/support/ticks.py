"""Synthesised world ticks in a recording (McapLog, no network), for the replay tests: what was written,
and what a seek restores."""

from __future__ import annotations

from pathlib import Path

import msgpack

from recorder.mcap_log import McapLog
from truav.wire import keys, schema

RUN = "seek"
T0 = 1_700_000_000_000_000_000
MS = 1_000_000
N_UAVS = 2


def tick_messages(run: str, tick: int) -> list[tuple[str, bytes]]:
    """One world tick as the bus carries it: tick, an observation per UAV, UAV 0's beacon, a step metric."""
    world, uav0 = schema.Sequencer("world"), schema.Sequencer("uav/0")
    out = [(keys.world_tick(run), schema.encode(world.stamp(schema.Tick(
        tick=tick, episode=0, sim_time=float(tick), deadline_ms=80.0, n_uavs=N_UAVS))))]
    for uav in range(N_UAVS):
        out.append((keys.uav_obs(run, uav), schema.encode(world.stamp(schema.Obs(
            tick=tick, episode=0, uav=uav, pos=(100.0 * uav, float(tick)), vehicles_in_range=1, queued_packets=0,
            relayed=0, covered=1, energy_j=1.0, speed_max=15.0, done=False)))))
    out.append((keys.uav_beacon(run, 0), schema.encode(uav0.stamp(schema.Beacon(
        uav=0, tick=tick, pos=(0.0, float(tick)), vel=(0.0, 1.0))))))
    out.append((keys.metrics_step(run), schema.encode(world.stamp(schema.Metrics(
        scope="step", tick=tick, episode=0, values={"coverage_pct": float(tick)})))))
    return out


PER_TICK = 2 + N_UAVS + 1  # tick, obs per UAV, beacon, metrics


def write_ticks(log: McapLog, run: str, ticks: range, gap_ms: float) -> list[tuple[str, bytes, int]]:
    written = []
    for tick in ticks:
        t = T0 + round(tick * gap_ms * MS)
        for k, (key, payload) in enumerate(tick_messages(run, tick)):
            log.write(key, payload, t + k * 1000)
            written.append((key, payload, t + k * 1000))
    return written


def make_ticks(path: Path, ticks: int = 60, gap_ms: float = 10.0, run: str = RUN) -> list[tuple[str, bytes, int]]:
    with McapLog(path) as log:
        return write_ticks(log, run, range(ticks), gap_ms)


def last_before(written: list[tuple[str, bytes, int]], tick: int) -> list[tuple[str, bytes]]:
    """Each channel's last message before world tick ``tick`` starts, in recorded order."""
    cut = next(i for i, (k, p, _) in enumerate(written) if k.endswith("/world/tick") and msgpack.unpackb(p)["tick"] == tick)
    last: dict[str, tuple[str, bytes, int]] = {}
    for item in written[:cut]:
        last[item[0]] = item
    return [(k, p) for k, p, _ in sorted(last.values(), key=lambda w: w[2])]


def landed_on(written: list[tuple[str, bytes, int]], tick: int) -> list[tuple[str, bytes]]:
    """What a seek to world tick ``tick`` sends: each channel's last message before the tick starts, then the
    tick's own world tick message (the seek lands on that tick: its status says ``tick``)."""
    start = next((k, p) for k, p, _ in written if k.endswith("/world/tick") and msgpack.unpackb(p)["tick"] == tick)
    return [m for m in last_before(written, tick) if not m[0].endswith("/world/tick")] + [start]


def of_tick(written: list[tuple[str, bytes, int]], tick: int) -> list[tuple[str, bytes]]:
    return [(k, p) for k, p, _ in written if msgpack.unpackb(p)["tick"] == tick]
