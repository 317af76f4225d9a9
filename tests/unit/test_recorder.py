"""Tests for the MCAP recorder library: writer, reader, recover, check (in process; the SIGKILL
durability test, a writer in a child process, is tests/swarm/test_recorder_sigkill.py)."""

from __future__ import annotations

import io
import json
import sys
from pathlib import Path

import msgpack
import pytest
from mcap.opcode import Opcode
from mcap.reader import NonSeekingReader, make_reader
from mcap.records import Chunk, MessageIndex
from mcap.stream_reader import StreamReader, breakup_chunk

REPO = Path(__file__).resolve().parents[2]
if str(REPO) not in sys.path:  # plain `pytest` puts the test's folder, not the repo root, on sys.path
    sys.path.insert(0, str(REPO))

from recorder.check import CheckReport, check  # noqa: E402
from recorder.mcap_log import (  # noqa: E402
    JSON_ENCODING,
    JSONSCHEMA_ENCODING,
    MIRROR_PREFIX,
    MSGPACK_ENCODING,
    McapLog,
)
from recorder.reader import iter_messages, probe, read_metadata, read_schemas  # noqa: E402
from recorder.recover import compact, recover  # noqa: E402

RUN = "t1"
T0 = 1_700_000_000_000_000_000  # a wall-clock-like ns timestamp
MS = 1_000_000


def beacon(uav: int, seq: int, t: int, inc: int | None = None) -> bytes:
    """A beacon payload; without ``inc``, as written before incarnations (still decodable, inc 0)."""
    body = {"v": 1, "kind": "beacon", "src": f"uav/{uav}", "seq": seq, "t": t}
    if inc is not None:
        body["inc"] = inc
    return msgpack.packb({**body, "uav": uav, "tick": seq, "pos": [10.0 + seq, -2.5], "vel": [1.0, 0.5]})


def obs(uav: int, seq: int, t: int) -> bytes:
    return msgpack.packb({"v": 1, "kind": "obs", "src": "world", "seq": seq, "t": t, "tick": seq, "episode": 0,
                          "uav": uav, "pos": [1.0, 2.0], "vehicles_in_range": 3, "queued_packets": 0,
                          "relayed": 1, "covered": 2, "energy_j": 5.0, "speed_max": 20.0, "done": False})


def metrics(seq: int, t: int) -> bytes:
    return msgpack.packb({"v": 1, "kind": "metrics", "src": "world", "seq": seq, "t": t, "scope": "step",
                          "tick": seq, "episode": 2, "values": {"reward": 0.25 * seq, "coverage": float("nan")}})


def positions(seq: int, t: int) -> bytes:
    return msgpack.packb({"v": 1, "kind": "positions", "src": "world", "seq": seq, "t": t, "tick": seq,
                          "uavs": [[1.0, 2.0], [3.0, 4.0]], "vehicles": [[5.0, 6.0]]})


def key(*parts: object) -> str:
    return "/".join(["truav", RUN, *map(str, parts)])


def write_mixed(log: McapLog, ticks: int = 50) -> list[tuple[str, bytes, int, int]]:
    """Interleave several keys; return what was written as (key, payload, log_time, publish_time)."""
    written = []
    for tick in range(ticks):
        base = T0 + tick * 100 * MS
        batch = [(key("uav", u, "beacon"), beacon(u, tick, base - 7 * MS + u)) for u in range(3)]
        batch += [(key("uav", u, "obs"), obs(u, tick * 3 + u, base - 5 * MS)) for u in range(3)]
        batch += [(key("metrics", "step"), metrics(tick, base - 3 * MS)),
                  (key("world", "positions"), positions(tick, base - 1 * MS))]
        for i, (k, payload) in enumerate(batch):
            log_time = base + i * 1000
            log.write(k, payload, log_time)
            written.append((k, payload, log_time, msgpack.unpackb(payload)["t"]))
    return written


def finished_bytes(**kwargs: object) -> tuple[bytes, list[tuple[str, bytes, int, int]], McapLog]:
    buf = io.BytesIO()
    kwargs.setdefault("foxglove", False)  # the Foxglove mirror has its own tests (test_foxglove.py)
    log = McapLog(buf, **kwargs)  # type: ignore[arg-type]
    log.set_metadata("config", {"run": RUN, "n_uavs": 3, "note": "test"})
    written = write_mixed(log)
    log.close()
    return buf.getvalue(), written, log


