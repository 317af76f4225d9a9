"""Read TRUAV MCAP logs back as ``(key, payload, log_time, publish_time)``.

Every read goes through :mod:`recorder.mcap_guard` (bounded record lengths and decompression, CRC-checked
chunks, validated schemas, channels, messages and metadata), finished file or not:

* :func:`probe` walks the top-level record framing (opcode + uint64 length)
  and stops at the first record that runs past the end of the file (the torn
  tail a killed writer leaves); a finished file (footer + closing magic) is
  read up to its summary.
* :func:`iter_salvaged_records` then streams records out of exactly that
  prefix, breaking chunks up with CRC validation and skipping (counting, in a
  :class:`SalvageStats`) any chunk or record that fails.

:func:`iter_messages`, :func:`read_metadata` and :func:`read_schemas` raise
:class:`recorder.mcap_guard.DamagedRecording` (one line naming the file and the
first bad record) at the first damage unless given a ``damage`` to fill in;
`truav log check`, ``info`` and ``recover`` read leniently and report it.
The JSON mirror channels (``/json/...``) are skipped unless asked for.
"""

from __future__ import annotations

import contextlib
import io
import os
import struct
from dataclasses import dataclass
from fnmatch import fnmatchcase
from typing import IO, Iterator, NamedTuple, Optional, Sequence, Union

from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, DataEnd, Footer, McapRecord, Message, Metadata, Schema

from recorder.mcap_guard import DATA_ONLY, DamagedRecording, Malformed, ReadDamage, Validator, chunk_records, walk
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


SalvageStats = ReadDamage
"""What a lenient read left out (corrupt chunks, invalid records, notes naming them); see recorder.mcap_guard."""


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


def iter_salvaged_records(
    stream: IO[bytes], state: FileState, stats: Optional[SalvageStats] = None
) -> Iterator[McapRecord]:
    """Data-section records (Header, Schema, Channel, Message, Metadata,
    Attachment...) of the valid prefix, chunks broken up, every one checked
    (:mod:`recorder.mcap_guard`); what fails is counted in ``stats`` and left
    out. Stops at DataEnd so a finished file's summary is not read as data."""
    stats = stats if stats is not None else SalvageStats()
    check = Validator(stats)
    summary_at = None
    for offset, _, record in walk(stream, len(MCAP_MAGIC), state.valid_end, stats, skip=_NOT_DATA):
        if isinstance(record, DataEnd):
            summary_at = stream.tell()  # just past DataEnd: walk() read exactly its body
            break
        if isinstance(record, Footer):
            break
        if isinstance(record, Chunk):
            try:
                inner = chunk_records(record)
            except Malformed as exc:
                stats.chunk(offset, str(exc))
                continue
            for item in inner:
                if check(item, offset):
                    stats.records += 1
                    yield item
        elif record is not None and check(record, offset):
            stats.records += 1
            yield record
    # What follows DataEnd is the summary: data hidden there (a forged DataEnd) is damage, not silence.
    if summary_at is None:
        return
    for offset, opcode, _ in walk(stream, summary_at, state.valid_end, stats, skip=_ANY):
        if opcode in DATA_ONLY:
            stats.invalid(f"{Opcode(opcode).name.lower()} record at offset {offset}, after the data section's end")


_ANY = frozenset(range(256))
_NOT_DATA = frozenset({Opcode.MESSAGE_INDEX, Opcode.CHUNK_INDEX, Opcode.ATTACHMENT_INDEX, Opcode.METADATA_INDEX,
                       Opcode.STATISTICS, Opcode.SUMMARY_OFFSET})


def _checked(records: Iterator[McapRecord], stats: SalvageStats, strict: bool,
             source: "Source") -> Iterator[McapRecord]:
    """``records``; when ``strict``, DamagedRecording at the first damage."""
    for record in records:
        if strict and stats.damaged:
            break
        yield record
    if strict and stats.damaged:
        name = os.fspath(source) if isinstance(source, (str, os.PathLike)) else "<stream>"
        raise DamagedRecording(f"{name}: damaged recording: {stats.describe()}; `truav log check {name}` "
                               f"shows it, `truav log recover {name} FIXED.mcap` keeps what is sound")


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


def iter_messages(
    source: Source,
    include: Patterns = None,
    exclude: Patterns = None,
    start_ns: Optional[int] = None,
    end_ns: Optional[int] = None,
    *,
    include_mirrors: bool = False,
    damage: Optional[SalvageStats] = None,
) -> Iterator[RecordedMessage]:
    """Messages in file order (= arrival order), finished file or not.

    ``include``/``exclude`` are glob patterns over keys; ``start_ns`` is an
    inclusive and ``end_ns`` an exclusive bound on the receive time. Without
    ``damage``, DamagedRecording at the first damage; with it, damage is
    counted there and the sound messages still come.
    """
    keep = TopicFilter(include, exclude, include_mirrors)
    stats = damage if damage is not None else SalvageStats()
    with open_source(source) as stream:
        state = probe(stream)
        channels: dict[int, Channel] = {}
        for record in _checked(iter_salvaged_records(stream, state, stats), stats, damage is None, source):
            if isinstance(record, Message):
                channel = channels.get(record.channel_id)
                if channel is not None and keep(channel.topic) and (start_ns is None or record.log_time >= start_ns) \
                        and (end_ns is None or record.log_time < end_ns):
                    yield RecordedMessage(channel.topic, record.data, record.log_time, record.publish_time)
            elif isinstance(record, Channel):
                channels.setdefault(record.id, record)


def read_metadata(source: Source, damage: Optional[SalvageStats] = None) -> dict[str, dict[str, str]]:
    """Metadata records by name (a later record of the same name wins); DamagedRecording as iter_messages."""
    out: dict[str, dict[str, str]] = {}
    stats = damage if damage is not None else SalvageStats()
    with open_source(source) as stream:
        state = probe(stream)
        for record in _checked(iter_salvaged_records(stream, state, stats), stats, damage is None, source):
            if isinstance(record, Metadata):
                out[record.name] = dict(record.metadata)
    return out


def read_schemas(source: Source, damage: Optional[SalvageStats] = None) -> dict[str, Schema]:
    """Schema of every channel, by topic (mirrors included), e.g. to decode JSON mirrors."""
    schemas: dict[int, Schema] = {}
    topics: dict[str, int] = {}
    stats = damage if damage is not None else SalvageStats()
    with open_source(source) as stream:
        state = probe(stream)
        for record in _checked(iter_salvaged_records(stream, state, stats), stats, damage is None, source):
            if isinstance(record, Schema):
                schemas.setdefault(record.id, record)
            elif isinstance(record, Channel):
                topics.setdefault(record.topic, record.schema_id)
    return {topic: schemas[sid] for topic, sid in topics.items() if sid in schemas}
