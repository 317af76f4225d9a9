"""The one guarded reading of an MCAP file's records: recordings come from elsewhere and are untrusted.

Every ``truav log`` tool reads through this module (via :mod:`recorder.reader` and
:mod:`recorder.log_copy`), never through mcap's readers, which trust what a file declares. Here:

* every record's declared length is checked against the bytes left in the file and against
  :data:`MAX_RECORD_BYTES` *before* anything is read or allocated; a chunk's declared uncompressed
  size against the same cap; decompression (zstd, lz4) is a bounded read of at most the declared
  size plus one byte, so a compression bomb costs no more than the cap;
* every chunk's CRC is checked before its records are used; a chunk that fails (CRC, compression,
  records that do not parse) is counted and left out, never handed on;
* schemas, channels, messages and metadata are validated (:class:`Validator`): a channel naming an
  undeclared schema, a message on an undeclared channel, a topic or name over
  :data:`MAX_NAME_CHARS`, a log time past :data:`LOG_TIME_MAX_NS` (the year 2100) are left out and
  named in :class:`ReadDamage`'s notes (record, file offset, why).

A tool then says what was left out: ``check`` counts it as a problem, ``cut``/``merge``/``recover``
write what was sound, mark the output (:data:`DAMAGE_METADATA`) and exit 1, the others refuse the
file in one line with exit 1 (:class:`DamagedRecording`). docs/reference/untrusted-recordings.md lists the caps and codes.
"""

from __future__ import annotations

import heapq
import io
import struct
import zlib
from dataclasses import dataclass, field
from typing import IO, Callable, Iterator, Optional

from mcap.data_stream import ReadDataStream
from mcap.exceptions import EndOfFile
from mcap.opcode import Opcode
from mcap.records import (Attachment, AttachmentIndex, Channel, Chunk, ChunkIndex, DataEnd, Footer, Header,
                          McapRecord, Message, MessageIndex, Metadata, MetadataIndex, Schema, Statistics,
                          SummaryOffset)

__all__ = ["EXIT_DAMAGED", "MAX_RECORD_BYTES", "MAX_NAME_CHARS", "LOG_TIME_MAX_NS", "MAX_BUFFERED_BYTES",
           "DAMAGE_METADATA", "DATA_ONLY",
           "ReadDamage", "DamagedRecording", "damage_line", "Validator", "walk", "chunk_records", "read_summary",
           "GuardedSummary", "ordered_messages"]

MAX_RECORD_BYTES = 64 * 1024 * 1024
"""Cap on any one record's length and on a chunk's uncompressed size (the recorder writes chunks of at most
1 MiB): a larger declaration is damage, refused before allocating."""
MAX_NAME_CHARS = 1024
"""Cap on a topic, schema name, encoding or metadata name (bus keys are a few dozen characters)."""
LOG_TIME_MAX_NS = 4_102_444_800 * 10**9
"""Latest plausible log time (2100-01-01 UTC): a later one is damage (a player would wait for it)."""
MAX_BUFFERED_BYTES = 256 * 1024 * 1024
"""Log-time ordering keeps at most this many decompressed bytes of overlapping chunks; past it order is
given up for bounded memory (never the case for a recorder's file, whose chunks barely overlap)."""
EXIT_DAMAGED = 1
"""Every `truav log` tool's exit code for a damaged recording (docs/reference/untrusted-recordings.md); 2 stays a user mistake."""
DAMAGE_METADATA = "truav.damage"
"""Metadata record a tool writes into a file made from a damaged one; `truav log check` reports it."""
MAX_NOTES = 5
DATA_ONLY = frozenset({Opcode.CHUNK, Opcode.MESSAGE, Opcode.METADATA, Opcode.ATTACHMENT})
"""Records of the data section only: one after DataEnd (in the summary) is hidden data, so damage."""

_HEAD = struct.Struct("<BQ")
_MESSAGE = struct.Struct("<HIQQ")
_FOOTER_TAIL = _HEAD.size + 20 + 8  # footer record + closing magic


