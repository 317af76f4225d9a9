"""What the recorder knows about TRUAV payloads, and the JSON it mirrors them to.

Deliberately self-contained (msgpack only, no ``truav.wire.schema`` import): the
recorder must record anything, including payloads the schema module would
reject, so it only needs the envelope (``kind``, ``src``, ``seq``, ``t``, ``inc``) to
route, sequence-check and timestamp a message.  The JSON Schemas document the
fields of each kind as ``truav.wire.schema`` defines them (for MCAP viewers); the
mirror builder turns metrics into plain JSON for Foxglove's plots, which cannot
decode msgpack (beacons and positions go to :mod:`recorder.foxglove`).
"""

from __future__ import annotations

import json
import math
from typing import Any, Callable, NamedTuple, Optional

import msgpack

from truav.wire.messages import _SENT_IF_SET

SCHEMA_PREFIX = "truav."  # bus schema name = SCHEMA_PREFIX + kind
MIRROR_SCHEMA_PREFIX = "truav.json."
KINDS = ("tick", "obs", "beacon", "action", "metrics", "fault", "control", "positions", "state", "command", "health",
         "beacons", "rejection", "replay_status", "world_snapshot", "agent_snapshot", "qshare")
UNKNOWN_KIND = "unknown"  # a key whose first payload had no usable kind
MIRRORED_KINDS = ("metrics",)  # beacons and positions: the Foxglove mirror (recorder.foxglove) shows them

_U64 = (1 << 64) - 1


# --- envelope ---------------------------------------------------------------------
class Envelope(NamedTuple):
    """The routing fields of a decoded bus payload, plus the whole decoded map."""

    kind: str
    src: str
    seq: int
    t: Optional[int]  # sender wall time (ns), None when absent or out of uint64 range
    body: dict
    inc: int = 0  # the sender's incarnation (a process start); 0 when absent (older payloads) or not an int


def envelope_fields(payload: bytes) -> Optional[tuple[str, str, int, Optional[int], dict, int]]:
    """:func:`decode_envelope` as a plain tuple (cheaper to build on the hot path)."""
    try:
        body = msgpack.unpackb(payload)
    except Exception:  # msgpack raises ValueError, ExtraData, FormatError, StackError...
        return None
    if type(body) is not dict:
        return None
    kind = body.get("kind")
    src = body.get("src")
    seq = body.get("seq")
    if type(kind) is not str or type(src) is not str or type(seq) is not int:
        return None
    t = body.get("t")
    if type(t) is not int or not 0 <= t <= _U64:
        t = None
    inc = body.get("inc", 0)
    if type(inc) is not int:
        inc = 0
    return kind, src, seq, t, body, inc


def decode_envelope(payload: bytes) -> Optional[Envelope]:
    """Decode a payload's envelope, or None if it is not a usable TRUAV message.

    Usable means: msgpack of a map with a str ``kind``, a str ``src`` and an
    int ``seq``.  Anything else is recorded raw and counted as undecodable;
    the full schema validation belongs to ``truav.wire.schema``, not the recorder.
    """
    fields = envelope_fields(payload)
    return None if fields is None else Envelope(*fields)


def kind_from_key(key: str) -> str:
    """Guess a kind from a key (``truav/r/uav/3/beacon`` -> beacon) for undecodable
    first payloads; ``metrics/step`` and ``fault/crash`` name the kind before the last part."""
    for part in reversed(key.split("/")):
        if part in KINDS:
            return part
    return UNKNOWN_KIND


# --- JSON Schemas -------------------------------------------------------------------
_INT = {"type": "integer"}
_NUM = {"type": "number"}
_STR = {"type": "string"}
_XY = {"type": "array", "items": _NUM, "minItems": 2, "maxItems": 2, "description": "[x, y] metres"}
_POINTS = {"type": "array", "items": _XY}
_ENVELOPE_PROPS = {
    "v": {**_INT, "description": "schema version"},
    "kind": {**_STR, "description": "message kind"},
    "src": {**_STR, "description": "sender id: world, uav/<i>, controller, recorder, fault, replay"},
    "seq": {**_INT, "description": "per-sender, per-kind counter; a jump means messages were lost"},
    "t": {**_INT, "description": "sender wall clock when stamped, ns since the Unix epoch"},
    "inc": {**_INT, "description": "sender incarnation (random per process start): seq restarts from 0 with a new one"},
}
_SNAPSHOT_ARRAYS = {"type": "object", "description": "a lock-step snapshot's state: name -> [dtype, shape, "
                    "little-endian bytes] (truav log resim --from restores it)",
                    "additionalProperties": {"type": "array", "minItems": 3, "maxItems": 3}}
