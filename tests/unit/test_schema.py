"""Tests for truav.wire.schema (wire format) and truav.wire.keys (key expressions)."""

from __future__ import annotations

import math
from dataclasses import FrozenInstanceError
from typing import Any

import msgpack
import numpy as np
import pytest

from truav.wire import keys, schema
from truav.wire.schema import (
    Action,
    Beacon,
    Control,
    Fault,
    Metrics,
    Obs,
    Positions,
    SchemaError,
    Sequencer,
    Tick,
    decode,
    encode,
)

FUZZ_SEED = 20240611
T0_NS = 1_700_000_000_123_456_789  # a 19-digit wall-clock timestamp


def fake_clock(start: int = T0_NS, step: int = 1_000):
    state = [start - step]

    def clock() -> int:
        state[0] += step
        return state[0]

    return clock


def samples() -> list[schema.Message]:
    """One valid, unstamped message of every kind."""
    return [
        Tick(tick=7, episode=2, sim_time=3.5, deadline_ms=50.0, n_uavs=8),
        Obs(tick=7, episode=2, uav=3, pos=(10.5, -2.25), vehicles_in_range=4, queued_packets=12, relayed=3,
            covered=2, energy_j=0.75, speed_max=20.0, done=False),
        Beacon(uav=3, tick=7, pos=(1234.567, 987.654), vel=(3.2, -1.5)),
        Action(uav=3, tick=7, action=15),
        Metrics(scope=schema.SCOPE_STEP, tick=7, episode=2, values={"pdr": 0.9, "delay_ms": 12.0}),
        Fault(fault=schema.FAULT_LATENCY, phase=schema.PHASE_START, target="uav/3",
              params={"delay_ms": 200.0, "jitter": 5, "dist": "normal"}),
        Control(command="fault_plan", args={"events": [{"at": 1.5, "kind": "loss", "p": 0.2}], "dry": True,
                                            "note": None}),
        Positions(tick=7, uavs=((0.0, 1.0), (2.0, 3.0)), vehicles=((5.0, 6.0),)),
        schema.State(uav=3, tick=7, episode=2, step=4, pos=(10.5, 2.25), vehicles_in_range=4, queued_packets=12,
                     relayed=3, covered=2, energy_j=0.75, done=False, pad=bytes(20)),
        schema.Command(uav=3, tick=7, action=5, pad=bytes(8)),
        schema.Health(uav=3, last_tick=7, steps=7, stale_obs_skipped=1, rejected={"not_msgpack": 2},
                      senders={"?": 1, "(other senders)": 1}),
        schema.Beacons(entries=((3, 7, (1234.5, 987.25), (3.2, -1.5)), (4, 7, (10.0, 20.0), (0.0, 0.0)))),
        schema.Rejection(uav=3, at_tick=7, reason="out_of_range", refused_kind="action",
                         key="truav/r/uav/3/action", detail="action.action=99 outside [-1, 15]",
                         counts={"out_of_range": 2, "bad_type": 1}),
        schema.ReplayStatus(state=schema.REPLAY_PAUSED, position_s=12.5, span_s=60.0, tick=40, rate=2.0, paused=True,
                            sent=1234, restored=17, loop=0),
        schema.WorldSnapshot(tick=7, episode=0, arrays={"t": ("<i8", (), bytes(8)),
                                                        "pos": ("<f8", (1, 2, 2), bytes(32))}),
        schema.AgentSnapshot(uav=3, tick=7, arrays={"q_rows": ("<i8", (2,), bytes(16))}),
        schema.QShare(uav=3, tick=7, episode=2, part=0, parts=2, states=np.array([5, 17]), counts=np.array([4, 1]),
                      q=np.linspace(-1.0, 2.5, 32)),
        schema.Override(uav=3, release=False, goal=(120.5, 4000.0), speed=7.5),
    ]


def stamped_samples() -> list[schema.Message]:
    seq = Sequencer("world", clock=fake_clock())
    return [seq.stamp(m) for m in samples()]


def wire(msg: schema.Message) -> dict[str, Any]:
    return msgpack.unpackb(encode(msg), raw=False)


