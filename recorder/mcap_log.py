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

The pieces, each in its own module: :class:`recorder.mcap_writer.McapWriter`
frames the file (records, chunks closed on a timer, the summary; why it does
not use :class:`mcap.writer.Writer` is said there),
:class:`recorder.mirror_channels.MirrorChannels` writes the JSON and Foxglove
mirrors, :class:`recorder.seq_stats.SenderStats` counts the per-sender
sequence statistics.  :class:`McapLog` decodes each envelope once and hands it
to the three.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Optional, Union

from mcap.records import Attachment

from recorder.foxglove import FoxgloveMirror, Out
from recorder.mcap_writer import (  # noqa: F401  (re-exported: process, reader and the tests import them from here)
    COMPACT_CHUNK_BYTES,
    COMPACT_CHUNK_SPAN_NS,
    COMPACT_FAST_ZSTD_LEVEL,
    COMPACT_STRONG_BUDGET_S,
    COMPACT_ZSTD_LEVEL,
    COMPRESSIONS,
    DEFAULT_CHUNK_BYTES,
    DEFAULT_COMPRESSION,
    DEFAULT_FLUSH_INTERVAL_S,
    DEFAULT_ZSTD_LEVEL,
    JSON_ENCODING,
    JSONSCHEMA_ENCODING,
    LIBRARY,
    MAX_ID,
    MCAP_MAGIC,
    MSGPACK_ENCODING,
    PROFILE,
    McapWriter,
    Output,
)
from recorder.mirror_channels import (  # noqa: F401  (the naming constants: re-exported)
    META_KIND, META_MIRROR_OF, MIRROR_PREFIX, KeyChannel, MirrorChannels, is_mirror_topic)
from recorder.schemas import KINDS, SCHEMA_PREFIX, Envelope, bus_schema, decode_envelope, envelope_fields, \
    kind_from_key, mirror_builder
from recorder.seq_stats import MAX_TRACKED_SENDERS, OTHER_SENDERS, SenderStats, SeqStats  # noqa: F401

__all__ = ["McapLog", "LogSummary", "SeqStats", "Envelope", "decode_envelope"]