@dataclass
class ReadDamage:
    """What a guarded read left out, and why (filled in while it runs)."""

    corrupt_chunks: int = 0  # chunks left out: CRC, compression, size or contents bad
    invalid_records: int = 0  # schemas, channels, messages, metadata left out (see notes)
    error: Optional[str] = None  # why reading stopped before the end of the readable part, if it did
    records: int = 0  # records handed on
    notes: list[str] = field(default_factory=list)  # the first MAX_NOTES reasons, each naming a record
    _seen: set = field(default_factory=set, repr=False)

    @property
    def damaged(self) -> bool:
        return bool(self.corrupt_chunks or self.invalid_records or self.error)

    def note(self, text: str, key: object = None) -> None:
        """Remember a reason (once per ``key``, when given: one line per bad channel, not per message)."""
        if key is not None:
            if key in self._seen:
                return
            self._seen.add(key)
        if len(self.notes) < MAX_NOTES:
            self.notes.append(text)

    def chunk(self, offset: int, why: str) -> None:
        self.corrupt_chunks += 1
        self.note(f"chunk at offset {offset}: {why}")

    def invalid(self, text: str, key: object = None) -> None:
        self.invalid_records += 1
        self.note(text, key)

    def describe(self) -> str:
        """One phrase: counts, then the first reasons."""
        parts = []
        if self.corrupt_chunks:
            parts.append(f"{self.corrupt_chunks} corrupt chunk(s) left out")
        if self.invalid_records:
            parts.append(f"{self.invalid_records} invalid record(s) left out")
        if self.error:
            parts.append(f"unreadable after some point ({self.error})")
        text = ", ".join(parts) or "no damage"
        return text + (f" ({'; '.join(self.notes)})" if self.notes else "")

    def as_metadata(self, source: str) -> dict[str, str]:
        """The :data:`DAMAGE_METADATA` record of a file written from a damaged ``source``."""
        return {"source": source, "corrupt_chunks": str(self.corrupt_chunks),
                "invalid_records": str(self.invalid_records), "error": self.error or "",
                "what": self.describe()}


class DamagedRecording(ValueError):
    """A recording with damage a tool will not read past; the message is one line naming the file."""


def damage_line(path: object, exc: BaseException) -> str:
    """One line for a damage error: a DamagedRecording says it all, anything else is named."""
    if isinstance(exc, DamagedRecording):
        return str(exc)
    return f"{path}: damaged recording ({type(exc).__name__}: {str(exc)[:300]})"


class Malformed(ValueError):
    """A record whose bytes do not parse as what its opcode says."""


class _Strict(ReadDataStream):
    """mcap's field reader, but a short read (a length running past its record) is an error."""

    def read(self, length: int) -> bytes:
        data = super().read(length) if length else b""
        if len(data) != length:
            raise EndOfFile()
        return data


_PARSERS: dict[int, Callable[[ReadDataStream], McapRecord]] = {
    Opcode.HEADER: Header.read, Opcode.FOOTER: Footer.read, Opcode.SCHEMA: Schema.read,
    Opcode.CHANNEL: Channel.read, Opcode.CHUNK: Chunk.read, Opcode.MESSAGE_INDEX: MessageIndex.read,
    Opcode.CHUNK_INDEX: ChunkIndex.read, Opcode.ATTACHMENT: Attachment.read,
    Opcode.ATTACHMENT_INDEX: AttachmentIndex.read, Opcode.STATISTICS: Statistics.read,
    Opcode.METADATA: Metadata.read, Opcode.METADATA_INDEX: MetadataIndex.read,
    Opcode.SUMMARY_OFFSET: SummaryOffset.read, Opcode.DATA_END: DataEnd.read,
}