@pytest.mark.parametrize("compression", ["zstd", "lz4", "none"])
def test_roundtrip_in_memory(compression: str) -> None:
    data, written, _ = finished_bytes(compression=compression)
    got = list(iter_messages(io.BytesIO(data)))
    assert [tuple(m) for m in got] == written  # file order == write order, mirrors skipped
    for k in {w[0] for w in written}:  # per channel: same messages, same order, same times
        assert [tuple(m) for m in got if m.key == k] == [w for w in written if w[0] == k]
    assert read_metadata(io.BytesIO(data))["config"] == {"run": RUN, "n_uavs": "3", "note": "test"}


def test_official_reader_reads_finished_file_and_statistics() -> None:
    data, written, log = finished_bytes()
    reader = make_reader(io.BytesIO(data), validate_crcs=True)
    summary = reader.get_summary()
    assert summary is not None and summary.statistics is not None
    stats = summary.statistics
    topics = {c.id: c.topic for c in summary.channels.values()}
    bus = [m for _, c, m in reader.iter_messages() if not c.topic.startswith(MIRROR_PREFIX)]
    assert len(bus) == len(written)
    mirrors = sum(1 for k, *_ in written if k.endswith("step"))
    assert stats.message_count == len(written) + mirrors
    assert stats.channel_count == len(summary.channels) == 8 + 1  # 8 keys, metrics/step mirrored
    per_topic = {topics[cid]: n for cid, n in stats.channel_message_counts.items()}
    assert per_topic[key("uav", 1, "beacon")] == 50 and per_topic[MIRROR_PREFIX + key("metrics", "step")] == 50
    assert stats.message_start_time == written[0][2] and stats.message_end_time == written[-1][2]
    assert stats.chunk_count == len(summary.chunk_indexes) >= 1 and stats.metadata_count == 1
    for channel in summary.channels.values():
        schema = summary.schemas[channel.schema_id]
        assert schema.encoding == JSONSCHEMA_ENCODING
        if not channel.topic.startswith(MIRROR_PREFIX):
            assert channel.message_encoding == MSGPACK_ENCODING
            assert schema.name == "truav." + channel.topic.rsplit("/", 1)[-1].replace("step", "metrics")
    # sequence and publish time fields carry the envelope's seq and t
    msgs = list(make_reader(io.BytesIO(data)).iter_messages(topics=[key("uav", 2, "obs")]))
    assert [m.sequence for _, _, m in msgs] == [t * 3 + 2 for t in range(50)]
    assert [m.publish_time for _, _, m in msgs] == [w[3] for w in written if w[0] == key("uav", 2, "obs")]
    # the non-seeking reader validates the chunk CRCs of a linear pass too
    assert sum(1 for _ in NonSeekingReader(io.BytesIO(data), validate_crcs=True).iter_messages()) == stats.message_count
    assert log.summary().chunks == stats.chunk_count


def test_message_indexes_point_at_their_messages() -> None:
    """Our hand-packed MessageIndex records, parsed by mcap, locate the right messages."""
    buf = io.BytesIO()
    with McapLog(buf, foxglove=False) as log:
        for tick in range(5):
            write_mixed(log, ticks=3)
            log.flush()
    by_offset: dict = {}
    checked = 0
    for record in StreamReader(io.BytesIO(buf.getvalue()), emit_chunks=True).records:
        if isinstance(record, Chunk):
            breakup_chunk(record, validate_crc=True)  # CRC holds
            by_offset = _message_offsets(record)
        elif isinstance(record, MessageIndex):
            for log_time, offset in record.records:
                message = by_offset[offset]
                assert message.channel_id == record.channel_id and message.log_time == log_time
                checked += 1
    assert checked == 5 * 3 * 8 + 5 * 3 * 1  # bus + mirror messages


def _message_offsets(chunk: Chunk) -> dict:
    """Map offset-in-uncompressed-chunk -> Message, walking the records by hand."""
    from mcap.records import Message
    from mcap.stream_reader import get_chunk_data_stream

    stream, length = get_chunk_data_stream(chunk)
    out = {}
    while stream.count < length:
        offset = stream.count
        opcode, size = stream.read1(), stream.read8()
        if opcode == Opcode.MESSAGE:
            out[offset] = Message.read(stream, size)
        else:
            stream.read(size)
    return out


