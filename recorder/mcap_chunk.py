"""The record bytes of an MCAP file: the chunk being filled, and the summary section.

:class:`OpenChunk` packs the two per-message hot records, ``Message`` and its
``MessageIndex`` entries, with one precompiled :class:`struct.Struct` each,
byte for byte as ``mcap.records.Message.write`` / ``MessageIndex.write`` lay
them out (the tests parse them back with mcap's readers), and seals itself
into a ``Chunk`` record; :func:`summary_section` lays out the summary.  Every
other record is serialised with mcap's own record classes.  Used by
:class:`recorder.mcap_writer.McapWriter`.
"""

from __future__ import annotations

import struct
import zlib
from typing import Callable

from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import Chunk, ChunkIndex, McapRecord, SummaryOffset

__all__ = ["OpenChunk", "summary_section", "serialise"]

# opcode, record length, channel_id, sequence, log_time, publish_time (then data)
_MESSAGE_HEAD = struct.Struct("<BQHIQQ")
_MESSAGE_FIXED = 2 + 4 + 8 + 8
# opcode, record length, channel_id, byte length of the (log_time, offset) array
_MESSAGE_INDEX_HEAD = struct.Struct("<BQHI")
_OP_MESSAGE = int(Opcode.MESSAGE)
_pack_message_head = _MESSAGE_HEAD.pack
_OP_MESSAGE_INDEX = int(Opcode.MESSAGE_INDEX)


class OpenChunk:
    """The chunk being filled: its Message records, their index, their log-time range.

    Schema and Channel records go in too (:meth:`add_record`), ahead of their
    first user; a chunk without messages keeps them for the next one (as
    mcap's Writer does).
    """

    __slots__ = ("data", "index", "n", "start", "end", "opened", "_clock")

    def __init__(self, clock: Callable[[], float]) -> None:
        self._clock = clock
        self.data = bytearray()
        self.index: dict[int, list[int]] = {}  # channel id -> flat [log_time, offset, ...]
        self.n = 0  # messages
        self.start = 0  # log-time range of the messages
        self.end = 0
        self.opened = 0.0  # clock reading at the first message

    def add_record(self, record: McapRecord) -> None:
        self.data += serialise(record)

    def append(self, cid: int, seq: int, log_time: int, pub: int, data: bytes) -> None:
        """Add one Message record to the open chunk and index it; per-channel counts
        and file-wide times are folded in when the chunk closes (cheaper)."""
        head = _pack_message_head(_OP_MESSAGE, _MESSAGE_FIXED + len(data), cid, seq, log_time, pub)  # may raise
        chunk = self.data
        index = self.index.get(cid)
        if index is None:
            index = self.index[cid] = []
        index.append(log_time)
        index.append(len(chunk))
        chunk += head
        chunk += data
        if self.n:
            if log_time > self.end:
                self.end = log_time
            elif log_time < self.start:
                self.start = log_time
        else:
            self.opened = self._clock()
            self.start = self.end = log_time
        self.n += 1

    def seal(self, compression: str, compress: Callable[[bytes], bytes], offset: int,
             msg_counts: dict[int, int]) -> tuple[bytes, ChunkIndex]:
        """The Chunk record and its MessageIndex records as one blob to write at ``offset``, and the
        chunk's index entry; adds the messages per channel to ``msg_counts`` (:meth:`reset` empties it)."""
        raw = bytes(self.data)
        chunk = Chunk(
            compression=compression,
            data=compress(raw),
            message_start_time=self.start,
            message_end_time=self.end,
            uncompressed_crc=zlib.crc32(raw),
            uncompressed_size=len(raw),
        )
        builder = RecordBuilder()
        chunk.write(builder)
        chunk_length = builder.count
        parts = [builder.end()]
        position = offset + chunk_length
        index_offsets: dict[int, int] = {}
        for cid, flat in self.index.items():
            msg_counts[cid] += len(flat) // 2
            body = struct.pack(f"<{len(flat)}Q", *flat)
            parts.append(_MESSAGE_INDEX_HEAD.pack(_OP_MESSAGE_INDEX, 2 + 4 + len(body), cid, len(body)))
            parts.append(body)
            index_offsets[cid] = position
            position += _MESSAGE_INDEX_HEAD.size + len(body)
        blob = b"".join(parts)
        entry = ChunkIndex(
            message_start_time=chunk.message_start_time,
            message_end_time=chunk.message_end_time,
            chunk_start_offset=offset,
            chunk_length=chunk_length,
            message_index_offsets=index_offsets,
            message_index_length=len(blob) - chunk_length,
            compression=chunk.compression,
            compressed_size=len(chunk.data),
            uncompressed_size=chunk.uncompressed_size,
        )
        return blob, entry

    def reset(self) -> None:
        """Empty, once the sealed chunk is written."""
        self.data = bytearray()
        self.index = {}
        self.n = 0


def summary_section(summary_start: int, groups: list[tuple[Opcode, list[McapRecord]]]) -> tuple[bytes, int, int]:
    """The summary section starting at file offset ``summary_start``: the record groups (empty ones
    left out), then a SummaryOffset per group.  Returns its bytes, the offset of its SummaryOffset
    records and the footer's summary CRC."""
    summary = RecordBuilder()
    offsets: list[SummaryOffset] = []
    for opcode, records in groups:
        if not records:
            continue
        start = summary.count
        for record in records:
            record.write(summary)
        offsets.append(SummaryOffset(group_opcode=opcode, group_start=summary_start + start,
                                     group_length=summary.count - start))
    summary_offset_start = summary_start + summary.count
    for offset_record in offsets:
        offset_record.write(summary)
    data = summary.end()
    crc = zlib.crc32(data)
    # the footer CRC also covers the footer's own fields up to summary_crc
    crc = zlib.crc32(struct.pack("<BQQQ", Opcode.FOOTER, 8 + 8 + 4, summary_start, summary_offset_start), crc)
    return data, summary_offset_start, crc


def serialise(record: McapRecord) -> bytes:
    """One record's bytes, through mcap's own ``write``."""
    builder = RecordBuilder()
    record.write(builder)
    return builder.end()
