"""`truav log cut`: a window of a recording, by time or by tick, as a recording of its own.

The window is ``[start, end)`` of log time (receive time): given in seconds from the recording's
first message, in absolute nanoseconds, or by tick (``from_tick..to_tick``: from the log time of
the first world tick message in that range to that of the next tick message outside it, so the
observations, actions and beacons of the last tick stay in). Topics are chosen with globs as
replay's (``*`` also matches ``/``); a JSON mirror goes with the key it mirrors.

So that a player or a late joiner starts from the state at the window's start, the last message of
every chosen channel before the window is kept, re-stamped to the window's start (a replay of the
cut then starts at once, not after the silence before the window) and listed in the ``truav.cut``
metadata record with its original log time, publish time and CRC-32: :class:`KeptMessages` finds
them again, and ``truav log merge`` puts them back where they were. Every metadata record of the
input (run config, recording facts) is kept; ``truav.cut`` says what was cut from what.
"""

from __future__ import annotations

import json
import os
import zlib
from dataclasses import dataclass, field
from fnmatch import fnmatchcase
from pathlib import Path
from typing import Iterable, Optional, Sequence

from mcap.records import Channel, Metadata

from recorder.log_copy import (FinishedLog, LogMessage, OutputChannels, dump, new_writer, open_finished,
                               written_atomically)
from recorder.mcap_guard import DAMAGE_METADATA, DamagedRecording, ReadDamage
from recorder.mcap_writer import LIBRARY
from recorder.mirror_channels import META_MIRROR_OF, is_mirror_topic
from recorder.schemas import envelope_fields
from truav.errors import UserError

__all__ = ["CUT_METADATA", "TICK_PATTERN", "Window", "WindowSpec", "CutReport", "KeptMessages", "cut",
           "resolve_window", "ChannelChoice"]

CUT_METADATA = "truav.cut"
"""Metadata record of a cut: source, window, topics, and ``kept`` (the re-stamped last-before messages)."""
TICK_PATTERN = "truav/*/world/tick"
NS = 1_000_000_000


@dataclass(frozen=True)
class WindowSpec:
    """The window as the user gave it (each bound optional; seconds and ns of one bound exclusive)."""

    start_s: Optional[float] = None  # seconds from the recording's first message
    end_s: Optional[float] = None
    start_ns: Optional[int] = None  # absolute log time
    end_ns: Optional[int] = None
    from_tick: Optional[int] = None
    to_tick: Optional[int] = None

    @property
    def by_tick(self) -> bool:
        return self.from_tick is not None or self.to_tick is not None

    @property
    def by_time(self) -> bool:
        return any(v is not None for v in (self.start_s, self.end_s, self.start_ns, self.end_ns))


@dataclass(frozen=True)
class Window:
    """Resolved: ``[start_ns, end_ns)`` of log time; None = from the first / to the last message."""

    start_ns: Optional[int]
    end_ns: Optional[int]

    def holds(self, log_time: int) -> bool:
        return (self.start_ns is None or log_time >= self.start_ns) and (self.end_ns is None or log_time < self.end_ns)


def resolve_window(log: FinishedLog, spec: WindowSpec) -> Window:
    """The log-time window of ``spec`` in ``log``; UserError for a contradictory or empty one."""
    if spec.by_tick and spec.by_time:
        raise UserError("--from-tick/--to-tick: give a window by tick or by time, not both")
    if spec.start_s is not None and spec.start_ns is not None:
        raise UserError("--start and --start-ns: give the start once")
    if spec.end_s is not None and spec.end_ns is not None:
        raise UserError("--end and --end-ns: give the end once")
    if spec.by_tick:
        return _tick_window(log, spec.from_tick, spec.to_tick)
    first = log.first_log_time or 0
    start = spec.start_ns if spec.start_s is None else first + round(spec.start_s * NS)
    end = spec.end_ns if spec.end_s is None else first + round(spec.end_s * NS)
    if start is not None and end is not None and end <= start:
        raise UserError(f"--end: the window must end after it starts (start {(start - first) / NS:.3f} s, end "
                        f"{(end - first) / NS:.3f} s from the first message)")
    return Window(start, end)


