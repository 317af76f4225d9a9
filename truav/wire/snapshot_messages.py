"""Snapshot messages from state arrays and back: a world's (world.world_state) and an agent's
(agents.decision_state) named numpy arrays as the schema's ``[dtype, shape, data]`` triples
(schema.WorldSnapshot, schema.AgentSnapshot). Pure, no I/O.

A state too large for one message (MAX_SNAPSHOT_BYTES: a city of tens of thousands of vehicles, or an agent
that updated more than ~7,000 Q-table rows) is not published: :func:`fits` says so before encoding."""

from __future__ import annotations

import numpy as np

from truav.options import opt
from truav.wire import schema

SNAPSHOT_EVERY = 100
"""Default of --snapshot-every: a recorded lock-step run's state every 100 ticks."""


def snapshot_every_option():
    """The --snapshot-every field of the world's and the agents' options (one declaration for both: they
    must snapshot at the same ticks)."""
    return opt(SNAPSHOT_EVERY, flag="--snapshot-every", type="non_negative_int", metavar="TICKS",
               help=f"lock-step with --record: the world and every agent publish their whole state every TICKS "
                    f"ticks, so `truav log resim --from` restores from the latest one instead of tick 0 "
                    f"(default {SNAPSHOT_EVERY}; 0: none)")


def snapshot_due(lockstep: bool, every: int, tick: int) -> bool:
    """Whether tick ``tick``'s round starts with a snapshot (the world's and every agent's)."""
    return lockstep and every > 0 and tick % every == 0

_ENVELOPE_ALLOWANCE = 1024
"""Bytes kept for the envelope, the keys and the msgpack headers of a snapshot's arrays."""


def wire_arrays(state: dict[str, np.ndarray]) -> schema.SnapshotArrays:
    """``state``'s arrays as [dtype, shape, little-endian bytes] (each float64, int64 or uint64)."""
    out = {}
    for name, a in state.items():
        a = np.asarray(a)
        dtype = a.dtype.newbyteorder("<")
        if dtype.str not in ("<f8", "<i8", "<u8"):
            raise ValueError(f"state array {name} is {a.dtype}: only float64, int64 and uint64 travel")
        out[name] = (dtype.str, tuple(int(n) for n in a.shape), np.ascontiguousarray(a, dtype).tobytes())
    return out


def state_arrays(arrays: schema.SnapshotArrays) -> dict[str, np.ndarray]:
    """The numpy arrays of a (schema-checked) snapshot message's ``arrays``, each its own copy."""
    return {name: np.frombuffer(data, np.dtype(dtype)).reshape(shape).astype(np.dtype(dtype).newbyteorder("="))
            for name, (dtype, shape, data) in arrays.items()}


def fits(state: dict[str, np.ndarray]) -> bool:
    """Whether ``state`` fits one snapshot message (its arrays' bytes and an allowance for the rest)."""
    return len(state) <= schema.MAX_SNAPSHOT_ARRAYS and \
        sum(np.asarray(a).nbytes + 64 for a in state.values()) + _ENVELOPE_ALLOWANCE <= schema.MAX_SNAPSHOT_BYTES


def world_snapshot(tick: int, episode: int, state: dict[str, np.ndarray]) -> schema.WorldSnapshot:
    return schema.WorldSnapshot(tick=tick, episode=episode, arrays=wire_arrays(state))


def agent_snapshot(uav: int, tick: int, state: dict[str, np.ndarray]) -> schema.AgentSnapshot:
    return schema.AgentSnapshot(uav=uav, tick=tick, arrays=wire_arrays(state))


__all__ = ["SNAPSHOT_EVERY", "agent_snapshot", "fits", "snapshot_due", "snapshot_every_option", "state_arrays", "wire_arrays", "world_snapshot"]