def test_json_mirrors_decode_as_json_with_json_schema() -> None:
    data, written, _ = finished_bytes()
    schemas = read_schemas(io.BytesIO(data))
    mirrors = [m for m in iter_messages(io.BytesIO(data), include_mirrors=True) if m.key.startswith(MIRROR_PREFIX)]
    assert {m.key for m in mirrors} == {MIRROR_PREFIX + key("metrics", "step")}
    reader = make_reader(io.BytesIO(data))
    encodings = {c.topic: c.message_encoding for c in reader.get_summary().channels.values()}  # type: ignore[union-attr]
    for m in mirrors:
        assert encodings[m.key] == JSON_ENCODING
        schema = json.loads(schemas[m.key].data)
        assert schemas[m.key].encoding == JSONSCHEMA_ENCODING and schema["type"] == "object"
        value = json.loads(m.payload)
        _validate(value, schema)
    last_metrics = [json.loads(m.payload) for m in mirrors if m.key.endswith("metrics/step")][-1]
    assert last_metrics == {"tick": 49, "episode": 2, "scope": "step", "reward": 12.25}  # NaN left out
    # bus schemas are JSON Schema too, documenting the envelope
    bus_schema = json.loads(schemas[key("uav", 0, "beacon")].data)
    assert {"v", "kind", "src", "seq", "t", "pos", "vel"} <= set(bus_schema["properties"])


_JSON_TYPES = {"object": dict, "array": list, "string": str, "integer": int, "number": (int, float),
               "boolean": bool, "null": type(None)}


def _validate(value: object, schema: dict) -> None:
    """A tiny JSON Schema check (type, properties, required, items, additionalProperties)."""
    kinds = schema.get("type")
    if kinds is not None:
        kinds = [kinds] if isinstance(kinds, str) else kinds
        assert any(isinstance(value, _JSON_TYPES[k]) and not (k in ("integer", "number") and isinstance(value, bool))
                   for k in kinds), (value, schema)
    if isinstance(value, dict):
        assert set(schema.get("required", ())) <= set(value)
        props = schema.get("properties", {})
        for name, item in value.items():
            sub = props.get(name, schema.get("additionalProperties"))
            if isinstance(sub, dict):
                _validate(item, sub)
    if isinstance(value, list) and "items" in schema:
        for item in value:
            _validate(item, schema["items"])


def test_check_finds_gaps_duplicates_and_reordering() -> None:
    buf = io.BytesIO()
    sent = [s for s in range(100) if s not in (10, 11, 12, 50)]  # the bus lost 4 messages
    sent += [99, 70]  # a duplicate and a late one (70 is also kept in order, so it's a dup)
    sent.insert(30, 5)  # a duplicate arriving late
    with McapLog(buf) as log:
        for i, seq in enumerate(sent):
            log.write(key("uav", 7, "beacon"), beacon(7, seq, T0 + i), T0 + i)
        for seq in (0, 1, 3):  # another sender with one gap
            log.write(key("uav", 8, "beacon"), beacon(8, seq, T0), T0 + 1000 + seq)
        online = log.summary()
    report = check(io.BytesIO(buf.getvalue()))
    s7 = report.senders[("uav/7", "beacon", 0)]
    assert (s7.count, s7.first_seq, s7.last_seq) == (len(sent), 0, 99)
    assert s7.missing == 4 and s7.gap_ranges == [(10, 12), (50, 50)] and s7.gaps == 2
    assert s7.duplicates == 3 and s7.out_of_order == 0
    s8 = report.senders[("uav/8", "beacon", 0)]
    assert s8.gap_ranges == [(2, 2)] and s8.missing == 1
    assert report.missing == 5 and report.finished and report.torn_bytes == 0
    assert report.channels[key("uav", 7, "beacon")].messages == len(sent)
    text = report.format_report()
    assert "10-12, 50" in text and "uav/7" in text and "finished" in text
    # the writer's online counters agree on the forward gaps
    assert online.senders[("uav/7", "beacon", 0)].missing == 4 and online.senders[("uav/7", "beacon", 0)].gaps == 2
    assert online.senders[("uav/7", "beacon", 0)].backwards == 3


