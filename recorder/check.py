"""Audit a recording: which messages did the bus lose, and did the recorder lose any?

Every sender numbers its messages per kind (envelope ``seq`` 0, 1, 2 ...)
from its start; a restarted sender (an agent started again, each one-shot
``truav-swarm faults`` command, which sends as ``supervisor``) numbers from
0 again under a new *incarnation* (envelope ``inc``, random per process
start).  So the audit runs per stream = (src, kind, incarnation), and within
a recording:

* a *gap* in one stream's seq numbers = messages that never reached the
  recorder (dropped on the bus or by the sender, or sent before the recorder
  subscribed) — the recorder writes everything it receives; a sender's
  later incarnations started while the recorder ran, so theirs must start
  at seq 0 (the first one may predate the recorder);
* an *unfinished* file (no footer) = the recorder itself died; it lost its
  last <= flush_interval of messages, which show as a cut tail, not as gaps
  (run ``truav log recover`` to finish the file);
* a *corrupt chunk* (bad CRC or compression) = messages lost on disk;
* a *pause* (``pause``/``resume`` on ``control/recorder``) leaves out messages on purpose: the
  ``truav.pause`` metadata names their seq ranges (:mod:`recorder.pause`), and gaps inside them
  count as ``paused``, not missing.

The file is read record by record (the salvage path of :mod:`recorder.reader`),
so a damaged chunk is counted, not fatal.  ``truav log check`` exits 1 when
any of these (or duplicates, reordering, undecodable payloads, or no message at all) is found:
:attr:`CheckReport.problems` lists them.  Figures are exact (computed
offline over the whole file), unlike the online counts of
:meth:`recorder.mcap_log.McapLog.summary`.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Optional

from mcap.records import Channel, Message, Metadata

from recorder.mcap_guard import DAMAGE_METADATA
from recorder.pause import skipped_ranges, stream_label
from recorder.record_modes import PAUSE_METADATA
from recorder.reader import SalvageStats, Source, TopicFilter, iter_salvaged_records, open_source, probe
from recorder.schemas import decode_envelope

MAX_RANGES_SHOWN = 4
MAX_STREAMS_NAMED = 3  # streams a problem line names (the table lists them all)


@dataclass
class SenderCheck:
    """Sequence audit of one (src, kind, incarnation) stream."""

    src: str
    kind: str
    inc: int = 0  # the sender's incarnation (0: a payload without one, from before incarnations)
    incarnation: int = 1  # its rank among the src's incarnations, in order of their first message
    count: int = 0  # messages present (duplicates included)
    first_seq: Optional[int] = None  # lowest seq present
    last_seq: Optional[int] = None  # highest seq present
    missing: int = 0  # seq numbers in [first_seq, last_seq] never recorded
    gap_ranges: list[tuple[int, int]] = field(default_factory=list)  # inclusive (lo, hi)
    duplicates: int = 0  # messages repeating a seq already recorded
    out_of_order: int = 0  # messages with a seq below one recorded before them (not duplicates)
    paused: int = 0  # seq numbers left out while the recorder was paused (truav.pause): not a loss

    @property
    def gaps(self) -> int:
        return len(self.gap_ranges)

    @property
    def label(self) -> str:
        """``uav/1 action, incarnation 2 (inc 1f3a...)``: how a problem names the stream."""
        return f"{self.src} {self.kind}, incarnation {self.incarnation} (inc {self.inc:016x})"

    def ranges_text(self, max_ranges: int = 4) -> str:
        text = ", ".join(f"{lo}" if lo == hi else f"{lo}-{hi}" for lo, hi in self.gap_ranges[:max_ranges])
        return text + (f", ... (+{self.gaps - max_ranges})" if self.gaps > max_ranges else "")


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
    senders: dict[tuple[str, str, int], SenderCheck]  # (src, kind, inc) ->
    corrupt_chunks: int = 0  # chunks whose CRC or compression was bad: their messages are lost
    read_error: Optional[str] = None  # why reading stopped before the end, if it did
    invalid_records: int = 0  # schemas, channels, messages, metadata left out as invalid (recorder.mcap_guard)
    damage_notes: list[str] = field(default_factory=list)  # the first reasons, each naming a record
    made_from_damaged: list[str] = field(default_factory=list)  # truav.damage records: written from damaged files

    @property
    def damaged(self) -> bool:
        """Chunks or records of this file were left out as damaged (what `report`, `play`, `resim` refuse)."""
        return bool(self.corrupt_chunks or self.read_error or self.invalid_records)

    @property
    def missing(self) -> int:
        """Messages the bus lost, over all senders."""
        return sum(s.missing for s in self.senders.values())

    @property
    def paused(self) -> int:
        """Messages left out on purpose while the recorder was paused."""
        return sum(s.paused for s in self.senders.values())

    @property
    def problems(self) -> list[str]:
        """What is wrong with the recording, one phrase each; empty for a complete one."""
        out = []
        if self.messages == 0:
            out.append("no bus messages in the file (nothing was recorded, or nothing survived)")
        if not self.finished:
            out.append("unfinished (the recorder died; run `truav log recover` to finish the file)")
        if self.corrupt_chunks:
            out.append(f"{self.corrupt_chunks} corrupt chunk(s) (their messages are lost)")
        if self.invalid_records:
            out.append(f"{self.invalid_records} invalid record(s) left out ({'; '.join(self.damage_notes)})")
        for what in self.made_from_damaged:
            out.append(f"written from a damaged recording ({what})")
        if self.read_error:
            out.append(f"damaged, unreadable after some point ({self.read_error})")
        streams = sorted(self.senders.values(), key=lambda c: (c.src, c.kind, c.incarnation))
        if self.missing:
            gappy = [c for c in streams if c.missing]
            where = "; ".join(f"{c.label}: seq {c.ranges_text(2)}" for c in gappy[:MAX_STREAMS_NAMED])
            more = f"; ... ({len(gappy) - MAX_STREAMS_NAMED} more streams)" if len(gappy) > MAX_STREAMS_NAMED else ""
            out.append(f"{self.missing} message(s) missing by seq ({where}{more})")
        for attr, what in (("duplicates", "duplicate(s)"), ("out_of_order", "out of order")):
            bad = [c for c in streams if getattr(c, attr)]
            if bad:
                where = "; ".join(f"{c.label}: {getattr(c, attr)}" for c in bad[:MAX_STREAMS_NAMED])
                more = f"; ... ({len(bad) - MAX_STREAMS_NAMED} more streams)" if len(bad) > MAX_STREAMS_NAMED else ""
                out.append(f"{sum(getattr(c, attr) for c in bad)} {what} ({where}{more})")
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
        if self.corrupt_chunks or self.read_error or self.invalid_records:
            state += (f"; DAMAGED: {self.corrupt_chunks} corrupt chunk(s) skipped, {self.invalid_records} invalid "
                      f"record(s) left out"
                      + (f", stopped early: {self.read_error}" if self.read_error else ""))
        lines = [
            f"{self.path}: {state}",
            f"{self.messages} messages over {span:.3f} s, {self.undecodable} undecodable, "
            f"{self.missing} missing by seq (lost before reaching the recorder)"
            + (f", {self.paused} not recorded while paused" if self.paused else ""),
            "",
        ]
        rows = [("src", "kind", "#", "inc", "msgs", "first", "last", "missing", "gaps", "dup", "ooo", "gap ranges")]
        for s in sorted(self.senders.values(), key=lambda c: (c.src, c.kind, c.incarnation)):
            rows.append((s.src, s.kind, s.incarnation, f"{s.inc:016x}", s.count, s.first_seq, s.last_seq, s.missing,
                         s.gaps, s.duplicates, s.out_of_order, s.ranges_text(max_ranges) or "-"))
        lines += _table(rows, numeric=(2, *range(4, 11)))
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

    def __init__(self, src: str, kind: str, inc: int, incarnation: int) -> None:
        self.check = SenderCheck(src=src, kind=kind, inc=inc, incarnation=incarnation)
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

    def finish(self, paused: list[tuple[int, int]] = ()) -> SenderCheck:  # type: ignore[assignment]
        """The stream's figures; seq ranges in ``paused`` were left out on purpose (not missing)."""
        check = self.check
        ordered = sorted(self.seen)
        if ordered:
            check.first_seq, check.last_seq = ordered[0], ordered[-1]
            if check.incarnation > 1 and ordered[0] > 0:  # started while recording: its first messages are lost
                self._gap(0, ordered[0] - 1, paused)
            for lo, hi in zip(ordered, ordered[1:]):
                if hi > lo + 1:
                    self._gap(lo + 1, hi - 1, paused)
        return check

    def _gap(self, lo: int, hi: int, paused: list[tuple[int, int]]) -> None:
        """Seq lo..hi absent: what a pause covers is paused, each remaining run a gap."""
        check = self.check
        for p_lo, p_hi in sorted(paused):
            if p_hi < lo or p_lo > hi:
                continue
            if p_lo > lo:
                check.gap_ranges.append((lo, p_lo - 1))
                check.missing += p_lo - lo
            covered_hi = min(hi, p_hi)
            check.paused += covered_hi - max(lo, p_lo) + 1
            lo = covered_hi + 1
            if lo > hi:
                return
        check.gap_ranges.append((lo, hi))
        check.missing += hi - lo + 1