def reason_of(payload: bytes) -> str:
    with pytest.raises(SchemaError) as info:
        decode(payload)
    return info.value.reason


# --- round trips and stamping ------------------------------------------------------
@pytest.mark.parametrize("msg", stamped_samples(), ids=lambda m: m.KIND)
def test_roundtrip_every_kind(msg: schema.Message) -> None:
    data = encode(msg)
    back = decode(data)
    assert type(back) is type(msg)
    assert back == msg
    assert encode(back) == data
    envelope = wire(msg)
    assert list(envelope)[:5] == ["v", "kind", "src", "seq", "t"]
    assert envelope["v"] == schema.SCHEMA_VERSION and envelope["kind"] == msg.KIND


def test_every_kind_has_a_sample_and_a_size_limit() -> None:
    assert sorted(m.KIND for m in samples()) == sorted(schema.KINDS)
    for m in stamped_samples():
        assert len(encode(m)) <= schema.size_limit(m.KIND) <= schema.MAX_PAYLOAD_BYTES


def test_sequencer_stamps_per_kind_counters_deterministically() -> None:
    seq = Sequencer("uav/3", clock=fake_clock(step=10))
    beacon = Beacon(uav=3, tick=0, pos=(0.0, 0.0), vel=(0.0, 0.0))
    action = Action(uav=3, tick=0, action=1)
    out = [seq.stamp(beacon), seq.stamp(action), seq.stamp(beacon), seq.stamp(beacon), seq.stamp(action)]
    assert [(m.KIND, m.seq) for m in out] == [("beacon", 0), ("action", 0), ("beacon", 1), ("beacon", 2),
                                             ("action", 1)]
    assert [m.t for m in out] == [T0_NS + 10 * k for k in range(5)]
    assert all(m.src == "uav/3" for m in out)
    assert beacon.src == "" and beacon.seq == 0  # the original is untouched (frozen)
    with pytest.raises(FrozenInstanceError):
        beacon.tick = 5  # type: ignore[misc]


def test_sequencer_rejects_bad_src_and_bad_clock() -> None:
    with pytest.raises(ValueError):
        Sequencer("")
    with pytest.raises(ValueError):
        Sequencer("uav 3")
    with pytest.raises(SchemaError):
        Sequencer("world", clock=lambda: -1).stamp(Action(uav=0, tick=0, action=0))


def test_encode_requires_stamp() -> None:
    with pytest.raises(SchemaError) as info:
        encode(Action(uav=0, tick=0, action=0))
    assert info.value.reason == schema.R_UNSTAMPED
    with pytest.raises(SchemaError):
        encode({"v": 1})  # type: ignore[arg-type]


def test_beacon_size_is_small_and_pinned() -> None:
    b = Sequencer("uav/3", clock=fake_clock(), incarnation=(1 << 62) + 1).stamp(
        Beacon(uav=3, tick=1234, pos=(1234.567, 987.654), vel=(3.2, -1.5)))
    assert len(encode(b)) == 114  # documented in the truav.wire.schema docstring
    worst = Beacon(uav=1023, tick=schema.INT64_MAX, pos=(1.0, 2.0), vel=(3.0, 4.0), src="uav/1023",
                   seq=schema.UINT64_MAX, t=schema.INT64_MAX, inc=schema.INT64_MAX)
    assert len(encode(worst)) == schema.BEACON_MAX_BYTES