def test_check_counts_out_of_order() -> None:
    buf = io.BytesIO()
    with McapLog(buf) as log:
        for i, seq in enumerate([0, 1, 3, 2, 4]):
            log.write(key("uav", 1, "beacon"), beacon(1, seq, T0), T0 + i)
    s = check(io.BytesIO(buf.getvalue())).senders[("uav/1", "beacon", 0)]
    assert (s.out_of_order, s.duplicates, s.missing) == (1, 0, 0)


def _restarts(streams: list[tuple[int, list[int]]]) -> CheckReport:
    """uav/1's beacons: one (incarnation, seqs) per process start, written one after the other."""
    buf = io.BytesIO()
    with McapLog(buf) as log:
        i = 0
        for inc, seqs in streams:
            for seq in seqs:
                log.write(key("uav", 1, "beacon"), beacon(1, seq, T0 + i, inc), T0 + i)
                i += 1
        online = log.summary()
    assert online.missing == check(io.BytesIO(buf.getvalue())).missing  # the writer's live counts agree
    return check(io.BytesIO(buf.getvalue()))


def test_check_splits_a_sender_at_each_restart_and_finds_a_loss_in_any_incarnation() -> None:
    """A restarted sender numbers from 0 again under a new incarnation: not duplicates; a message
    missing from the second process is found and named (sender, incarnation, seq)."""
    first, second, third = 0xA1, 0xB2, 0xC3
    complete = _restarts([(first, list(range(40))), (second, list(range(25))), (third, list(range(5)))])
    assert complete.problems == [], complete.problems
    assert [(s.incarnation, s.count) for s in sorted(complete.senders.values(), key=lambda s: s.incarnation)] \
        == [(1, 40), (2, 25), (3, 5)]
    table = complete.format_report().splitlines()
    assert table[3].split()[:4] == ["src", "kind", "#", "inc"] and table[6].split()[:4] == ["uav/1", "beacon", "3",
                                                                                               "00000000000000c3"]
    lost = _restarts([(first, list(range(40))), (second, [s for s in range(25) if s != 17]), (third, list(range(5)))])
    assert lost.missing == 1 and len(lost.problems) == 1
    assert "uav/1 beacon, incarnation 2 (inc 00000000000000b2): seq 17" in lost.problems[0]
    # a later incarnation started while recording: its first messages missing count too (not the first's)
    late = _restarts([(first, list(range(3, 40))), (second, list(range(2, 25)))])
    assert late.missing == 2 and late.senders[("uav/1", "beacon", second)].gap_ranges == [(0, 1)]
    # within one incarnation a repeat is still a duplicate
    dup = _restarts([(first, list(range(40))), (second, [*range(25), 7])])
    assert dup.problems == ["1 duplicate(s) (uav/1 beacon, incarnation 2 (inc 00000000000000b2): 1)"]


GARBAGE = [b"", b"\xc1", b"not msgpack at all", msgpack.packb([1, 2, 3]),
           msgpack.packb({"kind": "beacon", "seq": 1}),  # no src
           msgpack.packb({"kind": "beacon", "src": "uav/1", "seq": "1"}),  # seq not an int
           msgpack.packb({"v": 1, "kind": "beacon", "src": "uav/1", "seq": 0, "t": 5}) + b"\x00"]  # extra data


def test_garbage_payloads_are_recorded_raw_and_counted() -> None:
    buf = io.BytesIO()
    with McapLog(buf) as log:
        for i, payload in enumerate(GARBAGE):
            log.write(key("uav", 1, "beacon"), payload, T0 + i)
        log.write(key("uav", 1, "beacon"), beacon(1, 0, T0), T0 + 100)
        # a decodable observation whose fields don't fit the Foxglove mirror: recorded, mirror skipped
        odd = msgpack.packb({"v": 1, "kind": "obs", "src": "world", "seq": 1, "t": T0, "uav": "one", "pos": [1, 2]})
        log.write(key("uav", 1, "obs"), odd, T0 + 101)
        log.write("some/other/topic", b"\xff\xfe", T0 + 102)
        summary = log.summary()
    assert summary.undecodable == len(GARBAGE) + 1 and summary.mirror_errors == 1
    assert summary.messages == len(GARBAGE) + 3 and summary.mirror_messages == 2  # "joined" logs: uav/1, world
    got = list(iter_messages(io.BytesIO(buf.getvalue())))
    assert [m.payload for m in got] == [*GARBAGE, beacon(1, 0, T0), odd, b"\xff\xfe"]
    assert [m.publish_time for m in got[: len(GARBAGE)]] == [T0 + i for i in range(len(GARBAGE))]
    report = check(io.BytesIO(buf.getvalue()))
    assert report.undecodable == len(GARBAGE) + 1
    assert report.channels[key("uav", 1, "beacon")].undecodable == len(GARBAGE)
    schemas = read_schemas(io.BytesIO(buf.getvalue()))
    assert schemas[key("uav", 1, "beacon")].name == "truav.beacon"  # kind guessed from the key
    assert schemas["some/other/topic"].name == "truav.unknown"