def _tick_window(log: FinishedLog, from_tick: Optional[int], to_tick: Optional[int]) -> Window:
    if from_tick is not None and to_tick is not None and to_tick < from_tick:
        raise UserError(f"--to-tick {to_tick}: before --from-tick {from_tick}")
    lo = 0 if from_tick is None else from_tick
    hi = to_tick
    topics = [c.topic for c in log.summary.channels.values() if fnmatchcase(c.topic, TICK_PATTERN)]
    if not topics:
        raise UserError(f"--from-tick/--to-tick: {log.path} has no world tick messages ({TICK_PATTERN})")
    ticks: list[tuple[int, int]] = []  # (log time, tick)
    for _, _, message in log.messages(ReadDamage(), set(topics)):  # damage is counted by the copying pass
        fields = envelope_fields(message.data)
        tick = None if fields is None else fields[4].get("tick")
        if type(tick) is int:
            ticks.append((message.log_time, tick))
    inside = [i for i, (_, t) in enumerate(ticks) if t >= lo and (hi is None or t <= hi)]
    if not inside:
        seen = f"{min(t for _, t in ticks)}..{max(t for _, t in ticks)}" if ticks else "none"
        raise UserError(f"--from-tick/--to-tick: no world tick in {lo}..{'' if hi is None else hi} "
                        f"(the recording's ticks: {seen})")
    first = inside[0]
    after = next((j for j in range(first + 1, len(ticks))
                  if not (ticks[j][1] >= lo and (hi is None or ticks[j][1] <= hi))), None)
    start = ticks[first][0] if from_tick is not None else None
    # the next tick outside the range (without --to-tick: one going back below --from-tick, a new run)
    end = ticks[after][0] if after is not None else None
    return Window(start, end)


class ChannelChoice:
    """Which channels a cut keeps: globs over bus keys (``*`` also matches ``/``); a JSON mirror
    follows the key it mirrors, other mirrors (Foxglove's) match by their own topic."""

    def __init__(self, include: Sequence[str] = (), exclude: Sequence[str] = ()) -> None:
        self.include = tuple(include)
        self.exclude = tuple(exclude)

    def topic(self, topic: str) -> bool:
        return ((not self.include or any(fnmatchcase(topic, p) for p in self.include))
                and not any(fnmatchcase(topic, p) for p in self.exclude))

    def __call__(self, channel: Channel) -> bool:
        if is_mirror_topic(channel.topic):
            mirrored = channel.metadata.get(META_MIRROR_OF)
            return self.topic(mirrored) if mirrored else self.topic(channel.topic)
        return self.topic(channel.topic)

    def check_against(self, channels: Iterable[Channel]) -> None:
        """UserError when an include pattern matches no recorded key, or the filters keep no channel."""
        keys = sorted({c.topic for c in channels})
        for pattern in self.include:
            if not any(fnmatchcase(k, pattern) for k in keys):
                bus = [k for k in keys if not is_mirror_topic(k)]
                raise UserError(f"--topics {pattern!r} matches no recorded key; keys are: "
                                + ", ".join(bus[:12]) + (" ..." if len(bus) > 12 else ""))


class KeptMessages:
    """The re-stamped last-before messages of a cut file (from its ``truav.cut`` records), found again by
    topic, window start, publish time and CRC-32 of the payload."""

    def __init__(self, records: Iterable[Metadata]) -> None:
        self._entries: dict[tuple[str, int, int, int], list[int]] = {}  # (topic, at, pub, crc) -> original log times
        self.starts: set[int] = set()
        for record in records:
            if record.name != CUT_METADATA:
                continue
            try:
                at = int(record.metadata.get("start_ns", ""))
                kept = json.loads(record.metadata.get("kept", "[]"))
                entries = [(str(topic), int(log_time), int(pub), int(crc)) for topic, log_time, pub, crc in kept]
            except (ValueError, TypeError):  # no start (nothing kept) or a record not of ours
                continue
            self.starts.add(at)
            for topic, log_time, pub, crc in entries:
                self._entries.setdefault((topic, at, pub, crc), []).append(log_time)

    def __bool__(self) -> bool:
        return bool(self._entries)

    def original_log_time(self, topic: str, log_time: int, publish_time: int, data: bytes) -> Optional[int]:
        """The original log time of this message if it is a kept one (each entry matches once), else None."""
        if log_time not in self.starts:
            return None
        times = self._entries.get((topic, log_time, publish_time, zlib.crc32(data)))
        return times.pop(0) if times else None


@dataclass
class CutReport:
    in_path: str
    out_path: str
    window: Window
    messages: int = 0  # in the window
    kept: int = 0  # last-before messages kept (re-stamped to the window's start)
    channels: int = 0
    skipped: int = 0  # messages before the window or on channels not chosen (those after it are not read)
    source_first_log_time: Optional[int] = None  # of the input
    first_log_time: Optional[int] = None  # of the window's messages
    last_log_time: Optional[int] = None
    metadata: list[str] = field(default_factory=list)  # names of the records copied
    damage: ReadDamage = field(default_factory=ReadDamage)  # what of the input was left out as damaged


