"""Read TRUAV MCAP logs back as ``(key, payload, log_time, publish_time)``.

A finished file (footer + closing magic) is read through mcap's
:func:`mcap.reader.make_reader`, which uses the summary's chunk indexes.  A
file whose recorder died has no summary; it is read with mcap's
:class:`mcap.stream_reader.StreamReader` over its *valid prefix*:

* :func:`probe` walks the top-level record framing (opcode + uint64 length)
  and stops at the first record that runs past the end of the file (the torn
  tail a killed writer leaves).  Checking the framing first matters because
  ``StreamReader`` does not notice a short read inside a record: a cut
  ``Chunk`` would come back with short data instead of an error.
* :func:`iter_salvaged_records` then streams records out of exactly that
  prefix, breaking chunks up with CRC validation and skipping (counting) any
  chunk that fails it.

The JSON mirror channels (``/json/...``) are skipped unless asked for.
Time bounds are applied here rather than passed to mcap, whose bound
arguments changed names between releases (``start_time`` -> ``starting_at``).
"""

from __future__ import annotations

import contextlib
import io
import os
import struct
from dataclasses import dataclass
from fnmatch import fnmatchcase
from typing import IO, Iterable, Iterator, NamedTuple, Optional, Sequence, Union

from mcap.exceptions import EndOfFile
from mcap.opcode import Opcode
from mcap.reader import McapReader, make_reader
from mcap.records import Channel, Chunk, DataEnd, McapRecord, Message, Metadata, Schema
from mcap.stream_reader import StreamReader, breakup_chunk
from mcap.summary import Summary

from recorder.mcap_log import MCAP_MAGIC, is_mirror_topic

Source = Union[str, "os.PathLike[str]", IO[bytes]]
Patterns = Union[str, Sequence[str], None]

_RECORD_HEAD = struct.Struct("<BQ")  # opcode, record length
_FOOTER_LENGTH = 8 + 8 + 4  # summary_start, summary_offset_start, summary_crc
_FOOTER_TAIL = _RECORD_HEAD.size + _FOOTER_LENGTH + len(MCAP_MAGIC)


class RecordedMessage(NamedTuple):
    """One recorded bus message; unpacks as ``key, payload, log_time, publish_time``."""

    key: str
    payload: bytes
    log_time: int  # receive time, ns
    publish_time: int  # sender's envelope t (receive time if it had none), ns


@dataclass(frozen=True)
class FileState:
    """Where the readable part of an MCAP file ends."""

    size: int
    finished: bool  # footer and closing magic present: a summary can be used
    valid_end: int  # offset just past the last complete top-level record

    @property
    def torn_bytes(self) -> int:
        """Bytes after the last complete record: a half-written chunk, typically."""
        return 0 if self.finished else self.size - self.valid_end


@dataclass
class SalvageStats:
    """Filled in by :func:`iter_salvaged_records` while it runs."""

    corrupt_chunks: int = 0  # chunks skipped: CRC mismatch or undecompressable
    error: Optional[str] = None  # why reading stopped before valid_end, if it did
    records: int = 0  # records yielded


def probe(stream: IO[bytes]) -> FileState:
    """Find whether ``stream`` (seekable, MCAP from offset 0) is finished, and if
    not, where its last complete record ends.  Raises ValueError if not MCAP."""
    stream.seek(0, io.SEEK_END)
    size = stream.tell()
    stream.seek(0)
    if stream.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
        raise ValueError("not an MCAP file (bad leading magic)")
    if size >= len(MCAP_MAGIC) + _FOOTER_TAIL:
        stream.seek(size - _FOOTER_TAIL)
        tail = stream.read(_FOOTER_TAIL)
        opcode, length = _RECORD_HEAD.unpack_from(tail)
        if opcode == Opcode.FOOTER and length == _FOOTER_LENGTH and tail.endswith(MCAP_MAGIC):
            return FileState(size=size, finished=True, valid_end=size)
    position = len(MCAP_MAGIC)
    while True:
        stream.seek(position)
        head = stream.read(_RECORD_HEAD.size)
        if len(head) < _RECORD_HEAD.size:
            break
        opcode, length = _RECORD_HEAD.unpack(head)
        end = position + _RECORD_HEAD.size + length
        # opcode 0 is invalid in MCAP: zero-filled space after a crash, not a record
        if opcode == 0 or end > size:
            break
        position = end
        if opcode == Opcode.FOOTER:
            break
    return FileState(size=size, finished=False, valid_end=position)


class _Prefix(io.RawIOBase):
    """The first ``limit`` bytes of a stream, so StreamReader never sees the torn tail."""

    def __init__(self, raw: IO[bytes], limit: int) -> None:
        super().__init__()
        self._raw = raw
        self._left = limit

    def readable(self) -> bool:
        return True

    def readinto(self, buffer: "bytearray | memoryview") -> int:  # type: ignore[override]
        n = min(len(buffer), self._left)
        if n <= 0:
            return 0
        data = self._raw.read(n)
        buffer[: len(data)] = data
        self._left -= len(data)
        return len(data)


