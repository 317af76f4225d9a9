"""MCAP framing: the records of a file, chunks closed on a timer, the summary section.

:class:`McapWriter` knows nothing about the bus: it registers schemas and
channels, packs messages into an in-memory chunk, closes the chunk when it is
old (``flush_interval_s``), big (``chunk_bytes``) or spans too long
(``chunk_span_ns``), and writes the summary, footer and closing magic at
:meth:`McapWriter.close`.  :class:`recorder.mcap_log.McapLog` puts bus
messages into it; ``recorder.recover`` copies records through it.

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
hot records, ``Message`` and ``MessageIndex``, which :mod:`recorder.mcap_chunk`
packs with one precompiled :class:`struct.Struct` each, byte for byte as
``mcap.records.Message.write`` / ``MessageIndex.write`` lay them out (the
tests parse them back with mcap's readers).
"""

from __future__ import annotations

import os
import time
from typing import IO, Any, Callable, Mapping, Optional, Union

from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (
    Attachment,
    AttachmentIndex,
    Channel,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    McapRecord,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
)

from recorder.mcap_chunk import OpenChunk, summary_section
from truav import jsonio

__all__ = ["McapWriter", "Output"]

# --- format constants -----------------------------------------------------------
MCAP_MAGIC = b"\x89MCAP0\r\n"  # spec: 0x89 "MCAP" "0" "\r\n", at both ends of a file
MSGPACK_ENCODING = "msgpack"  # spelled out: older mcap.well_known lacks MessagePack
JSON_ENCODING = "json"
JSONSCHEMA_ENCODING = "jsonschema"
PROFILE = ""  # no MCAP profile fits a msgpack bus
LIBRARY = "truav-recorder/1"


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



class Registry:
    """The file's schemas and channels: ids handed out once, records put in the open chunk ahead of
    their first message, messages counted per channel for the Statistics record."""

    def __init__(self, chunk: OpenChunk) -> None:
        self._chunk = chunk
        self.channels: list[Channel] = []
        self.schemas: list[Schema] = []
        self._schema_ids: dict[tuple[str, str], int] = {}  # (name, encoding) -> id
        self.msg_counts: dict[int, int] = {}  # channel id -> messages (Statistics)

    def json_schema_id(self, name: str, schema: dict[str, Any]) -> int:
        """The id of a JSON Schema (registered, in the open chunk, on first use)."""
        sid = self._schema_ids.get((name, JSONSCHEMA_ENCODING))
        if sid is None:
            sid = len(self.schemas) + 1
            if sid > MAX_ID:
                raise ValueError("too many schemas for MCAP's uint16 ids")
            record = Schema(id=sid, name=name, encoding=JSONSCHEMA_ENCODING,
                            data=jsonio.dumps(schema, separators=(",", ":")).encode())
            self.schemas.append(record)
            self._schema_ids[(name, JSONSCHEMA_ENCODING)] = sid
            self._chunk.add_record(record)  # in the chunk, before its first user
        return sid

    def add_schema(self, name: str, encoding: str, data: bytes) -> int:
        """Register a schema as is; returns its id (the same for the same name and encoding)."""
        sid = self._schema_ids.get((name, encoding))
        if sid is None:
            sid = len(self.schemas) + 1
            if sid > MAX_ID:
                raise ValueError("too many schemas for MCAP's uint16 ids")
            record = Schema(id=sid, name=name, encoding=encoding, data=bytes(data))
            self.schemas.append(record)
            self._schema_ids[(name, encoding)] = sid
            self._chunk.add_record(record)
        return sid

    def add_channel(self, topic: str, message_encoding: str, schema_id: int, metadata: Mapping[str, str]) -> int:
        """Register a channel as is; returns its id."""
        cid = len(self.channels) + 1
        if cid > MAX_ID:
            raise ValueError("too many channels (keys) for MCAP's uint16 ids")
        record = Channel(id=cid, topic=topic, message_encoding=message_encoding, metadata=dict(metadata),
                         schema_id=schema_id)
        self.channels.append(record)
        self.msg_counts[cid] = 0
        self._chunk.add_record(record)
        return cid


