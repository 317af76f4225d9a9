"""Recordings and live runs open in Foxglove: well-known schemas, JSON Schemas its parser
accepts, compact finished files, and the live WebSocket view (loopback, bounded)."""

from __future__ import annotations

import asyncio
import json
import os
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

import msgpack
import pytest
from foxglove import messages as fm
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from mcap.reader import make_reader

from recorder.foxglove import DEFAULT_ORIGIN, FoxgloveMirror, Geometry
from recorder.mcap_log import COMPACT_CHUNK_SPAN_NS, McapLog, is_mirror_topic
from recorder.recover import compact
from tests.support.waits import free_port

RUN = "fox"
T0 = 1_700_000_000_000_000_000
MS = 1_000_000
SDK_CLASSES = {"foxglove.SceneUpdate": fm.SceneUpdate, "foxglove.FrameTransforms": fm.FrameTransforms,
               "foxglove.LocationFix": fm.LocationFix, "foxglove.Log": fm.Log}


def decoder(name: str, data: bytes):
    """A protobuf message class built from a schema's FileDescriptorSet."""
    fds = descriptor_pb2.FileDescriptorSet.FromString(data)
    pool = descriptor_pool.DescriptorPool()
    for f in fds.file:
        pool.Add(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(name))


def type_unions(schema) -> list:
    """Every ``"type": [..]`` in a JSON Schema (Foxglove's parser rejects them)."""
    if isinstance(schema, dict):
        found = [schema["type"]] if isinstance(schema.get("type"), list) else []
        return found + [u for v in schema.values() for u in type_unions(v)]
    if isinstance(schema, list):
        return [u for v in schema for u in type_unions(v)]
    return []


def pack(kind: str, src: str, seq: int, **body) -> bytes:
    return msgpack.packb({"v": 1, "kind": kind, "src": src, "seq": seq, "t": T0 + seq, **body})


def synthetic_run(log: McapLog, ticks: int = 30, n_uavs: int = 3) -> None:
    """What a world and its agents put on the bus, tick by tick (a sequence gap at tick 10)."""
    world_seq = 0
    for tick in range(ticks):
        t = T0 + tick * 100 * MS
        for u in range(n_uavs):
            log.write(f"truav/{RUN}/uav/{u}/obs", pack("obs", "world", world_seq, tick=tick, episode=0, uav=u,
                                                       pos=[1000.0 + 10 * tick + u, 2000.0], relayed=u % 2,
                                                       covered=1), t + u)
            world_seq += 1
            seq = tick + (1 if tick >= 10 and u == 1 else 0)  # uav/1 loses beacon 10
            log.write(f"truav/{RUN}/uav/{u}/beacon", pack("beacon", f"uav/{u}", seq, uav=u, tick=tick,
                                                          pos=[1.0, 2.0], vel=[0.0, 0.0]), t + 10 + u)
        log.write(f"truav/{RUN}/world/positions", pack("positions", "world", tick, tick=tick,
                                                       uavs=[[1000.0 + 10 * tick + u, 2000.0] for u in range(n_uavs)],
                                                       vehicles=[[250.0 * k, 17.3 * tick] for k in range(20)]), t + 20)
        log.write(f"truav/{RUN}/metrics/step", pack("metrics", "world", tick, scope="step", tick=tick, episode=0,
                                                    values={"covered": 3.0, "pdr": float("nan")}), t + 30)
    log.write(f"truav/{RUN}/fault/loss", pack("fault", "fault", 0, fault="loss", phase="start", target="beacon",
                                              params={"p": 0.5}), T0 + 5 * 100 * MS)