def parse(opcode: int, body: bytes) -> Optional[McapRecord]:
    """One record from its body; None for an opcode MCAP does not define (skipped, as the spec says)."""
    if opcode == Opcode.MESSAGE:
        if len(body) < _MESSAGE.size:
            raise Malformed("a message shorter than its fixed fields")
        cid, seq, log_time, pub = _MESSAGE.unpack_from(body)
        return Message(channel_id=cid, sequence=seq, log_time=log_time, publish_time=pub, data=bytes(body[22:]))
    parser = _PARSERS.get(opcode)
    if parser is None:
        return None
    try:
        return parser(_Strict(io.BytesIO(body)))
    except (EndOfFile, struct.error, UnicodeDecodeError, ValueError, OverflowError, MemoryError) as exc:
        raise Malformed(f"{Opcode(opcode).name.lower()} record does not parse ({type(exc).__name__})") from None


def walk(stream: IO[bytes], start: int, end: int, damage: ReadDamage,
         skip: frozenset[int] = frozenset()) -> Iterator[tuple[int, int, Optional[McapRecord]]]:
    """``(offset, opcode, record)`` of the top-level records in ``[start, end)``; records whose opcode is in
    ``skip`` are not read (record None). Stops at the footer, and at a record running past ``end`` (damage:
    :func:`recorder.reader.probe` has cut a torn tail off already). A record over the cap is skipped as damage."""
    position = start
    while position + _HEAD.size <= end:
        stream.seek(position)
        opcode, length = _HEAD.unpack(stream.read(_HEAD.size))
        body_at = position + _HEAD.size
        if opcode == 0 or length > end - body_at:  # (probe() already cut an unfinished file's torn tail off)
            damage.error = damage.error or (f"record at offset {position} (opcode {opcode:#04x}) declares "
                                            f"{length:,} bytes, past the end of its section")
            return
        if length > MAX_RECORD_BYTES:
            damage.invalid(f"record of opcode {opcode:#04x} at offset {position}: declares {length:,} bytes, over "
                           f"the {MAX_RECORD_BYTES:,}-byte cap")
        elif opcode in skip:
            yield position, opcode, None
        else:
            try:
                record = parse(opcode, stream.read(length))
            except Malformed as exc:
                if opcode == Opcode.CHUNK:
                    damage.chunk(position, str(exc))
                else:
                    damage.invalid(f"{exc} at offset {position}")
                record = None
            else:
                if record is not None:
                    yield position, opcode, record
        if opcode == Opcode.FOOTER:
            return
        position = body_at + length


def _decompress(compression: str, data: bytes, size: int) -> bytes:
    """At most ``size`` + 1 bytes out, whatever the data claims (the +1 tells a lie)."""
    if compression == "":
        return data
    if compression == "zstd":
        import zstandard
        reader = zstandard.ZstdDecompressor().stream_reader(io.BytesIO(data), read_across_frames=True)
        parts, got = [], 0
        while got <= size:
            part = reader.read(size + 1 - got)
            if not part:
                break
            parts.append(part)
            got += len(part)
        return b"".join(parts)
    if compression == "lz4":
        import lz4.frame
        return lz4.frame.LZ4FrameDecompressor().decompress(data, max_length=size + 1)
    raise Malformed(f"unknown compression {compression[:40]!r}")