_BODY_PROPS: dict[str, dict[str, Any]] = {
    "tick": {"tick": _INT, "episode": _INT, "sim_time": _NUM, "deadline_ms": _NUM, "n_uavs": _INT},
    "obs": {
        "tick": _INT, "episode": _INT, "uav": _INT, "pos": _XY, "vehicles_in_range": _INT,
        "queued_packets": _INT, "relayed": _INT, "covered": _INT, "energy_j": _NUM,
        "speed_max": _NUM, "done": {"type": "boolean"}, "densest_sector": _INT,
        "exclusive": _INT, "disc_offset": _XY, "disc_vehicles": _INT,
    },
    "beacon": {"uav": _INT, "tick": _INT, "pos": _XY, "vel": {**_XY, "description": "[vx, vy] m/s"},
               "fields": {"type": "object", "description": "an API agent's beacon_fields(), present only if any "
                          "(at most 8; values bool, int or number)"}},
    "action": {"uav": _INT, "tick": _INT, "action": _INT},
    "beacons": {"entries": {"type": "array", "description": "--batch-beacons: one process's beacons of a tick, "
                            "each [uav, tick, [x, y], [vx, vy]]",
                            "items": {"type": "array", "minItems": 4, "maxItems": 4}}},
    "metrics": {
        "scope": {"enum": ["step", "episode"]}, "tick": _INT, "episode": _INT,
        "values": {"type": "object", "additionalProperties": _NUM},
    },
    "fault": {
        "fault": _STR, "phase": {"enum": ["start", "end"]}, "target": _STR,
        "params": {"type": "object", "description": "numbers or strings, by fault kind"},
    },
    "control": {"command": _STR, "args": {"type": "object"}},
    "positions": {"tick": _INT, "uavs": _POINTS, "vehicles": _POINTS},
    "state": {
        "uav": _INT, "tick": _INT, "episode": _INT, "step": _INT, "pos": _XY, "vehicles_in_range": _INT,
        "queued_packets": _INT, "relayed": _INT, "covered": _INT, "energy_j": _NUM, "done": {"type": "boolean"},
        "pad": {"description": "padding bytes to central.upload_bytes (the modelled report size)"},
    },
    "override": {"uav": _INT, "release": {"type": "boolean", "description": "true: end the override"},
                 "goal": {**_XY, "description": "[x, y] m to fly to"},
                 "speed": {**_NUM, "description": "m/s; 0: the UAV's full speed"}},
    "command": {"uav": _INT, "tick": _INT, "action": _INT,
                "pad": {"description": "padding bytes to central.download_bytes"}},
    "health": {"uav": _INT, "last_tick": {**_INT, "description": "last tick answered, -1 none yet"}, "steps": _INT,
               "stale_obs_skipped": _INT,
               "rejected": {"type": "object", "additionalProperties": _INT, "description": "refused messages by reason"},
               "senders": {"type": "object", "additionalProperties": _INT, "description": "the most refused senders"},
               "heard": {"type": "array", "items": _INT, "description": "beacons heard so far from each UAV "
                         "(index: sender id), after link faults; absent in older recordings"}},
    "qshare": {"uav": _INT, "tick": _INT,
               "episode": {**_INT, "description": "the episode the share was made after (its round)"},
               "part": {**_INT, "description": "this part's index, also the key's last chunk"},
               "parts": {**_INT, "description": "parts of the share"},
               "states": {"type": "array", "items": _INT, "description": "states of the rows"},
               "counts": {"type": "array", "items": _INT, "description": "visit counts of those states"},
               "q": {"type": "array", "items": _NUM, "description": "the rows, 16 values per state, row-major"}},
    "rejection": {"uav": _INT,
                  "at_tick": {**_INT, "description": "the refused action's tick (late/stale), else the world's "
                                                     "latest tick; -1 before tick 0"},
                  "reason": {**_STR, "description": "reason code of the first message refused since the last one"},
                  "refused_kind": {**_STR, "description": "the kind its key carries, e.g. action"},
                  "key": {**_STR, "description": "the key it came on"},
                  "detail": {**_STR, "description": "what was wrong, at most 160 characters"},
                  "counts": {"type": "object", "additionalProperties": _INT,
                             "description": "everything refused of this UAV since the last rejection, by reason"}},
    "replay_status": {"state": {"enum": ["playing", "paused", "waiting", "ended"]},
                      "position_s": {**_NUM, "description": "s from the recording's first message"},
                      "span_s": _NUM, "tick": {**_INT, "description": "last tick sent, -1 none yet"}, "rate": _NUM,
                      "paused": {"type": "boolean"}, "sent": _INT, "restored": _INT, "loop": _INT},
    "world_snapshot": {"tick": _INT, "episode": _INT, "arrays": _SNAPSHOT_ARRAYS},
    "agent_snapshot": {"uav": _INT, "tick": _INT, "arrays": _SNAPSHOT_ARRAYS},
}


