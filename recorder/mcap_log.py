"""Durable MCAP writer for the TRUAV bus recorder.

:class:`McapLog` records every bus message as ``(key, payload bytes, receive
time)``; it knows nothing about Zenoh, so a thin process wrapper feeds it.

Layout of a file:

* one MCAP channel per bus key (topic = key, message encoding ``msgpack``),
  with a schema ``truav.<kind>`` whose JSON Schema documents the decoded map;
* for beacons, metrics and positions a JSON *mirror* channel
  ``/json/<key>`` (message encoding ``json``, a real JSON Schema) because
  Foxglove cannot decode msgpack;
* Foxglove well-known-schema mirrors (``/foxglove/...``: 3D scene, frame
  transforms, one LocationFix per UAV, a Log), built by
  :class:`recorder.foxglove.FoxgloveMirror` with foxglove-sdk's schema classes
  (protobuf encoding, the SDK's own schemas); every mirror topic starts with
  "/" and no bus key does (:func:`is_mirror_topic`);
* ``log_time`` = receive time, ``publish_time`` = envelope ``t`` and
  ``sequence`` = envelope ``seq`` (mod 2**32), so other MCAP tools see them.

Why chunks are framed here instead of by :class:`mcap.writer.Writer`:

* Durability.  A recorder killed with SIGKILL must lose at most ~100 ms.
  Only chunks that reached the OS survive, so the open chunk must be closed
  on a *timer*, not only when it is full.  ``Writer.flush()`` (which closes
  the chunk) exists in the installed mcap 1.6.0 but not in older releases
  that ``mcap>=1.2`` admits (nor in the upstream snapshot we read), and the
  alternative is the name-mangled ``Writer._Writer__finalize_chunk``.
* Speed.  ``Writer.add_message`` costs ~5.5 us/message (a dataclass, a
  ``MessageIndex`` tuple and six ``struct.pack`` calls through ``BytesIO``),
  half of the 10 us budget that 100 k msgs/s allows.

So every record is serialised with mcap's own record classes (``Header``,
``Schema``, ``Channel``, ``Chunk``, ``ChunkIndex``, ``Metadata``,
``Statistics``, ``SummaryOffset``, ``Footer`` ...), except the two per-message
hot records, ``Message`` and ``MessageIndex``, which are packed with one
precompiled :class:`struct.Struct` each, byte for byte as
``mcap.records.Message.write`` / ``MessageIndex.write`` lay them out (the
tests parse them back with mcap's readers).
"""

from __future__ import annotations

import json
import os
import struct
import time
import zlib
from dataclasses import dataclass, field, replace
from typing import IO, Any, Callable, Mapping, Optional, Union

from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (
    Attachment,
    AttachmentIndex,
    Channel,
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    McapRecord,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)

from recorder.foxglove import MESSAGE_ENCODING as FOXGLOVE_ENCODING
from recorder.foxglove import FoxgloveMirror, FoxSchema, Out
from recorder.schemas import (
    KINDS,
    MIRROR_SCHEMA_PREFIX,
    SCHEMA_PREFIX,
    Envelope,
    bus_schema,
    decode_envelope,
    envelope_fields,
    kind_from_key,
    mirror_builder,
    mirror_schema,
)

__all__ = ["McapLog", "LogSummary", "SeqStats", "Envelope", "decode_envelope"]

# --- format constants -----------------------------------------------------------
MCAP_MAGIC = b"\x89MCAP0\r\n"  # spec: 0x89 "MCAP" "0" "\r\n", at both ends of a file
MSGPACK_ENCODING = "msgpack"  # spelled out: older mcap.well_known lacks MessagePack
JSON_ENCODING = "json"
JSONSCHEMA_ENCODING = "jsonschema"
PROFILE = ""  # no MCAP profile fits a msgpack bus
LIBRARY = "truav-recorder/1"