def test_beacon_fields_ride_along_only_when_set_and_are_bounded() -> None:
    """An API agent's beacon_fields(): off the wire when empty (TRUAV's beacon keeps its bytes), round-tripped
    when set, and a hostile map (too many, a long or unprintable name, a str or NaN value) refused."""
    seq = Sequencer("uav/3", clock=fake_clock(), incarnation=1)
    plain = seq.stamp(Beacon(uav=3, tick=7, pos=(1.0, 2.0), vel=(0.5, 0.0)))
    assert b"fields" not in encode(plain) and decode(encode(plain), "beacon").fields == {}
    sent = seq.stamp(Beacon(uav=3, tick=7, pos=(1.0, 2.0), vel=(0.5, 0.0),
                            fields={"load": 3, "busy": True, "share": 0.25, "n": np.int64(2)}))
    assert decode(encode(sent), "beacon").fields == {"load": 3, "busy": True, "share": 0.25, "n": 2}
    worst = Beacon(uav=1023, tick=schema.INT64_MAX, pos=(1.0, 2.0), vel=(3.0, 4.0), src="uav/1023",
                   seq=schema.UINT64_MAX, t=schema.INT64_MAX, inc=schema.INT64_MAX,
                   fields={f"{i}".ljust(schema.MAX_BEACON_FIELD_NAME, "x"): schema.INT64_MAX
                           for i in range(schema.MAX_BEACON_FIELDS)})
    assert len(encode(worst)) == schema.BEACON_MAX_BYTES + schema.BEACON_FIELDS_MAX_BYTES
    wire = msgpack.unpackb(encode(sent))
    for bad in ({str(i): i for i in range(schema.MAX_BEACON_FIELDS + 1)}, {"x" * 33: 1}, {"": 1}, {"\x07": 1},
                {"a": "text"}, {"a": [1]}, {"a": None}, {"a": 2 ** 63}, [1, 2]):
        with pytest.raises(SchemaError):
            decode(msgpack.packb({**wire, "fields": bad}), "beacon")
    with pytest.raises(SchemaError):  # NaN cannot be built, nor decoded
        decode(msgpack.packb({**wire, "fields": {"a": float("nan")}}), "beacon")
    # a beacon with fields but without its position is still missing a field, not told of an extra one
    with pytest.raises(SchemaError, match="lacks"):
        decode(msgpack.packb({k: v for k, v in wire.items() if k != "pos"}), "beacon")
    with pytest.raises(SchemaError, match="unexpected"):
        decode(msgpack.packb({**msgpack.unpackb(encode(plain)), "extra": 1}), "beacon")


def test_constructors_normalise_numpy_and_ints() -> None:
    o = Obs(tick=np.int64(3), episode=np.uint8(1), uav=np.int32(2), pos=np.array([1, 2], dtype=np.float32),
            vehicles_in_range=np.int64(0), queued_packets=0, relayed=0, covered=0, energy_j=1,
            speed_max=np.float32(15.5), done=np.bool_(True))
    assert type(o.tick) is int and type(o.uav) is int and type(o.energy_j) is float
    assert o.pos == (1.0, 2.0) and type(o.pos[0]) is float
    assert o.done is True
    p = Positions(tick=0, uavs=np.zeros((3, 2)), vehicles=np.empty((0, 2)))
    assert p.uavs == ((0.0, 0.0),) * 3 and p.vehicles == ()
    stamped = Sequencer("world").stamp(p)
    assert decode(encode(stamped)) == stamped


