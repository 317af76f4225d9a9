"""`truav log info`: what a recording holds, ``mcap info`` plus this project's meaning.

One pass over the file (finished or not: :func:`recorder.reader.iter_messages`, JSON and Foxglove
mirrors included) counts messages per topic, per sender (the envelope's ``src``) and per kind, with
first/last log time and mean rate; each (src, kind, incarnation) stream's sequence gaps
(:class:`recorder.seq_stats.SenderStats`); the fault windows (``fault`` messages paired start/end
per fault and target, as ``truav report`` shades them); the world's tick range; and what the
metadata says of the run (run name, seed, scheme, lock-step), its part of a split recording, the
window it was cut to, or what it was merged from. A cut's kept last-before messages are counted
on their topics (``kept``) but not timed (their log time is the window's start) nor in the sequence
statistics, where they would look like gaps.
:func:`info` returns a :class:`FileInfo`; :meth:`FileInfo.as_json` and :meth:`FileInfo.format`
are the two outputs.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from typing import Any, Optional

from mcap.records import Header, Metadata

from recorder.check import _table
from recorder.cut import CUT_METADATA, KeptMessages
from recorder.merge import MERGE_METADATA, PART_METADATA
from recorder.metadata import CONFIG_METADATA, RECORDING_METADATA
from recorder.mirror_channels import is_mirror_topic
from recorder.mcap_guard import ReadDamage, Validator, read_summary, walk
from recorder.mcap_log import MCAP_MAGIC
from recorder.reader import iter_messages, open_source, probe, read_metadata
from recorder.report_data import Recording
from recorder.schemas import envelope_fields, kind_from_key
from recorder.seq_stats import SenderStats

__all__ = ["FileInfo", "Tally", "info", "RUN_METADATA"]

RUN_METADATA = "truav.run"  # how `truav-swarm up` ran (seed, scheme, lock-step...), when the recording has it
RUN_FIELDS = ("seed", "scheme", "lockstep", "episodes")
CONFIG_FIELDS = ("scenario.n_uavs", "scenario.steps_per_episode")
NS = 1e9


@dataclass
class Tally:
    """Messages of one topic, sender or kind; a cut's kept messages are counted but not timed (their log
    time is the window's start, not theirs)."""

    count: int = 0
    first: Optional[int] = None  # log time, ns
    last: Optional[int] = None
    kept: int = 0  # a cut's kept last-before messages among them

    def add(self, log_time: int, kept: bool = False) -> None:
        self.count += 1
        if kept:
            self.kept += 1
            return
        self.first = log_time if self.first is None or log_time < self.first else self.first
        self.last = log_time if self.last is None or log_time > self.last else self.last

    @property
    def rate_hz(self) -> Optional[float]:
        """Mean rate over the tally's span ((count - 1) intervals); None for fewer than two or no span."""
        timed = self.count - self.kept
        if timed < 2 or self.first is None or self.last is None or self.last == self.first:
            return None
        return (timed - 1) * NS / (self.last - self.first)


@dataclass
class StreamInfo:
    src: str
    kind: str
    inc: int
    count: int
    first_seq: Optional[int]
    last_seq: Optional[int]
    gaps: int
    missing: int
    backwards: int


