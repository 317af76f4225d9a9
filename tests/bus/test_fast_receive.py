"""The fast receive path (issue 28) says of every input what the reference path said.

``reference_decode``, ``reference_check_placement`` and ``ReferenceGuard.check`` below are the decoder,
placement check and guard as they were before the receive path was made cheap, copied verbatim (names
resolved to the same schema tables): a corpus of valid and hostile payloads, keys and messages goes through
both, and every outcome must match (the same message, field types and order included, or the same
SchemaError: reason, text and sender). The inbox tests then push a mix of valid and hostile samples
through real Zenoh sessions on loopback and check the bus's counts against the reference verdicts.
"""

from __future__ import annotations

import dataclasses
import random
import time
from collections import Counter
from typing import Any

import msgpack
import numpy as np
import pytest
import zenoh

from truav.bus import placement
from truav.wire import codec, guard as guard_mod, keys, schema
from truav.wire.guard import (CONTROL_SHUTDOWN, R_DUPLICATE, R_IMPLAUSIBLE, R_SENDER, R_TICK, SPEED_MARGIN,
                             SUPERVISOR, Bounds, Guard)
from truav.bus.inbox import Inbox
from truav.wire.messages import (_BODY_FIELDS, _LEGACY_WIRE_KEYS, _OPTIONAL_FIELDS, _SIZE_LIMIT, _WIRE_KEYS,
                                 MESSAGE_CLASSES, Message)
from truav.bus.placement import R_KEY_MISMATCH, expected_kind
from truav.wire.schema_names import (_ENVELOPE_KEYS, MAX_PAYLOAD_BYTES, MAX_SRC_LEN, R_BAD_TYPE, R_EXTRA_FIELD,
                                    R_MISSING_FIELD, R_NOT_BYTES, R_NOT_MAP, R_NOT_MSGPACK, R_TOO_LARGE,
                                    R_UNKNOWN_KIND, R_UNSTAMPED, R_VERSION, SCHEMA_VERSION, SchemaError)

RUN = "test_fast_receive"
SEED = 20261202
WAIT_S = 5.0
unpack_limits = codec.unpack_limits


# --- the reference decoder (truav/wire/codec.py before the fast path, verbatim; since then fields sent only
# when set, Beacon.fields, are filled with their default when absent and never named missing) ------------
def reference_decode(data: bytes | bytearray | memoryview, expect: str | None = None) -> Message:
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
        return _reference_from_map(obj, len(data))
    except SchemaError as exc:
        exc.src = src
        raise
    except Exception as exc:  # defensive: validators should only raise SchemaError
        raise SchemaError(R_BAD_TYPE, f"{type(exc).__name__}: {str(exc)[:80]}", src=src) from None


def _reference_from_map(obj: dict[Any, Any], size: int) -> Message:
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
    added = {f: _OPTIONAL_FIELDS[kind][f] for f in MESSAGE_CLASSES[kind].ADDED if f not in obj}
    if added and {**obj, **added}.keys() in (_WIRE_KEYS[kind], _LEGACY_WIRE_KEYS[kind]):  # before fields added since
        obj = {**obj, **added}
    if obj.keys() != _WIRE_KEYS[kind]:
        if obj.keys() == _LEGACY_WIRE_KEYS[kind]:  # an older sender: incarnation unknown
            obj = {**obj, "inc": 0}
        else:
            expected = (*_ENVELOPE_KEYS, *_BODY_FIELDS[kind])
            missing = [k for k in expected if k not in obj and k not in MESSAGE_CLASSES[kind].SENT_IF_SET]
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


# --- the reference placement check (truav/bus/placement.py before the fast path, verbatim) -------------
def key_facts(key: str) -> tuple[str | None, int | None]:
    return expected_kind(key), keys.parse_uav_id(key)


uav_of_src = keys.parse_uav_identity


def reference_check_placement(key: str, msg: Message) -> None:
    kind, key_uav = key_facts(key)
    if kind is not None and kind != msg.KIND:
        raise SchemaError(R_KEY_MISMATCH, f"{msg.KIND} message on {key} (expects {kind})", src=msg.src)
    body_uav = getattr(msg, "uav", None)
    if key_uav is not None and body_uav is not None and body_uav != key_uav:
        raise SchemaError(R_KEY_MISMATCH, f"{msg.KIND} for uav {body_uav} on {key}", src=msg.src)
    src_uav = uav_of_src(msg.src)
    if src_uav is not None and src_uav != key_uav:
        raise SchemaError(R_KEY_MISMATCH, f"sender {msg.src} may not appear on {key}", src=msg.src)
    last = key.rsplit("/", 1)[-1]
    if kind == schema.KIND_METRICS and isinstance(msg, schema.Metrics) and msg.scope != last:
        raise SchemaError(R_KEY_MISMATCH, f"{msg.scope} metrics on {key}", src=msg.src)
    if kind == schema.KIND_FAULT and isinstance(msg, schema.Fault) and msg.fault != last:
        raise SchemaError(R_KEY_MISMATCH, f"{msg.fault} fault on {key}", src=msg.src)
    if kind == schema.KIND_COMMAND and isinstance(msg, schema.Command) and last != str(msg.uav):
        raise SchemaError(R_KEY_MISMATCH, f"command for uav {msg.uav} on {key}", src=msg.src)
    if kind == schema.KIND_OVERRIDE and isinstance(msg, schema.Override) and last != str(msg.uav):  # (added since)
        raise SchemaError(R_KEY_MISMATCH, f"override of uav {msg.uav} on {key}", src=msg.src)


