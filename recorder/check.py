"""Audit a recording: which messages did the bus lose, and did the recorder lose any?

Every sender numbers its messages per kind (envelope ``seq`` 0, 1, 2 ...),
so within a recording:

* a *gap* in one sender's seq numbers = messages that never reached the
  recorder (dropped on the bus or by the sender, or sent before the recorder
  subscribed) — the recorder writes everything it receives;
* an *unfinished* file (no footer) = the recorder itself died; it lost its
  last <= flush_interval of messages, which show as a cut tail, not as gaps
  (run ``truav log recover`` to finish the file);
* a *corrupt chunk* (bad CRC or compression) = messages lost on disk.

The file is read record by record (the salvage path of :mod:`recorder.reader`),
so a damaged chunk is counted, not fatal.  ``truav log check`` exits 1 when
any of these (or duplicates, reordering, undecodable payloads) is found:
:attr:`CheckReport.problems` lists them.  Figures are exact (computed
offline over the whole file), unlike the online counts of
:meth:`recorder.mcap_log.McapLog.summary`.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Optional

from mcap.records import Channel, Message

from recorder.reader import SalvageStats, Source, TopicFilter, iter_salvaged_records, open_source, probe
from recorder.schemas import decode_envelope

MAX_RANGES_SHOWN = 4


@dataclass
class SenderCheck:
    """Sequence audit of one (src, kind) sender."""

    src: str
    kind: str
    count: int = 0  # messages present (duplicates included)
    first_seq: Optional[int] = None  # lowest seq present
    last_seq: Optional[int] = None  # highest seq present
    missing: int = 0  # seq numbers in [first_seq, last_seq] never recorded
    gap_ranges: list[tuple[int, int]] = field(default_factory=list)  # inclusive (lo, hi)
    duplicates: int = 0  # messages repeating a seq already recorded
    out_of_order: int = 0  # messages with a seq below one recorded before them (not duplicates)

    @property
    def gaps(self) -> int:
        return len(self.gap_ranges)


@dataclass
class ChannelCheck:
    messages: int = 0
    undecodable: int = 0


@dataclass
class CheckReport:
    path: str
    finished: bool  # False: the recorder died; its file lacks the tail and the summary
    torn_bytes: int
    messages: int
    undecodable: int
    first_log_time: Optional[int]
    last_log_time: Optional[int]
    channels: dict[str, ChannelCheck]
    senders: dict[tuple[str, str], SenderCheck]
    corrupt_chunks: int = 0  # chunks whose CRC or compression was bad: their messages are lost
    read_error: Optional[str] = None  # why reading stopped before the end, if it did

    @property
    def missing(self) -> int:
        """Messages the bus lost, over all senders."""
        return sum(s.missing for s in self.senders.values())

    @property
    def problems(self) -> list[str]:
        """What is wrong with the recording, one phrase each; empty for a complete one."""
        out = []
        if not self.finished:
            out.append("unfinished (the recorder died; run `truav log recover` to finish the file)")
        if self.corrupt_chunks:
            out.append(f"{self.corrupt_chunks} corrupt chunk(s) (their messages are lost)")
        if self.read_error:
            out.append(f"unreadable after some point ({self.read_error})")
        if self.missing:
            out.append(f"{self.missing} message(s) missing by seq")
        duplicates = sum(s.duplicates for s in self.senders.values())
        reordered = sum(s.out_of_order for s in self.senders.values())
        if duplicates:
            out.append(f"{duplicates} duplicate(s)")
        if reordered:
            out.append(f"{reordered} out of order")
        if self.undecodable:
            out.append(f"{self.undecodable} undecodable")
        return out

    def format_report(self, max_ranges: int = MAX_RANGES_SHOWN) -> str:
        """A plain-text report: file state, one row per sender, one row per channel."""
        span = (
            (self.last_log_time - self.first_log_time) / 1e9
            if self.first_log_time is not None and self.last_log_time is not None
            else 0.0
        )
        state = ("finished" if self.finished else
                 f"UNFINISHED (recorder died; {self.torn_bytes} torn bytes; run `truav log recover`)")
        if self.corrupt_chunks or self.read_error:
            state += (f"; DAMAGED: {self.corrupt_chunks} corrupt chunk(s) skipped"
                      + (f", stopped early: {self.read_error}" if self.read_error else ""))
        lines = [
            f"{self.path}: {state}",
            f"{self.messages} messages over {span:.3f} s, {self.undecodable} undecodable, "
            f"{self.missing} missing by seq (lost before reaching the recorder)",
            "",
        ]
        rows = [("src", "kind", "msgs", "first", "last", "missing", "gaps", "dup", "ooo", "gap ranges")]
        for (src, kind), s in sorted(self.senders.items()):
            ranges = ", ".join(f"{lo}" if lo == hi else f"{lo}-{hi}" for lo, hi in s.gap_ranges[:max_ranges])
            if s.gaps > max_ranges:
                ranges += f", ... (+{s.gaps - max_ranges})"
            rows.append((src, kind, s.count, s.first_seq, s.last_seq, s.missing, s.gaps,
                         s.duplicates, s.out_of_order, ranges or "-"))
        lines += _table(rows, numeric=range(2, 9))
        lines.append("")
        rows = [("channel", "msgs", "undecodable")]
        rows += [(key, c.messages, c.undecodable) for key, c in sorted(self.channels.items())]
        lines += _table(rows, numeric=(1, 2))
        return "\n".join(lines)


def _table(rows: list[tuple], numeric: "range | tuple[int, ...]") -> list[str]:
    cells = [["-" if v is None else str(v) for v in row] for row in rows]
    widths = [max(len(row[i]) for row in cells) for i in range(len(cells[0]))]
    out = []
    for row in cells:
        parts = [cell.rjust(w) if i in numeric else cell.ljust(w) for i, (cell, w) in enumerate(zip(row, widths))]
        out.append("  ".join(parts).rstrip())
    return out


class _SeqAudit:
    """Per-sender accumulator: seen set + running max, finished into a SenderCheck."""

    __slots__ = ("check", "seen", "top")

    def __init__(self, src: str, kind: str) -> None:
        self.check = SenderCheck(src=src, kind=kind)
        self.seen: set[int] = set()
        self.top: Optional[int] = None

    def add(self, seq: int) -> None:
        self.check.count += 1
        if seq in self.seen:
            self.check.duplicates += 1
            return
        if self.top is not None and seq < self.top:
            self.check.out_of_order += 1
        self.seen.add(seq)
        if self.top is None or seq > self.top:
            self.top = seq

    def finish(self) -> SenderCheck:
        check = self.check
        ordered = sorted(self.seen)
        if ordered:
            check.first_seq, check.last_seq = ordered[0], ordered[-1]
            for lo, hi in zip(ordered, ordered[1:]):
                if hi > lo + 1:
                    check.gap_ranges.append((lo + 1, hi - 1))
                    check.missing += hi - lo - 1
        return check


def check(source: Source) -> CheckReport:
    """Audit the bus channels of a recording (finished or not; mirrors ignored)."""
    stats = SalvageStats()
    keep = TopicFilter()  # bus channels only: the JSON mirrors repeat them
    with open_source(source) as stream:
        state = probe(stream)
        audits: dict[tuple[str, str], _SeqAudit] = {}
        channels: dict[str, ChannelCheck] = {}
        topics: dict[int, str] = {}
        messages = undecodable = 0
        first: Optional[int] = None
        last: Optional[int] = None
        for record in iter_salvaged_records(stream, state, stats):
            if isinstance(record, Channel):
                topics.setdefault(record.id, record.topic)
                continue
            key = topics.get(record.channel_id) if isinstance(record, Message) else None
            if key is None or not keep(key):  # other records, mirrors, messages of an undeclared channel
                continue
            payload, log_time = record.data, record.log_time
            messages += 1
            first = log_time if first is None or log_time < first else first
            last = log_time if last is None or log_time > last else last
            channel = channels.get(key)
            if channel is None:
                channel = channels[key] = ChannelCheck()
            channel.messages += 1
            env = decode_envelope(payload)
            if env is None:
                undecodable += 1
                channel.undecodable += 1
                continue
            audit = audits.get((env.src, env.kind))
            if audit is None:
                audit = audits[(env.src, env.kind)] = _SeqAudit(env.src, env.kind)
            audit.add(env.seq)
    name = os.fspath(source) if isinstance(source, (str, os.PathLike)) else "<stream>"
    return CheckReport(
        path=name, finished=state.finished, torn_bytes=state.torn_bytes, messages=messages,
        undecodable=undecodable, first_log_time=first, last_log_time=last, channels=channels,
        senders={k: a.finish() for k, a in audits.items()},
        corrupt_chunks=stats.corrupt_chunks, read_error=stats.error,
    )