def test_explicit_publish_time_and_reader_filters() -> None:
    data, written, _ = finished_bytes()
    buf = io.BytesIO()
    with McapLog(buf) as log:
        log.write(key("uav", 0, "beacon"), beacon(0, 0, T0), T0 + 5, publish_time_ns=T0 + 3)
    assert list(iter_messages(io.BytesIO(buf.getvalue())))[0].publish_time == T0 + 3
    src = io.BytesIO(data)
    beacons = list(iter_messages(src, include="truav/*/uav/*/beacon", exclude=["*/uav/2/*"]))
    assert {m.key for m in beacons} == {key("uav", 0, "beacon"), key("uav", 1, "beacon")}
    lo, hi = written[80][2], written[160][2]
    window = list(iter_messages(src, start_ns=lo, end_ns=hi))
    assert [tuple(m) for m in window] == written[80:160]
    assert list(iter_messages(src, include="nothing/*")) == []


def test_time_based_flush_makes_messages_readable_before_close() -> None:
    """maybe_flush() closes the open chunk after flush_interval_s on the log's clock."""
    now = [100.0]
    buf = io.BytesIO()
    log = McapLog(buf, flush_interval_s=0.05, clock=lambda: now[0])
    log.write(key("uav", 0, "beacon"), beacon(0, 0, T0), T0)
    size = len(buf.getvalue())
    assert log.next_flush_due() == pytest.approx(100.05)
    now[0] += 0.049
    assert not log.maybe_flush() and len(buf.getvalue()) == size  # still in memory
    now[0] += 0.002
    assert log.maybe_flush() and len(buf.getvalue()) > size and log.next_flush_due() is None
    # an unfinished file reads back through the streaming fallback
    unfinished = io.BytesIO(buf.getvalue())
    state = probe(unfinished)
    assert not state.finished and state.torn_bytes == 0
    assert [m.payload for m in iter_messages(unfinished)] == [beacon(0, 0, T0)]
    # write() itself flushes once the open chunk is old enough
    log.write(key("uav", 0, "beacon"), beacon(0, 1, T0), T0 + 1)
    now[0] += 0.06
    log.write(key("uav", 0, "beacon"), beacon(0, 2, T0), T0 + 2)
    assert len(list(iter_messages(io.BytesIO(buf.getvalue())))) == 3
    log.close()
    with pytest.raises(ValueError):
        log.write(key("uav", 0, "beacon"), beacon(0, 3, T0), T0 + 3)