def chunk_records(chunk: Chunk) -> list[McapRecord]:
    """The schemas, channels and messages of a chunk, once its size, decompression and CRC are checked;
    Malformed (the reason) otherwise."""
    size = chunk.uncompressed_size
    if size > MAX_RECORD_BYTES:
        raise Malformed(f"declares {size:,} uncompressed bytes, over the {MAX_RECORD_BYTES:,}-byte cap")
    try:
        data = _decompress(chunk.compression, chunk.data, size)
    except Malformed:
        raise
    except Exception as exc:  # zstandard.ZstdError, lz4's RuntimeError...: the bytes are not what they claim
        raise Malformed(f"{chunk.compression} data does not decompress ({type(exc).__name__})") from None
    if len(data) != size:
        raise Malformed(f"decompresses to {'more' if len(data) > size else len(data)} bytes, not the "
                        f"{size:,} it declares")
    if chunk.uncompressed_crc and zlib.crc32(data) != chunk.uncompressed_crc:
        raise Malformed("CRC mismatch (the bytes changed since it was written)")
    out: list[McapRecord] = []
    position = 0
    while position < size:
        if size - position < _HEAD.size:
            raise Malformed("a record cut short inside the chunk")
        opcode, length = _HEAD.unpack_from(data, position)
        position += _HEAD.size
        if length > size - position:
            raise Malformed("a record running past the chunk's end")
        if opcode not in (Opcode.MESSAGE, Opcode.CHANNEL, Opcode.SCHEMA):
            raise Malformed(f"a record of opcode {opcode:#04x} inside the chunk")
        out.append(parse(opcode, data[position:position + length]))  # type: ignore[arg-type]
        position += length
    return out


class Validator:
    """Schemas and channels declared so far; each record checked before it is handed on."""

    def __init__(self, damage: ReadDamage) -> None:
        self.damage = damage
        self.schemas: dict[int, Schema] = {}
        self.channels: dict[int, Channel] = {}

    def __call__(self, record: McapRecord, offset: int) -> bool:
        """True when ``record`` may be used; False (noted) when it is left out."""
        invalid = self.damage.invalid
        if isinstance(record, Message):
            if record.channel_id not in self.channels:
                invalid(f"message(s) on channel {record.channel_id}, never declared (first near offset {offset})",
                        ("orphan", record.channel_id))
                return False
            if record.log_time > LOG_TIME_MAX_NS:
                invalid(f"message(s) with a log time after the year 2100 ({record.log_time} ns, near offset "
                        f"{offset})", ("time", record.channel_id))
                return False
            return True
        if isinstance(record, Channel):
            if len(record.topic) > MAX_NAME_CHARS or not record.topic:
                invalid(f"channel {record.id} at offset {offset}: topic of {len(record.topic):,} characters "
                        f"(1-{MAX_NAME_CHARS} allowed)")
                return False
            if record.schema_id and record.schema_id not in self.schemas:
                invalid(f"channel {record.id} ({record.topic[:80]}) at offset {offset}: names schema "
                        f"{record.schema_id}, never declared")
                return False
            if any(len(k) > MAX_NAME_CHARS or len(v) > MAX_NAME_CHARS for k, v in record.metadata.items()) \
                    or len(record.message_encoding) > MAX_NAME_CHARS:
                invalid(f"channel {record.id} at offset {offset}: metadata or encoding over {MAX_NAME_CHARS} "
                        f"characters")
                return False
            known = self.channels.get(record.id)
            if known is None:
                self.channels[record.id] = record
            return True
        if isinstance(record, Schema):
            if record.id == 0 or len(record.name) > MAX_NAME_CHARS or len(record.encoding) > MAX_NAME_CHARS:
                invalid(f"schema {record.id} at offset {offset}: id 0, or a name or encoding over "
                        f"{MAX_NAME_CHARS} characters")
                return False
            self.schemas.setdefault(record.id, record)
            return True
        if isinstance(record, Metadata):
            if len(record.name) > MAX_NAME_CHARS:
                invalid(f"metadata record at offset {offset}: name of {len(record.name):,} characters")
                return False
            return True
        return True


@dataclass
class GuardedSummary:
    """What a finished file's summary section says, each record checked."""

    schemas: dict[int, Schema]
    channels: dict[int, Channel]
    chunk_indexes: list[ChunkIndex]
    statistics: Optional[Statistics]
    data_end: int  # where the data section ends (the summary's start)


def read_footer(stream: IO[bytes], size: int) -> Optional[Footer]:
    stream.seek(size - _FOOTER_TAIL)
    tail = stream.read(_FOOTER_TAIL)
    try:
        footer = parse(Opcode.FOOTER, tail[_HEAD.size:_HEAD.size + 20])
    except Malformed:
        return None
    return footer if isinstance(footer, Footer) else None