class McapWriter:
    """Append-only MCAP framing that survives SIGKILL minus ~flush_interval_s.

    ``output`` is a path (opened, owned and closed here) or a writable binary
    stream (flushed, never closed; offsets count from its current position).

    Durability: messages accumulate in an in-memory chunk; the chunk is
    compressed, written and ``flush()``-ed to the OS once its oldest message is
    ``flush_interval_s`` old (checked by :meth:`close_chunk_if_due` when
    ``auto_flush``, and by :meth:`maybe_flush`, which the process wrapper must
    also call from a timer so a quiet bus does not strand a chunk), or once it
    holds ``chunk_bytes``.  Data handed to the OS survives the death of the
    process; ``fsync=True`` also makes it survive a power cut, at a syscall per
    chunk.  A file whose writer died has no summary: ``recorder.recover``
    finishes it.  Not thread-safe.
    """

    def __init__(
        self,
        output: Output,
        *,
        compression: str = DEFAULT_COMPRESSION,
        flush_interval_s: float = DEFAULT_FLUSH_INTERVAL_S,
        chunk_bytes: int = DEFAULT_CHUNK_BYTES,
        chunk_span_ns: Optional[int] = None,
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
        self.closed = False  # a plain attribute: McapLog reads it per message
        self._open = OpenChunk(clock)
        self._registry = Registry(self._open)
        self.append = self._open.append  # the hot path: one bound method, no indirection
        # summary section material
        self._chunk_indexes: list[ChunkIndex] = []
        self._metadata_indexes: list[MetadataIndex] = []
        self._attachment_indexes: list[AttachmentIndex] = []
        self._n_messages = 0  # in written chunks; the open chunk holds _open.n more
        self._time_min: Optional[int] = None  # over written chunks
        self._time_max: Optional[int] = None
        self._stream.write(MCAP_MAGIC)
        self._offset += len(MCAP_MAGIC)
        self._write_records(Header(profile=PROFILE, library=library))
        self._stream.flush()

    @property
    def messages(self) -> int:
        """Message records so far, in written chunks and in the open one."""
        return self._n_messages + self._open.n

    @property
    def chunks(self) -> int:
        """Chunks written."""
        return len(self._chunk_indexes)

    @property
    def bytes_written(self) -> int:
        return self._offset

    def log_time_range(self) -> tuple[Optional[int], Optional[int]]:
        """(first, last) log time of the messages so far, the open chunk's included; (None, None) if none."""
        lo, hi = self._time_min, self._time_max
        if self._open.n:
            lo = self._open.start if lo is None else min(lo, self._open.start)
            hi = self._open.end if hi is None else max(hi, self._open.end)
        return lo, hi

    # --- registry ------------------------------------------------------------------------------
    def json_schema_id(self, name: str, schema: dict[str, Any]) -> int:
        """The id of a JSON Schema (registered, in the open chunk, on first use)."""
        return self._registry.json_schema_id(name, schema)

    def add_schema(self, name: str, encoding: str, data: bytes) -> int:
        """Register a schema as is; returns its id (the same for the same name and encoding)."""
        return self._registry.add_schema(name, encoding, data)

    def add_channel(self, topic: str, message_encoding: str, schema_id: int, metadata: Mapping[str, str]) -> int:
        """Register a channel as is; returns its id."""
        return self._registry.add_channel(topic, message_encoding, schema_id, metadata)

    # --- messages (append: OpenChunk.append, bound in __init__) -------------------------------
    def close_chunk_if_due(self) -> None:
        """When auto_flush: close the open chunk once it holds ``chunk_bytes`` or is ``flush_interval_s`` old."""
        if self._auto_flush and (
            len(self._open.data) >= self._chunk_bytes or self._clock() - self._open.opened >= self._interval
        ):
            self._close_chunk()

    def add_message(self, channel_id: int, sequence: int, log_time: int, publish_time: int, data: bytes) -> None:
        """Append one message to a channel of :meth:`add_channel` (no envelope decoding, no
        mirrors); the chunk closes once it holds ``chunk_bytes``, before a message that would make
        its log times span ``chunk_span_ns`` or more, or on the timer when auto_flush."""
        if self.closed:
            raise ValueError("add_message() on a closed McapLog")
        span = self._chunk_span  # a chunk's messages, in whatever order, stay within a span of log time
        chunk = self._open
        if span is not None and chunk.n and (log_time - chunk.start >= span or chunk.end - log_time >= span):
            self._close_chunk()
        self.append(channel_id, sequence & _U32, log_time, publish_time, data)
        if len(chunk.data) >= self._chunk_bytes or (
                self._auto_flush and self._clock() - chunk.opened >= self._interval):
            self._close_chunk()

    def set_zstd_level(self, level: int) -> None:
        """Compress the chunks closed from now on at this zstd level (no effect without zstd)."""
        if self._compression_name == "zstd":
            self._compress = _compressor("zstd", level)

    # --- flushing -----------------------------------------------------------------------------
    def maybe_flush(self, now: Optional[float] = None) -> bool:
        """Close and flush the open chunk if its oldest message is ``flush_interval_s`` old.

        ``now`` is a reading of the ``clock`` given to the constructor (default
        :func:`time.monotonic`).  Returns True when a chunk was written.  Call it
        every few tens of ms from the recorder loop even when no message arrives.
        """
        if self.closed or self._open.n == 0:
            return False
        if (self._clock() if now is None else now) - self._open.opened < self._interval:
            return False
        self._close_chunk()
        return True

    def next_flush_due(self) -> Optional[float]:
        """Clock reading at which :meth:`maybe_flush` will write, None if nothing is pending;
        a process wrapper can use it as its receive timeout."""
        if self.closed or self._open.n == 0:
            return None
        return self._open.opened + self._interval

    def flush(self) -> None:
        """Write the open chunk now (whatever its age) and flush the stream."""
        if not self.closed:
            self._close_chunk()
            self._sync()

    # --- records outside chunks ---------------------------------------------------------------
    def set_metadata(self, name: str, data: Mapping[str, Any]) -> None:
        """Store a named string map (e.g. the run config) as an MCAP Metadata record.

        Non-str values are JSON-encoded.  Written and flushed at once (outside
        any chunk), so it survives a crash that comes right after.
        """
        if self.closed:
            raise ValueError("set_metadata() on a closed McapLog")
        record = Metadata(
            name=name,
            metadata={str(k): v if isinstance(v, str) else jsonio.dumps(v, sort_keys=True, default=str) for k, v in data.items()},
        )
        offset = self._offset
        length = self._write_records(record)
        self._metadata_indexes.append(MetadataIndex(offset=offset, length=length, name=name))
        self._sync()

    def add_metadata(self, name: str, metadata: Mapping[str, str]) -> None:
        """A Metadata record with string values, as is."""
        self.set_metadata(name, dict(metadata))

    def add_attachment(self, record: Attachment) -> None:
        """An Attachment record, written outside chunks and indexed in the summary."""
        if self.closed:
            raise ValueError("add_attachment() on a closed McapLog")
        offset = self._offset
        length = self._write_records(record)
        self._attachment_indexes.append(AttachmentIndex(
            offset=offset, length=length, log_time=record.log_time, create_time=record.create_time,
            data_size=len(record.data), name=record.name, media_type=record.media_type))

    def close(self) -> None:
        """Write the last chunk, the summary section (schemas, channels, statistics,
        chunk and metadata indexes), the footer and the closing magic.  Idempotent."""
        if self.closed:
            return
        self._close_chunk()
        self._write_records(DataEnd(data_section_crc=0))  # 0: not computed, as Writer's default
        summary_start = self._offset
        data, summary_offset_start, crc = summary_section(summary_start, [
            (Opcode.SCHEMA, list(self._registry.schemas)),
            (Opcode.CHANNEL, list(self._registry.channels)),
            (Opcode.STATISTICS, [self._statistics()]),
            (Opcode.CHUNK_INDEX, list(self._chunk_indexes)),
            (Opcode.ATTACHMENT_INDEX, list(self._attachment_indexes)),
            (Opcode.METADATA_INDEX, list(self._metadata_indexes)),
        ])
        self._stream.write(data)
        self._offset += len(data)
        self._write_records(Footer(summary_start=summary_start, summary_offset_start=summary_offset_start,
                                   summary_crc=crc))
        self._stream.write(MCAP_MAGIC)
        self._offset += len(MCAP_MAGIC)
        self._sync()
        self.closed = True
        if self._owned:
            self._stream.close()

    def _statistics(self) -> Statistics:
        return Statistics(
            attachment_count=len(self._attachment_indexes),
            channel_count=len(self._registry.channels),
            channel_message_counts=dict(self._registry.msg_counts),
            chunk_count=len(self._chunk_indexes),
            message_count=self._n_messages,
            message_end_time=self._time_max or 0,
            message_start_time=self._time_min or 0,
            metadata_count=len(self._metadata_indexes),
            schema_count=len(self._registry.schemas),
        )

    # --- chunks -----------------------------------------------------------------------------
    def _close_chunk(self) -> None:
        """Compress the open chunk, write Chunk + its MessageIndex records in one
        write() and flush them to the OS.  Schema/Channel records waiting in a
        chunk without messages stay for the next one (as mcap's Writer does)."""
        if self._open.n == 0:
            return
        blob, entry = self._open.seal(self._compression, self._compress, self._offset, self._registry.msg_counts)
        self._stream.write(blob)
        self._offset += len(blob)
        self._chunk_indexes.append(entry)
        self._n_messages += self._open.n
        start, end = entry.message_start_time, entry.message_end_time
        self._time_min = start if self._time_min is None else min(self._time_min, start)
        self._time_max = end if self._time_max is None else max(self._time_max, end)
        self._open.reset()
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