def test_recover_every_truncation_point(tmp_path: Path) -> None:
    """Cut a file with flushed chunks at many byte offsets: recover always yields a
    valid file holding exactly the complete chunks before the cut, in order."""
    path = tmp_path / "full.mcap"
    with McapLog(path, flush_interval_s=0.05) as log:
        log.set_metadata("config", {"run": RUN})
        for tick in range(20):
            for u in range(4):
                log.write(key("uav", u, "beacon"), beacon(u, tick, T0 + tick), T0 + tick * 1000 + u)
            log.flush()
    data = path.read_bytes()
    all_msgs = [tuple(m) for m in iter_messages(path)]
    seen_counts = set()
    for cut in range(len(data) - 1, 40, -max(7, len(data) // 97)):  # ~100 cuts
        cut_path, out = tmp_path / "cut.mcap", tmp_path / "out.mcap"
        cut_path.write_bytes(data[:cut])
        report = recover(cut_path, out)
        assert report.truncated and report.clean
        reader = make_reader(open(out, "rb"), validate_crcs=True)
        assert reader.get_summary() is not None
        got = [tuple(m) for m in iter_messages(out)]
        assert got == all_msgs[: len(got)]  # a prefix, in order
        assert report.messages == len(list(iter_messages(out, include_mirrors=True)))
        seen_counts.add(len(got))
    assert len(seen_counts) > 10 and max(seen_counts) == len(all_msgs)
    untouched = recover(path, tmp_path / "copy.mcap")
    assert not untouched.truncated and untouched.torn_bytes == 0
    assert read_metadata(tmp_path / "copy.mcap")["config"] == {"run": RUN}


def test_a_compacted_file_cut_at_any_byte_recovers_every_whole_chunk_before_the_cut(tmp_path: Path) -> None:
    """The finish rewrites a recording into chunks of at most 2 s (not one chunk for a short run), so a
    copy cut anywhere (a full disk, a copy interrupted) keeps every chunk that ends before the cut."""
    path = tmp_path / "run.mcap"
    with McapLog(path) as log:  # 20 s of a run: 4 UAVs beaconing at 10 Hz
        for tick in range(200):
            for u in range(4):
                log.write(key("uav", u, "beacon"), beacon(u, tick, T0 + tick * 100 * MS), T0 + tick * 100 * MS + u)
    compact(path)
    all_msgs = [tuple(m) for m in iter_messages(path)]
    with open(path, "rb") as f:
        chunks = make_reader(f).get_summary().chunk_indexes
    assert len(chunks) == 10 and all(c.message_end_time - c.message_start_time < 2_000_000_000 for c in chunks)
    data = path.read_bytes()
    for cut in [len(data) // 2, *range(len(data) - 1, 40, -max(11, len(data) // 37))]:
        cut_path, out = tmp_path / "cut.mcap", tmp_path / "out.mcap"
        cut_path.write_bytes(data[:cut])
        recover(cut_path, out, zstd_level=3)
        whole = [c for c in chunks if c.chunk_start_offset + c.chunk_length <= cut]
        got = [tuple(m) for m in iter_messages(out)]
        assert got == all_msgs[:len(got)]  # a prefix, in order
        # every bus message of the chunks that end before the cut, no more
        in_whole = sum(1 for m in all_msgs if any(c.message_start_time <= m[2] <= c.message_end_time for c in whole))
        assert len(got) == in_whole, (cut, len(whole))
        if cut == len(data) // 2:
            assert len(got) >= len(all_msgs) // 3  # issue 25: half a file gives back at least a third


def test_recover_skips_a_corrupt_chunk_and_a_zero_filled_tail(tmp_path: Path) -> None:
    """A chunk whose CRC fails is dropped and counted; zeros after a crash end the data."""
    path = tmp_path / "full.mcap"
    with McapLog(path, compression="none") as log:
        for tick in range(3):
            log.write(key("uav", 0, "beacon"), beacon(0, tick, T0), T0 + tick)
            log.flush()  # one chunk per message
        log.write(key("uav", 0, "beacon"), beacon(0, 3, T0), T0 + 3)  # stays in memory
        data = bytearray(path.read_bytes())  # the file as a crash now would leave it...
    needle = beacon(0, 1, T0)
    at = bytes(data).index(needle)
    data[at + len(needle) - 1] ^= 0xFF  # ...with chunk 2's payload damaged
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(bytes(data) + b"\0" * 4096)
    state = probe(open(cut, "rb"))
    assert not state.finished and state.torn_bytes == 4096
    report = recover(cut, tmp_path / "out.mcap")
    assert report.corrupt_chunks == 1 and not report.clean and report.truncated
    seqs = [msgpack.unpackb(m.payload)["seq"] for m in iter_messages(tmp_path / "out.mcap")]
    assert seqs == [0, 2]  # message 3 was still in memory; 1 was damaged


def test_bad_times_raise_without_corrupting_the_log() -> None:
    buf = io.BytesIO()
    with McapLog(buf) as log:
        log.write(key("uav", 0, "beacon"), beacon(0, 0, T0), T0)
        with pytest.raises(Exception):
            log.write(key("uav", 0, "beacon"), beacon(0, 1, T0), -1)
        with pytest.raises(Exception):
            log.write(key("uav", 0, "beacon"), beacon(0, 1, T0), T0, publish_time_ns=1 << 64)
        log.write(key("uav", 0, "beacon"), beacon(0, 2, T0), T0 + 2)
        assert log.summary().channels == {key("uav", 0, "beacon"): 2}
    reader = make_reader(io.BytesIO(buf.getvalue()), validate_crcs=True)
    assert [m.sequence for _, _, m in reader.iter_messages(topics=[key("uav", 0, "beacon")])] == [0, 2]