@pytest.mark.parametrize(
    "build",
    [
        lambda: Action(uav=0, tick=0, action=16),
        lambda: Action(uav=0, tick=0, action=-2),  # -1 is an explicit hover
        lambda: Action(uav=1024, tick=0, action=0),
        lambda: Action(uav=True, tick=0, action=0),
        lambda: Action(uav=0, tick=-1, action=0),
        lambda: Action(uav=0, tick=0, action=1.0),
        lambda: Beacon(uav=0, tick=0, pos=(math.nan, 0.0), vel=(0.0, 0.0)),
        lambda: Beacon(uav=0, tick=0, pos=(0.0, 0.0), vel=(math.inf, 0.0)),
        lambda: Beacon(uav=0, tick=0, pos=(0.0, 0.0, 0.0), vel=(0.0, 0.0)),
        lambda: Beacon(uav=0, tick=0, pos="xy", vel=(0.0, 0.0)),
        lambda: Tick(tick=0, episode=0, sim_time=0.0, deadline_ms=0.0, n_uavs=1),
        lambda: Tick(tick=0, episode=0, sim_time=-1.0, deadline_ms=10.0, n_uavs=1),
        lambda: Tick(tick=0, episode=0, sim_time=0.0, deadline_ms=10.0, n_uavs=1025),
        lambda: Obs(tick=0, episode=0, uav=0, pos=(0, 0), vehicles_in_range=-1, queued_packets=0, relayed=0,
                    covered=0, energy_j=0.0, speed_max=1.0, done=False),
        lambda: Obs(tick=0, episode=0, uav=0, pos=(0, 0), vehicles_in_range=0, queued_packets=0, relayed=0,
                    covered=0, energy_j=-0.1, speed_max=1.0, done=False),
        lambda: Obs(tick=0, episode=0, uav=0, pos=(0, 0), vehicles_in_range=0, queued_packets=0, relayed=0,
                    covered=0, energy_j=0.0, speed_max=1.0, done=1),
        lambda: Metrics(scope="batch", tick=0, episode=0, values={}),
        lambda: Metrics(scope="step", tick=0, episode=0, values={"pdr": math.nan}),
        lambda: Metrics(scope="step", tick=0, episode=0, values={"": 1.0}),
        lambda: Metrics(scope="step", tick=0, episode=0, values={f"m{k}": 1.0 for k in range(129)}),
        lambda: Fault(fault="loss", phase="middle", target="*", params={}),
        lambda: Fault(fault="lo ss", phase="start", target="*", params={}),
        lambda: Fault(fault="loss", phase="start", target="", params={}),
        lambda: Fault(fault="loss", phase="start", target="*", params={"p": [0.1]}),
        lambda: Fault(fault="loss", phase="start", target="*", params={"p": True}),
        lambda: Control(command="go", args={"x": b"bytes"}),
        lambda: Control(command="go", args={"x": math.inf}),
        lambda: Control(command="go", args=[1, 2]),
        lambda: Control(command="go", args=nested(schema.MAX_ARGS_DEPTH + 2)),
        lambda: Positions(tick=0, uavs=np.zeros((schema.MAX_UAVS + 1, 2)), vehicles=()),
        lambda: Positions(tick=0, uavs=(), vehicles=[(0.0, 0.0)] * (schema.MAX_VEHICLE_POSITIONS + 1)),
        lambda: Positions(tick=0, uavs=np.array([[0.0, np.nan]]), vehicles=()),
        lambda: Positions(tick=0, uavs=np.zeros((2, 3)), vehicles=()),
        lambda: Action(uav=0, tick=0, action=0, src="bad src"),
        lambda: Action(uav=0, tick=0, action=0, seq=-1),
    ],
)
def test_constructors_reject_invalid_values(build) -> None:
    with pytest.raises(SchemaError):
        build()


def nested(depth: int) -> dict[str, Any]:
    out: dict[str, Any] = {"leaf": 1}
    for _ in range(depth):
        out = {"x": out}
    return out


# --- decode rejections -----------------------------------------------------------------
def valid_wire() -> dict[str, Any]:
    return wire(Sequencer("uav/3", clock=fake_clock(), incarnation=7).stamp(Action(uav=3, tick=9, action=4)))  # fixed: ids stay equal across pytest -n workers


def with_(**changes: Any) -> bytes:
    w = valid_wire()
    w.update(changes)
    return msgpack.packb(w, use_bin_type=True)


def without(name: str) -> bytes:
    w = valid_wire()
    del w[name]
    return msgpack.packb(w, use_bin_type=True)