_U32 = 0xFFFFFFFF


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
        # True: the default scene geometry; the recorder process passes one built from the run config
        fox: Optional[FoxgloveMirror] = (FoxgloveMirror() if foxglove is True else foxglove or None) \
            if mirrors else None
        self._writer_args = dict(compression=compression, flush_interval_s=flush_interval_s, chunk_bytes=chunk_bytes,
                                 chunk_span_ns=chunk_span_ns, auto_flush=auto_flush, fsync=fsync,
                                 zstd_level=zstd_level, clock=clock, library=library)
        self._mirrors = mirrors
        self._fox = fox
        self._fox_kinds = fox.KINDS if fox is not None else frozenset()
        # the streams' figures run on across rotate(): callbacks reach whichever file is open
        self._stats = SenderStats(*((lambda *a: self._mirror.joined(*a), lambda *a: self._mirror.lost(*a))
                                    if fox is not None else ()))
        self._observe = self._stats.observe
        self._undecodable = 0
        self._earlier = LogSummary()  # the files finished by rotate(): their counts
        self._open_file(output)

    def _open_file(self, output: Output) -> None:
        """A new file: its writer, mirrors and channel table (channels are declared again on first use)."""
        self._writer = writer = McapWriter(output, **self._writer_args)
        self._append = writer.append
        self._close_chunk_if_due = writer.close_chunk_if_due
        self._mirror = MirrorChannels(writer, self._fox)
        self._chans: dict[str, KeyChannel] = {}

    def rotate(self, output: Output) -> None:
        """Finish the current file (summary, footer) and go on writing into ``output``: a
        self-contained file of its own (schemas and channels declared again, metadata as the
        caller sets it); :meth:`summary` keeps counting over both."""
        this = self._file_summary()
        self._writer.close()
        earlier = self._earlier
        for name in ("messages", "mirror_messages", "mirror_errors", "chunks", "bytes_written"):
            setattr(earlier, name, getattr(earlier, name) + getattr(this, name))
        for key, n in this.channels.items():
            earlier.channels[key] = earlier.channels.get(key, 0) + n
        self._open_file(output)

    @property
    def bytes_on_disk(self) -> int:
        """Bytes of the current file handed to the OS so far (closed chunks, metadata; the open chunk
        not yet: it is compressed when it closes)."""
        return self._writer.bytes_written

    def log_time_range(self) -> tuple[Optional[int], Optional[int]]:
        """(first, last) log time in the current file, (None, None) before its first message."""
        return self._writer.log_time_range()

    # --- context manager -------------------------------------------------------------
    def __enter__(self) -> "McapLog":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def closed(self) -> bool:
        return self._writer.closed

    # --- writing ------------------------------------------------------------------------
    def write(self, key: str, payload: bytes, log_time_ns: int, publish_time_ns: Optional[int] = None) -> None:
        """Record one bus message received at ``log_time_ns`` (wall clock, ns).

        ``publish_time_ns`` defaults to the envelope's ``t`` (or the receive
        time when the payload is undecodable).  Raises ``struct.error`` for
        times outside uint64 and ValueError once closed.
        """
        if self._writer.closed:
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
            self._observe(src, kind, inc, seq, log_time_ns, pub)  # see SeqStats
            if chan.mirror is not None and kind == chan.kind:
                self._mirror.write_json(key, chan, body, log_time_ns, pub, seq & _U32)
            if kind in self._fox_kinds and kind == chan.kind:
                self._mirror.feed_foxglove(kind, body, log_time_ns, pub)
        self._close_chunk_if_due()

    def skip(self, payload: bytes) -> None:
        """A message not written on purpose (the recorder is paused): the per-sender counts move past its
        seq (:meth:`recorder.seq_stats.SenderStats.skip`), so the pause is not counted as a sequence gap."""
        env = envelope_fields(payload)
        if env is not None:
            kind, src, seq, _t, _body, inc = env
            self._stats.skip(src, kind, inc, seq)

    def write_foxglove(self, out: Out, log_time_ns: int, publish_time_ns: Optional[int] = None) -> None:
        """Record one Foxglove mirror message (channel and schema made on first use)."""
        if self._writer.closed:
            raise ValueError("write_foxglove() on a closed McapLog")
        self._mirror.write_foxglove(out, log_time_ns, publish_time_ns)

    def maybe_flush(self, now: Optional[float] = None) -> bool:
        """Close and flush the open chunk if its oldest message is ``flush_interval_s`` old
        (see :meth:`McapWriter.maybe_flush`); True when a chunk was written."""
        return self._writer.maybe_flush(now)

    def next_flush_due(self) -> Optional[float]:
        """Clock reading at which :meth:`maybe_flush` will write, None if nothing is pending."""
        return self._writer.next_flush_due()

    def flush(self) -> None:
        """Write the open chunk now (whatever its age) and flush the stream."""
        self._writer.flush()

    def set_metadata(self, name: str, data: Mapping[str, Any]) -> None:
        """Store a named string map (e.g. the run config) as an MCAP Metadata record, flushed at once."""
        self._writer.set_metadata(name, data)

    # --- copying records (tests; recorder.recover uses McapWriter itself) -------------------
    def add_schema(self, name: str, encoding: str, data: bytes) -> int:
        """Register a schema as is; returns its id (the same for the same name and encoding)."""
        return self._writer.add_schema(name, encoding, data)

    def add_channel(self, topic: str, message_encoding: str, schema_id: int, metadata: Mapping[str, str]) -> int:
        """Register a channel as is; returns its id."""
        return self._writer.add_channel(topic, message_encoding, schema_id, metadata)

    def add_message(self, channel_id: int, sequence: int, log_time: int, publish_time: int, data: bytes) -> None:
        """Append one message to a channel of :meth:`add_channel` (no envelope decoding, no mirrors)."""
        self._writer.add_message(channel_id, sequence, log_time, publish_time, data)

    def set_zstd_level(self, level: int) -> None:
        """Compress the chunks closed from now on at this zstd level (no effect without zstd)."""
        self._writer.set_zstd_level(level)

    def add_metadata(self, name: str, metadata: Mapping[str, str]) -> None:
        """A Metadata record with string values, as is."""
        self._writer.add_metadata(name, metadata)

    def add_attachment(self, record: Attachment) -> None:
        """An Attachment record, written outside chunks and indexed in the summary."""
        self._writer.add_attachment(record)

    def close(self) -> None:
        """Write the last chunk, the summary section, the footer and the closing magic.  Idempotent."""
        self._writer.close()

    # --- statistics ------------------------------------------------------------------------
    def summary(self) -> LogSummary:
        """Counts so far (over every file since :meth:`rotate`): messages per key,
        per-(src, kind, incarnation) sequence stats, undecodable."""
        this, earlier = self._file_summary(), self._earlier
        for name in ("messages", "mirror_messages", "mirror_errors", "chunks", "bytes_written"):
            setattr(this, name, getattr(earlier, name) + getattr(this, name))
        for key, n in earlier.channels.items():
            this.channels[key] = this.channels.get(key, 0) + n
        this.undecodable = self._undecodable
        this.senders = self._stats.snapshot()
        return this

    def _file_summary(self) -> LogSummary:
        writer, mirror = self._writer, self._mirror
        return LogSummary(
            messages=writer.messages - mirror.messages,
            mirror_messages=mirror.messages,
            mirror_errors=mirror.errors,
            chunks=writer.chunks,
            bytes_written=writer.bytes_written,
            channels={key: chan.count for key, chan in self._chans.items()},
        )

    # --- registry ------------------------------------------------------------------------------
    def _open_channel(self, key: str, kind: Optional[str]) -> KeyChannel:
        """Channel for a new key; the schema follows the first payload's kind, else the key's."""
        kind = kind if kind in KINDS else kind_from_key(key)
        sid = self._writer.json_schema_id(SCHEMA_PREFIX + kind, bus_schema(kind))
        cid = self._writer.add_channel(key, MSGPACK_ENCODING, sid, {META_KIND: kind})
        mirror = mirror_builder(kind) if self._mirrors else None
        chan = KeyChannel(id=cid, kind=kind, mirror=mirror)
        self._chans[key] = chan
        return chan