def check(source: Source) -> CheckReport:
    """Audit the bus channels of a recording (finished or not; mirrors ignored)."""
    stats = SalvageStats()
    keep = TopicFilter()  # bus channels only: the JSON mirrors repeat them
    with open_source(source) as stream:
        state = probe(stream)
        audits: dict[tuple[str, str, int], _SeqAudit] = {}
        incarnations: dict[str, dict[int, int]] = {}  # src -> {inc: rank, in order of first message}
        channels: dict[str, ChannelCheck] = {}
        topics: dict[int, str] = {}
        messages = undecodable = 0
        first: Optional[int] = None
        last: Optional[int] = None
        paused: dict[str, list[tuple[int, int]]] = {}  # stream label -> seq ranges left out by pauses
        made_from_damaged: list[str] = []
        for record in iter_salvaged_records(stream, state, stats):
            if isinstance(record, Channel):
                topics.setdefault(record.id, record.topic)
                continue
            if isinstance(record, Metadata) and record.name == DAMAGE_METADATA:
                made_from_damaged.append(f"{record.metadata.get('source', '?')[:200]}: "
                                         f"{record.metadata.get('what', '?')[:500]}")
                continue
            if isinstance(record, Metadata) and record.name == PAUSE_METADATA:
                for label, span in skipped_ranges(record.metadata).items():
                    paused.setdefault(label, []).append(span)
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
            audit = audits.get((env.src, env.kind, env.inc))
            if audit is None:
                ranks = incarnations.setdefault(env.src, {})
                rank = ranks.setdefault(env.inc, len(ranks) + 1)
                audit = audits[(env.src, env.kind, env.inc)] = _SeqAudit(env.src, env.kind, env.inc, rank)
            audit.add(env.seq)
    name = os.fspath(source) if isinstance(source, (str, os.PathLike)) else "<stream>"
    return CheckReport(
        path=name, finished=state.finished, torn_bytes=state.torn_bytes, messages=messages,
        undecodable=undecodable, first_log_time=first, last_log_time=last, channels=channels,
        senders={k: a.finish(paused.get(stream_label(*k), [])) for k, a in audits.items()},
        corrupt_chunks=stats.corrupt_chunks, read_error=stats.error, invalid_records=stats.invalid_records,
        damage_notes=[n for n in stats.notes if not n.startswith("chunk at")], made_from_damaged=made_from_damaged,
    )
