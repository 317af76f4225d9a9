"""Encoding, decoding and stamping of wire messages (:mod:`truav.bus.schema`): msgpack out of a
stamped message, a validated message out of untrusted bytes, and the per-sender :class:`Sequencer`."""

from __future__ import annotations

import copy
import os
import threading
import time
from collections.abc import Callable, Mapping
from typing import Any

import msgpack

from truav.bus.field_checks import _src, _uint63
from truav.bus.messages import (_BODY_FIELDS, _LEGACY_WIRE_KEYS, _LOOSE_LIMITS, _SIZE_LIMIT, _UNPACK_LIMITS,
                                _WIRE_KEYS, MESSAGE_CLASSES, M, Message)
from truav.bus.schema_names import (_ENVELOPE_KEYS, MAX_PAYLOAD_BYTES, MAX_SRC_LEN, R_BAD_TYPE, R_EXTRA_FIELD,
                                    R_MISSING_FIELD, R_NOT_BYTES, R_NOT_MAP, R_NOT_MSGPACK, R_TOO_LARGE, R_UNKNOWN_KIND,
                                    R_UNSTAMPED, R_VERSION, SCHEMA_VERSION, SchemaError)

# --- encode / decode ------------------------------------------------------------------
def encode(msg: Message) -> bytes:
    """Encode a stamped message to msgpack bytes; SchemaError if unstamped or too large."""
    kind = getattr(type(msg), "KIND", None)
    if MESSAGE_CLASSES.get(kind) is not type(msg):  # type: ignore[arg-type]
        raise SchemaError(R_BAD_TYPE, f"cannot encode {type(msg).__name__}: not a schema message")
    if not msg.src:
        raise SchemaError(R_UNSTAMPED, f"{kind} has no src; stamp it with a Sequencer (or publish via a Bus)")
    wire: dict[str, Any] = {"v": SCHEMA_VERSION, "kind": kind, "src": msg.src, "seq": msg.seq, "t": msg.t,
                            "inc": msg.inc}
    for name in _BODY_FIELDS[kind]:
        wire[name] = getattr(msg, name)
    try:
        data = msgpack.packb(wire, use_bin_type=True)
    except Exception as exc:  # only reachable if a caller mutated a message's dict fields
        raise SchemaError(R_BAD_TYPE, f"{kind} cannot be packed: {exc}", src=msg.src) from None
    if len(data) > _SIZE_LIMIT[kind]:
        raise SchemaError(R_TOO_LARGE, f"{kind} is {len(data)} bytes, limit {_SIZE_LIMIT[kind]}", src=msg.src)
    return data


def unpack_limits(kind: str | None) -> Mapping[str, int]:
    """msgpack Unpacker limits for a payload of ``kind`` (None: the loosest of any kind)."""
    return _UNPACK_LIMITS.get(kind, _LOOSE_LIMITS) if kind is not None else _LOOSE_LIMITS


def decode(data: bytes | bytearray | memoryview, expect: str | None = None) -> Message:
    """Decode and validate one message; raises only SchemaError on bad input.

    ``expect`` is the kind the key carries (see ``placement.expected_kind``):
    the payload is then held to that kind's size and msgpack limits *before*
    parsing (a 1 MB "observation" with 124k extra keys costs a length check,
    not a parse).  Without it, the loosest limits of any kind apply."""
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise SchemaError(R_NOT_BYTES, f"expected bytes, got {type(data).__name__}")
    limit = _SIZE_LIMIT.get(expect, MAX_PAYLOAD_BYTES) if expect is not None else MAX_PAYLOAD_BYTES
    if len(data) > limit:
        raise SchemaError(R_TOO_LARGE, f"{len(data)} bytes, limit {limit}" + (f" for {expect}" if expect else ""))
    try:
        unpacker = msgpack.Unpacker(raw=False, strict_map_key=True, use_list=True,
                                    max_buffer_size=max(limit, 1), **unpack_limits(expect))
        unpacker.feed(data)
        obj = unpacker.unpack()
        if unpacker.tell() != len(data):
            raise msgpack.ExtraData(obj, b"")
    except ValueError as exc:
        if "exceeds max" in str(exc):  # msgpack's own limits: refused while parsing, before building it
            raise SchemaError(R_TOO_LARGE, str(exc)[:80]) from None
        raise SchemaError(R_NOT_MSGPACK, f"{type(exc).__name__}: {str(exc)[:80] or 'invalid msgpack'}") from None
    except Exception as exc:  # msgpack raises many types (OutOfData, ExtraData, StackError, ...)
        raise SchemaError(R_NOT_MSGPACK, f"{type(exc).__name__}: {str(exc)[:80] or 'invalid msgpack'}") from None
    if not isinstance(obj, dict):
        raise SchemaError(R_NOT_MAP, f"top level is {type(obj).__name__}")
    src = obj.get("src")
    src = src if isinstance(src, str) and len(src) <= MAX_SRC_LEN else None
    try:
        return _from_map(obj, len(data))
    except SchemaError as exc:
        exc.src = src
        raise
    except Exception as exc:  # defensive: validators should only raise SchemaError
        raise SchemaError(R_BAD_TYPE, f"{type(exc).__name__}: {str(exc)[:80]}", src=src) from None


