"""The state snapshots a lock-step recording holds (`truav-swarm up --lockstep --record`, every
--snapshot-every ticks): the world's (world/snapshot) and every agent's (uav/<i>/snapshot) of one tick.

A branch (`truav log resim --from TICK`) restores the latest complete one at or before TICK instead of
re-simulating from tick 0 (recorder.resim_branch); a snapshot is complete when the world's and every
agent's of its tick were recorded and decode. Only the snapshot messages are read, one tick's kept at a
time, so memory stays that of one snapshot whatever the recording's length.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Iterator

import numpy as np

from recorder.reader import iter_messages
from truav.wire import keys, schema
from truav.wire.snapshot_messages import state_arrays


MAX_PENDING_TICKS = 4
"""Incomplete snapshot ticks kept while reading: one tick's messages arrive together, so an older tick
still incomplete never completes (its memory is freed)."""


@dataclass
class Snapshot:
    """One tick's recorded state: the world's and every agent's (in UAV order)."""

    tick: int
    episode: int
    world: dict[str, np.ndarray]
    agents: list[dict[str, np.ndarray]]


def _snapshot_messages(path: str | os.PathLike[str], run: str):
    agents = f"{keys.prefix(run)}/{keys.UAV}/*/{keys.SNAPSHOT}"
    for _, payload, _, _ in iter_messages(path, include=[keys.world_snapshot(run), agents]):
        try:
            msg = schema.decode(payload)
        except schema.SchemaError:
            continue  # a damaged snapshot: that tick is not complete
        if isinstance(msg, (schema.WorldSnapshot, schema.AgentSnapshot)):
            yield msg


def iter_snapshots(path: str | os.PathLike[str], run: str, n_uavs: int) -> Iterator[Snapshot]:
    """Every complete snapshot of run ``run``, in the order the recording completes them (tick order)."""
    world: dict[int, schema.WorldSnapshot] = {}
    agents: dict[int, dict[int, schema.AgentSnapshot]] = {}
    last = -1
    for msg in _snapshot_messages(path, run):
        tick = msg.tick
        if tick <= last:
            continue  # a duplicate of a tick already handed out
        if isinstance(msg, schema.WorldSnapshot):
            world.setdefault(tick, msg)
        elif msg.uav < n_uavs:
            agents.setdefault(tick, {}).setdefault(msg.uav, msg)
        for stale in sorted({*world, *agents})[:-MAX_PENDING_TICKS]:  # never completed (an agent's was lost)
            world.pop(stale, None)
            agents.pop(stale, None)
        if tick in world and len(agents.get(tick, {})) == n_uavs:
            yield Snapshot(tick, world[tick].episode, state_arrays(world[tick].arrays),
                           [state_arrays(agents[tick][i].arrays) for i in range(n_uavs)])
            last = tick
            for older in [t for t in (*world, *agents) if t <= tick]:
                world.pop(older, None)
                agents.pop(older, None)


def latest_snapshot(path: str | os.PathLike[str], run: str, n_uavs: int, at_or_before: int) -> Snapshot | None:
    """The latest complete snapshot of run ``run`` at or before tick ``at_or_before``, or None."""
    best = None
    for snap in iter_snapshots(path, run, n_uavs):
        if snap.tick > at_or_before:
            break
        best = snap
    return best


def differing_arrays(snap: Snapshot, world: dict[str, np.ndarray], agents: list[dict[str, np.ndarray]],
                     run: str) -> list[tuple[str, str]]:
    """(key, array name) of every array of ``snap`` not bit for bit the state given (a re-simulation's), the
    world's first, then each agent's; an array missing on either side counts."""
    from world.world_state import upgraded  # a snapshot from an older version, as this one captures it

    out = []
    pairs = [(keys.world_snapshot(run), upgraded(snap.world), world)] + \
        [(keys.uav_snapshot(run, i), rec, mine) for i, (rec, mine) in enumerate(zip(snap.agents, agents))]
    for key, recorded, simulated in pairs:
        for name in sorted(set(recorded) | set(simulated)):
            a, b = recorded.get(name), simulated.get(name)
            if a is None or b is None or a.dtype != b.dtype or a.shape != b.shape or a.tobytes() != b.tobytes():
                out.append((key, name))
    return out


__all__ = ["Snapshot", "differing_arrays", "iter_snapshots", "latest_snapshot"]
