"""Turn an unfinished MCAP (recorder SIGKILLed, disk full...) into a finished one.

The valid prefix is streamed with mcap's ``StreamReader`` (see
:mod:`recorder.reader`: framing check, CRC-checked chunks, torn tail
skipped) and every schema, channel, message, metadata and attachment is
rewritten, in file order, with :class:`recorder.mcap_writer.McapWriter` (mcap's
own record classes) into bounded chunks (at most COMPACT_CHUNK_SPAN_NS of log
time and COMPACT_CHUNK_BYTES each, so a copy cut at any byte still salvages
every whole chunk before the cut) compressed hard (COMPACT_ZSTD_LEVEL for the
first COMPACT_STRONG_BUDGET_S seconds of work, then COMPACT_FAST_ZSTD_LEVEL:
the cost of a long file stays bounded, streamed chunk by chunk), plus the
summary section (statistics, chunk indexes) that ``make_reader`` and Foxglove
want.  :func:`compact` does the same in place for a finished file: the
recorder calls it at a clean finish.  The output is written to
``<out>.part`` and renamed into place, so a crash during recovery never
leaves a half file under ``out``.
"""

from __future__ import annotations

import itertools
import math
import os
import time
from dataclasses import dataclass, field
from typing import Optional

from mcap.records import Attachment, Channel, Header, Message, Metadata, Schema

from recorder.mcap_writer import (
    COMPACT_CHUNK_BYTES,
    COMPACT_CHUNK_SPAN_NS,
    COMPACT_FAST_ZSTD_LEVEL,
    COMPACT_STRONG_BUDGET_S,
    COMPACT_ZSTD_LEVEL,
    COMPRESSIONS,
    DEFAULT_COMPRESSION,
    LIBRARY,
    McapWriter,
)
from recorder.mcap_guard import DAMAGE_METADATA
from recorder.reader import SalvageStats, iter_salvaged_records, probe

RECOVERED_BY = f"{LIBRARY} recover"
PART_SUFFIX = ".part"


@dataclass
class RecoverReport:
    """What :func:`recover` salvaged, and what it had to drop."""

    in_path: str
    out_path: str
    truncated: bool  # the input had no footer: its writer never finished it
    input_bytes: int
    torn_bytes: int  # bytes after the last complete record (dropped)
    messages: int  # messages written to out_path (JSON mirrors included)
    schemas: int
    channels: int
    metadata: int
    attachments: int
    corrupt_chunks: int  # complete chunks dropped because their CRC or compression was bad
    orphan_messages: int  # messages on a channel never declared (dropped)
    invalid_records: int  # schemas, channels, messages, metadata failing recorder.mcap_guard's checks (dropped)
    first_log_time: Optional[int]
    last_log_time: Optional[int]
    error: Optional[str]  # why salvage stopped before the end of the valid prefix, if it did
    notes: list[str] = field(default_factory=list)  # the first reasons for what was left out, each naming a record

    @property
    def clean(self) -> bool:
        """Nothing but (possibly) a torn tail was lost."""
        return self.corrupt_chunks == 0 and self.orphan_messages == 0 and self.invalid_records == 0 \
            and self.error is None