def test_recording_mirrors_decode_with_the_sdk_schemas_and_json_schemas_have_no_unions(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    with McapLog(path, foxglove=FoxgloveMirror(Geometry(), DEFAULT_ORIGIN)) as log:
        synthetic_run(log)
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        summary = reader.get_summary()
        json_schemas = [s for s in summary.schemas.values() if s.encoding == "jsonschema"]
        assert json_schemas and all(type_unions(json.loads(s.data)) == [] for s in json_schemas)
        by_topic: dict[str, list] = {}
        for schema, channel, message in reader.iter_messages():
            if schema.encoding == "protobuf":
                sdk = SDK_CLASSES[schema.name].get_schema()  # the SDK's own schema, byte for byte
                assert (schema.name, schema.encoding, schema.data) == (sdk.name, sdk.encoding, bytes(sdk.data))
                by_topic.setdefault(channel.topic, []).append(decoder(schema.name, schema.data).FromString(message.data))
            elif channel.message_encoding == "json":
                assert "pdr" not in json.loads(message.data)  # NaN left out, not null
    assert {f"/foxglove/uav/{u}/fix" for u in range(3)} <= set(by_topic)
    fix = by_topic["/foxglove/uav/0/fix"][0]  # (1000, 2000) in a 5 km area centred on the origin
    assert fix.latitude == pytest.approx(DEFAULT_ORIGIN[0] - 500 / 111_319.5, abs=1e-5)
    assert fix.longitude < DEFAULT_ORIGIN[1] and fix.frame_id == "uav/0"
    scene = by_topic["/foxglove/scene"]
    assert len(scene) == 30  # one per tick
    entities = {e.id: e for e in scene[-1].entities}
    assert {"uav/0", "uav/1", "uav/2", "vehicles"} <= set(entities)
    assert len(entities["vehicles"].cubes) == 20 and entities["uav/1"].texts[0].text == "UAV 1"
    assert entities["uav/0"].cylinders[0].size.x == 2 * Geometry().comm_range_m  # the coverage disc
    assert len(entities["uav/1"].lines) == 1 and not entities["uav/0"].lines  # uav/1 relayed: link to an RSU
    static = {e.id for e in by_topic["/foxglove/scene/static"][0].entities}
    assert static == {"roads", "rsus"}
    assert [t.child_frame_id for t in by_topic["/foxglove/tf"][0].transforms] == ["uav/0", "uav/1", "uav/2"]
    logs = [m.message for m in by_topic["/foxglove/log"]]
    assert any("uav/2 joined" in m for m in logs) and any("fault loss start" in m for m in logs)
    assert any("1 beacon message(s) from uav/1 lost" in m for m in logs)


def test_compact_makes_bigger_bounded_chunks_and_keeps_every_message(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    with McapLog(path, flush_interval_s=1e-9) as log:  # a chunk per message: the worst case of a live run
        log.set_metadata("truav.config", {"toml": "x = 1"})
        synthetic_run(log, ticks=100)  # 10 s of log time

    def content(p: Path):
        with open(p, "rb") as f:
            r = make_reader(f, validate_crcs=True)
            msgs = [(c.topic, m.log_time, m.publish_time, m.sequence, m.data) for _, c, m in r.iter_messages()]
            return msgs, len(r.get_summary().chunk_indexes), {m.name: m.metadata for m in r.iter_metadata()}

    before_msgs, before_chunks, before_meta = content(path)
    size_before, size_after = compact(path)
    after_msgs, after_chunks, after_meta = content(path)
    assert sorted(after_msgs) == sorted(before_msgs) and after_meta == before_meta
    # about one per 2 s of log time (COMPACT_CHUNK_SPAN_NS; the mirrors' late log times start one more)
    assert before_chunks > 100 and 5 <= after_chunks <= 6
    with open(path, "rb") as f:
        spans = [c.message_end_time - c.message_start_time for c in make_reader(f).get_summary().chunk_indexes]
    assert max(spans) < COMPACT_CHUNK_SPAN_NS
    assert size_after == os.path.getsize(path) and size_after * 3 < size_before
    assert not list(tmp_path.glob("*.compact*"))


class _WsClient:
    """Foxglove WebSocket client: advertise -> subscribe to all -> count messages per topic."""

    def __init__(self, port: int, subprotocol: str, enough=lambda counts: False) -> None:
        self.url, self.subprotocol, self.enough = f"ws://127.0.0.1:{port}", subprotocol, enough
        self.channels: dict[int, dict] = {}
        self.counts: dict[str, int] = {}
        self.first: dict[str, bytes] = {}

    async def run(self, listen_s: float) -> None:
        import websockets

        async with websockets.connect(self.url, subprotocols=[self.subprotocol], open_timeout=5) as ws:
            assert ws.subprotocol == self.subprotocol
            deadline = time.monotonic() + listen_s
            while (left := deadline - time.monotonic()) > 0 and not self.enough(self.counts):
                try:
                    frame = await asyncio.wait_for(ws.recv(), left)
                except asyncio.TimeoutError:
                    break
                if isinstance(frame, str):
                    msg = json.loads(frame)
                    if msg["op"] == "advertise":
                        new = [c for c in msg["channels"] if c["id"] not in self.channels]
                        self.channels.update({c["id"]: c for c in new})
                        await ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                            {"id": c["id"], "channelId": c["id"]} for c in new]}))
                elif frame[0] == 1:  # message data: opcode, subscription id, log time, payload
                    sub, _t = struct.unpack_from("<IQ", frame, 1)
                    topic = self.channels[sub]["topic"]
                    self.counts[topic] = self.counts.get(topic, 0) + 1
                    self.first.setdefault(topic, frame[13:])