@dataclass
class FileInfo:
    path: str
    size: int
    finished: bool
    torn_bytes: int
    chunks: Optional[int]  # from the summary (None: unfinished)
    compression: list[str]
    library: Optional[str]
    messages: int = 0  # bus messages
    mirror_messages: int = 0
    undecodable: int = 0
    first: Optional[int] = None  # over every message
    last: Optional[int] = None
    topics: dict[str, Tally] = field(default_factory=dict)  # bus keys
    topic_kinds: dict[str, str] = field(default_factory=dict)
    mirrors: dict[str, Tally] = field(default_factory=dict)
    senders: dict[str, Tally] = field(default_factory=dict)
    sender_kinds: dict[str, set[str]] = field(default_factory=dict)
    kinds: dict[str, Tally] = field(default_factory=dict)
    streams: list[StreamInfo] = field(default_factory=list)
    faults: list[dict[str, Any]] = field(default_factory=list)  # fault, target, start_s, end_s (None: open)
    ticks: Optional[tuple[int, int]] = None  # lowest and highest world tick
    episodes: Optional[tuple[int, int]] = None
    kept: int = 0  # a cut's kept last-before messages (mirrors included)
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    damage: ReadDamage = field(default_factory=ReadDamage)  # what was left out as damaged (not counted above)

    @property
    def span_s(self) -> float:
        return 0.0 if self.first is None or self.last is None else (self.last - self.first) / NS

    def rel(self, ns: Optional[int]) -> Optional[float]:
        """Seconds from the file's first message."""
        return None if ns is None or self.first is None else (ns - self.first) / NS

    # --- what the metadata says ------------------------------------------------------------------
    def run_facts(self) -> dict[str, Any]:
        """Run name, seed, scheme, lock-step, the config's sizes: what is known, JSON values decoded."""
        facts: dict[str, Any] = {}
        recording = self.metadata.get(RECORDING_METADATA, {})
        if "run" in recording:
            facts["run"] = recording["run"]
        for name in RUN_FIELDS:
            if name in self.metadata.get(RUN_METADATA, {}):
                facts[name] = _json(self.metadata[RUN_METADATA][name])
        config = self.metadata.get(CONFIG_METADATA, {})
        for name in CONFIG_FIELDS:
            if name in config:
                facts[name] = _json(config[name])
        if recording.get("started"):
            facts["started"] = recording["started"]
        if recording.get("host"):
            facts["host"] = recording["host"]
        return facts

    def part(self) -> Optional[dict[str, str]]:
        record = self.metadata.get(PART_METADATA)
        return None if record is None else {k: record.get(k, "") for k in ("session", "part", "reason")}

    def cut(self) -> Optional[dict[str, Any]]:
        record = self.metadata.get(CUT_METADATA)
        if record is None:
            return None
        out: dict[str, Any] = {k: record.get(k, "") for k in ("source", "start_ns", "end_ns", "from_tick", "to_tick")}
        out["topics"], out["exclude"] = _strings(record.get("topics", "[]")), _strings(record.get("exclude", "[]"))
        out["kept_before"] = _json(record.get("kept_before", "0"))
        return out

    def merge(self) -> Optional[dict[str, Any]]:
        record = self.metadata.get(MERGE_METADATA)
        if record is None:
            return None
        inputs = _json(record.get("inputs", "[]"))
        return {"inputs": [i.get("file") if isinstance(i, dict) else i for i in inputs] if isinstance(inputs, list)
                else [inputs],
                "duplicates_dropped": _json(record.get("duplicates_dropped", "0")),
                "sessions": _json(record.get("sessions", "{}")), "missing_parts": _json(record.get("missing_parts", "{}"))}

    # --- outputs ------------------------------------------------------------------------------------
    def as_json(self) -> dict[str, Any]:
        def tally(t: Tally) -> dict[str, Any]:
            return {"messages": t.count, "kept": t.kept, "first_log_time_ns": t.first, "last_log_time_ns": t.last,
                    "first_s": self.rel(t.first), "last_s": self.rel(t.last), "rate_hz": t.rate_hz}

        return {
            "path": self.path, "size": self.size, "finished": self.finished, "torn_bytes": self.torn_bytes,
            "chunks": self.chunks, "compression": self.compression, "library": self.library,
            "messages": self.messages, "mirror_messages": self.mirror_messages, "undecodable": self.undecodable,
            "kept": self.kept, "first_log_time_ns": self.first, "last_log_time_ns": self.last,
            "duration_s": self.span_s,
            "run": self.run_facts(), "part": self.part(), "cut": self.cut(), "merge": self.merge(),
            "ticks": None if self.ticks is None else list(self.ticks),
            "episodes": None if self.episodes is None else list(self.episodes),
            "topics": {k: {"kind": self.topic_kinds.get(k), **tally(t)} for k, t in sorted(self.topics.items())},
            "senders": {k: {"kinds": sorted(self.sender_kinds.get(k, ())), **tally(t)}
                        for k, t in sorted(self.senders.items())},
            "kinds": {k: tally(t) for k, t in sorted(self.kinds.items())},
            "streams": [vars(s) for s in self.streams],
            "faults": self.faults,
            "mirrors": {k: tally(t) for k, t in sorted(self.mirrors.items())},
            "damage": {"corrupt_chunks": self.damage.corrupt_chunks, "invalid_records": self.damage.invalid_records,
                       "error": self.damage.error, "notes": self.damage.notes},
            "metadata": {name: {k: v for k, v in m.items() if k not in ("toml", "kept")}
                         for name, m in sorted(self.metadata.items())},
        }

    def format(self) -> str:
        state = "finished" if self.finished else f"UNFINISHED ({self.torn_bytes:,} torn bytes; `truav log recover`)"
        chunks = "" if self.chunks is None else f", {self.chunks} chunks ({'/'.join(self.compression) or 'none'})"
        lines = [f"{self.path}: {state}, {self.size:,} bytes{chunks}",
                 f"{self.messages:,} bus messages (+{self.mirror_messages:,} mirror) on {len(self.topics)} keys "
                 f"over {self.span_s:.3f} s, {len(self.senders)} senders, {self.undecodable} undecodable"]
        facts = self.run_facts()
        if self.ticks is not None:
            facts["ticks"] = f"{self.ticks[0]}..{self.ticks[1]}"
        if self.episodes is not None:
            facts["episodes seen"] = f"{self.episodes[0]}..{self.episodes[1]}"
        if facts:
            lines.append("run: " + ", ".join(f"{k} {v}" for k, v in facts.items()))
        part = self.part()
        if part:
            lines.append(f"part {part['part']} of session {part['session']} (ended: {part['reason']})")
        cut = self.cut()
        if cut:
            ticks = f", ticks {cut['from_tick']}..{cut['to_tick']}" if cut["from_tick"] or cut["to_tick"] else ""
            chosen = (f"; topics {' '.join(cut['topics'])}" if cut["topics"] else "") + \
                (f"; excluded {' '.join(cut['exclude'])}" if cut["exclude"] else "")
            lines.append(f"cut from {cut['source']}: log time [{cut['start_ns'] or 'start'}, {cut['end_ns'] or 'end'})"
                         f"{ticks}{chosen}; {cut['kept_before']} last-before messages kept at the window's start"
                         + (" (a sender's streams on keys not chosen show as gaps)" if chosen else ""))
        merge = self.merge()
        if merge:
            lines.append(f"merged from {len(merge['inputs'])} files ({', '.join(map(str, merge['inputs']))}), "
                         f"{merge['duplicates_dropped']} duplicates dropped"
                         + (f"; MISSING parts {merge['missing_parts']}" if merge["missing_parts"] else ""))
        lines.append("metadata: " + (", ".join(sorted(self.metadata)) or "none"))
        if self.damage.damaged:
            lines.append(f"DAMAGED: {self.damage.describe()}")

        def times(t: Tally) -> tuple[str, str, str]:
            rate = t.rate_hz
            return _s(self.rel(t.first)), _s(self.rel(t.last)), "-" if rate is None else f"{rate:.2f}"

        if self.kept:  # a cut: how many of each topic's messages are the kept last-before one
            lines += ["", *_table([("topic", "kind", "msgs", "kept", "first_s", "last_s", "rate_hz")]
                                  + [(k, self.topic_kinds.get(k, "?"), t.count, t.kept, *times(t))
                                     for k, t in sorted(self.topics.items())], numeric=(2, 3, 4, 5, 6))]
        else:
            lines += ["", *_table([("topic", "kind", "msgs", "first_s", "last_s", "rate_hz")]
                                  + [(k, self.topic_kinds.get(k, "?"), t.count, *times(t))
                                     for k, t in sorted(self.topics.items())], numeric=(2, 3, 4, 5))]
        gaps: dict[str, tuple[int, int]] = {}
        for s in self.streams:
            g, m = gaps.get(s.src, (0, 0))
            gaps[s.src] = (g + s.gaps, m + s.missing)
        lines += ["", *_table([("sender", "kinds", "msgs", "first_s", "last_s", "rate_hz", "gaps", "missing")]
                              + [(k, ",".join(sorted(self.sender_kinds.get(k, ()))), t.count, *times(t),
                                  *gaps.get(k, (0, 0))) for k, t in sorted(self.senders.items())], numeric=(2, 3, 4, 5, 6, 7))]
        lines += ["", *_table([("kind", "msgs", "first_s", "last_s", "rate_hz")]
                              + [(k, t.count, *times(t)) for k, t in sorted(self.kinds.items())], numeric=(1, 2, 3, 4))]
        if self.faults:
            lines += ["", *_table([("fault", "target", "start_s", "end_s")]
                                  + [(f["fault"], f["target"], _s(f["start_s"]), _s(f["end_s"]) if f["end_s"] is not None
                                      else "(open)") for f in self.faults], numeric=(2, 3))]
        else:
            lines += ["", "faults: none"]
        if self.mirrors:
            lines.append(f"mirrors: {len(self.mirrors)} topics, {self.mirror_messages:,} messages")
        return "\n".join(lines)