@pytest.mark.parametrize(
    ("payload", "reason"),
    [
        (b"", schema.R_NOT_MSGPACK),
        (b"\xc1", schema.R_NOT_MSGPACK),  # never-used msgpack byte
        (msgpack.packb(valid_wire()) + b"\x00", schema.R_NOT_MSGPACK),  # trailing data
        (msgpack.packb(valid_wire())[:-3], schema.R_NOT_MSGPACK),  # truncated
        (b"\x91" * 5000 + b"\xc0", schema.R_NOT_MSGPACK),  # nesting bomb
        (msgpack.packb({1: 2}), schema.R_NOT_MSGPACK),  # non-str map key
        (msgpack.packb([1, 2, 3]), schema.R_NOT_MAP),
        (msgpack.packb("hello"), schema.R_NOT_MAP),
        (without("v"), schema.R_VERSION),
        (with_(v=2), schema.R_VERSION),
        (with_(v="1"), schema.R_VERSION),
        (with_(v=True), schema.R_VERSION),
        (with_(kind="teleport"), schema.R_UNKNOWN_KIND),
        (with_(kind=7), schema.R_UNKNOWN_KIND),
        (without("kind"), schema.R_UNKNOWN_KIND),
        (without("action"), schema.R_MISSING_FIELD),
        (without("seq"), schema.R_MISSING_FIELD),
        (with_(extra=1), schema.R_EXTRA_FIELD),
        (with_(src=""), schema.R_UNSTAMPED),
        (with_(src=5), schema.R_BAD_TYPE),
        (with_(tick="9"), schema.R_BAD_TYPE),
        (with_(tick=9.0), schema.R_BAD_TYPE),
        (with_(tick=None), schema.R_BAD_TYPE),
        (with_(action=True), schema.R_BAD_TYPE),
        (with_(tick=-1), schema.R_OUT_OF_RANGE),
        (with_(tick=schema.UINT64_MAX), schema.R_OUT_OF_RANGE),
        (with_(action=16), schema.R_OUT_OF_RANGE),
        (with_(uav=1024), schema.R_OUT_OF_RANGE),
        (with_(src="x" * 65), schema.R_OUT_OF_RANGE),
        (with_(pad="x" * schema.MAX_SMALL_PAYLOAD_BYTES), schema.R_TOO_LARGE),
        (b"\x00" * (schema.MAX_PAYLOAD_BYTES + 1), schema.R_TOO_LARGE),
    ],
)
def test_decode_rejects(payload: bytes, reason: str) -> None:
    assert reason_of(payload) == reason


def test_decode_rejects_nan_and_inf_floats() -> None:
    w = wire(stamped_samples()[2])  # beacon
    for bad in (math.nan, math.inf, -math.inf):
        w["pos"] = [bad, 0.0]
        assert reason_of(msgpack.packb(w)) == schema.R_OUT_OF_RANGE


def test_decoded_messages_are_normalised_and_frozen() -> None:
    w = wire(stamped_samples()[2])  # beacon
    w["pos"] = [3, 4]  # ints where floats belong: accepted and stored as floats, as by the constructor
    b = decode(msgpack.packb(w))
    assert b.pos == (3.0, 4.0) and all(type(x) is float for x in b.pos)
    assert b == schema.Beacon(src=b.src, seq=b.seq, t=b.t, inc=b.inc, uav=b.uav, tick=b.tick, pos=(3, 4), vel=b.vel)
    with pytest.raises(FrozenInstanceError):
        b.tick = 0  # type: ignore[misc]


def test_decode_error_carries_sender_and_is_a_value_error() -> None:
    with pytest.raises(ValueError) as info:
        decode(with_(action=99))
    assert isinstance(info.value, SchemaError) and info.value.src == "uav/3"
    assert reason_of(b"\x00" * 3) == schema.R_NOT_MSGPACK
    with pytest.raises(SchemaError) as info2:
        decode("text")  # type: ignore[arg-type]
    assert info2.value.reason == schema.R_NOT_BYTES


def test_peek_src() -> None:
    for m in stamped_samples():
        assert schema.peek_src(encode(m)) == "world"
    assert schema.peek_src(b"\xc1garbage") is None
    assert schema.peek_src(msgpack.packb([1, 2])) is None
    assert schema.peek_src(msgpack.packb({"v": 1, "src": 3})) is None
    assert schema.peek_src(b"") is None


# --- fuzzing: decode raises SchemaError and nothing else ---------------------------------
HOSTILE_VALUES: list[Any] = [
    None, True, False, -1, 0, 1, 15, 16, 1023, 1024, 2**63, -(2**63), 2**64 - 1, 0.5, -0.0, math.nan, math.inf,
    "", "x", "uav/3", "step", "start", "\u00e9\u4e2d", b"", b"\xff\x00", [], [1], [1.0, 2.0], [[1.0, 2.0]],
    [math.nan, 1.0], {}, {"a": 1.0}, {"a": [1, {"b": None}]}, {"": 1}, msgpack.ExtType(5, b"abc"),
]


