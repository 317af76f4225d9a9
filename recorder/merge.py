"""`truav log merge`: several recordings (parts of a split run, cuts, runs) as one, ``mcap merge``'s way.

* Messages come out in log-time order (each input read in log-time order by mcap's indexed reader,
  the inputs merged with :func:`heapq.merge`; ties in input order).
* Inputs are ordered first: the parts of one split recording (a ``truav.part`` metadata record:
  session, 1-based part) together, in part order, placed by their session's first message; any
  other file by its first message. A ``<stem>.parts.json`` index stands for its parts.
* Schemas and channels are written once (:class:`recorder.log_copy.OutputChannels`).
* A message present in several inputs is written once: a duplicate is the same topic, log time,
  publish time and payload bytes (overlapping cuts, or parts of one run given twice).
* A cut's kept last-before messages (re-stamped to the cut's start, listed in its ``truav.cut``
  record) get their original log times back, so cutting a recording in pieces and merging the
  pieces gives back the recording's messages, each once.
* Metadata records are kept, identical ones once; the inputs' ``truav.part`` and ``truav.cut``
  records are folded into one ``truav.merge`` record saying what was merged from what.
"""

from __future__ import annotations

import contextlib
import dataclasses
import heapq
import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator, Optional, Sequence

from mcap.records import Metadata

from recorder.cut import CUT_METADATA, KeptMessages
from recorder.log_copy import FinishedLog, LogMessage, OutputChannels, dump, new_writer, open_finished, \
    written_atomically
from recorder.mcap_guard import DAMAGE_METADATA, ReadDamage
from recorder.mcap_writer import LIBRARY
from recorder.record_modes import PART_METADATA, PARTS_INDEX_SUFFIX
from truav.errors import UserError

__all__ = ["MERGE_METADATA", "PART_METADATA", "PARTS_INDEX_SUFFIX", "MergeReport", "merge", "expand_inputs"]

MERGE_METADATA = "truav.merge"
FOLDED = (PART_METADATA, CUT_METADATA)
MAX_PARTS = 100_000
"""Highest part number taken from a truav.part record (a recorder splitting every second for a day writes
86,400); a larger one is ignored, so a forged 10**30 cannot make the missing-parts list huge."""


@dataclass
class InputInfo:
    path: Path
    rank: int  # position among the inputs after ordering
    messages: int
    first_log_time: Optional[int]
    last_log_time: Optional[int]
    part: Optional[dict[str, str]]  # its truav.part record
    cuts: list[dict[str, str]]  # its truav.cut records (window, source; not the kept list)

    @property
    def session(self) -> Optional[str]:
        return None if self.part is None else self.part.get("session") or None

    @property
    def part_number(self) -> Optional[int]:
        """The part's number, None when absent or outside 1..MAX_PARTS (a record from elsewhere)."""
        try:
            number = None if self.part is None else int(str(self.part.get("part", "")))
        except ValueError:
            return None
        return number if number is not None and 1 <= number <= MAX_PARTS else None

    def as_json(self) -> dict:
        return {"file": self.path.name, "messages": self.messages, "first_log_time_ns": self.first_log_time,
                "last_log_time_ns": self.last_log_time,
                "part": None if self.part is None else {k: self.part.get(k) for k in ("session", "part", "reason")},
                "cuts": [{k: c.get(k) for k in ("source", "start_ns", "end_ns", "from_tick", "to_tick", "topics",
                                                "exclude")} for c in self.cuts]}


@dataclass
class MergeReport:
    out_path: str
    inputs: list[InputInfo]
    messages: int = 0  # written
    duplicates: int = 0  # dropped as duplicates
    restored: int = 0  # cuts' kept messages given back their original log times
    channels: int = 0
    metadata: int = 0  # records written (truav.merge included)
    first_log_time: Optional[int] = None
    last_log_time: Optional[int] = None
    missing_parts: dict[str, list[int]] = field(default_factory=dict)  # session -> part numbers not given
    damaged: dict[str, ReadDamage] = field(default_factory=dict)  # input file -> what of it was left out


def expand_inputs(paths: Sequence[str | os.PathLike[str]]) -> list[Path]:
    """The files to merge: a ``<stem>.parts.json`` index stands for the parts it lists (beside it)."""
    out: list[Path] = []
    for raw in paths:
        path = Path(raw)
        if not path.name.endswith(PARTS_INDEX_SUFFIX):
            out.append(path)
            continue
        try:
            index = json.loads(path.read_text())
            names = [row["path"] for row in index["parts"]]
        except OSError as exc:
            raise UserError(f"IN {path}: {exc.strerror or exc}") from None
        except (ValueError, KeyError, TypeError):
            raise UserError(f"IN {path}: not a parts index (JSON with parts[].path)") from None
        if not names:
            raise UserError(f"IN {path}: the index lists no parts")
        out += [path.with_name(str(name)) for name in names]
    return out


