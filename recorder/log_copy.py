"""Copying records between finished MCAP recordings: what `truav log cut` and `truav log merge` share.

* :func:`open_finished` opens a recording through its summary's chunk index (a finished file only:
  its messages come out in log-time order, overlapping chunks included, which the salvage path of
  :mod:`recorder.reader` cannot promise), every chunk and record checked by
  :mod:`recorder.mcap_guard`: a damaged one is left out and counted in :attr:`FinishedLog.damage`,
  which cut and merge report (exit 1) and write into their output as a ``truav.damage`` record; an
  unfinished one is a :class:`truav.errors.UserError` that points at ``truav log recover``.
* :class:`OutputChannels` registers an input's schemas and channels in a
  :class:`recorder.mcap_writer.McapWriter` once: a channel equal to one already written (topic,
  encodings, metadata, schema) reuses its id, so merged inputs share their channels as ``mcap
  merge`` does.
* :func:`written_atomically` writes ``<out>.part`` and renames it over ``out`` only when
  finished; on any failure the part is removed and ``out`` is untouched.
"""

from __future__ import annotations

import contextlib
import math
import os
from pathlib import Path
from typing import IO, Iterator, NamedTuple, Optional

from mcap.opcode import Opcode
from mcap.records import Attachment, Channel, Message, Metadata, Schema

from recorder.mcap_guard import (DamagedRecording, GuardedSummary, ReadDamage, Validator,
                                 ordered_messages, read_summary, walk)

from recorder.mcap_writer import COMPACT_CHUNK_BYTES, COMPACT_CHUNK_SPAN_NS, McapWriter
from recorder.reader import probe
from recorder.recover import PART_SUFFIX
from recorder.record_modes import PARTS_INDEX_SUFFIX
from truav.errors import UserError
from truav import jsonio

__all__ = ["LogMessage", "FinishedLog", "open_finished", "OutputChannels", "written_atomically", "new_writer",
           "not_mcap_reason", "dump", "damage_errors"]

COPY_ZSTD_LEVEL = 9
"""Cut and merge outputs: zstd 9 (a few times faster than the recorder's level-19 compaction, a few % larger)."""


class LogMessage(NamedTuple):
    """One message of an input, with what is needed to copy it."""

    schema: Optional[Schema]
    channel: Channel
    message: Message


class FinishedLog:
    """A finished recording open for reading: its summary, its messages in log-time order, its metadata;
    what was left out as damaged is counted in :attr:`damage`."""

    def __init__(self, path: Path, stream: IO[bytes], summary: GuardedSummary, damage: ReadDamage) -> None:
        self.path = path
        self._stream = stream
        self.summary = summary
        self.damage = damage
        self._scanned: Optional[tuple[list[Metadata], list[Attachment]]] = None

    def messages(self, damage: Optional[ReadDamage] = None, topics: Optional[set[str]] = None
                 ) -> Iterator[LogMessage]:
        """Every sound message (of ``topics``, if given), ascending log time (ties in file order); what is
        left out is counted in ``damage`` (default: :attr:`damage`)."""
        check = Validator(self.damage if damage is None else damage)
        check.schemas, check.channels = dict(self.summary.schemas), dict(self.summary.channels)
        for schema, channel, message in ordered_messages(self._stream, self.summary, check):
            if topics is None or channel.topic in topics:
                yield LogMessage(schema, channel, message)

    def _scan(self) -> tuple[list[Metadata], list[Attachment]]:
        """One walk over the data section's top-level records (chunk bodies skipped): the metadata and
        attachments, and every chunk the summary's index leaves out (damage: its messages would be lost
        silently; a chunk indexed twice is read once, recorder.mcap_guard.read_summary)."""
        if self._scanned is None:
            check = Validator(self.damage)
            found: list = []
            chunks: set[int] = set()
            for offset, opcode, record in walk(self._stream, 8, self.summary.data_end, self.damage, skip=_BULK):
                if opcode == Opcode.CHUNK:
                    chunks.add(offset)
                elif isinstance(record, (Metadata, Attachment)) and check(record, offset):
                    found.append(record)
            indexed = {c.chunk_start_offset for c in self.summary.chunk_indexes}
            if chunks and not indexed:
                raise UserError(f"IN {self.path}: its summary has no chunk index; `truav log recover {self.path} "
                                f"FIXED.mcap` rewrites it")
            for offset in sorted(chunks - indexed):
                self.damage.chunk(offset, "not in the summary's chunk index")
            self._scanned = ([r for r in found if isinstance(r, Metadata)],
                             [r for r in found if isinstance(r, Attachment)])
        return self._scanned

    def metadata(self) -> list[Metadata]:
        """Every metadata record, in file order (repeated names included)."""
        return self._scan()[0]

    def attachments(self) -> list[Attachment]:
        return self._scan()[1]

    @property
    def first_log_time(self) -> Optional[int]:
        stats = self.summary.statistics
        return stats.message_start_time if stats is not None and stats.message_count else None

    @property
    def last_log_time(self) -> Optional[int]:
        stats = self.summary.statistics
        return stats.message_end_time if stats is not None and stats.message_count else None

    @property
    def message_count(self) -> int:
        stats = self.summary.statistics
        return stats.message_count if stats is not None else 0