def decode_or_schema_error(payload: bytes) -> schema.Message | None:
    try:
        msg = decode(payload)
    except SchemaError as exc:
        assert exc.reason in {
            schema.R_NOT_BYTES, schema.R_TOO_LARGE, schema.R_NOT_MSGPACK, schema.R_NOT_MAP, schema.R_VERSION,
            schema.R_UNKNOWN_KIND, schema.R_MISSING_FIELD, schema.R_EXTRA_FIELD, schema.R_BAD_TYPE,
            schema.R_OUT_OF_RANGE, schema.R_UNSTAMPED,
        }
        return None
    # anything that decodes is a valid message that re-encodes to a decodable payload
    assert decode(encode(msg)) == msg
    return msg


def test_fuzz_random_bytes() -> None:
    rng = np.random.default_rng(FUZZ_SEED)
    for _ in range(3000):
        n = int(rng.integers(0, 200))
        payload = rng.integers(0, 256, size=n, dtype=np.uint8).tobytes()
        if rng.random() < 0.5 and n:  # start like a msgpack map more often
            payload = bytes([0x80 | int(rng.integers(0, 16))]) + payload
        decode_or_schema_error(payload)


def test_fuzz_byte_mutations_of_valid_messages() -> None:
    rng = np.random.default_rng(FUZZ_SEED + 1)
    valid = [encode(m) for m in stamped_samples()]
    accepted = 0
    for _ in range(4000):
        buf = bytearray(valid[int(rng.integers(len(valid)))])
        for _ in range(int(rng.integers(1, 4))):
            op = rng.random()
            pos = int(rng.integers(0, len(buf))) if buf else 0
            if op < 0.5 and buf:
                buf[pos] = int(rng.integers(0, 256))
            elif op < 0.7:
                del buf[pos:pos + int(rng.integers(1, 8))]
            elif op < 0.9:
                buf[pos:pos] = rng.integers(0, 256, size=int(rng.integers(1, 8)), dtype=np.uint8).tobytes()
            else:
                buf = buf[: int(rng.integers(0, len(buf) + 1))]
        accepted += decode_or_schema_error(bytes(buf)) is not None
    assert accepted < 4000  # the mutations did bite


def test_fuzz_field_mutations_of_valid_messages() -> None:
    rng = np.random.default_rng(FUZZ_SEED + 2)
    valid = [wire(m) for m in stamped_samples()]
    for _ in range(3000):
        w = dict(valid[int(rng.integers(len(valid)))])
        names = list(w)
        for _ in range(int(rng.integers(1, 3))):
            op = rng.random()
            name = names[int(rng.integers(len(names)))]
            if op < 0.7:
                w[name] = HOSTILE_VALUES[int(rng.integers(len(HOSTILE_VALUES)))]
            elif op < 0.85:
                w.pop(name, None)
            else:
                w[f"x{int(rng.integers(100))}"] = 1
        decode_or_schema_error(msgpack.packb(w, use_bin_type=True))


# --- keys ----------------------------------------------------------------------------------
def test_key_builders() -> None:
    run = "exp_1-a"
    assert keys.world_tick(run) == "truav/exp_1-a/world/tick"
    assert keys.uav_obs(run, 3) == "truav/exp_1-a/uav/3/obs"
    assert keys.uav_beacon(run, 3) == "truav/exp_1-a/uav/3/beacon"
    assert keys.uav_action(run, 0) == "truav/exp_1-a/uav/0/action"
    assert keys.all_beacons(run) == "truav/exp_1-a/uav/*/beacon"
    assert keys.everything(run) == "truav/exp_1-a/**"
    assert keys.metrics_step(run) == "truav/exp_1-a/metrics/step"
    assert keys.metrics_episode(run) == "truav/exp_1-a/metrics/episode"
    assert keys.fault(run, "loss") == "truav/exp_1-a/fault/loss"
    assert keys.control(run, "replay", "plan") == "truav/exp_1-a/control/replay/plan"
    assert keys.alive_world(run) == "truav/exp_1-a/alive/world"
    assert keys.alive_uav(run, 7) == "truav/exp_1-a/alive/uav/7"
    assert keys.alive_recorder(run) == "truav/exp_1-a/alive/recorder"
    assert keys.uav_identity(5) == "uav/5"