def _s(seconds: Optional[float]) -> str:
    return "-" if seconds is None else f"{seconds:.3f}"


def _strings(text: str) -> list[str]:
    """A recorded JSON list of patterns, as strings whatever it holds (a record from elsewhere)."""
    value = _json(text)
    return [str(v) for v in value] if isinstance(value, list) else [str(value)]


def _json(text: str) -> Any:
    try:
        return json.loads(text)
    except (TypeError, ValueError):
        return text


def info(path: str | os.PathLike[str]) -> FileInfo:
    """What ``path`` (an MCAP recording, finished or not) holds. ValueError if it is not MCAP."""
    damage = ReadDamage()
    with open_source(path) as stream:
        state = probe(stream)
        chunks, compression, library = None, [], None
        summary = read_summary(stream, state.size, Validator(ReadDamage())) if state.finished else None
        if summary is not None:  # its damage is not counted: the records themselves are read below
            chunks = len(summary.chunk_indexes)
            compression = sorted({c.compression[:20] or "none" for c in summary.chunk_indexes})
        header = next((r for _, _, r in walk(stream, len(MCAP_MAGIC), state.valid_end, ReadDamage())), None)
        library = header.library[:200] if isinstance(header, Header) else None
    result = FileInfo(path=os.fspath(path), size=state.size, finished=state.finished, torn_bytes=state.torn_bytes,
                      chunks=chunks, compression=compression, library=library, damage=damage)
    result.metadata = read_metadata(path, damage=ReadDamage())  # its damage is the same as the messages' below
    kept = KeptMessages(Metadata(name=n, metadata=m) for n, m in result.metadata.items())
    seq = SenderStats()
    faults: list[tuple[int, dict]] = []
    ticks: list[int] = []
    episodes: list[int] = []
    for key, payload, log_time, pub in iter_messages(path, include_mirrors=True, damage=damage):
        result.first = log_time if result.first is None or log_time < result.first else result.first
        result.last = log_time if result.last is None or log_time > result.last else result.last
        is_kept = bool(kept) and kept.original_log_time(key, log_time, pub, payload) is not None
        result.kept += is_kept
        if is_mirror_topic(key):
            result.mirror_messages += 1
            result.mirrors.setdefault(key, Tally()).add(log_time, is_kept)
            continue
        result.messages += 1
        result.topics.setdefault(key, Tally()).add(log_time, is_kept)
        env = envelope_fields(payload)
        if env is None:
            result.undecodable += 1
            result.topic_kinds.setdefault(key, kind_from_key(key))
            continue
        kind, src, number, _, body, inc = env
        result.topic_kinds.setdefault(key, kind)
        result.senders.setdefault(src, Tally()).add(log_time, is_kept)
        result.sender_kinds.setdefault(src, set()).add(kind)
        result.kinds.setdefault(kind, Tally()).add(log_time, is_kept)
        if is_kept:  # not a gap in its stream, not an event of the window
            continue
        seq.observe(src, kind, inc, number, log_time, pub)
        if kind == "fault":
            faults.append((log_time, body))
        elif kind == "tick":
            if type(body.get("tick")) is int:
                ticks.append(body["tick"])
            if type(body.get("episode")) is int:
                episodes.append(body["episode"])
    for (src, kind, inc), s in sorted(seq.snapshot().items()):
        result.streams.append(StreamInfo(src, kind, inc, s.count, s.first_seq, s.last_seq, s.gaps, s.missing,
                                         s.backwards))
    spans = Recording(first_ns=result.first, faults=faults).fault_spans()
    result.faults = [{"fault": f.fault, "target": f.target, "start_s": f.start_s, "end_s": f.end_s} for f in spans]
    result.ticks = (min(ticks), max(ticks)) if ticks else None
    result.episodes = (min(episodes), max(episodes)) if episodes else None
    return result