# --- the reference guard (Guard.check before the fast path, verbatim) ----------------------------------
class ReferenceGuard(Guard):
    def check(self, key: str, msg: schema.Message) -> tuple[str, str] | None:
        b, src = self.bounds, msg.src
        # (schema.Rejection added since, with the kind: only the world tells a sender what it refused)
        if isinstance(msg, (schema.Tick, schema.Obs, schema.Positions, schema.Metrics, schema.Rejection)):
            if src != keys.SRC_WORLD:
                return R_SENDER, f"{msg.KIND} from {src}"
        elif isinstance(msg, (schema.Beacon, schema.Action, schema.State, schema.Health, schema.QShare)):
            # (schema.QShare added since, with the kind: a federated share comes from its own UAV)
            if src != f"uav/{msg.uav}":
                return R_SENDER, f"{msg.KIND} of uav {msg.uav} from {src}"
        elif isinstance(msg, schema.Control):
            if not (src == SUPERVISOR or (src == keys.SRC_WORLD and msg.command == CONTROL_SHUTDOWN)):
                return R_SENDER, f"control {msg.command!r} from {src}"
        elif isinstance(msg, schema.Fault):  # (the world's override events added since, with the override kind)
            if not (src == SUPERVISOR or (src == keys.SRC_WORLD and msg.fault == schema.FAULT_OVERRIDE)):
                return R_SENDER, f"fault from {src}"
        elif isinstance(msg, schema.Override):  # (added since, with the kind)
            if src not in (SUPERVISOR, keys.SRC_OPERATOR):
                return R_SENDER, f"override from {src}"
        elif isinstance(msg, schema.Command):
            if src != keys.SRC_CONTROLLER:
                return R_SENDER, f"command from {src}"
        elif isinstance(msg, schema.ReplayStatus):
            if src != keys.SRC_REPLAY:
                return R_SENDER, f"replay status from {src}"
        uav = getattr(msg, "uav", None)
        if uav is not None and uav >= b.n_uavs:
            return R_IMPLAUSIBLE, f"uav {uav} >= n_uavs {b.n_uavs}"
        tick = getattr(msg, "tick", None)
        resyncs = isinstance(msg, (schema.Tick, schema.Obs, schema.Metrics))  # the world's own (sender checked)
        if tick is not None and not self._near(tick) and not (resyncs and self._resync(tick)):
            return R_TICK, f"tick {tick}, current {self._tick}"
        if isinstance(msg, schema.Obs):
            if not b.in_area(msg.pos):
                return R_IMPLAUSIBLE, f"pos {msg.pos} outside the area"
            if max(msg.vehicles_in_range, msg.covered) > b.max_count \
                    or max(msg.queued_packets, msg.relayed) > b.max_packets:
                return R_IMPLAUSIBLE, "counts above the scenario's vehicles and queues"
            if msg.energy_j > b.max_energy_j or msg.speed_max > b.max_speed * SPEED_MARGIN:
                return R_IMPLAUSIBLE, f"energy {msg.energy_j} J or speed {msg.speed_max} m/s"
            self._advance(msg.tick)
        elif isinstance(msg, schema.Tick):
            if msg.n_uavs != b.n_uavs:
                return R_IMPLAUSIBLE, f"tick for {msg.n_uavs} UAVs, scenario has {b.n_uavs}"
            self._advance(msg.tick)
        elif isinstance(msg, schema.State):
            if not b.in_area(msg.pos) or max(msg.vehicles_in_range, msg.covered) > b.max_count \
                    or max(msg.queued_packets, msg.relayed) > b.max_packets or msg.energy_j > b.max_energy_j:
                return R_IMPLAUSIBLE, f"state of uav {msg.uav}: values the world cannot produce"
        elif isinstance(msg, schema.Beacon):
            vx, vy = msg.vel
            if not b.in_area(msg.pos) or (vx * vx + vy * vy) ** 0.5 > b.max_speed * SPEED_MARGIN:
                return R_IMPLAUSIBLE, f"beacon pos {msg.pos} vel {msg.vel}"
        elif isinstance(msg, schema.Action):
            with self._lock:
                if msg.tick == self._last_action[msg.uav]:
                    return R_DUPLICATE, f"second action of uav {msg.uav} for tick {msg.tick}"
                # An older tick's action is an answer delayed behind a newer one, not malformed: passed on,
                # the world counts it as stale (world.process.world_process).
                self._last_action[msg.uav] = max(self._last_action[msg.uav], msg.tick)
        elif isinstance(msg, schema.QShare):  # (added since, with the kind)
            if msg.part >= msg.parts or len(msg.counts) != len(msg.states) or len(msg.q) != 16 * len(msg.states):
                return R_IMPLAUSIBLE, (f"qshare of uav {msg.uav}: part {msg.part} of {msg.parts}, {len(msg.states)} "
                                       f"states, {len(msg.counts)} counts, {len(msg.q)} values")
        elif isinstance(msg, schema.Override):  # (added since, with the kind)
            if not msg.release and not b.in_area(msg.goal):
                return R_IMPLAUSIBLE, f"override goal {msg.goal} outside the area"
        elif isinstance(msg, schema.Positions):
            if len(msg.uavs) != b.n_uavs or len(msg.vehicles) > b.max_count:
                return R_IMPLAUSIBLE, f"{len(msg.uavs)} UAVs, {len(msg.vehicles)} vehicles"
        return None