@pytest.mark.parametrize("bad", ["", "a/b", "a b", "a*", "**", "é", "x" * 65, None, 3])
def test_bad_run_names_raise_clear_value_error(bad: Any) -> None:
    with pytest.raises(ValueError, match="run name"):
        keys.world_tick(bad)


@pytest.mark.parametrize("bad", [-1, 1024, True, 1.0, "3"])
def test_bad_uav_ids_raise(bad: Any) -> None:
    with pytest.raises(ValueError, match="UAV id"):
        keys.uav_obs("r", bad)


@pytest.mark.parametrize(
    ("key", "expected"),
    [
        ("truav/r/uav/3/obs", 3),
        ("truav/r/uav/0/beacon", 0),
        ("truav/r/uav/1023/action", 1023),
        ("truav/r/alive/uav/12", 12),
        ("truav/r/uav/1024/obs", None),
        ("truav/r/uav/03/obs", None),
        ("truav/r/uav/-1/obs", None),
        ("truav/r/uav/x/obs", None),
        ("truav/r/world/tick", None),
        ("other/r/uav/3/obs", None),
        ("", None),
    ],
)
def test_parse_uav_id(key: str, expected: int | None) -> None:
    assert keys.parse_uav_id(key) == expected


def test_parse_identity_and_run() -> None:
    assert keys.parse_uav_identity("uav/7") == 7
    assert keys.parse_uav_identity("world") is None
    assert keys.parse_uav_identity("uav/2000") is None
    assert keys.parse_run("truav/abc/world/tick") == "abc"
    assert keys.parse_run("nope/abc") is None


@pytest.mark.parametrize("size", [78, 200, 255, 258, 300, 4096])
def test_padded_state_and_command_have_the_models_sizes(size: int) -> None:
    """Scheme central's uploads and commands are padded to the control-plane model's message sizes
    (central.upload_bytes / download_bytes), so the bytes measured on the bus are the modelled ones."""
    seq = Sequencer("uav/3")
    state = seq.stamp(schema.State(uav=3, tick=123456, episode=9, step=99, pos=(1.5, 2.5), vehicles_in_range=3,
                                   queued_packets=4, relayed=1, covered=2, energy_j=12.5, done=False, pad=b""))
    command = Sequencer("controller").stamp(schema.Command(uav=3, tick=123456, action=5, pad=b""))
    for msg in (state, command):
        data = encode(schema.padded(msg, size))
        assert size - 2 <= len(data) <= size or len(encode(msg)) > size
        assert decode(data).pad == bytes(len(decode(data).pad))
    assert len(encode(schema.padded(state, 200))) == 200 and len(encode(schema.padded(command, 100))) == 100
    assert len(encode(schema.padded(command, 78))) == len(encode(command)) == 90  # the envelope alone is longer


def test_each_sequencer_is_a_new_incarnation_and_old_payloads_still_decode() -> None:
    """A restarted sender numbers from 0 again; its incarnation tells the two streams apart."""
    first, restarted = Sequencer("uav/1"), Sequencer("uav/1")
    a = decode(encode(first.stamp(Action(uav=1, tick=5, action=2))))
    b = decode(encode(restarted.stamp(Action(uav=1, tick=9, action=2))))
    assert a.seq == b.seq == 0
    assert a.inc == first.incarnation and b.inc == restarted.incarnation
    assert 0 < a.inc <= schema.INT64_MAX and a.inc != b.inc
    # a payload written before incarnations existed (a recording): decoded, incarnation unknown (0)
    old = {"v": 1, "kind": "action", "src": "uav/1", "seq": 3, "t": 7, "uav": 1, "tick": 5, "action": 2}
    assert decode(msgpack.packb(old)).inc == 0
    with pytest.raises(SchemaError) as info:
        decode(msgpack.packb({**old, "inc": -1}))
    assert info.value.reason == schema.R_OUT_OF_RANGE
