"""Turn an unfinished MCAP (recorder SIGKILLed, disk full...) into a finished one.

The valid prefix is streamed with mcap's ``StreamReader`` (see
:mod:`recorder.reader`: framing check, CRC-checked chunks, torn tail
skipped) and every schema, channel, message, metadata and attachment is
rewritten, in file order, with mcap's own :class:`mcap.writer.Writer`, which
adds the summary section (statistics, chunk indexes) that ``make_reader``
and Foxglove want.  The output is written to ``<out>.part`` and renamed into
place, so a crash during recovery never leaves a half file under ``out``.
"""

from __future__ import annotations

import itertools
import os
from dataclasses import dataclass
from typing import Optional

from mcap.records import Attachment, Channel, Header, Message, Metadata, Schema
from mcap.writer import CompressionType, Writer

from recorder.mcap_log import DEFAULT_COMPRESSION, LIBRARY
from recorder.reader import SalvageStats, iter_salvaged_records, probe

_COMPRESSION_TYPES = {"none": CompressionType.NONE, "lz4": CompressionType.LZ4, "zstd": CompressionType.ZSTD}
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
    first_log_time: Optional[int]
    last_log_time: Optional[int]
    error: Optional[str]  # why salvage stopped before the end of the valid prefix, if it did

    @property
    def clean(self) -> bool:
        """Nothing but (possibly) a torn tail was lost."""
        return self.corrupt_chunks == 0 and self.orphan_messages == 0 and self.error is None


def recover(in_path: str | os.PathLike[str], out_path: str | os.PathLike[str], *,
            compression: str = DEFAULT_COMPRESSION) -> RecoverReport:
    """Salvage ``in_path`` into a finished MCAP at ``out_path`` (must differ).

    Also works on a finished file (then it is a plain re-chunking copy).
    """
    if os.path.abspath(in_path) == os.path.abspath(out_path):
        raise ValueError("recover() needs a different out_path: the input is evidence")
    if compression not in _COMPRESSION_TYPES:
        raise ValueError(f"compression must be one of {sorted(_COMPRESSION_TYPES)}")
    part = os.fspath(out_path) + PART_SUFFIX
    stats = SalvageStats()
    counts = dict(messages=0, schemas=0, channels=0, metadata=0, attachments=0, orphans=0)
    first: Optional[int] = None
    last: Optional[int] = None
    with open(in_path, "rb") as src:
        state = probe(src)
        records = iter_salvaged_records(src, state, stats)
        with open(part, "wb") as dst:
            writer = Writer(dst, compression=_COMPRESSION_TYPES[compression])
            first_record = next(records, None)
            header = first_record if isinstance(first_record, Header) else Header("", "")
            writer.start(profile=header.profile, library=f"{RECOVERED_BY} ({header.library})")
            schema_ids: dict[int, int] = {}  # input id -> output id
            channel_ids: dict[int, int] = {}
            pending = [] if isinstance(first_record, Header) or first_record is None else [first_record]
            for record in itertools.chain(pending, records):
                if isinstance(record, Message):
                    cid = channel_ids.get(record.channel_id)
                    if cid is None:
                        counts["orphans"] += 1
                        continue
                    writer.add_message(channel_id=cid, log_time=record.log_time, data=record.data,
                                       publish_time=record.publish_time, sequence=record.sequence)
                    counts["messages"] += 1
                    first = record.log_time if first is None else min(first, record.log_time)
                    last = record.log_time if last is None else max(last, record.log_time)
                elif isinstance(record, Channel):
                    if record.id in channel_ids:  # repeated declaration
                        continue
                    channel_ids[record.id] = writer.register_channel(
                        topic=record.topic, message_encoding=record.message_encoding,
                        schema_id=schema_ids.get(record.schema_id, 0), metadata=dict(record.metadata))
                    counts["channels"] += 1
                elif isinstance(record, Schema):
                    if record.id in schema_ids:
                        continue
                    schema_ids[record.id] = writer.register_schema(
                        name=record.name, encoding=record.encoding, data=record.data)
                    counts["schemas"] += 1
                elif isinstance(record, Metadata):
                    writer.add_metadata(record.name, dict(record.metadata))
                    counts["metadata"] += 1
                elif isinstance(record, Attachment):
                    writer.add_attachment(create_time=record.create_time, log_time=record.log_time,
                                          name=record.name, media_type=record.media_type, data=record.data)
                    counts["attachments"] += 1
            writer.finish()
            dst.flush()
            os.fsync(dst.fileno())
    os.replace(part, out_path)
    return RecoverReport(
        in_path=os.fspath(in_path), out_path=os.fspath(out_path), truncated=not state.finished,
        input_bytes=state.size, torn_bytes=state.torn_bytes, messages=counts["messages"],
        schemas=counts["schemas"], channels=counts["channels"], metadata=counts["metadata"],
        attachments=counts["attachments"], corrupt_chunks=stats.corrupt_chunks,
        orphan_messages=counts["orphans"], first_log_time=first, last_log_time=last, error=stats.error,
    )