# --- a corpus -------------------------------------------------------------------------------------------
SENDER_OF = {schema.KIND_TICK: "world", schema.KIND_OBS: "world", schema.KIND_POSITIONS: "world",
             schema.KIND_METRICS: "world", schema.KIND_FAULT: SUPERVISOR, schema.KIND_CONTROL: SUPERVISOR,
             schema.KIND_COMMAND: keys.SRC_CONTROLLER, schema.KIND_BEACONS: "uav/3", schema.KIND_REJECTION: "world",
             schema.KIND_REPLAY_STATUS: keys.SRC_REPLAY, schema.KIND_WORLD_SNAPSHOT: "world",
             schema.KIND_OVERRIDE: keys.SRC_OPERATOR}


def samples() -> list[Message]:
    """One valid, unstamped message of every kind (a kind added since has to be added here)."""
    return [
        schema.Tick(tick=7, episode=2, sim_time=3.5, deadline_ms=50.0, n_uavs=8),
        schema.Obs(tick=7, episode=2, uav=3, pos=(10.5, -2.25), vehicles_in_range=4, queued_packets=12, relayed=3,
                   covered=2, energy_j=0.75, speed_max=20.0, done=False, densest_sector=3),
        schema.Beacon(uav=3, tick=7, pos=(1234.567, 987.654), vel=(3.2, -1.5)),
        schema.Beacon(uav=3, tick=7, pos=(1.0, 2.0), vel=(0.0, 0.0), fields={"load": 3, "busy": True, "x": 0.5}),
        schema.Action(uav=3, tick=7, action=15),
        schema.Action(uav=3, tick=8, action=schema.HOVER),
        schema.Metrics(scope=schema.SCOPE_STEP, tick=7, episode=2, values={"pdr": 0.9, "delay_ms": 12.0}),
        schema.Fault(fault=schema.FAULT_LATENCY, phase=schema.PHASE_START, target="uav/3",
                     params={"delay_ms": 200.0, "jitter": 5, "dist": "normal"}),
        schema.Control(command="fault_plan", args={"events": [{"at": 1.5, "kind": "loss", "p": 0.2}], "dry": True,
                                                   "note": None}),
        schema.Positions(tick=7, uavs=((0.0, 1.0), (2.0, 3.0)), vehicles=((5.0, 6.0),)),
        schema.State(uav=3, tick=7, episode=2, step=4, pos=(10.5, 2.25), vehicles_in_range=4, queued_packets=12,
                     relayed=3, covered=2, energy_j=0.75, done=True, pad=bytes(20)),
        schema.Command(uav=3, tick=7, action=5, pad=bytes(8)),
        schema.Health(uav=3, last_tick=-1, steps=7, stale_obs_skipped=1, rejected={"not_msgpack": 2},
                      senders={"?": 1, "(other senders)": 1}),
        schema.Beacons(entries=((3, 7, (1234.5, 987.25), (3.2, -1.5)), (4, 7, (10.0, 20.0), (0.0, 0.0)))),
        schema.Rejection(uav=3, at_tick=7, reason="out_of_range", refused_kind="action",
                         key="truav/r/uav/3/action", detail="action.action=99 outside [-1, 15]",
                         counts={"out_of_range": 2, "bad_type": 1}),
        schema.ReplayStatus(state=schema.REPLAY_PLAYING, position_s=1.5, span_s=9.0, tick=7, rate=1.0, paused=False,
                            sent=40, restored=0, loop=0),
        schema.WorldSnapshot(tick=7, episode=0, arrays={"t": ("<i8", (), bytes(8)),
                                                        "uav_pos": ("<f8", (1, 2, 2), bytes(32))}),
        schema.AgentSnapshot(uav=3, tick=7, arrays={"q_rows": ("<i8", (2,), bytes(16)),
                                                    "rng": ("<u8", (6,), bytes(48))}),
        schema.QShare(uav=3, tick=7, episode=2, part=0, parts=1, states=np.array([5, 17]), counts=np.array([4, 1]),
                      q=np.arange(32, dtype=np.float64)),
        schema.Override(uav=3, release=False, goal=(120.5, 40.0), speed=7.5),
        schema.Override(uav=3, release=True, goal=(-9e9, 0.0), speed=0.0),
    ]


def stamped(msg: Message, src: str | None = None) -> Message:
    src = src or SENDER_OF.get(msg.KIND) or f"uav/{msg.uav}"
    return schema.Sequencer(src, clock=lambda: 1_700_000_000_123_456_789, incarnation=12345).stamp(msg)


def wire_of(msg: Message) -> dict[str, Any]:
    return msgpack.unpackb(schema.encode(msg), raw=False)


def pack(obj: Any) -> bytes | None:
    try:
        return msgpack.packb(obj, use_bin_type=True)
    except (OverflowError, TypeError, ValueError):
        return None


NAN, INF = float("nan"), float("inf")
HOSTILE_VALUES: list[Any] = [
    None, True, False, 0, 1, -1, 3, 15, 16, -2, 1023, 1024, (1 << 63) - 1, 1 << 63, (1 << 64) - 1, -(1 << 63),
    0.0, -0.0, 1.5, -1.5, 1e308, -1e308, NAN, INF, -INF, 5e-324,
    "", "x", "uav/3", "world", "step", "episode", "start", "a" * 64, "a" * 65, "a" * 300, "é", "bad chars!", "a/",
    b"", b"\x00", b"x" * 100, [], [1.0], [1.0, 2.0], [1, 2], [True, 1.0], [1.0, NAN], [INF, 0.0], [1.0, -INF],
    [1.0, 2.0, 3.0], [[1.0, 2.0]], [[1.0, 2.0], [3.0, NAN]], [[1.0, 2.0, 3.0]], [["a", 1.0]], ["a", "b"],
    {}, {"a": 1}, {"a": 1.0}, {"a": NAN}, {"a": "b"}, {"": 1}, {"a" * 70: 1}, {"a": [1]}, {"a": {"b": None}},
    {"a": True}, {"a": -1}, {"a": 1 << 63}, {"bad key!": 1}, {"x": [1, [2, [3, {"y": "z"}]]]},
    msgpack.ExtType(1, b"x"),
]