# --- naming constants (readers rely on these) --------------------------------------
MIRROR_PREFIX = "/json/"  # mirror topic = MIRROR_PREFIX + key; bus keys never start with "/"
META_KIND = "truav.kind"  # channel metadata: kind the schema was chosen for
META_MIRROR_OF = "truav.mirror_of"  # channel metadata on mirrors: the mirrored key


def is_mirror_topic(topic: str) -> bool:
    """JSON and Foxglove mirrors start with "/"; bus keys never do."""
    return topic.startswith("/")


COMPRESSIONS = {"none": "", "lz4": "lz4", "zstd": "zstd"}  # option -> Chunk.compression
DEFAULT_COMPRESSION = "zstd"
DEFAULT_FLUSH_INTERVAL_S = 0.05  # max age of the oldest message still in memory
DEFAULT_CHUNK_BYTES = 512 * 1024  # also close a chunk once this big (bounds memory)
DEFAULT_ZSTD_LEVEL = 3
# A finished file is rewritten once into bigger, strongly compressed chunks (see recorder.recover.compact):
# 50 ms chunks make the indexes a third of the file and halve what zstd can find to share. The chunks stay
# bounded (Foxglove recommends at most 4 MB), so a file cut at any byte keeps every whole chunk before the
# cut: a chunk closes before it spans COMPACT_CHUNK_SPAN_NS of log time or once it holds COMPACT_CHUNK_BYTES.
COMPACT_CHUNK_BYTES = 1024 * 1024  # uncompressed: one level-19 compression stays short (the budget below)
# Two seconds of the run per chunk at most. Measured on a default `up --record` run's file (one measurement,
# shared machine): one chunk 463 kB; 1 s chunks +16.5%, 2 s +8.5%, 4 s +4.7%, and cut at half its size it
# recovered 52%, 52% and 42% of its messages.
COMPACT_CHUNK_SPAN_NS = 2_000_000_000
COMPACT_ZSTD_LEVEL = 19  # zstd's strongest usual level: ~1-2 MB/s, ~7% smaller than level 9 on a default run
COMPACT_FAST_ZSTD_LEVEL = 9  # ~50x faster: the chunks after the strong level's time budget is spent
COMPACT_STRONG_BUDGET_S = 10.0  # seconds of level-19 work a compaction may spend (+ one chunk); then level 9
MAX_ID = 0xFFFF  # schema and channel ids are uint16

_U32 = 0xFFFFFFFF
# opcode, record length, channel_id, sequence, log_time, publish_time (then data)
_MESSAGE_HEAD = struct.Struct("<BQHIQQ")
_MESSAGE_FIXED = 2 + 4 + 8 + 8
# opcode, record length, channel_id, byte length of the (log_time, offset) array
_MESSAGE_INDEX_HEAD = struct.Struct("<BQHI")
_OP_MESSAGE = int(Opcode.MESSAGE)
_pack_message_head = _MESSAGE_HEAD.pack
_OP_MESSAGE_INDEX = int(Opcode.MESSAGE_INDEX)


# --- statistics -------------------------------------------------------------------------
MAX_TRACKED_SENDERS = 4096
"""(src, kind, incarnation) streams tracked one by one; further ones pool under OTHER_SENDERS (bounded memory)."""
OTHER_SENDERS = "(other senders)"


@dataclass(slots=True)
class SeqStats:
    """Online sequence tracking for one (src, kind, incarnation) stream.

    Counted as messages arrive, so a reordered message that later fills a
    gap still counts as ``missing`` and ``backwards``; ``recorder.check``
    recomputes exact figures offline.
    """

    count: int = 0
    first_seq: Optional[int] = None
    last_seq: Optional[int] = None  # highest seq seen
    gaps: int = 0  # forward jumps by more than one
    missing: int = 0  # seq numbers those jumps skipped
    backwards: int = 0  # seq <= highest seen (duplicate or reordered)