def merge(out_path: str | os.PathLike[str], in_paths: Sequence[str | os.PathLike[str]]) -> MergeReport:
    """Merge ``in_paths`` (finished recordings, or parts indexes) into ``out_path``; UserError before
    anything is written for an input that is not a finished MCAP."""
    named = [os.path.realpath(p) for p in in_paths]
    twice = next((p for k, p in enumerate(in_paths) if named[k] in named[:k]), None)
    if twice is not None:  # as replay refuses it: a slip of the command line, not a second input
        raise UserError(f"IN {twice}: the same file is named twice")
    paths = expand_inputs(in_paths)
    if not paths:
        raise UserError("IN: give at least one recording")
    out_abs = Path(out_path).resolve()
    for path in paths:
        if path.resolve() == out_abs:
            raise UserError(f"OUT {out_path}: is also an input")
    with contextlib.ExitStack() as stack:
        logs = [stack.enter_context(open_finished(p)) for p in paths]
        entries = [(log, meta, _info(log, meta)) for log in logs for meta in (log.metadata(),)]
        _ordered([info for _, _, info in entries])  # ranks them
        entries.sort(key=lambda e: e[2].rank)
        report = MergeReport(os.fspath(out_path), [info for _, _, info in entries],
                             missing_parts=_missing_parts([info for _, _, info in entries]))
        with written_atomically(out_path) as stream:
            writer = new_writer(stream, f"{LIBRARY} merge")
            channels = OutputChannels(writer)
            seen_meta: set[tuple] = set()
            seen_attachments: set[tuple] = set()
            for log, meta, _ in entries:
                for record in meta:
                    key = (record.name, tuple(sorted(record.metadata.items())))
                    if record.name in FOLDED or key in seen_meta:
                        continue
                    seen_meta.add(key)
                    writer.add_metadata(record.name, dict(record.metadata))
                    report.metadata += 1
                for attachment in log.attachments():
                    key = (attachment.name, attachment.log_time, bytes(attachment.data))
                    if key not in seen_attachments:
                        seen_attachments.add(key)
                        writer.add_attachment(attachment)
            restored = [0]
            streams = [_ranked(info.rank, _restored(log, KeptMessages(meta), restored)) for log, meta, info in entries]
            now: Optional[int] = None
            at_now: set[tuple] = set()  # (topic, publish time, payload) of the messages written at log time `now`
            for rank, item in heapq.merge(*streams, key=lambda e: e[1].message.log_time):
                m = item.message
                if m.log_time != now:
                    now, at_now = m.log_time, set()
                key = (item.channel.topic, m.publish_time, bytes(m.data))
                if key in at_now:
                    report.duplicates += 1
                    continue
                at_now.add(key)
                cid = channels.channel_id(rank, item.schema, item.channel)
                writer.add_message(cid, m.sequence, m.log_time, m.publish_time, m.data)
                report.messages += 1
                report.first_log_time = m.log_time if report.first_log_time is None else report.first_log_time
                report.last_log_time = m.log_time
            report.damaged = {log.path.name: log.damage for log, _, _ in entries if log.damage.damaged}
            for name, damage in report.damaged.items():  # so that `truav log check` of OUT does not call it sound
                writer.add_metadata(DAMAGE_METADATA, damage.as_metadata(name))
                report.metadata += 1
            report.restored = restored[0]
            report.channels = len(channels.topics)
            writer.add_metadata(MERGE_METADATA, _merge_record(report))
            report.metadata += 1
            writer.close()
    return report


def _info(log: FinishedLog, meta: list[Metadata]) -> InputInfo:
    part = next((dict(r.metadata) for r in reversed(meta) if r.name == PART_METADATA), None)
    cuts = [dict(r.metadata) for r in meta if r.name == CUT_METADATA]
    return InputInfo(path=log.path, rank=-1, messages=log.message_count, first_log_time=log.first_log_time,
                     last_log_time=log.last_log_time, part=part, cuts=cuts)


def _ordered(infos: list[InputInfo]) -> list[InputInfo]:
    """Parts of a session together in part order, placed at the session's first message; others by their first."""
    big = 1 << 64

    def first(info: InputInfo) -> int:
        return big if info.first_log_time is None else info.first_log_time

    session_first: dict[str, int] = {}
    for info in infos:
        if info.session is not None:
            session_first[info.session] = min(session_first.get(info.session, big), first(info))
    keyed = sorted(enumerate(infos), key=lambda e: (
        session_first[e[1].session] if e[1].session is not None else first(e[1]),
        e[1].session or "", e[1].part_number or 0, e[0]))
    for rank, (_, info) in enumerate(keyed):
        info.rank = rank
    return [info for _, info in keyed]


def _missing_parts(infos: list[InputInfo]) -> dict[str, list[int]]:
    given: dict[str, set[int]] = {}
    for info in infos:
        if info.session is not None and info.part_number is not None:
            given.setdefault(info.session, set()).add(info.part_number)
    return {s: sorted(set(range(1, max(parts) + 1)) - parts) for s, parts in given.items()
            if set(range(1, max(parts) + 1)) - parts}


def _ranked(rank: int, items: Iterator[LogMessage]) -> Iterator[tuple[int, LogMessage]]:
    for item in items:
        yield rank, item


def _restored(log: FinishedLog, kept: KeptMessages, count: list[int]) -> Iterator[LogMessage]:
    """``log``'s messages in log-time order, a cut's kept messages at their original log times."""
    if not kept:
        yield from log.messages()
        return
    pending: list[tuple[int, int, LogMessage]] = []  # heap of (original log time, arrival, message)
    for n, item in enumerate(log.messages()):
        m = item.message
        original = kept.original_log_time(item.channel.topic, m.log_time, m.publish_time, m.data)
        if original is not None:
            count[0] += 1
            heapq.heappush(pending, (original, n, item._replace(message=dataclasses.replace(m, log_time=original))))
            continue
        while pending and pending[0][0] <= m.log_time:
            yield heapq.heappop(pending)[2]
        yield item
    while pending:
        yield heapq.heappop(pending)[2]


def _merge_record(report: MergeReport) -> dict[str, str]:
    sessions: dict[str, list[int]] = {}
    for info in report.inputs:
        if info.session is not None and info.part_number is not None:
            sessions.setdefault(info.session, []).append(info.part_number)
    return {
        "inputs": dump([info.as_json() for info in report.inputs]),
        "messages": str(report.messages),
        "duplicates_dropped": str(report.duplicates),
        "restored_kept_messages": str(report.restored),
        "sessions": dump(sessions),
        "missing_parts": dump(report.missing_parts),
    }