def nested(depth: int) -> dict[str, Any]:
    out: dict[str, Any] = {"leaf": 1}
    for _ in range(depth):
        out = {"n": out}
    return out


def hostile_payloads() -> list[bytes]:
    """Valid payloads of every kind, and every way of spoiling them the corpus knows."""
    rng = random.Random(SEED)
    out: list[bytes] = []
    for msg in samples():
        good = stamped(msg)
        raw = schema.encode(good)
        wire = wire_of(good)
        out.append(raw)
        out += [raw[:n] for n in range(len(raw))]  # truncated
        out += [raw + b"\x00", raw + b"\xc0", raw + raw, raw + b"\xc1"]  # trailing bytes
        for _ in range(30):  # flipped bytes
            b = bytearray(raw)
            for _ in range(rng.randint(1, 3)):
                b[rng.randrange(len(b))] = rng.randrange(256)
            out.append(bytes(b))
        for name in wire:  # every field: removed, and every hostile value
            out.append(pack({k: v for k, v in wire.items() if k != name}))
            for value in HOSTILE_VALUES:
                out.append(pack({**wire, name: value}))
        legacy = {k: v for k, v in wire.items() if k != "inc"}  # an older sender's
        out += [pack(legacy), pack({**legacy, "extra": 1})]
        out += [pack({**wire, "extra": 1}), pack({**wire, 1: 1}), pack({**wire, b"k": 1}),
                pack(dict(reversed(wire.items()))), pack({**wire, "src": good.src + "x" * 70})]
        for other in MESSAGE_CLASSES:  # the wrong kind
            out.append(pack({**wire, "kind": other}))
        for src in ("", "uav/3", "uav/4", "world", "supervisor", "controller", "replay", "uav/03", "a b", "x" * 64):
            out.append(pack({**wire, "src": src}))
    out += [b"", b"\xc1", b"\x80", b"\x90", b"\xa0", b"\x01", b"\xc0", b"\xff" * 8, b"\xde\xff\xff", b"\xdf" + b"\xff" * 4,
            pack([1, 2]), pack("str"), pack(None), pack(1.5), pack({"v": 1}), pack({"kind": "beacon"}),
            pack({"v": 2, "kind": "beacon"}), pack({"v": True, "kind": "beacon"}), pack({"v": 1.0, "kind": "beacon"}),
            pack({"v": 1, "kind": None}), pack({"v": 1, "kind": ["beacon"]}), pack({"v": [1] * 30, "kind": "x"}),
            pack({"v": 1, "kind": "x" * 100}), pack(nested(20)), pack({"v": 1, "kind": "control", "args": nested(20)}),
            b"\x91" * 2000 + b"\xc0",  # nested too deep for msgpack's stack
            pack({f"k{i}": i for i in range(19)}), pack({f"k{i}": i for i in range(200)}), pack({"s": "x" * 65}),
            pack({"a": [0] * 3}), pack({"b": b"x"}), pack({"a": list(range(40_000))}),
            pack({"v": 1, "kind": "positions", "src": "world", "seq": 0, "t": 0, "inc": 0, "tick": 0,
                  "uavs": [[1.0, 2.0]] * 3, "vehicles": [[0.0, 0.0]] * 40_000}),
            bytes(schema.MAX_SMALL_PAYLOAD_BYTES + 1), bytes(schema.MAX_CONTROL_PAYLOAD_BYTES + 1)]
    out += [bytes(rng.randrange(256) for _ in range(rng.randint(1, 200))) for _ in range(300)]
    return [p for p in out if p is not None]


def outcome(decode, data: Any, expect: str | None) -> tuple:
    """What decoding says: the message (its type, its fields with their types and order) or the error."""
    try:
        msg = decode(data, expect)
    except SchemaError as exc:
        return ("refused", exc.reason, str(exc), exc.detail, exc.src)
    except Exception as exc:  # neither may raise anything else
        return ("raised", type(exc).__name__, str(exc))
    return ("message", type(msg), msg, repr(list(vars(msg).items())))


def placed(check, key: str, msg: Message) -> tuple | None:
    """What a placement check says: None, or the error."""
    try:
        check(key, msg)
    except SchemaError as exc:
        return ("refused", exc.reason, str(exc), exc.detail, exc.src)
    except Exception as exc:
        return ("raised", type(exc).__name__, str(exc))
    return None


EXPECTS = (None, *MESSAGE_CLASSES, "no_such_kind", "")


GUARDED_KINDS = (schema.KIND_TICK, schema.KIND_OBS, schema.KIND_BEACON, schema.KIND_ACTION, schema.KIND_METRICS,
                 schema.KIND_FAULT, schema.KIND_CONTROL, schema.KIND_POSITIONS, schema.KIND_STATE,
                 schema.KIND_COMMAND, schema.KIND_HEALTH, schema.KIND_REJECTION, schema.KIND_OVERRIDE)
