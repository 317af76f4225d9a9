"""What the recorder knows about TRUAV payloads, and the JSON it mirrors them to.

Deliberately self-contained (msgpack only, no ``truav.bus.schema`` import): the
recorder must record anything, including payloads the schema module would
reject, so it only needs the envelope (``kind``, ``src``, ``seq``, ``t``) to
route, sequence-check and timestamp a message.  The JSON Schemas document the
fields of each kind as ``truav.bus.schema`` defines them (for MCAP viewers); the
mirror builders turn beacons, metrics and positions into JSON for Foxglove,
which cannot decode msgpack.
"""

from __future__ import annotations

import json
import math
from typing import Any, Callable, NamedTuple, Optional

import msgpack

SCHEMA_PREFIX = "truav."  # bus schema name = SCHEMA_PREFIX + kind
MIRROR_SCHEMA_PREFIX = "truav.json."
KINDS = ("tick", "obs", "beacon", "action", "metrics", "fault", "control", "positions")
UNKNOWN_KIND = "unknown"  # a key whose first payload had no usable kind
MIRRORED_KINDS = ("beacon", "metrics", "positions")

_U64 = (1 << 64) - 1
_isfinite = math.isfinite


# --- envelope ---------------------------------------------------------------------
class Envelope(NamedTuple):
    """The routing fields of a decoded bus payload, plus the whole decoded map."""

    kind: str
    src: str
    seq: int
    t: Optional[int]  # sender wall time (ns), None when absent or out of uint64 range
    body: dict


def envelope_fields(payload: bytes) -> Optional[tuple[str, str, int, Optional[int], dict]]:
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
    return kind, src, seq, t, body


def decode_envelope(payload: bytes) -> Optional[Envelope]:
    """Decode a payload's envelope, or None if it is not a usable TRUAV message.

    Usable means: msgpack of a map with a str ``kind``, a str ``src`` and an
    int ``seq``.  Anything else is recorded raw and counted as undecodable;
    the full schema validation belongs to ``truav.bus.schema``, not the recorder.
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
    "src": {**_STR, "description": "sender id: world, uav/<i>, recorder, fault, replay"},
    "seq": {**_INT, "description": "per-sender, per-kind counter; a jump means messages were lost"},
    "t": {**_INT, "description": "sender wall clock when stamped, ns since the Unix epoch"},
}
_BODY_PROPS: dict[str, dict[str, Any]] = {
    "tick": {"tick": _INT, "episode": _INT, "sim_time": _NUM, "deadline_ms": _NUM, "n_uavs": _INT},
    "obs": {
        "tick": _INT, "episode": _INT, "uav": _INT, "pos": _XY, "vehicles_in_range": _INT,
        "queued_packets": _INT, "relayed": _INT, "covered": _INT, "energy_j": _NUM,
        "speed_max": _NUM, "done": {"type": "boolean"},
    },
    "beacon": {"uav": _INT, "tick": _INT, "pos": _XY, "vel": {**_XY, "description": "[vx, vy] m/s"}},
    "action": {"uav": _INT, "tick": _INT, "action": _INT},
    "metrics": {
        "scope": {"enum": ["step", "episode"]}, "tick": _INT, "episode": _INT,
        "values": {"type": "object", "additionalProperties": _NUM},
    },
    "fault": {
        "fault": _STR, "phase": {"enum": ["start", "end"]}, "target": _STR,
        "params": {"type": "object", "additionalProperties": {"type": ["number", "string"]}},
    },
    "control": {"command": _STR, "args": {"type": "object"}},
    "positions": {"tick": _INT, "uavs": _POINTS, "vehicles": _POINTS},
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
        "required": [*_ENVELOPE_PROPS, *body] if body else ["kind", "src", "seq"],
    }


_NUM_OR_NULL = {"type": ["number", "null"]}  # null = the value was NaN/inf
_XY_OBJ = {"type": "object", "properties": {"x": _NUM_OR_NULL, "y": _NUM_OR_NULL}, "required": ["x", "y"]}
_MIRROR_SCHEMAS: dict[str, dict[str, Any]] = {
    "beacon": {
        "type": "object",
        "properties": {"uav": _INT, "tick": _INT, "x": _NUM_OR_NULL, "y": _NUM_OR_NULL,
                       "vx": _NUM_OR_NULL, "vy": _NUM_OR_NULL},
        "required": ["uav", "tick", "x", "y", "vx", "vy"],
    },
    "metrics": {
        "type": "object",
        "description": "metric values flattened next to tick/episode/scope; a value named like "
        "one of those is stored as value_<name>",
        "properties": {"tick": {"type": ["integer", "null"]}, "episode": {"type": ["integer", "null"]},
                       "scope": {"type": ["string", "null"]}},
        "required": ["tick", "episode", "scope"],
        "additionalProperties": _NUM_OR_NULL,
    },
    "positions": {
        "type": "object",
        "properties": {"tick": _INT, "uavs": {"type": "array", "items": _XY_OBJ},
                       "vehicles": {"type": "array", "items": _XY_OBJ}},
        "required": ["tick", "uavs", "vehicles"],
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


_BEACON_JSON = '{"uav":%d,"tick":%d,"x":%r,"y":%r,"vx":%r,"vy":%r}'  # %r of a float == json's


def _beacon_json(b: dict) -> bytes:
    """Hand-formatted: beacons are the most frequent mirror, and building a dict for
    json's encoder costs ~2 us more per message (of a ~10 us budget)."""
    x, y = b["pos"]
    vx, vy = b["vel"]
    x, y, vx, vy = float(x), float(y), float(vx), float(vy)
    uav, tick = int(b["uav"]), int(b["tick"])
    if _isfinite(x) and _isfinite(y) and _isfinite(vx) and _isfinite(vy):
        return (_BEACON_JSON % (uav, tick, x, y, vx, vy)).encode()
    return _json_encode({"uav": uav, "tick": tick, "x": _num(x), "y": _num(y),
                         "vx": _num(vx), "vy": _num(vy)}).encode()


_METRIC_RESERVED = ("tick", "episode", "scope")


def _metrics_json(b: dict) -> bytes:
    tick, episode, scope = b.get("tick"), b.get("episode"), b.get("scope")
    out: dict[str, Any] = {
        "tick": tick if type(tick) is int else None,
        "episode": episode if type(episode) is int else None,
        "scope": scope if type(scope) is str else None,
    }
    for name, value in b["values"].items():
        name = str(name)
        out["value_" + name if name in _METRIC_RESERVED else name] = _num(value)
    return _json_encode(out).encode()


def _positions_json(b: dict) -> bytes:
    return _json_encode({"tick": int(b["tick"]),
                         "uavs": [{"x": _num(p[0]), "y": _num(p[1])} for p in b["uavs"]],
                         "vehicles": [{"x": _num(p[0]), "y": _num(p[1])} for p in b["vehicles"]]}).encode()


# one reusable encoder: json.dumps(..., separators=...) builds a new one per call
_json_encode = json.JSONEncoder(separators=(",", ":"), allow_nan=False, ensure_ascii=False).encode
_MIRROR_BUILDERS: dict[str, Callable[[dict], bytes]] = {
    "beacon": _beacon_json, "metrics": _metrics_json, "positions": _positions_json,
}


def mirror_builder(kind: str) -> Optional[Callable[[dict], bytes]]:
    """decoded body -> JSON bytes of its mirror message, for MIRRORED_KINDS; else None.
    The builder raises (KeyError, TypeError, ValueError...) on a body that does not fit."""
    return _MIRROR_BUILDERS.get(kind)
