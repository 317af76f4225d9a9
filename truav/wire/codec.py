"""Encoding, decoding and stamping of wire messages (:mod:`truav.wire.schema`): msgpack out of a
stamped message, a validated message out of untrusted bytes, and the per-sender :class:`Sequencer`."""

from __future__ import annotations

import copy
import os
import threading
import time
from collections.abc import Callable, Mapping
from typing import Any

import msgpack
import numpy as np

from truav.wire.field_checks import Check, _src, _uint63
from truav.wire.messages import (_BODY_FIELDS, _LEGACY_WIRE_KEYS, _LOOSE_LIMITS, _OPTIONAL_FIELDS, _SENT_IF_SET, _SIZE_LIMIT,
                                _UNPACK_LIMITS, _WIRE_KEYS, MESSAGE_CLASSES, M, Message)
from truav.wire.schema_names import (_ENVELOPE_KEYS, MAX_PAYLOAD_BYTES, MAX_SRC_LEN, R_BAD_TYPE, R_EXTRA_FIELD,
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
    if_set = _SENT_IF_SET[kind]
    for name in _BODY_FIELDS[kind]:
        value = getattr(msg, name)
        if if_set and name in if_set and not value:
            continue  # an optional field left empty stays off the wire
        wire[name] = value.tolist() if type(value) is np.ndarray else value  # qshare's rows and counts
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
    not a parse).  Without it, the loosest limits of any kind apply.

    This is the hot path of every receiver (an agent decodes its neighbours' beacons each tick): one
    ``msgpack.unpackb`` with the kind's limits, then the checks of the map and the kind's compiled
    field checks (:func:`_compile_builder`).  A refusal says exactly what it said when a streaming
    ``Unpacker`` parsed (:func:`_unpack_reference`): trailing bytes, bytes that are no msgpack, nesting
    too deep, an incomplete object and a msgpack limit are told as it tells them; any other bytes
    ``unpackb`` refuses are parsed again by it."""
    if type(data) is not bytes and not isinstance(data, (bytes, bytearray, memoryview)):
        raise SchemaError(R_NOT_BYTES, f"expected bytes, got {type(data).__name__}")
    limit, limits = _EXPECT.get(expect, _LOOSE_EXPECT)  # type: ignore[misc]
    size = len(data)
    if size > limit:
        raise SchemaError(R_TOO_LARGE, f"{size} bytes, limit {limit}" + (f" for {expect}" if expect else ""))
    try:
        if limits is None:  # limits unpackb cannot take as they are: the reference parse only
            raise ValueError
        obj = _unpackb(data, raw=False, strict_map_key=True, use_list=True, max_map_len=limits[0],
                       max_array_len=limits[1], max_str_len=limits[2], max_bin_len=limits[3], max_ext_len=limits[4])
    except (msgpack.ExtraData, msgpack.FormatError, msgpack.StackError) as exc:  # the reference's exceptions
        raise SchemaError(R_NOT_MSGPACK, f"{type(exc).__name__}: {str(exc)[:80] or 'invalid msgpack'}") from None
    except ValueError as exc:
        text = str(exc)
        if "exceeds max" in text:  # msgpack's own limits (the same check and text in unpackb and Unpacker)
            raise SchemaError(R_TOO_LARGE, text[:80]) from None
        if text == _UNPACKB_INCOMPLETE:  # where the reference Unpacker runs out of data
            raise SchemaError(R_NOT_MSGPACK, _INCOMPLETE_DETAIL) from None
        obj = _unpack_reference(data, expect, limit)  # anything else: the reference parse says why
    except Exception:
        obj = _unpack_reference(data, expect, limit)
    if not isinstance(obj, dict):
        raise SchemaError(R_NOT_MAP, f"top level is {type(obj).__name__}")
    try:  # the checks of the map itself, in the order they always had
        if "v" not in obj:
            raise SchemaError(R_VERSION, "missing schema version 'v'")
        v = obj["v"]
        if type(v) is not int or v != SCHEMA_VERSION:
            raise SchemaError(R_VERSION, f"version {v!r:.20}, expected {SCHEMA_VERSION}")
        kind = obj.get("kind")
        if not isinstance(kind, str) or (plan := _KIND_PLAN.get(kind)) is None:
            raise SchemaError(R_UNKNOWN_KIND, f"kind {kind!r:.40}")
        if size > plan[0]:
            raise SchemaError(R_TOO_LARGE, f"{kind} is {size} bytes, limit {plan[0]}")
        if len(obj) != plan[1]:  # not the kind's keys (same count: the builder finds out)
            obj = _wire_keys_differ(obj, kind)
        return plan[2](obj)
    except SchemaError as exc:
        exc.src = _readable_src(obj)
        raise
    except Exception as exc:  # defensive: validators should only raise SchemaError
        raise SchemaError(R_BAD_TYPE, f"{type(exc).__name__}: {str(exc)[:80]}", src=_readable_src(obj)) from None


def _readable_src(obj: dict[Any, Any]) -> str | None:
    """The sender a refused map names, for the counts and the log (None if it names none a log can show)."""
    src = obj.get("src")
    return src if isinstance(src, str) and len(src) <= MAX_SRC_LEN else None


def _unpack_reference(data: bytes | bytearray | memoryview, expect: str | None, limit: int) -> Any:
    """The msgpack object in ``data`` as a streaming ``Unpacker`` with the limits of ``expect`` reads it,
    or the SchemaError its failure means (R_TOO_LARGE for a msgpack limit, R_NOT_MSGPACK otherwise).

    (``decode`` parsed this way until ``unpackb`` took over; it still says why bytes are refused.)"""
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
    return obj


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


def _wire_keys_differ(obj: dict[Any, Any], kind: str) -> dict[Any, Any]:
    """A wire map of ``kind`` whose keys are not the kind's: an older sender's (without ``inc``, taken as
    0), else SchemaError (a missing field first, else the extra ones). (The checks on the keys of
    ``decode`` as it was: ``obj.keys() != _WIRE_KEYS[kind]`` led here.)"""
    if obj.keys() == _WIRE_KEYS[kind]:  # every key, the optional ones sent (decode counted without them)
        return obj
    added = {k: v for k, v in _OPTIONAL_FIELDS[kind].items() if k not in obj}
    if added:  # an older sender, before fields added since: their defaults
        filled = {**obj, **added}
        if filled.keys() == _WIRE_KEYS[kind]:
            return filled
        if filled.keys() == _LEGACY_WIRE_KEYS[kind]:
            return {**filled, "inc": 0}
    if obj.keys() == _LEGACY_WIRE_KEYS[kind]:  # an older sender: incarnation unknown
        return {**obj, "inc": 0}
    expected = (*_ENVELOPE_KEYS, *_BODY_FIELDS[kind])
    missing = [k for k in expected if k not in obj and k not in _SENT_IF_SET[kind]]
    if missing:
        raise SchemaError(R_MISSING_FIELD, f"{kind} lacks {missing}")
    extra = [k for k in obj if k not in expected]
    raise SchemaError(R_EXTRA_FIELD, f"{kind} has unexpected {[repr(k)[:40] for k in extra[:5]]}")


_ABSENT = object()  # a field not in a wire map

MAX_REMEMBERED_TEXTS = 4096
"""Strings a text check accepted that the decoder remembers (per check; forgotten all at once when full, so
a flood of distinct sender names costs a check each and no memory beyond this)."""


def _compile_builder(cls: type[Message]) -> Callable[[dict[str, Any]], Message]:
    """The message of class ``cls`` a wire map of as many keys as the kind's holds, or SchemaError.

    The checks :func:`decode` made before a field's, then the field checks in ``cls._PLAN``'s order (the
    constructor's), without its keyword plumbing nor a call per field for the common case (a check's
    ``FAST``, see :mod:`truav.wire.field_checks`), which is inlined; a value off it goes through the check
    itself. Every field is looked up first: with the key count right, all found means the keys are the
    kind's (else the missing ones are named, as a set comparison of the keys would have found)."""
    env: dict[str, Any] = {"_new": object.__new__, "_cls": cls, "_MAX_TEXTS": MAX_REMEMBERED_TEXTS,
                           "_keys_differ": _wire_keys_differ, "_kind": cls.KIND, "SchemaError": SchemaError,
                           "R_UNSTAMPED": R_UNSTAMPED}
    plan = cls._PLAN
    src_var = next(f"v{i}" for i, (name, _, _) in enumerate(plan) if name == "src")
    if_set = cls.SENT_IF_SET
    env["_ABSENT"] = _ABSENT
    body: list[str] = ["try:", *(f"    v{i} = obj[{name!r}]" for i, (name, _, _) in enumerate(plan)
                                 if name not in if_set),
                       # not the kind's keys: an older sender's or a refusal (with an optional field sent, a
                       # map as long as the kind's can lack one, e.g. no ``inc``); the keys right, built again
                       "except KeyError:", "    return _again(_keys_differ(obj, _kind))",
                       f"if {src_var} == '':", f"    raise SchemaError(R_UNSTAMPED, {cls.KIND + ' has an empty src'!r})"]
    fields: list[str] = []
    for i, (name, path, check) in enumerate(plan):
        v, call = f"v{i}", f"v{i} = _c{i}(_p{i}, v{i})"
        env[f"_c{i}"], env[f"_p{i}"] = check, path
        if name in if_set:  # off the wire when empty: its default, else checked
            body += [f"{v} = obj.get({name!r}, _ABSENT)", f"if {v} is _ABSENT:", f"    {v} = {{}}", "else:",
                     f"    {call}"]  # a map, empty when left off (as the constructor's check makes it)
            fields.append(f"d[{name!r}] = {v}")
            continue
        fast = getattr(check, "FAST", None)
        tag = fast[0] if isinstance(fast, tuple) and fast else None
        if tag == "int" and type(fast[1]) is int and type(fast[2]) is int:
            body += [f"if not (type({v}) is int and {fast[1]!r} <= {v} <= {fast[2]!r}):", f"    {call}"]
        elif tag == "real":  # finite: -inf < v < inf (NaN compares False); 1e999 is the literal inf
            env[f"_lo{i}"] = lo = fast[1]
            cond = f"-1e999 < {v} < 1e999" if lo is None else f"_lo{i} {'<' if fast[2] else '<='} {v} < 1e999"
            body += [f"if not (type({v}) is float and {cond}):", f"    {call}"]
        elif tag == "bool":
            body += [f"if type({v}) is not bool:", f"    {call}"]
        elif tag == "choice":
            env[f"_o{i}"] = tuple(fast[1])
            body += [f"if not (type({v}) is str and {v} in _o{i}):", f"    {call}"]
        elif tag == "text":
            env[f"_k{i}"] = _REMEMBERED.setdefault(id(check), (check, set()))[1]
            body += [f"if not (type({v}) is str and {v} in _k{i}):", f"    {call}",
                     f"    if type({v}) is str:",
                     f"        if len(_k{i}) >= _MAX_TEXTS:", f"            _k{i}.clear()",
                     f"        _k{i}.add({v})"]
        elif tag == "vec2":
            body += [f"if (type({v}) is list or type({v}) is tuple) and len({v}) == 2 and type({v}[0]) is float "
                     f"and type({v}[1]) is float and -1e999 < {v}[0] < 1e999 and -1e999 < {v}[1] < 1e999:",
                     f"    {v} = ({v}[0], {v}[1])", "else:", f"    {call}"]
        else:
            body.append(call)
        fields.append(f"d[{name!r}] = {v}")
    body += ["m = _new(_cls)", "d = m.__dict__", *fields, "return m"]  # in _PLAN's order, as the constructor
    src = "def build(obj):\n" + "".join(f"    {line}\n" for line in body)
    exec(compile(src, f"<truav.wire.codec decoder of {cls.KIND}>", "exec"), env)
    env["_again"] = env["build"]
    return env["build"]


_REMEMBERED: dict[int, tuple[Check, set[str]]] = {}  # id(text check) -> (the check, kept alive; what it accepted)
_KIND_PLAN: dict[str, tuple[int, int, Callable[[dict[str, Any]], Message]]] = {
    kind: (_SIZE_LIMIT[kind], len(_WIRE_KEYS[kind]) - len(_SENT_IF_SET[kind]),  # type: ignore[arg-type]
           _compile_builder(cls))
    for kind, cls in MESSAGE_CLASSES.items()}
"""kind -> (its size limit, its number of wire keys, its builder): what ``decode`` needs of a kind."""

_LIMIT_NAMES = ("max_map_len", "max_array_len", "max_str_len", "max_bin_len", "max_ext_len")


def _unpackb_limits(limits: Mapping[str, int]) -> tuple[int, ...] | None:
    """``limits`` in the order ``decode`` hands them to ``unpackb``; None unless they are exactly those five
    (another set would leave unpackb and the reference Unpacker each a default of its own)."""
    return tuple(limits[name] for name in _LIMIT_NAMES) if set(limits) == set(_LIMIT_NAMES) else None


_LOOSE_EXPECT = (MAX_PAYLOAD_BYTES, _unpackb_limits(_LOOSE_LIMITS))
_EXPECT: dict[str | None, tuple[int, tuple[int, ...] | None]] = {
    None: _LOOSE_EXPECT,
    **{kind: (_SIZE_LIMIT.get(kind, MAX_PAYLOAD_BYTES), _unpackb_limits(unpack_limits(kind)))
       for kind in (*_SIZE_LIMIT, *_UNPACK_LIMITS)}}
"""expect -> (size limit, msgpack limits) as ``decode`` applied them (any other expect: the loosest)."""
_unpackb = msgpack.unpackb


def _incomplete_texts() -> tuple[str, str]:
    """What ``unpackb`` says of an incomplete object, and the detail the reference parse gives it."""
    try:
        _unpackb(b"\x91")
    except ValueError as exc:
        said = str(exc)
    else:  # pragma: no cover - msgpack changed: every incomplete input goes to the reference parse
        said = "\0"
    try:
        _unpack_reference(b"\x91", None, MAX_PAYLOAD_BYTES)
    except SchemaError as exc:
        return said, exc.detail
    raise AssertionError("an incomplete msgpack object decoded")  # pragma: no cover


_UNPACKB_INCOMPLETE, _INCOMPLETE_DETAIL = _incomplete_texts()


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