def iter_salvaged_records(
    stream: IO[bytes], state: FileState, stats: Optional[SalvageStats] = None
) -> Iterator[McapRecord]:
    """Data-section records (Header, Schema, Channel, Message, Metadata,
    Attachment...) of the valid prefix, chunks broken up; stops at DataEnd so a
    finished file's summary is not read as data."""
    stats = stats if stats is not None else SalvageStats()
    stream.seek(0)
    records = StreamReader(_Prefix(stream, state.valid_end), emit_chunks=True).records
    while True:
        try:
            record = next(records)
        except (StopIteration, EndOfFile):
            return
        except Exception as exc:  # a record that parses as garbage: keep what came before
            stats.error = f"{type(exc).__name__}: {exc}"
            return
        if isinstance(record, DataEnd):
            return
        if isinstance(record, Chunk):
            try:
                inner = breakup_chunk(record, validate_crc=True)
            except Exception:  # CRCValidationError, ZstdError, lz4 RuntimeError, ...
                stats.corrupt_chunks += 1
                continue
            stats.records += len(inner)
            yield from inner
        else:
            stats.records += 1
            yield record


class TopicFilter:
    """Glob include/exclude over topics (``fnmatch``: ``*`` also matches ``/``),
    mirrors off by default; memoised per topic since channels are few."""

    def __init__(self, include: Patterns = None, exclude: Patterns = None, include_mirrors: bool = False) -> None:
        self._include = _patterns(include)
        self._exclude = _patterns(exclude) or ()
        self._mirrors = include_mirrors
        self._memo: dict[str, bool] = {}

    def __call__(self, topic: str) -> bool:
        hit = self._memo.get(topic)
        if hit is None:
            hit = (
                (self._mirrors or not is_mirror_topic(topic))
                and (self._include is None or any(fnmatchcase(topic, p) for p in self._include))
                and not any(fnmatchcase(topic, p) for p in self._exclude)
            )
            self._memo[topic] = hit
        return hit


def _patterns(patterns: Patterns) -> Optional[tuple[str, ...]]:
    if patterns is None:
        return None
    return (patterns,) if isinstance(patterns, str) else tuple(patterns)


@contextlib.contextmanager
def open_source(source: Source) -> Iterator[IO[bytes]]:
    """A path is opened (and closed); a stream is used as is (must be seekable)."""
    if isinstance(source, (str, os.PathLike)):
        with open(source, "rb") as f:
            yield f
    else:
        yield source


def _indexed_reader(stream: IO[bytes]) -> Optional[tuple[McapReader, Summary]]:
    """mcap's reader and the summary of a finished file, or None if the summary is
    missing, has no chunk index, or is unreadable (then we stream instead)."""
    stream.seek(0)
    try:
        reader = make_reader(stream)
        summary = reader.get_summary()
    except Exception:  # a corrupt summary section
        return None
    if summary is None or not summary.chunk_indexes:
        return None
    return reader, summary


def iter_messages(
    source: Source,
    include: Patterns = None,
    exclude: Patterns = None,
    start_ns: Optional[int] = None,
    end_ns: Optional[int] = None,
    *,
    include_mirrors: bool = False,
) -> Iterator[RecordedMessage]:
    """Messages in file order (= arrival order), finished file or not.

    ``include``/``exclude`` are glob patterns over keys; ``start_ns`` is an
    inclusive and ``end_ns`` an exclusive bound on the receive time.
    """
    keep = TopicFilter(include, exclude, include_mirrors)
    with open_source(source) as stream:
        state = probe(stream)
        indexed = _indexed_reader(stream) if state.finished else None
        if indexed is not None:
            messages = _indexed(*indexed, keep)
        else:
            messages = _salvaged(stream, state, keep)
        for message in messages:
            if (start_ns is None or message.log_time >= start_ns) and (end_ns is None or message.log_time < end_ns):
                yield message


def _indexed(reader: McapReader, summary: Summary, keep: TopicFilter) -> Iterator[RecordedMessage]:
    topics = {c.topic for c in summary.channels.values() if keep(c.topic)}
    if not topics:
        return
    for _, channel, message in reader.iter_messages(topics=topics, log_time_order=False):
        yield RecordedMessage(channel.topic, message.data, message.log_time, message.publish_time)


def _salvaged(stream: IO[bytes], state: FileState, keep: TopicFilter) -> Iterator[RecordedMessage]:
    channels: dict[int, Channel] = {}
    for record in iter_salvaged_records(stream, state):
        if isinstance(record, Message):
            channel = channels.get(record.channel_id)
            if channel is not None and keep(channel.topic):
                yield RecordedMessage(channel.topic, record.data, record.log_time, record.publish_time)
        elif isinstance(record, Channel):
            channels[record.id] = record


def read_metadata(source: Source) -> dict[str, dict[str, str]]:
    """Metadata records by name (a later record of the same name wins)."""
    out: dict[str, dict[str, str]] = {}
    with open_source(source) as stream:
        state = probe(stream)
        indexed = _indexed_reader(stream) if state.finished else None
        if indexed is not None:
            records: Iterable[McapRecord] = indexed[0].iter_metadata()
        else:
            records = iter_salvaged_records(stream, state)
        for record in records:
            if isinstance(record, Metadata):
                out[record.name] = dict(record.metadata)
    return out


def read_schemas(source: Source) -> dict[str, Schema]:
    """Schema of every channel, by topic (mirrors included), e.g. to decode JSON mirrors."""
    schemas: dict[int, Schema] = {}
    topics: dict[str, int] = {}
    with open_source(source) as stream:
        state = probe(stream)
        indexed = _indexed_reader(stream) if state.finished else None
        if indexed is not None:
            summary = indexed[1]
            schemas.update(summary.schemas)
            topics = {c.topic: c.schema_id for c in summary.channels.values()}
        else:
            for record in iter_salvaged_records(stream, state):
                if isinstance(record, Schema):
                    schemas[record.id] = record
                elif isinstance(record, Channel):
                    topics[record.topic] = record.schema_id
    return {topic: schemas[sid] for topic, sid in topics.items() if sid in schemas}