def recover(in_path: str | os.PathLike[str], out_path: str | os.PathLike[str], *,
            compression: str = DEFAULT_COMPRESSION, chunk_bytes: int = COMPACT_CHUNK_BYTES,
            chunk_span_ns: int = COMPACT_CHUNK_SPAN_NS, zstd_level: int | None = None,
            compacting: bool = False, strong_budget_s: float = COMPACT_STRONG_BUDGET_S) -> RecoverReport:
    """Salvage ``in_path`` into a finished MCAP at ``out_path`` (must differ).

    Also works on a finished file (then it is a plain re-chunking copy).
    ``zstd_level`` None: COMPACT_ZSTD_LEVEL (~1-2 MB/s) for the chunks closed within
    ``strong_budget_s`` seconds of starting, COMPACT_FAST_ZSTD_LEVEL for the rest.
    """
    strong_until = math.inf
    if zstd_level is None:
        zstd_level, strong_until = COMPACT_ZSTD_LEVEL, time.monotonic() + strong_budget_s
    if os.path.abspath(in_path) == os.path.abspath(out_path):
        raise ValueError("recover() needs a different out_path: the input is evidence")
    if compression not in COMPRESSIONS:
        raise ValueError(f"compression must be one of {sorted(COMPRESSIONS)}")
    part = os.fspath(out_path) + PART_SUFFIX
    stats = SalvageStats()
    counts = dict(messages=0, schemas=0, channels=0, metadata=0, attachments=0, orphans=0)
    first: Optional[int] = None
    last: Optional[int] = None
    with open(in_path, "rb") as src:
        state = probe(src)
        records = iter_salvaged_records(src, state, stats)
        first_record = next(records, None)
        header = first_record if isinstance(first_record, Header) else Header("", "")
        with open(part, "wb") as dst:
            writer = McapWriter(dst, compression=compression, chunk_bytes=chunk_bytes, chunk_span_ns=chunk_span_ns,
                                flush_interval_s=math.inf,
                                auto_flush=False, zstd_level=zstd_level,
                                library=header.library if compacting else f"{RECOVERED_BY} ({header.library})")
            schema_ids: dict[int, int] = {}  # input id -> output id
            channel_ids: dict[int, int] = {}
            pending = [] if isinstance(first_record, Header) or first_record is None else [first_record]
            for record in itertools.chain(pending, records):
                if isinstance(record, Message):
                    cid = channel_ids.get(record.channel_id)
                    if cid is None:
                        counts["orphans"] += 1
                        continue
                    writer.add_message(cid, record.sequence, record.log_time, record.publish_time, record.data)
                    counts["messages"] += 1
                    if not counts["messages"] & 1023 and time.monotonic() > strong_until:  # budget spent
                        writer.set_zstd_level(COMPACT_FAST_ZSTD_LEVEL)
                        strong_until = math.inf
                    first = record.log_time if first is None else min(first, record.log_time)
                    last = record.log_time if last is None else max(last, record.log_time)
                elif isinstance(record, Channel):
                    if record.id in channel_ids:  # repeated declaration
                        continue
                    channel_ids[record.id] = writer.add_channel(
                        record.topic, record.message_encoding, schema_ids.get(record.schema_id, 0), record.metadata)
                    counts["channels"] += 1
                elif isinstance(record, Schema):
                    if record.id in schema_ids:
                        continue
                    schema_ids[record.id] = writer.add_schema(record.name, record.encoding, record.data)
                    counts["schemas"] += 1
                elif isinstance(record, Metadata):
                    writer.add_metadata(record.name, dict(record.metadata))
                    counts["metadata"] += 1
                elif isinstance(record, Attachment):
                    writer.add_attachment(record)
                    counts["attachments"] += 1
            if stats.damaged:  # so that `truav log check OUT` does not call the salvage sound
                writer.add_metadata(DAMAGE_METADATA, stats.as_metadata(os.path.basename(in_path)))
            writer.close()
            dst.flush()
            os.fsync(dst.fileno())
    os.replace(part, out_path)
    return RecoverReport(
        in_path=os.fspath(in_path), out_path=os.fspath(out_path), truncated=not state.finished,
        input_bytes=state.size, torn_bytes=state.torn_bytes, messages=counts["messages"],
        schemas=counts["schemas"], channels=counts["channels"], metadata=counts["metadata"],
        attachments=counts["attachments"], corrupt_chunks=stats.corrupt_chunks,
        orphan_messages=counts["orphans"], invalid_records=stats.invalid_records, first_log_time=first,
        last_log_time=last, error=stats.error, notes=list(stats.notes),
    )



COMPACT_SUFFIX = ".compact"


def compact(path: str | os.PathLike[str], *, compression: str = DEFAULT_COMPRESSION) -> tuple[int, int]:
    """Rewrite a finished recording in place into bigger, bounded chunks; returns (bytes before, after).

    The copy goes to ``<path>.compact`` (then ``.part``) and is renamed over
    ``path`` only when complete and fsynced, so a crash while compacting
    leaves the original file.  Raises OSError / ValueError on failure (the
    original is then untouched).
    """
    before = os.path.getsize(path)
    tmp = os.fspath(path) + COMPACT_SUFFIX
    try:
        report = recover(path, tmp, compression=compression, compacting=True)
        if report.truncated or not report.clean:
            raise ValueError(f"{path} is not a clean finished recording; run `truav log recover`")
        os.replace(tmp, path)
    finally:
        for leftover in (tmp, tmp + PART_SUFFIX):
            if os.path.exists(leftover):
                os.unlink(leftover)
    return before, os.path.getsize(path)