_BULK = frozenset({Opcode.CHUNK, Opcode.MESSAGE_INDEX})  # not read when looking for metadata and attachments


def damage_errors() -> tuple[type[BaseException], ...]:
    """What mcap's indexed reader raises on a damaged file (bad chunk, framing, compression)."""
    import struct

    import zstandard
    from mcap.exceptions import McapError
    return (DamagedRecording, McapError, zstandard.ZstdError, EOFError, UnicodeDecodeError, struct.error)


def not_mcap_reason(path: str | os.PathLike[str]) -> Optional[str]:
    """Why ``path`` cannot be read as an MCAP file (one phrase naming it), or None."""
    p = Path(path)
    if not p.exists():
        return f"{p}: no such file"
    if not p.is_file():
        return f"{p}: not a file"
    if p.name.endswith(PARTS_INDEX_SUFFIX):
        return f"{p}: the parts index of a split recording, not an MCAP file; `truav log merge ALL.mcap {p}` " \
               f"joins its parts into one"
    try:
        with open(p, "rb") as f:
            probe(f)
    except ValueError as exc:
        return f"{p}: {exc}"
    except OSError as exc:
        return f"{p}: {exc.strerror or exc}"
    return None


@contextlib.contextmanager
def open_finished(path: str | os.PathLike[str], flag: str = "IN") -> Iterator[FinishedLog]:
    """A finished recording, or UserError (not MCAP, unfinished, summary unreadable) naming ``flag`` and the file."""
    problem = not_mcap_reason(path)
    if problem:
        raise UserError(f"{flag} {problem}")
    p = Path(path)
    with open(p, "rb") as stream:
        state = probe(stream)
        if not state.finished:
            raise UserError(f"{flag} {p}: unfinished recording (its recorder died); "
                            f"`truav log recover {p} FIXED.mcap` finishes it first")
        damage = ReadDamage()
        summary = read_summary(stream, state.size, Validator(damage))
        if summary is None:
            raise UserError(f"{flag} {p}: no usable summary section; `truav log recover {p} FIXED.mcap` rewrites it")
        yield FinishedLog(p, stream, summary, damage)


def dump(value: object) -> str:
    """A metadata value: compact JSON."""
    return jsonio.dumps(value, separators=(",", ":"), sort_keys=True)


class OutputChannels:
    """Input channels -> output channel ids, one output channel per distinct channel."""

    def __init__(self, writer: McapWriter) -> None:
        self._writer = writer
        self._by_content: dict[tuple, int] = {}
        self._by_input: dict[tuple[int, int], int] = {}  # (input number, input channel id) -> output id
        self.topics: dict[int, str] = {}  # output channel id -> topic

    def channel_id(self, source: int, schema: Optional[Schema], channel: Channel) -> int:
        """The output id of ``channel`` of input number ``source`` (registered on first use)."""
        cid = self._by_input.get((source, channel.id))
        if cid is not None:
            return cid
        schema_key = None if schema is None else (schema.name, schema.encoding, bytes(schema.data))
        content = (channel.topic, channel.message_encoding, tuple(sorted(channel.metadata.items())), schema_key)
        cid = self._by_content.get(content)
        if cid is None:
            sid = 0 if schema is None else self._writer.add_schema(schema.name, schema.encoding, schema.data)
            cid = self._writer.add_channel(channel.topic, channel.message_encoding, sid, channel.metadata)
            self._by_content[content] = cid
            self.topics[cid] = channel.topic
        self._by_input[(source, channel.id)] = cid
        return cid


def new_writer(stream: IO[bytes], library: str) -> McapWriter:
    """A writer laying chunks out as a compacted recording does (bounded in bytes and log-time span)."""
    return McapWriter(stream, chunk_bytes=COMPACT_CHUNK_BYTES, chunk_span_ns=COMPACT_CHUNK_SPAN_NS,
                      flush_interval_s=math.inf, auto_flush=False, zstd_level=COPY_ZSTD_LEVEL, library=library)


@contextlib.contextmanager
def written_atomically(out: str | os.PathLike[str]) -> Iterator[IO[bytes]]:
    """A stream to ``<out>.part``, renamed to ``out`` when the block ends normally (after fsync), removed
    otherwise; missing directories of ``out`` are made."""
    part = Path(os.fspath(out) + PART_SUFFIX)
    part.parent.mkdir(parents=True, exist_ok=True)  # OUT's directory may be new (checked creatable before)
    try:
        with open(part, "wb") as stream:
            yield stream
            stream.flush()
            os.fsync(stream.fileno())
        os.replace(part, out)
    finally:
        part.unlink(missing_ok=True)
