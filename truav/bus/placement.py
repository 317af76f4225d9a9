"""Which message kind belongs on which key, and what that implies: the payload limit of a key, its
congestion control, and whether a message may appear on it (:func:`check_placement`).

The key-to-kind table is derived from the schema: each message class names the key chunks it lives on
(``PLACE``, built from :mod:`truav.wire.keys`' names)."""

from __future__ import annotations

import functools
from typing import NamedTuple

import zenoh

from truav.wire import keys, schema
from truav.wire.schema import Message, SchemaError

# Drop reasons added by the Bus on top of the schema's R_* reasons.
R_KEY_MISMATCH = "key_mismatch"  # payload does not belong on that key (kind, uav id, src)

# Kinds where the freshest value wins and loss is tolerable: published with
# CongestionControl.DROP.  Everything else (tick, obs, action, metrics, fault,
# control, and unknown keys) uses BLOCK, so a full queue delays rather than
# silently drops it.  Zenoh's default is DROP, which under CPU load drops even
# small messages queued behind a large one (seen in tests with 1 MiB payloads).
DROPPABLE_KINDS = frozenset({schema.KIND_BEACON, schema.KIND_POSITIONS})


# Which message kind belongs on which key (after ``truav/<run>/``): each message class's PLACE.
KIND_BY_KEY = {cls.PLACE: kind for kind, cls in schema.MESSAGE_CLASSES.items()}


def congestion_control(key: str) -> zenoh.CongestionControl:
    """DROP for keys of :data:`DROPPABLE_KINDS` (beacons, positions), BLOCK for everything else."""
    droppable = expected_kind(key) in DROPPABLE_KINDS
    return zenoh.CongestionControl.DROP if droppable else zenoh.CongestionControl.BLOCK


def expected_kind(key: str) -> str | None:
    """The message kind that belongs on a TRUAV key, or None if the key is not a known data key."""
    parts = key.split("/")
    if len(parts) < 3 or parts[0] != keys.ROOT:
        return None
    rest = parts[2:]
    if rest[0] == keys.UAV:
        if len(rest) == 4 and rest[2] == keys.BEACON:  # a range-limited beacon under its map cell
            return schema.KIND_BEACON
        if len(rest) == 4 and rest[2] == keys.QSHARE:  # one part of a federated Q share
            return schema.KIND_QSHARE if rest[3].isdigit() else None
        return KIND_BY_KEY.get((keys.UAV, rest[2])) if len(rest) == 3 else None
    if rest[0] == keys.WORLD:
        return KIND_BY_KEY.get(tuple(rest)) if len(rest) == 2 else None
    if rest[0] == keys.CONTROL_ROOT and len(rest) >= 2 and rest[1] == keys.OVERRIDE:  # control/override/<i> only
        return schema.KIND_OVERRIDE if len(rest) == 3 and keys.parse_uav_chunk(rest[2]) is not None else None
    if rest[0] == keys.GROUP:  # group/<first>-<last>/beacons, nothing else under group/
        return schema.KIND_BEACONS if keys.parse_group(key) is not None else None
    return KIND_BY_KEY.get((rest[0],)) if len(rest) >= 2 else None


def check_placement(key: str, msg: Message) -> None:
    """SchemaError(R_KEY_MISMATCH) if ``msg`` does not belong on ``key``.

    Checked: the kind the key carries, the body's ``uav`` against the key's
    UAV id, a ``uav/<j>`` sender only on keys of UAV ``j``, the metrics scope
    and the fault kind against the last key chunk.
    """
    facts = _FACTS.get(key)
    check_placed(facts if facts is not None else facts_of(key), key, msg)