def bus_schema(kind: str) -> dict[str, Any]:
    """JSON Schema of the *decoded* msgpack map of one kind (documentation for humans
    and tools; msgpack maps are structurally JSON)."""
    body = _BODY_PROPS.get(kind, {})
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": SCHEMA_PREFIX + kind,
        "description": f"TRUAV bus message, kind={kind!r}, msgpack-encoded map",
        "type": "object",
        "properties": {**_ENVELOPE_PROPS, **body},
        "required": [*(k for k in _ENVELOPE_PROPS if k != "inc"), *(k for k in body if k not in _SENT_IF_SET.get(kind, ()))]
        if body else ["kind", "src", "seq"],
    }


# No type unions (["number", "null"]) anywhere: Foxglove's JSON Schema parser rejects
# them.  A value that is NaN/inf (not JSON) or absent is simply left out, so only
# the fields that are always there are required.
_MIRROR_SCHEMAS: dict[str, dict[str, Any]] = {
    "metrics": {
        "type": "object",
        "description": "metric values flattened next to tick/episode/scope; a value named like "
        "one of those is stored as value_<name>; a value that is not finite is left out",
        "properties": {"tick": _INT, "episode": _INT, "scope": _STR},
        "additionalProperties": _NUM,
    },
}


def mirror_schema(kind: str) -> dict[str, Any]:
    """JSON Schema of the JSON mirror messages of ``kind`` (one of MIRRORED_KINDS)."""
    return {"$schema": "https://json-schema.org/draft/2020-12/schema",
            "title": MIRROR_SCHEMA_PREFIX + kind, **_MIRROR_SCHEMAS[kind]}


def _num(v: Any) -> Optional[float]:
    """float(v) for the mirror, None for NaN/inf (not JSON); raises on non-numbers."""
    f = float(v)
    return f if math.isfinite(f) else None


_METRIC_RESERVED = ("tick", "episode", "scope")


def _metrics_json(b: dict) -> bytes:
    tick, episode, scope = b.get("tick"), b.get("episode"), b.get("scope")
    out: dict[str, Any] = {}
    if type(tick) is int:
        out["tick"] = tick
    if type(episode) is int:
        out["episode"] = episode
    if type(scope) is str:
        out["scope"] = scope
    for name, value in b["values"].items():
        name = str(name)
        value = _num(value)
        if value is not None:
            out["value_" + name if name in _METRIC_RESERVED else name] = value
    return _json_encode(out).encode()


# one reusable encoder: json.dumps(..., separators=...) builds a new one per call
_json_encode = json.JSONEncoder(separators=(",", ":"), allow_nan=False, ensure_ascii=False).encode
_MIRROR_BUILDERS: dict[str, Callable[[dict], bytes]] = {
    "metrics": _metrics_json,
}


def mirror_builder(kind: str) -> Optional[Callable[[dict], bytes]]:
    """decoded body -> JSON bytes of its mirror message, for MIRRORED_KINDS; else None.
    The builder raises (KeyError, TypeError, ValueError...) on a body that does not fit."""
    return _MIRROR_BUILDERS.get(kind)