@dataclass
class LogSummary:
    """What :meth:`McapLog.summary` reports; a snapshot, safe to keep."""

    messages: int = 0  # bus messages written (mirrors excluded)
    mirror_messages: int = 0
    undecodable: int = 0  # not msgpack / not a map / no str kind+src and int seq
    mirror_errors: int = 0  # decodable, but the kind's fields did not fit the mirror
    chunks: int = 0
    bytes_written: int = 0
    channels: dict[str, int] = field(default_factory=dict)  # key -> messages
    senders: dict[tuple[str, str, int], SeqStats] = field(default_factory=dict)  # (src, kind, inc) ->

    @property
    def missing(self) -> int:
        """Sequence numbers skipped, over all senders."""
        return sum(s.missing for s in self.senders.values())


@dataclass(slots=True)
class _Chan:
    """Per-key channel state looked up once per message."""

    id: int
    kind: str
    mirror: Optional[Callable[[dict], bytes]]
    mirror_id: int = 0  # 0: mirror channel not created yet
    count: int = 0


Output = Union[str, "os.PathLike[str]", IO[bytes]]


def _compressor(name: str, zstd_level: int) -> Callable[[bytes], bytes]:
    if name == "zstd":
        import zstandard

        return zstandard.ZstdCompressor(level=zstd_level).compress  # reused context
    if name == "lz4":
        import lz4.frame

        return lz4.frame.compress
    if name == "none":
        return bytes
    raise ValueError(f"compression must be one of {sorted(COMPRESSIONS)}, got {name!r}")