def check_placed(facts: KeyFacts, key: str, msg: Message) -> None:
    """:func:`check_placement` with the key's facts at hand (``facts_of(key)``)."""
    kind, key_uav, last = facts[0], facts[1], facts[2]
    if kind is not None and kind != msg.KIND:
        raise SchemaError(R_KEY_MISMATCH, f"{msg.KIND} message on {key} (expects {kind})", src=msg.src)
    if kind == schema.KIND_BEACONS and isinstance(msg, schema.Beacons):
        _check_batch(key, msg)
        return
    body_uav = getattr(msg, "uav", None)
    if key_uav is not None and body_uav is not None and body_uav != key_uav:
        raise SchemaError(R_KEY_MISMATCH, f"{msg.KIND} for uav {body_uav} on {key}", src=msg.src)
    src = msg.src
    src_uav = _SRC_UAV.get(src, _UNSEEN)
    if src_uav is _UNSEEN:
        src_uav = _learn_src(src)
    if src_uav is not None and src_uav != key_uav:
        raise SchemaError(R_KEY_MISMATCH, f"sender {msg.src} may not appear on {key}", src=msg.src)
    if kind == _METRICS and isinstance(msg, schema.Metrics) and msg.scope != last:
        raise SchemaError(R_KEY_MISMATCH, f"{msg.scope} metrics on {key}", src=msg.src)
    if kind == _FAULT and isinstance(msg, schema.Fault) and msg.fault != last:
        raise SchemaError(R_KEY_MISMATCH, f"{msg.fault} fault on {key}", src=msg.src)
    if kind == _COMMAND and isinstance(msg, schema.Command) and last != str(msg.uav):
        raise SchemaError(R_KEY_MISMATCH, f"command for uav {msg.uav} on {key}", src=msg.src)
    if kind == schema.KIND_OVERRIDE and isinstance(msg, schema.Override) and last != str(msg.uav):
        raise SchemaError(R_KEY_MISMATCH, f"override of uav {msg.uav} on {key}", src=msg.src)
    if kind == schema.KIND_QSHARE and isinstance(msg, schema.QShare) and last != str(msg.part):
        raise SchemaError(R_KEY_MISMATCH, f"qshare part {msg.part} on {key}", src=msg.src)


def _check_batch(key: str, msg: "schema.Beacons") -> None:
    """A batch carries only UAVs its group key names, each once, and a UAV sender only its group's first."""
    first, last = keys.parse_group(key)
    src_uav = uav_of_src(msg.src)
    if src_uav is not None and src_uav != first:
        raise SchemaError(R_KEY_MISMATCH, f"sender {msg.src} may not appear on {key}", src=msg.src)
    uavs = [e[0] for e in msg.entries]
    foreign = [u for u in uavs if not first <= u <= last]
    if foreign:
        raise SchemaError(R_KEY_MISMATCH, f"beacons of uav {foreign[:5]} on {key}", src=msg.src)
    if len(set(uavs)) != len(uavs):
        raise SchemaError(R_KEY_MISMATCH, f"a uav twice in one batch on {key}", src=msg.src)


_METRICS, _FAULT, _COMMAND = schema.KIND_METRICS, schema.KIND_FAULT, schema.KIND_COMMAND


# A process sees the same few keys and senders over and over: parse each once. The caches are bounded,
# so a flood of distinct keys or senders from a misbehaving peer cannot grow memory: a full one is
# forgotten at once (and filled again by what keeps coming).
MAX_REMEMBERED_KEYS = 4096


class KeyFacts(NamedTuple):
    """What a key says of the messages on it."""

    kind: str | None
    """:func:`expected_kind`"""
    uav: int | None
    """The UAV id in the key (``keys.parse_uav_id``)"""
    last: str
    """Its last chunk (a metrics scope, a fault kind, a command's UAV id)"""
    size_limit: int
    """The largest payload it may carry (:func:`size_limit_of_key`)"""


_FACTS: dict[str, KeyFacts] = {}
_SRC_UAV: dict[str, int | None] = {}
_UNSEEN = object()


def facts_of(key: str) -> KeyFacts:
    """The :class:`KeyFacts` of ``key`` (parsed once, remembered)."""
    facts = _FACTS.get(key)
    if facts is None:
        kind = expected_kind(key)
        facts = KeyFacts(kind, keys.parse_uav_id(key), key.rsplit("/", 1)[-1],
                         schema.size_limit(kind) if kind is not None else schema.MAX_PAYLOAD_BYTES)
        if len(_FACTS) >= MAX_REMEMBERED_KEYS:
            _FACTS.clear()
        _FACTS[key] = facts
    return facts


def _learn_src(src: str) -> int | None:
    uav = keys.parse_uav_identity(src)
    if len(_SRC_UAV) >= MAX_REMEMBERED_KEYS:
        _SRC_UAV.clear()
    _SRC_UAV[src] = uav
    return uav


def key_facts(key: str) -> tuple[str | None, int | None]:
    """(expected_kind, UAV id) of a key."""
    facts = facts_of(key)
    return facts.kind, facts.uav


def size_limit_of_key(key: str) -> int:
    return facts_of(key).size_limit


@functools.lru_cache(maxsize=4096)
def uav_of_src(src: str) -> int | None:
    return keys.parse_uav_identity(src)