def read_summary(stream: IO[bytes], size: int, validator: Validator) -> Optional[GuardedSummary]:
    """The summary of a finished file (``size`` bytes), or None when it has none or it is unusable (then
    noted as damage when it is there but bad)."""
    footer = read_footer(stream, size)
    footer_at = size - _FOOTER_TAIL
    if footer is None or footer.summary_start == 0:
        return None
    if not 8 <= footer.summary_start <= footer_at:
        validator.damage.invalid(f"footer: summary start {footer.summary_start} outside the file")
        return None
    indexes: list[ChunkIndex] = []
    statistics = None
    for offset, opcode, record in walk(stream, footer.summary_start, footer_at, validator.damage, skip=DATA_ONLY):
        if opcode in DATA_ONLY:  # data hidden in the summary: no reader would show it
            validator.damage.invalid(f"{Opcode(opcode).name.lower()} record at offset {offset}, in the summary section")
        elif isinstance(record, (Schema, Channel)):
            validator(record, offset)
        elif isinstance(record, ChunkIndex):
            if record.chunk_start_offset + record.chunk_length > footer.summary_start or record.chunk_length < 9:
                validator.damage.invalid(f"chunk index at offset {offset}: points outside the data section")
                continue
            indexes.append(record)
        elif isinstance(record, Statistics):
            statistics = record
    return GuardedSummary(dict(validator.schemas), dict(validator.channels), indexes, statistics,
                          footer.summary_start)


def _read_chunk(stream: IO[bytes], index: ChunkIndex, damage: ReadDamage) -> Optional[list[McapRecord]]:
    offset = index.chunk_start_offset
    stream.seek(offset)
    head = stream.read(_HEAD.size)
    if len(head) < _HEAD.size:
        damage.chunk(offset, "not there")
        return None
    opcode, length = _HEAD.unpack(head)
    if opcode != Opcode.CHUNK or length + _HEAD.size > index.chunk_length:
        damage.chunk(offset, "the chunk index points at something else")
        return None
    if length > MAX_RECORD_BYTES:
        damage.chunk(offset, f"declares {length:,} bytes, over the {MAX_RECORD_BYTES:,}-byte cap")
        return None
    try:
        chunk = parse(Opcode.CHUNK, stream.read(length))
        return chunk_records(chunk)  # type: ignore[arg-type]
    except Malformed as exc:
        damage.chunk(offset, str(exc))
        return None


def ordered_messages(stream: IO[bytes], summary: GuardedSummary, validator: Validator
                     ) -> Iterator[tuple[Optional[Schema], Channel, Message]]:
    """Every sound message of a finished file in log-time order (ties in file order), chunk by chunk in
    the order of their start times; at most :data:`MAX_BUFFERED_BYTES` of overlapping chunks held."""
    chunks = sorted(summary.chunk_indexes, key=lambda c: (c.message_start_time, c.chunk_start_offset))
    heap: list[tuple[int, int, int, Message]] = []
    held: list[int] = [0]
    n = 0
    damage = validator.damage

    def load(index: ChunkIndex) -> None:
        nonlocal n
        records = _read_chunk(stream, index, damage)
        if records is None:
            return
        for record in records:
            if not validator(record, index.chunk_start_offset):
                continue
            if isinstance(record, Message):
                heapq.heappush(heap, (record.log_time, index.chunk_start_offset, n, record))
                n += 1
                held[0] += len(record.data)

    position = 0
    while position < len(chunks) or heap:
        while position < len(chunks) and (not heap or (chunks[position].message_start_time <= heap[0][0]
                                                       and held[0] < MAX_BUFFERED_BYTES)):
            load(chunks[position])
            position += 1
        if not heap:
            continue
        _, _, _, message = heapq.heappop(heap)
        held[0] -= len(message.data)
        channel = validator.channels[message.channel_id]
        damage.records += 1
        yield validator.schemas.get(channel.schema_id), channel, message