class McapLog:
    """Append-only MCAP log of bus messages that survives SIGKILL minus ~flush_interval_s.

    ``output`` is a path (opened, owned and closed here) or a writable binary
    stream (flushed, never closed; offsets count from its current position).

    Durability: messages accumulate in an in-memory chunk; the chunk is
    compressed, written and ``flush()``-ed to the OS once its oldest message is
    ``flush_interval_s`` old (checked on every :meth:`write` when ``auto_flush``,
    and by :meth:`maybe_flush`, which the process wrapper must also call from a
    timer so a quiet bus does not strand a chunk), or once it holds
    ``chunk_bytes``.  Data handed to the OS survives the death of the process;
    ``fsync=True`` also makes it survive a power cut, at a syscall per chunk.
    A file whose writer died has no summary: ``recorder.recover`` finishes it.

    Not thread-safe: Zenoh delivers samples on its own threads, so the process
    wrapper should hand them to one writer thread (e.g. through a queue).
    """

    def __init__(
        self,
        output: Output,
        *,
        compression: str = DEFAULT_COMPRESSION,
        flush_interval_s: float = DEFAULT_FLUSH_INTERVAL_S,
        chunk_bytes: int = DEFAULT_CHUNK_BYTES,
        chunk_span_ns: Optional[int] = None,
        mirrors: bool = True,
        foxglove: Union[FoxgloveMirror, bool] = True,
        auto_flush: bool = True,
        fsync: bool = False,
        zstd_level: int = DEFAULT_ZSTD_LEVEL,
        clock: Callable[[], float] = time.monotonic,
        library: str = LIBRARY,
    ) -> None:
        self._compress = _compressor(compression, zstd_level)
        self._compression_name = compression
        self._compression = COMPRESSIONS[compression]
        if flush_interval_s <= 0 or chunk_bytes <= 0 or (chunk_span_ns is not None and chunk_span_ns <= 0):
            raise ValueError("flush_interval_s, chunk_bytes and chunk_span_ns must be positive")
        self._interval = flush_interval_s
        self._chunk_bytes = chunk_bytes
        self._chunk_span = chunk_span_ns
        self._mirrors = mirrors
        # True: the default scene geometry; the recorder process passes one built from the run config
        self._fox: Optional[FoxgloveMirror] = (FoxgloveMirror() if foxglove is True else foxglove or None) \
            if mirrors else None
        self._fox_kinds = self._fox.KINDS if self._fox is not None else frozenset()
        self._fox_chans: dict[str, list[int]] = {}  # topic -> [channel id, sequence]
        self._srcs_seen: set[str] = set()
        self._first_inc: dict[str, int] = {}  # src -> its first incarnation recorded (the one that may predate us)
        self._auto_flush = auto_flush
        self._fsync = fsync
        self._clock = clock
        if isinstance(output, (str, os.PathLike)):
            self._stream: IO[bytes] = open(output, "wb")
            self._owned = True
        else:
            self._stream = output
            self._owned = False
        self._offset = 0  # bytes written so far = offset of the next record
        self._closed = False
        # registry
        self._chans: dict[str, _Chan] = {}
        self._channels: list[Channel] = []
        self._schemas: list[Schema] = []
        self._schema_ids: dict[tuple[str, str], int] = {}  # (name, encoding) -> id
        self._msg_counts: dict[int, int] = {}  # channel id -> messages (Statistics)
        # open chunk
        self._chunk = bytearray()
        self._index: dict[int, list[int]] = {}  # channel id -> flat [log_time, offset, ...]
        self._chunk_n = 0
        self._chunk_start = 0
        self._chunk_end = 0
        self._chunk_opened = 0.0
        # summary section material
        self._chunk_indexes: list[ChunkIndex] = []
        self._metadata_indexes: list[MetadataIndex] = []
        self._attachment_indexes: list[AttachmentIndex] = []
        self._n_messages = 0  # in written chunks; the open chunk holds _chunk_n more
        self._time_min: Optional[int] = None  # over written chunks
        self._time_max: Optional[int] = None
        # recorder statistics
        self._senders: dict[tuple[str, str, int], SeqStats] = {}
        self._undecodable = 0
        self._mirror_errors = 0
        self._mirror_messages = 0
        self._stream.write(MCAP_MAGIC)
        self._offset += len(MCAP_MAGIC)
        self._write_records(Header(profile=PROFILE, library=library))
        self._stream.flush()

    # --- context manager -------------------------------------------------------------
    def __enter__(self) -> "McapLog":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def closed(self) -> bool:
        return self._closed

    # --- writing ------------------------------------------------------------------------
    def write(self, key: str, payload: bytes, log_time_ns: int, publish_time_ns: Optional[int] = None) -> None:
        """Record one bus message received at ``log_time_ns`` (wall clock, ns).

        ``publish_time_ns`` defaults to the envelope's ``t`` (or the receive
        time when the payload is undecodable).  Raises ``struct.error`` for
        times outside uint64 and ValueError once closed.
        """
        if self._closed:
            raise ValueError("write() on a closed McapLog")
        env = envelope_fields(payload)
        chan = self._chans.get(key)
        if chan is None:
            chan = self._open_channel(key, None if env is None else env[0])
        if env is None:
            pub = log_time_ns if publish_time_ns is None else publish_time_ns
            self._append(chan.id, 0, log_time_ns, pub, payload)
            chan.count += 1
            self._undecodable += 1
        else:
            kind, src, seq, t, body, inc = env
            if publish_time_ns is not None:
                pub = publish_time_ns
            else:
                pub = log_time_ns if t is None else t
            self._append(chan.id, seq & _U32, log_time_ns, pub, payload)  # raises before counting
            chan.count += 1
            # sequence tracking, inlined (hot path); see SeqStats
            # a restarted sender numbers from 0 again under a new incarnation: a stream of its own
            stats = self._senders.get((src, kind, inc))
            if stats is None and len(self._senders) >= MAX_TRACKED_SENDERS:  # src and inc are the sender's choice
                src, inc = OTHER_SENDERS, 0
                stats = self._senders.get((src, kind, inc))
            if stats is None:
                stats = self._senders[(src, kind, inc)] = SeqStats(count=1, first_seq=seq, last_seq=seq)
                if self._first_inc.setdefault(src, inc) != inc and seq:  # a later process starts at seq 0
                    stats.gaps, stats.missing = 1, seq
                if self._fox is not None and src not in self._srcs_seen:
                    self._srcs_seen.add(src)
                    self.write_foxglove(self._fox.joined(src, log_time_ns), log_time_ns, pub)
            else:
                stats.count += 1
                last = stats.last_seq
                if seq == last + 1:  # type: ignore[operator]
                    stats.last_seq = seq
                elif seq > last:  # type: ignore[operator]
                    stats.gaps += 1
                    stats.missing += seq - last - 1  # type: ignore[operator]
                    stats.last_seq = seq
                    if self._fox is not None:
                        self.write_foxglove(self._fox.lost(src, kind, seq - last - 1, log_time_ns), log_time_ns, pub)
                else:
                    stats.backwards += 1
            if chan.mirror is not None and kind == chan.kind:
                self._write_mirror(key, chan, body, log_time_ns, pub, seq & _U32)
            if kind in self._fox_kinds and kind == chan.kind:
                try:
                    outs = self._fox.feed(kind, body, log_time_ns)  # type: ignore[union-attr]
                except Exception:  # odd bodies: counted, as for the JSON mirrors
                    self._mirror_errors += 1
                else:
                    for out in outs:
                        self.write_foxglove(out, log_time_ns, pub)
        if self._auto_flush and (
            len(self._chunk) >= self._chunk_bytes or self._clock() - self._chunk_opened >= self._interval
        ):
            self._close_chunk()

    def write_foxglove(self, out: Out, log_time_ns: int, publish_time_ns: Optional[int] = None) -> None:
        """Record one Foxglove mirror message (channel and schema made on first use)."""
        if self._closed:
            raise ValueError("write_foxglove() on a closed McapLog")
        entry = self._fox_chans.get(out.topic)
        if entry is None:
            sid = self._raw_schema_id(out.schema)
            entry = self._fox_chans[out.topic] = [
                self._new_channel(out.topic, FOXGLOVE_ENCODING, sid, {META_KIND: "foxglove"}), 0]
        self._append(entry[0], entry[1] & _U32, log_time_ns,
                     log_time_ns if publish_time_ns is None else publish_time_ns, out.data)
        entry[1] += 1
        self._mirror_messages += 1

    def maybe_flush(self, now: Optional[float] = None) -> bool:
        """Close and flush the open chunk if its oldest message is ``flush_interval_s`` old.

        ``now`` is a reading of the ``clock`` given to the constructor (default
        :func:`time.monotonic`).  Returns True when a chunk was written.  Call it
        every few tens of ms from the recorder loop even when no message arrives.
        """
        if self._closed or self._chunk_n == 0:
            return False
        if (self._clock() if now is None else now) - self._chunk_opened < self._interval:
            return False
        self._close_chunk()
        return True

    def next_flush_due(self) -> Optional[float]:
        """Clock reading at which :meth:`maybe_flush` will write, None if nothing is pending;
        a process wrapper can use it as its receive timeout."""
        if self._closed or self._chunk_n == 0:
            return None
        return self._chunk_opened + self._interval

    def flush(self) -> None:
        """Write the open chunk now (whatever its age) and flush the stream."""
        if not self._closed:
            self._close_chunk()
            self._sync()

    def set_metadata(self, name: str, data: Mapping[str, Any]) -> None:
        """Store a named string map (e.g. the run config) as an MCAP Metadata record.

        Non-str values are JSON-encoded.  Written and flushed at once (outside
        any chunk), so it survives a crash that comes right after.
        """
        if self._closed:
            raise ValueError("set_metadata() on a closed McapLog")
        record = Metadata(
            name=name,
            metadata={str(k): v if isinstance(v, str) else json.dumps(v, sort_keys=True, default=str) for k, v in data.items()},
        )
        offset = self._offset
        length = self._write_records(record)
        self._metadata_indexes.append(MetadataIndex(offset=offset, length=length, name=name))
        self._sync()

    # --- copying records (recorder.recover: salvage and compaction) ----------------------
    def add_schema(self, name: str, encoding: str, data: bytes) -> int:
        """Register a schema as is; returns its id (the same for the same name and encoding)."""
        return self._raw_schema_id(FoxSchema(name, encoding, bytes(data)))

    def add_channel(self, topic: str, message_encoding: str, schema_id: int, metadata: Mapping[str, str]) -> int:
        """Register a channel as is; returns its id."""
        return self._new_channel(topic, message_encoding, schema_id, dict(metadata))

    def add_message(self, channel_id: int, sequence: int, log_time: int, publish_time: int, data: bytes) -> None:
        """Append one message to a channel of :meth:`add_channel` (no envelope decoding, no
        mirrors); the chunk closes once it holds ``chunk_bytes``, before a message that would make
        its log times span ``chunk_span_ns`` or more, or on the timer when auto_flush."""
        if self._closed:
            raise ValueError("add_message() on a closed McapLog")
        span = self._chunk_span  # a chunk's messages, in whatever order, stay within a span of log time
        if span is not None and self._chunk_n and (log_time - self._chunk_start >= span
                                                    or self._chunk_end - log_time >= span):
            self._close_chunk()
        self._append(channel_id, sequence & _U32, log_time, publish_time, data)
        if len(self._chunk) >= self._chunk_bytes or (
                self._auto_flush and self._clock() - self._chunk_opened >= self._interval):
            self._close_chunk()

    def set_zstd_level(self, level: int) -> None:
        """Compress the chunks closed from now on at this zstd level (no effect without zstd)."""
        if self._compression_name == "zstd":
            self._compress = _compressor("zstd", level)

    def add_metadata(self, name: str, metadata: Mapping[str, str]) -> None:
        """A Metadata record with string values, as is."""
        self.set_metadata(name, dict(metadata))

    def add_attachment(self, record: Attachment) -> None:
        """An Attachment record, written outside chunks and indexed in the summary."""
        if self._closed:
            raise ValueError("add_attachment() on a closed McapLog")
        offset = self._offset
        length = self._write_records(record)
        self._attachment_indexes.append(AttachmentIndex(
            offset=offset, length=length, log_time=record.log_time, create_time=record.create_time,
            data_size=len(record.data), name=record.name, media_type=record.media_type))

    def close(self) -> None:
        """Write the last chunk, the summary section (schemas, channels, statistics,
        chunk and metadata indexes), the footer and the closing magic.  Idempotent."""
        if self._closed:
            return
        self._close_chunk()
        self._write_records(DataEnd(data_section_crc=0))  # 0: not computed, as Writer's default
        summary_start = self._offset
        summary = RecordBuilder()
        groups: list[SummaryOffset] = []

        def group(opcode: Opcode, records: list[McapRecord]) -> None:
            if not records:
                return
            start = summary.count
            for record in records:
                record.write(summary)
            groups.append(SummaryOffset(group_opcode=opcode, group_start=summary_start + start,
                                        group_length=summary.count - start))

        group(Opcode.SCHEMA, list(self._schemas))
        group(Opcode.CHANNEL, list(self._channels))
        group(Opcode.STATISTICS, [self._statistics()])
        group(Opcode.CHUNK_INDEX, list(self._chunk_indexes))
        group(Opcode.ATTACHMENT_INDEX, list(self._attachment_indexes))
        group(Opcode.METADATA_INDEX, list(self._metadata_indexes))
        summary_offset_start = summary_start + summary.count
        for offset_record in groups:
            offset_record.write(summary)
        data = summary.end()
        crc = zlib.crc32(data)
        # the footer CRC also covers the footer's own fields up to summary_crc
        crc = zlib.crc32(struct.pack("<BQQQ", Opcode.FOOTER, 8 + 8 + 4, summary_start, summary_offset_start), crc)
        self._stream.write(data)
        self._offset += len(data)
        self._write_records(Footer(summary_start=summary_start, summary_offset_start=summary_offset_start,
                                   summary_crc=crc))
        self._stream.write(MCAP_MAGIC)
        self._offset += len(MCAP_MAGIC)
        self._sync()
        self._closed = True
        if self._owned:
            self._stream.close()

    # --- statistics ------------------------------------------------------------------------
    def summary(self) -> LogSummary:
        """Counts so far: messages per key, per-(src, kind, incarnation) sequence stats, undecodable."""
        return LogSummary(
            messages=self._n_messages + self._chunk_n - self._mirror_messages,
            mirror_messages=self._mirror_messages,
            undecodable=self._undecodable,
            mirror_errors=self._mirror_errors,
            chunks=len(self._chunk_indexes),
            bytes_written=self._offset,
            channels={key: chan.count for key, chan in self._chans.items()},
            senders={k: replace(v) for k, v in self._senders.items()},
        )

    def _statistics(self) -> Statistics:
        return Statistics(
            attachment_count=len(self._attachment_indexes),
            channel_count=len(self._channels),
            channel_message_counts=dict(self._msg_counts),
            chunk_count=len(self._chunk_indexes),
            message_count=self._n_messages,
            message_end_time=self._time_max or 0,
            message_start_time=self._time_min or 0,
            metadata_count=len(self._metadata_indexes),
            schema_count=len(self._schemas),
        )

    # --- registry ------------------------------------------------------------------------------
    def _schema_id(self, name: str, schema: dict[str, Any]) -> int:
        sid = self._schema_ids.get((name, JSONSCHEMA_ENCODING))
        if sid is None:
            sid = len(self._schemas) + 1
            if sid > MAX_ID:
                raise ValueError("too many schemas for MCAP's uint16 ids")
            record = Schema(id=sid, name=name, encoding=JSONSCHEMA_ENCODING,
                            data=json.dumps(schema, separators=(",", ":")).encode())
            self._schemas.append(record)
            self._schema_ids[(name, JSONSCHEMA_ENCODING)] = sid
            self._chunk += _serialise(record)  # in the chunk, before its first user
        return sid

    def _raw_schema_id(self, schema: FoxSchema) -> int:
        sid = self._schema_ids.get((schema.name, schema.encoding))
        if sid is None:
            sid = len(self._schemas) + 1
            if sid > MAX_ID:
                raise ValueError("too many schemas for MCAP's uint16 ids")
            record = Schema(id=sid, name=schema.name, encoding=schema.encoding, data=schema.data)
            self._schemas.append(record)
            self._schema_ids[(schema.name, schema.encoding)] = sid
            self._chunk += _serialise(record)
        return sid

    def _new_channel(self, topic: str, encoding: str, schema_id: int, metadata: dict[str, str]) -> int:
        cid = len(self._channels) + 1
        if cid > MAX_ID:
            raise ValueError("too many channels (keys) for MCAP's uint16 ids")
        record = Channel(id=cid, topic=topic, message_encoding=encoding, metadata=metadata, schema_id=schema_id)
        self._channels.append(record)
        self._msg_counts[cid] = 0
        self._chunk += _serialise(record)
        return cid

    def _open_channel(self, key: str, kind: Optional[str]) -> _Chan:
        """Channel for a new key; the schema follows the first payload's kind, else the key's."""
        kind = kind if kind in KINDS else kind_from_key(key)
        sid = self._schema_id(SCHEMA_PREFIX + kind, bus_schema(kind))
        cid = self._new_channel(key, MSGPACK_ENCODING, sid, {META_KIND: kind})
        mirror = mirror_builder(kind) if self._mirrors else None
        chan = _Chan(id=cid, kind=kind, mirror=mirror)
        self._chans[key] = chan
        return chan

    def _write_mirror(self, key: str, chan: _Chan, body: dict, log_time: int, pub: int, seq: int) -> None:
        """Best effort: a body whose fields do not fit the mirror is only counted."""
        try:
            data = chan.mirror(body)  # type: ignore[misc]
        except Exception:  # KeyError, TypeError, ValueError, IndexError from odd bodies
            self._mirror_errors += 1
            return
        if chan.mirror_id == 0:
            sid = self._schema_id(MIRROR_SCHEMA_PREFIX + chan.kind, mirror_schema(chan.kind))
            chan.mirror_id = self._new_channel(MIRROR_PREFIX + key, JSON_ENCODING, sid,
                                               {META_KIND: chan.kind, META_MIRROR_OF: key})
        self._mirror_messages += 1
        self._append(chan.mirror_id, seq, log_time, pub, data)

    # --- chunks -----------------------------------------------------------------------------
    def _append(self, cid: int, seq: int, log_time: int, pub: int, data: bytes) -> None:
        """Add one Message record to the open chunk and index it; per-channel counts
        and file-wide times are folded in when the chunk closes (cheaper)."""
        head = _pack_message_head(_OP_MESSAGE, _MESSAGE_FIXED + len(data), cid, seq, log_time, pub)  # may raise
        chunk = self._chunk
        index = self._index.get(cid)
        if index is None:
            index = self._index[cid] = []
        index.append(log_time)
        index.append(len(chunk))
        chunk += head
        chunk += data
        if self._chunk_n:
            if log_time > self._chunk_end:
                self._chunk_end = log_time
            elif log_time < self._chunk_start:
                self._chunk_start = log_time
        else:
            self._chunk_opened = self._clock()
            self._chunk_start = self._chunk_end = log_time
        self._chunk_n += 1

    def _close_chunk(self) -> None:
        """Compress the open chunk, write Chunk + its MessageIndex records in one
        write() and flush them to the OS.  Schema/Channel records waiting in a
        chunk without messages stay for the next one (as mcap's Writer does)."""
        if self._chunk_n == 0:
            return
        raw = bytes(self._chunk)
        chunk = Chunk(
            compression=self._compression,
            data=self._compress(raw),
            message_start_time=self._chunk_start,
            message_end_time=self._chunk_end,
            uncompressed_crc=zlib.crc32(raw),
            uncompressed_size=len(raw),
        )
        builder = RecordBuilder()
        chunk.write(builder)
        chunk_length = builder.count
        parts = [builder.end()]
        chunk_offset = self._offset
        position = chunk_offset + chunk_length
        index_offsets: dict[int, int] = {}
        for cid, flat in self._index.items():
            self._msg_counts[cid] += len(flat) // 2
            body = struct.pack(f"<{len(flat)}Q", *flat)
            parts.append(_MESSAGE_INDEX_HEAD.pack(_OP_MESSAGE_INDEX, 2 + 4 + len(body), cid, len(body)))
            parts.append(body)
            index_offsets[cid] = position
            position += _MESSAGE_INDEX_HEAD.size + len(body)
        blob = b"".join(parts)
        self._stream.write(blob)
        self._offset += len(blob)
        self._chunk_indexes.append(ChunkIndex(
            message_start_time=chunk.message_start_time,
            message_end_time=chunk.message_end_time,
            chunk_start_offset=chunk_offset,
            chunk_length=chunk_length,
            message_index_offsets=index_offsets,
            message_index_length=len(blob) - chunk_length,
            compression=chunk.compression,
            compressed_size=len(chunk.data),
            uncompressed_size=chunk.uncompressed_size,
        ))
        self._n_messages += self._chunk_n
        start, end = chunk.message_start_time, chunk.message_end_time
        self._time_min = start if self._time_min is None else min(self._time_min, start)
        self._time_max = end if self._time_max is None else max(self._time_max, end)
        self._chunk = bytearray()
        self._index = {}
        self._chunk_n = 0
        self._sync()

    # --- output --------------------------------------------------------------------------------
    def _write_records(self, *records: McapRecord) -> int:
        builder = RecordBuilder()
        for record in records:
            record.write(builder)
        data = builder.end()
        self._stream.write(data)
        self._offset += len(data)
        return len(data)

    def _sync(self) -> None:
        self._stream.flush()
        if self._fsync:
            try:
                os.fsync(self._stream.fileno())
            except (AttributeError, OSError, ValueError):  # BytesIO & co have no file
                pass


def _serialise(record: McapRecord) -> bytes:
    """One record's bytes, through mcap's own ``write``."""
    builder = RecordBuilder()
    record.write(builder)
    return builder.end()