"""The kinds whose sender and values the guard checks (a new kind decodes through the corpus all the same)."""


def test_every_kind_is_in_the_corpus() -> None:
    missing = set(MESSAGE_CLASSES) - {m.KIND for m in samples()}
    assert not missing, f"add a valid message of {sorted(missing)} to samples() (and its sender to SENDER_OF)"


def test_decode_says_what_the_reference_decoder_says_of_every_payload() -> None:
    payloads = hostile_payloads()
    # the reference keeps nothing between calls: its answers are worked out once, for both rounds
    wants = [[outcome(reference_decode, raw, expect) for expect in EXPECTS] for raw in payloads]
    for _ in range(2):  # the second round with the decoder's remembered texts filled
        for raw, answers in zip(payloads, wants):
            for expect, want in zip(EXPECTS, answers):
                assert outcome(codec.decode, raw, expect) == want, (raw[:80], expect)
    seen = Counter(want[1] if want[0] == "refused" else want[0] for answers in wants for want in answers)
    # the corpus reaches every reason the decoder has, and valid messages of every kind
    assert {R_NOT_MSGPACK, R_NOT_MAP, R_TOO_LARGE, R_VERSION, R_UNKNOWN_KIND, R_MISSING_FIELD, R_EXTRA_FIELD,
            R_BAD_TYPE, schema.R_OUT_OF_RANGE, R_UNSTAMPED, "message"} <= set(seen)
    assert "raised" not in seen


@pytest.mark.parametrize("as_", [bytearray, memoryview, lambda b: memoryview(bytearray(b))],
                         ids=["bytearray", "memoryview", "memoryview of bytearray"])
def test_decode_takes_every_bytes_like_as_the_reference_does(as_) -> None:
    for raw in hostile_payloads()[::7]:
        for expect in (None, schema.KIND_BEACON, schema.KIND_CONTROL):
            assert outcome(codec.decode, as_(raw), expect) == outcome(reference_decode, as_(raw), expect)


@pytest.mark.parametrize("data", ["text", None, 12, [b"x"], {"v": 1}], ids=repr)
def test_decode_refuses_what_is_not_bytes_as_the_reference_does(data) -> None:
    for expect in (None, schema.KIND_BEACON):
        assert outcome(codec.decode, data, expect) == outcome(reference_decode, data, expect)
        assert outcome(codec.decode, data, expect)[1] == R_NOT_BYTES


def test_legacy_payloads_of_every_kind_decode_with_incarnation_zero() -> None:
    for msg in samples():
        wire = wire_of(stamped(msg))
        del wire["inc"]
        got = outcome(codec.decode, pack(wire), msg.KIND)
        assert got == outcome(reference_decode, pack(wire), msg.KIND)
        assert got[0] == "message" and got[2].inc == 0


def test_remembered_sender_names_stay_bounded_under_a_flood_of_unique_ones() -> None:
    wire = wire_of(stamped(schema.Beacon(uav=3, tick=7, pos=(1.0, 2.0), vel=(0.0, 0.0))))
    for i in range(codec.MAX_REMEMBERED_TEXTS + 500):
        raw = pack({**wire, "src": f"uav/{i}/x"})
        assert outcome(codec.decode, raw, "beacon") == outcome(reference_decode, raw, "beacon")
    assert all(len(texts) <= codec.MAX_REMEMBERED_TEXTS for _, texts in codec._REMEMBERED.values())


# --- placement and guard -----------------------------------------------------------------------------------
def placement_keys() -> list[str]:
    out = [keys.uav_beacon(RUN, u) for u in (0, 3, 4, 1023)]
    out += [f"truav/{RUN}/uav/3/{last}" for last in ("obs", "action", "state", "health", "beacon", "nope")]
    out += [f"truav/{RUN}/uav/03/beacon", f"truav/{RUN}/uav/1024/beacon", f"truav/{RUN}/uav/3/cell/beacon",
            f"truav/{RUN}/uav/3/7_9/beacon", f"truav/{RUN}/world/tick", f"truav/{RUN}/world/positions",
            f"truav/{RUN}/metrics/step", f"truav/{RUN}/metrics/episode", f"truav/{RUN}/fault/latency",
            f"truav/{RUN}/fault/loss", f"truav/{RUN}/control/cmd", f"truav/{RUN}/controller/3",
            f"truav/{RUN}/controller/4", f"truav/{RUN}/controller/03", f"truav/{RUN}/alive/uav/3", "truav/x",
            "other/run/uav/3/beacon", f"truav/{RUN}", ""]
    return out