def peek_src(data: bytes | bytearray | memoryview) -> str | None:
    """Best-effort sender id of a payload without decoding its body (None if unreadable).

    Reads only the first envelope entries, so it is cheap even for a large
    ``positions`` payload; the result is *not* validated against the schema.
    """
    try:
        unpacker = msgpack.Unpacker(raw=False, strict_map_key=True, max_buffer_size=max(len(data), 1))
        unpacker.feed(data)
        for _ in range(min(unpacker.read_map_header(), len(_ENVELOPE_KEYS))):
            if unpacker.unpack() == "src":
                src = unpacker.unpack()
                return src if isinstance(src, str) and 0 < len(src) <= MAX_SRC_LEN else None
            unpacker.skip()
    except Exception:  # hostile bytes: any msgpack failure just means "unknown"
        return None
    return None


def _from_map(obj: dict[Any, Any], size: int) -> Message:
    if "v" not in obj:
        raise SchemaError(R_VERSION, "missing schema version 'v'")
    v = obj["v"]
    if type(v) is not int or v != SCHEMA_VERSION:
        raise SchemaError(R_VERSION, f"version {v!r:.20}, expected {SCHEMA_VERSION}")
    kind = obj.get("kind")
    if not isinstance(kind, str) or kind not in MESSAGE_CLASSES:
        raise SchemaError(R_UNKNOWN_KIND, f"kind {kind!r:.40}")
    if size > _SIZE_LIMIT[kind]:
        raise SchemaError(R_TOO_LARGE, f"{kind} is {size} bytes, limit {_SIZE_LIMIT[kind]}")
    if obj.keys() != _WIRE_KEYS[kind]:
        if obj.keys() == _LEGACY_WIRE_KEYS[kind]:  # an older sender: incarnation unknown
            obj = {**obj, "inc": 0}
        else:
            expected = (*_ENVELOPE_KEYS, *_BODY_FIELDS[kind])
            missing = [k for k in expected if k not in obj]
            if missing:
                raise SchemaError(R_MISSING_FIELD, f"{kind} lacks {missing}")
            extra = [k for k in obj if k not in expected]
            raise SchemaError(R_EXTRA_FIELD, f"{kind} has unexpected {[repr(k)[:40] for k in extra[:5]]}")
    if obj["src"] == "":
        raise SchemaError(R_UNSTAMPED, f"{kind} has an empty src")
    cls = MESSAGE_CLASSES[kind]
    # The checks the constructor would run, without its keyword plumbing (decode is the hot path:
    # every agent decodes its 19 neighbours' beacons each tick).
    msg = object.__new__(cls)
    msg.__dict__.update({name: check(path, obj[name]) for name, path, check in cls._PLAN})
    return msg  # type: ignore[return-value]


def padded(msg: M, size: int) -> M:
    """A copy of a stamped ``msg`` whose ``pad`` makes its encoding ``size`` bytes long (or up to
    2 bytes short, where msgpack's bin length header grows), or unpadded when it is longer anyway."""
    rest = len(encode(_with_pad(msg, b""))) - 2  # without the empty bin's 2 bytes

    def total(n: int) -> int:
        return rest + n + (2 if n < 256 else 3 if n < 65536 else 5)

    fits = [n for n in range(max(size - rest - 5, 0), max(size - rest - 1, 0)) if total(n) <= size]
    return _with_pad(msg, bytes(max(fits, default=0)))


def _with_pad(msg: M, pad: bytes) -> M:
    out = copy.copy(msg)
    object.__setattr__(out, "pad", pad)
    return out


# --- stamping ---------------------------------------------------------------------------
def new_incarnation() -> int:
    """A fresh incarnation id: 63 random bits from the OS, never 0 (0 means "unknown").

    It names a process lifetime, not simulation randomness, so it comes from ``os.urandom``
    and not from the run's seeded generators (two starts with the same seed must differ)."""
    while True:
        inc = int.from_bytes(os.urandom(8), "little") >> 1
        if inc:
            return inc


class Sequencer:
    """Stamps ``src``, ``seq`` (per kind, from 0), ``t`` and ``inc`` on outgoing messages.

    ``clock`` returns int nanoseconds (default :func:`time.time_ns`); inject a
    fake for deterministic tests.  ``incarnation`` (default :func:`new_incarnation`)
    tells this numbering apart from that of an earlier or later sender of the same
    ``src``.  Thread-safe.
    """

    def __init__(self, src: str, clock: Callable[[], int] = time.time_ns, incarnation: int | None = None) -> None:
        self._src = _src("src", src)
        if not self._src:
            raise ValueError("Sequencer src must be non-empty")
        self._inc = new_incarnation() if incarnation is None else _uint63("inc", incarnation)
        self._clock = clock
        self._next: dict[str, int] = {}
        self._lock = threading.Lock()

    @property
    def src(self) -> str:
        return self._src

    @property
    def incarnation(self) -> int:
        return self._inc

    def stamp(self, msg: M) -> M:
        """A copy of ``msg`` with this sender's src and incarnation, the next seq of its kind and t=clock()."""
        kind = type(msg).KIND
        if MESSAGE_CLASSES.get(kind) is not type(msg):
            raise SchemaError(R_BAD_TYPE, f"cannot stamp {type(msg).__name__}: not a schema message")
        with self._lock:
            seq = self._next.get(kind, 0)
            self._next[kind] = seq + 1
            t = _uint63(f"{kind}.t", self._clock())
        stamped = copy.copy(msg)  # the body is already validated: skip __post_init__
        object.__setattr__(stamped, "src", self._src)
        object.__setattr__(stamped, "seq", seq)
        object.__setattr__(stamped, "t", t)
        object.__setattr__(stamped, "inc", self._inc)
        return stamped