def cut(in_path: str | os.PathLike[str], out_path: str | os.PathLike[str], spec: WindowSpec,
        include: Sequence[str] = (), exclude: Sequence[str] = ()) -> CutReport:
    """Write the window ``spec`` of ``in_path`` (channels chosen by the globs) to ``out_path``.

    UserError (nothing written) for an input that is not a finished MCAP, a contradictory window, a
    pattern matching nothing, or a window holding no message. Damaged chunks and records are left out,
    counted in the report's ``damage`` and named in a ``truav.damage`` record of the output."""
    choice = ChannelChoice(include, exclude)
    with open_finished(in_path) as log:
        choice.check_against(log.summary.channels.values())
        window = resolve_window(log, spec)
        report = CutReport(os.fspath(in_path), os.fspath(out_path), window,
                           source_first_log_time=log.first_log_time)
        with written_atomically(out_path) as stream:
            writer = new_writer(stream, f"{LIBRARY} cut")
            channels = OutputChannels(writer)
            for record in log.metadata():
                writer.add_metadata(record.name, dict(record.metadata))
                report.metadata.append(record.name)
            for attachment in log.attachments():
                writer.add_attachment(attachment)
            last_before: dict[int, LogMessage] = {}  # input channel id -> its last message before the window
            kept_entries: list[list] = []
            pending_kept = True
            for item in log.messages():
                message = item.message
                if not choice(item.channel):
                    report.skipped += 1
                    continue
                if window.start_ns is not None and message.log_time < window.start_ns:
                    last_before[item.channel.id] = item
                    report.skipped += 1
                    continue
                if window.end_ns is not None and message.log_time >= window.end_ns:
                    break  # log-time order: nothing later is in the window
                if pending_kept:
                    pending_kept = False
                    kept_entries = _write_kept(writer, channels, last_before.values(), window.start_ns)
                    report.kept = len(kept_entries)
                cid = channels.channel_id(0, item.schema, item.channel)
                writer.add_message(cid, message.sequence, message.log_time, message.publish_time, message.data)
                report.messages += 1
                report.first_log_time = message.log_time if report.first_log_time is None else report.first_log_time
                report.last_log_time = message.log_time
            report.damage = log.damage
            if report.messages == 0 and log.damage.damaged:
                raise DamagedRecording(f"{in_path}: damaged recording, nothing sound in the window: "
                                       f"{log.damage.describe()}; {out_path} not written")
            if report.messages == 0:
                raise UserError(f"{in_path}: the window {_window_text(window, log)} holds no message of the "
                                f"chosen topics; {out_path} not written")
            report.channels = len(channels.topics)
            writer.add_metadata(CUT_METADATA, _cut_record(log, window, spec, choice, report, kept_entries))
            if log.damage.damaged:  # so that `truav log check` of the cut does not call it sound
                writer.add_metadata(DAMAGE_METADATA, log.damage.as_metadata(Path(log.path).name))
            writer.close()
    return report


def _write_kept(writer, channels: OutputChannels, kept: Iterable[LogMessage], at: Optional[int]) -> list[list]:
    """Write the last-before messages at the window's start, oldest first; their entries for ``truav.cut``."""
    entries = []
    if at is None:
        return entries
    for item in sorted(kept, key=lambda m: m.message.log_time):
        m = item.message
        cid = channels.channel_id(0, item.schema, item.channel)
        writer.add_message(cid, m.sequence, at, m.publish_time, m.data)
        entries.append([item.channel.topic, m.log_time, m.publish_time, zlib.crc32(m.data)])
    return entries


def _window_text(window: Window, log: FinishedLog) -> str:
    first = log.first_log_time or 0

    def s(ns: int) -> str:
        return f"{(ns - first) / NS:.3f} s"

    start = "first message" if window.start_ns is None else s(window.start_ns)
    end = "last message]" if window.end_ns is None else s(window.end_ns) + ")"
    return f"[{start}, {end}"


def _cut_record(log: FinishedLog, window: Window, spec: WindowSpec, choice: ChannelChoice, report: CutReport,
                kept: list[list]) -> dict[str, str]:
    def text(v: Optional[int]) -> str:
        return "" if v is None else str(v)

    return {
        "source": Path(log.path).name,
        "source_first_log_time_ns": text(log.first_log_time),
        "source_last_log_time_ns": text(log.last_log_time),
        "source_messages": str(log.message_count),
        "start_ns": text(window.start_ns),
        "end_ns": text(window.end_ns),
        "from_tick": text(spec.from_tick),
        "to_tick": text(spec.to_tick),
        "topics": dump(list(choice.include)),
        "exclude": dump(list(choice.exclude)),
        "messages": str(report.messages),
        "kept_before": str(len(kept)),
        "kept": dump(kept),  # [topic, original log time ns, publish time ns, crc32 of the payload]
    }