def guard_corpus(rng: random.Random, n: int) -> list[Message]:
    base = samples()
    srcs = ["world", "supervisor", "controller", "uav/3", "uav/4", "uav/0", "uav/49", "uav/50", "replay", "x"]
    variants: dict[str, list[dict[str, Any]]] = {
        "uav": [{"uav": u} for u in (0, 3, 4, 49, 50, 1023)],
        "tick": [{"tick": t} for t in (0, 5, 7, 7, 7, 8, 8, 9, 63, 64, 65, 70, 71, 72, 100, 1000, 10**6, (1 << 63) - 1)],
        "pos": [{"pos": p} for p in ((1.0, 1.0), (-1.0, 0.0), (-1.5, 0.0), (5001.0, 5001.0), (5001.5, 0.0))],
        "vel": [{"vel": v} for v in ((0.0, 0.0), (30.0, 0.0), (30.3, 0.0), (30.31, 0.0), (-25.0, 20.0))],
        "n_uavs": [{"n_uavs": v} for v in (0, 49, 50, 51)],
        "vehicles_in_range": [{"vehicles_in_range": v} for v in (0, 100, 101)],
        "covered": [{"covered": v} for v in (0, 100, 101)],
        "queued_packets": [{"queued_packets": v} for v in (0, 1000, 1001)],
        "relayed": [{"relayed": v} for v in (0, 1000, 1001)],
        "energy_j": [{"energy_j": v} for v in (0.0, 1e5, 1e5 + 1)],
        "speed_max": [{"speed_max": v} for v in (0.0, 30.3, 30.31)],
        "command": [{"command": c} for c in ("shutdown", "fault_plan")],
        "uavs": [{"uavs": tuple((float(i), 0.0) for i in range(k))} for k in (0, 2, 50)],
        "vehicles": [{"vehicles": tuple((0.0, 0.0) for _ in range(k))} for k in (0, 100, 101)],
    }
    out = []
    for _ in range(n):
        msg = rng.choice(base)
        changes: dict[str, Any] = {}
        for name, options in variants.items():
            if hasattr(msg, name) and rng.random() < 0.4:
                changes.update(rng.choice(options))
        msg = dataclasses.replace(msg, **changes) if changes else msg
        out.append(stamped(msg, rng.choice(srcs) if rng.random() < 0.3 else None))
    return out


def test_placement_says_what_the_reference_says_of_every_key_and_message() -> None:
    msgs = guard_corpus(random.Random(SEED), 400)
    refusals = Counter()
    for key in placement_keys():
        for msg in msgs:
            want = placed(reference_check_placement, key, msg)
            assert placed(placement.check_placement, key, msg) == want, (key, msg)
            refusals[want[1] if want else None] += 1
            facts = placement.facts_of(key)
            assert placement.key_facts(key) == key_facts(key) == (facts.kind, facts.uav)
            assert placement.size_limit_of_key(key) == (schema.size_limit(facts.kind) if facts.kind else
                                                         MAX_PAYLOAD_BYTES)
    assert set(refusals) == {None, R_KEY_MISMATCH} and "raised" not in refusals


def test_remembered_keys_and_senders_stay_bounded_under_a_flood_of_unique_ones() -> None:
    msg = stamped(schema.Beacon(uav=3, tick=7, pos=(1.0, 2.0), vel=(0.0, 0.0)))
    for i in range(placement.MAX_REMEMBERED_KEYS + 500):
        key = f"truav/{RUN}/uav/{i}/beacon"
        assert placement.key_facts(key) == key_facts(key)
        forged = dataclasses.replace(msg, src=f"uav/{i}") if i < keys.MAX_UAVS else \
            object.__new__(schema.Beacon)
        if i >= keys.MAX_UAVS:
            forged.__dict__.update({**vars(msg), "src": f"x{i}"})
        assert placed(placement.check_placement, key, forged) == placed(reference_check_placement, key, forged)
    assert len(placement._FACTS) <= placement.MAX_REMEMBERED_KEYS
    assert len(placement._SRC_UAV) <= placement.MAX_REMEMBERED_KEYS


@pytest.mark.parametrize("seed", range(4))
def test_guard_says_what_the_reference_guard_says_and_keeps_the_same_state(seed, monkeypatch) -> None:
    now = [1000.0]
    monkeypatch.setattr(guard_mod.time, "monotonic", lambda: now[0])
    rng = random.Random(SEED + seed)
    bounds = Bounds(n_uavs=50, area_m=5000.0, max_count=100, max_packets=1000, max_speed=30.0, max_energy_j=1e5)
    verdicts = Counter()
    for n, msg in enumerate(guard_corpus(rng, 4000)):
        if n % 100 == 0:  # a fresh pair now and then: a far tick moves the window for good
            new, ref = Guard(bounds), ReferenceGuard(bounds)
        now[0] += rng.choice((0.0, 0.01, 0.5, 2.0))  # silences long enough to resync, sometimes
        if rng.random() < 0.05:
            new.sent(msg)
            ref.sent(msg)
        key = keys.uav_beacon(RUN, 3)
        want = ref.check(key, msg)
        assert new.check(key, msg) == want, msg
        assert (new._tick, new._last_action, new._advanced_at) == (ref._tick, ref._last_action, ref._advanced_at)
        verdicts[msg.KIND, want[0] if want else None] += 1
    for kind in GUARDED_KINDS:  # every kind accepted and refused, the kinds with bounds also as implausible
        assert verdicts[kind, None] and verdicts[kind, R_SENDER], kind
        if kind not in (schema.KIND_METRICS, schema.KIND_FAULT, schema.KIND_CONTROL):
            assert verdicts[kind, R_IMPLAUSIBLE], kind
    assert verdicts[schema.KIND_ACTION, R_DUPLICATE] and verdicts[schema.KIND_BEACON, R_TICK]


def test_guard_checks_a_subclass_of_a_message_as_the_reference_does() -> None:
    @dataclasses.dataclass(frozen=True)
    class MyBeacon(schema.Beacon):
        pass

    bounds = Bounds(n_uavs=50, area_m=5000.0, max_count=100, max_packets=1000, max_speed=30.0, max_energy_j=1e5)
    for src in ("uav/3", "uav/4", "world"):
        msg = MyBeacon(uav=3, tick=7, pos=(1.0, 2.0), vel=(40.0, 0.0), src=src)
        assert Guard(bounds).check("k", msg) == ReferenceGuard(bounds).check("k", msg)