def _connect_with_retries(port: int, subprotocol: str, listen_s: float, within_s: float,
                          enough=lambda counts: False) -> _WsClient:
    deadline = time.monotonic() + within_s
    while True:
        client = _WsClient(port, subprotocol, enough)
        try:
            asyncio.run(client.run(listen_s))
            return client
        except OSError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.5)


def test_up_with_foxglove_serves_live_channels_and_records_a_compact_file(tmp_path: Path) -> None:
    """`truav-swarm up --foxglove PORT --record F`: a WebSocket client on loopback gets the
    advertised channels and their messages while it runs; the finished file is compacted."""
    port, record = free_port(), tmp_path / "live.mcap"
    cmd = [sys.executable, "-m", "truav.cli.swarm", "up", "--scheme", "truav", "--agents", "2", "--episodes", "1", "--steps", "60",
           "--set", "scenario.n_vehicles=40", "--foxglove", str(port), "--record", str(record),
           "--out", str(tmp_path / "out"), "--quiet", "--no-plot",
           "--max-missed", "1"]  # real time: a busy host's missed actions are not what this test is about
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        client = _connect_with_retries(port, "foxglove.sdk.v1", listen_s=60.0, within_s=90.0, enough=lambda c: min(
            c.get("/foxglove/scene", 0), c.get("/foxglove/uav/1/fix", 0), c.get("/foxglove/tf", 0)) >= 5)
        out, _ = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, out
    topics = {c["topic"]: c for c in client.channels.values()}
    assert {"/foxglove/scene", "/foxglove/tf", "/foxglove/uav/0/fix", "/foxglove/uav/1/fix"} <= set(topics)
    assert topics["/foxglove/scene"]["schemaName"] == "foxglove.SceneUpdate"
    assert topics["/foxglove/scene"]["encoding"] == "protobuf"
    assert client.counts.get("/foxglove/scene", 0) >= 5 and client.counts.get("/foxglove/uav/1/fix", 0) >= 5
    schema = fm.SceneUpdate.get_schema()
    scene = decoder(schema.name, bytes(schema.data)).FromString(client.first["/foxglove/scene"])
    assert "vehicles" in {e.id for e in scene.entities}
    assert f"Foxglove: open ws://127.0.0.1:{port}" in out
    with open(record, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        chunks = reader.get_summary().chunk_indexes  # compacted at the clean finish: 2 s chunks, not 50 ms ones
        span = max(c.message_end_time for c in chunks) - min(c.message_start_time for c in chunks)
        assert len(chunks) <= span // COMPACT_CHUNK_SPAN_NS + 1, (len(chunks), span)
        assert all(c.message_end_time - c.message_start_time < COMPACT_CHUNK_SPAN_NS for c in chunks)
        mirrored = {c.topic for c in reader.get_summary().channels.values() if is_mirror_topic(c.topic)}
    assert {"/foxglove/scene", "/foxglove/uav/0/fix", "/foxglove/log"} <= mirrored


def test_view_rejects_a_bad_geo_origin_in_one_line(capsys) -> None:
    from truav.cli.swarm import main

    with pytest.raises(SystemExit) as exc:
        main(["view", "-e", "tcp/127.0.0.1:1", "--geo-origin", "91,0"])
    assert exc.value.code == 2
    assert "latitude must be in [-85, 85]" in capsys.readouterr().err


def test_live_view_thread_stops_when_asked(endpoint: str, bus_factory) -> None:
    """serve() on the test router: a client sees channels appear as the bus carries data."""
    from truav.bus import transport
    from truav.swarm.view import serve

    stop, ready = threading.Event(), threading.Event()
    port_box: list[int] = []

    def on_ready(port: int) -> None:
        port_box.append(port)
        ready.set()

    conf = transport.make_config("client", connect=[endpoint])
    thread = threading.Thread(target=serve, args=(RUN, conf, FoxgloveMirror()),
                              kwargs=dict(port=0, stop=stop, ready=on_ready), daemon=True)
    thread.start()
    try:
        assert ready.wait(20)
        world = bus_factory("world")
        from truav.wire import keys, schema

        def publish() -> None:
            for tick in range(40):
                if stop.is_set():
                    return
                world.publish(keys.world_positions(RUN), schema.Positions(
                    tick=tick, uavs=((100.0, 200.0),), vehicles=((0.0, 5.0), (250.0, 9.0))))
                time.sleep(0.05)

        feeder = threading.Thread(target=publish, daemon=True)
        feeder.start()
        client = _connect_with_retries(port_box[0], "foxglove.sdk.v1", listen_s=5.0, within_s=10,
                                       enough=lambda c: c.get("/foxglove/scene", 0) >= 3)
        feeder.join(5)
        assert client.counts.get("/foxglove/scene", 0) >= 3
    finally:
        stop.set()
        thread.join(10)
    assert not thread.is_alive()