# --- the inbox: counts through real Zenoh sessions -----------------------------------------------------
BOUNDS = Bounds(n_uavs=8, area_m=5000.0, max_count=100, max_packets=1000, max_speed=30.0, max_energy_j=1e5)


def beacon(uav: int, tick: int, src: str | None = None, **changes: Any) -> bytes:
    msg = dataclasses.replace(schema.Beacon(uav=uav, tick=tick, pos=(10.0, 20.0), vel=(1.0, 2.0)), **changes)
    return schema.encode(schema.Sequencer(src or f"uav/{uav}").stamp(msg))


def inbox_traffic() -> list[tuple[str, bytes]]:
    """(key, payload) a flood might bring to an agent's beacon inbox: valid beacons among junk."""
    k = lambda u: keys.uav_beacon(RUN, u)  # noqa: E731
    wire = msgpack.unpackb(beacon(2, 5))
    return [
        (k(1), beacon(1, 1)),
        (k(2), b"\xc1 not msgpack"),
        (k(2), beacon(2, 1)[:-3]),  # truncated
        (k(2), beacon(2, 1) + b"\x00"),  # extra bytes
        (k(3), beacon(3, 2)),
        (k(2), beacon(3, 2)),  # another UAV's beacon on this key
        (k(2), beacon(2, 2, src="uav/3")),  # forged sender (placement)
        (k(2), beacon(2, 2, src="world")),  # forged sender (guard)
        (k(2), pack({**wire, "uav": True})),  # bool for int
        (k(2), pack({**wire, "pos": [NAN, 1.0]})),
        (k(2), pack({**wire, "vel": [INF, 1.0]})),
        (k(2), pack({**wire, "tick": (1 << 64) - 1})),
        (k(2), pack({**wire, "tick": 1 << 63})),
        (k(2), pack({**wire, "src": "x" * 65})),  # above the str limit: too large while parsing
        (k(2), pack({**wire, "pos": [1.0, 2.0, 3.0]})),
        (k(2), pack({**wire, "extra": {"a": 1}})),
        (k(2), pack({k_: v for k_, v in wire.items() if k_ != "vel"})),
        (k(4), pack({k_: v for k_, v in msgpack.unpackb(beacon(4, 3)).items() if k_ != "inc"})),  # legacy: valid
        (k(2), pack({**wire, "kind": "action"})),
        (k(2), schema.encode(schema.Sequencer("uav/2").stamp(schema.Action(uav=2, tick=3, action=1)))),
        (k(5), beacon(5, 4, pos=(9000.0, 1.0))),  # outside the area (guard)
        (k(6), beacon(6, 4, vel=(40.0, 0.0))),  # too fast (guard)
        (k(9), beacon(9, 4)),  # uav >= n_uavs (guard)
        (k(2), bytes(schema.MAX_SMALL_PAYLOAD_BYTES + 1)),  # too large for the key, refused before copying
        (k(7), beacon(7, 5)),
        (k(1), beacon(1, 6)),
    ]


def reference_verdicts(traffic: list[tuple[str, bytes]], tagged: int = 0) -> tuple[list, Counter, dict]:
    """What the reference path makes of ``traffic`` (then ``tagged`` replayed puts): the messages it
    delivers, the malformed counts by reason and the rejections by reason and sender."""
    guard = ReferenceGuard(BOUNDS)
    delivered, malformed, rejected = [], Counter(), {}

    def refuse(reason: str, src: str | None) -> None:
        malformed[reason] += 1
        rejected.setdefault(reason, Counter())[src or "?"] += 1

    for key, raw in traffic:
        limit = min(MAX_PAYLOAD_BYTES, schema.size_limit(expected_kind(key)))
        if len(raw) > limit:
            refuse(R_TOO_LARGE, None)
            continue
        try:
            msg = reference_decode(raw, key_facts(key)[0])
            reference_check_placement(key, msg)
            verdict = guard.check(key, msg)
            if verdict is not None:
                raise SchemaError(verdict[0], verdict[1], src=msg.src)
        except SchemaError as exc:
            refuse(exc.reason, exc.src)
            continue
        delivered.append((key, msg))
    for _ in range(tagged):
        refuse(guard_mod.R_REPLAYED, keys.SRC_REPLAY)
    return delivered, malformed, {reason: dict(n) for reason, n in rejected.items()}


def test_reference_verdicts_cover_the_kinds_of_refusal() -> None:
    delivered, malformed, _ = reference_verdicts(inbox_traffic(), tagged=1)
    assert len(delivered) == 5
    assert {R_NOT_MSGPACK, R_TOO_LARGE, R_KEY_MISMATCH, R_SENDER, R_IMPLAUSIBLE, R_BAD_TYPE, schema.R_OUT_OF_RANGE,
            R_EXTRA_FIELD, R_MISSING_FIELD, guard_mod.R_REPLAYED} <= set(malformed)


def reader_bus(bus_factory):
    bus = bus_factory("uav/0")
    bus.guard = Guard(BOUNDS)
    bus.accept_replay = False
    return bus


def until(pred, timeout: float = WAIT_S) -> bool:
    deadline = time.monotonic() + timeout
    while not pred() and time.monotonic() < deadline:
        time.sleep(0.01)
    return pred()


class PassAll:
    """A link filter that passes everything without saying so: the inbox's filtered arrival path."""

    def decide(self, key, src, dst, now_ns):
        return True, 0.0


@pytest.mark.parametrize("link_filter", [None, PassAll()], ids=["unfiltered", "filtered"])
def test_inbox_counts_a_mix_of_valid_and_hostile_samples_as_the_reference_path(bus_factory, link_filter) -> None:
    sender, replay = bus_factory("world"), bus_factory(keys.SRC_REPLAY)
    reader = reader_bus(bus_factory)
    if link_filter is not None:
        reader.link_filter = link_filter
    box = reader.inbox(keys.all_beacons(RUN))
    probe = keys.uav_beacon(RUN, 1)
    deadline = time.monotonic() + WAIT_S  # until the subscription has propagated
    while not box.drain() and time.monotonic() < deadline:
        sender.publish_raw(probe, beacon(1, 0))
        box.wait(0.05)
    time.sleep(0.2)
    box.drain()
    before = reader.stats()
    assert before.malformed == {} and reader.rejections.as_dict() == {}

    traffic = inbox_traffic()
    for key, raw in traffic:
        sender.publish_raw(key, raw)
    replay.publish_raw(keys.uav_beacon(RUN, 3), beacon(3, 9))  # a replay's put in a live run
    sender.session.delete(keys.uav_beacon(RUN, 3))  # not a put: neither delivered nor counted
    got = []
    assert until(lambda: got.extend(box.drain()) or reader.stats().received - before.received >= len(traffic) + 1)
    time.sleep(0.2)
    got += box.drain()

    delivered, malformed, rejected = reference_verdicts(traffic, tagged=1)
    stats = reader.stats()
    assert stats.received - before.received == len(traffic) + 1
    assert stats.delivered - before.delivered == len(delivered) == len(got)
    assert sorted(repr((r.key, r.msg)) for r in got) == sorted(repr(d) for d in delivered)
    assert all(schema.decode(r.raw) == r.msg for r in got)
    assert stats.malformed == dict(malformed)
    assert stats.rejected == rejected
    assert stats.overflow == 0


def collect_samples(bus_factory) -> list[zenoh.Sample]:
    """The traffic as zenoh samples, taken off a plain subscriber (puts, a replay's put, a delete)."""
    sender, replay, taker = bus_factory("world"), bus_factory(keys.SRC_REPLAY), bus_factory("recorder")
    sub = taker.session.declare_subscriber(keys.all_beacons(RUN), zenoh.handlers.FifoChannel(1024))
    try:
        probe = keys.uav_beacon(RUN, 1)
        deadline = time.monotonic() + WAIT_S
        while sub.handler.try_recv() is None and time.monotonic() < deadline:
            sender.publish_raw(probe, beacon(1, 0))
            time.sleep(0.05)
        time.sleep(0.2)
        while sub.handler.try_recv() is not None:
            pass
        out: list[zenoh.Sample] = []
        replay.publish_raw(keys.uav_beacon(RUN, 3), beacon(3, 9))  # first: the other session's put
        deadline = time.monotonic() + WAIT_S
        while not out and time.monotonic() < deadline:
            sample = sub.handler.try_recv()
            if sample is None:
                time.sleep(0.01)
            else:
                out.append(sample)
        traffic = inbox_traffic()
        for key, raw in traffic:
            sender.publish_raw(key, raw)
        sender.session.delete(keys.uav_beacon(RUN, 3))  # last (the inbox counts a delete it compacts or evicts)
        deadline = time.monotonic() + WAIT_S
        while len(out) < len(traffic) + 2 and time.monotonic() < deadline:
            sample = sub.handler.try_recv()
            if sample is None:
                time.sleep(0.01)
            else:
                out.append(sample)
        assert len(out) == len(traffic) + 2
        return out
    finally:
        sub.undeclare()


@pytest.mark.parametrize("capacity,compact", [(4096, True), (8, True), (8, False)],
                         ids=["roomy", "compacting", "evicting"])
def test_inbox_counts_real_samples_fed_to_it_as_the_reference_path(bus_factory, capacity, compact) -> None:
    samples_ = collect_samples(bus_factory)
    puts = [s for s in samples_ if s.kind == zenoh.SampleKind.PUT]
    assert len(puts) == len(samples_) - 1 and samples_[-1].kind != zenoh.SampleKind.PUT
    traffic = [(str(s.key_expr), s.payload.to_bytes()) for s in puts if s.attachment is None]
    reader = reader_bus(bus_factory)
    box = Inbox(reader, capacity, compact=compact)
    for sample in samples_:
        box.on_sample(sample)
    got = box.drain()
    stats = reader.stats()
    assert stats.received == len(puts)  # each put counted once: drained, compacted or evicted
    if capacity > len(samples_) or compact:  # nothing valid evicted (at most 6 valid wait at once)
        delivered, malformed, rejected = reference_verdicts(traffic, tagged=1)
        assert stats.overflow == 0
    else:  # the oldest evicted unread: only the last ``capacity`` samples are judged
        kept = samples_[-capacity:]
        delivered, malformed, rejected = reference_verdicts(
            [(str(s.key_expr), s.payload.to_bytes()) for s in kept
             if s.kind == zenoh.SampleKind.PUT and s.attachment is None],
            tagged=sum(1 for s in kept if s.kind == zenoh.SampleKind.PUT and s.attachment is not None))
        assert stats.overflow == len(samples_) - capacity
    assert [(r.key, r.msg) for r in got] == delivered  # in arrival order
    assert stats.delivered == len(delivered)
    assert stats.malformed == dict(malformed)
    assert stats.rejected == rejected
