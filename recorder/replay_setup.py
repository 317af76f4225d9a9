"""What a replay is asked to do, checked before anything starts: its options, the recording's span and keys
(one file or a split recording's parts), the keys it keeps, the key rewriting of ``--run``, and the
statistics it reports. The engine is :mod:`recorder.replay`."""

from __future__ import annotations

from array import array
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from fnmatch import fnmatchcase
from pathlib import Path
from typing import Any, NamedTuple, Optional

from recorder.mcap_guard import DamagedRecording, LOG_TIME_MAX_NS, ReadDamage, Validator, read_summary
from recorder.mcap_log import is_mirror_topic
from recorder.reader import iter_messages, open_source, probe, read_schemas
from recorder.replay_source import Paths, SourceError, resolve_parts
from truav.wire import keys
from truav.wire.schema import DEFAULT_LOCKSTEP_WAIT_S

CONTROL_PART = "replay"  # commands arrive on keys.control(run, CONTROL_PART)
CONTROL_PATTERN = "truav/*/control/*"  # recorded control keys: skipped by default
SELF_CONTROL_PATTERN = f"truav/*/control/{CONTROL_PART}"  # never replayed
SELF_STATUS_PATTERN = "truav/*/replay/*"  # a recorded replay's own status: never replayed
ACTION_PATTERN = "truav/*/uav/*/action"  # --lockstep: the live agents answer, the recorded answers stay out
NS = 1_000_000_000
MAX_LATENESS_SAMPLES = 1_000_000  # timing statistics keep every k-th sample beyond this


class ReplayUsageError(ValueError):
    """A user mistake (missing file, not an MCAP, a pattern matching nothing...)."""


@dataclass(frozen=True)
class ReplayOptions:
    path: Paths  # one file, a parts index, or several files (a split recording's parts)
    run: Optional[str] = None  # publish under truav/<run>/ (default: the recorded run)
    rate: float = 1.0
    loops: Optional[int] = 1  # None: forever
    include: tuple[str, ...] = ()  # empty: every key
    exclude: tuple[str, ...] = ()
    start_s: float = 0.0
    duration_s: Optional[float] = None
    paused: bool = False
    with_control: bool = False
    lockstep: bool = False  # tick k goes out once the live agents answered tick k-1 (recorder.process.replay_bus)
    lockstep_wait_s: float = DEFAULT_LOCKSTEP_WAIT_S


@dataclass
class ReplayStats:
    """What a replay did, and how well it kept time."""

    published: int = 0
    restored: int = 0  # messages sent again after seeks (each channel's last value)
    seeks: int = 0
    lockstep_held: int = 0  # --lockstep: ticks held for the live agents' answers
    lockstep_given_up: int = 0  # --lockstep: answers not received within --lockstep-wait
    per_channel: Counter = field(default_factory=Counter)  # output key -> messages
    loops: int = 0  # complete passes
    wall_s: float = 0.0
    quit_reason: str = "end"
    lateness_ns: array = field(default_factory=lambda: array("q"))  # send time - due time, when not paused
    _sample_every: int = 1

    def add_lateness(self, late_ns: int) -> None:
        if self.published % self._sample_every == 0:
            self.lateness_ns.append(late_ns)
            if len(self.lateness_ns) >= MAX_LATENESS_SAMPLES:
                del self.lateness_ns[::2]
                self._sample_every *= 2

    def lateness_ms(self, q: float) -> float:
        """Quantile ``q`` of the lateness, in ms (0 when nothing was timed)."""
        if not self.lateness_ns:
            return 0.0
        ordered = sorted(self.lateness_ns)
        return ordered[min(int(q * len(ordered)), len(ordered) - 1)] / 1e6

    def format(self) -> str:
        restored = f" ({self.seeks} seek(s), {self.restored} restored)" if self.seeks else ""
        if self.lockstep_held:
            restored += (f"; lock-step: {self.lockstep_held} tick(s) held for the live agents' answers, "
                         f"{self.lockstep_given_up} answer(s) not received in time")
        return (f"replay: {self.published} messages on {len(self.per_channel)} channels in {self.wall_s:.2f} s{restored}, "
                f"{self.loops} complete pass(es), ended by {self.quit_reason}; timing: late by "
                f"p50 {self.lateness_ms(0.5):.2f} ms, p99 {self.lateness_ms(0.99):.2f} ms, "
                f"max {self.lateness_ms(1.0):.2f} ms")


@dataclass(frozen=True)
class RecordingInfo:
    """What a replay needs to know before it starts."""

    first_ns: int  # first receive time in the file (None-free: empty files are refused)
    last_ns: int
    topics: tuple[str, ...]  # bus keys (mirrors excluded)
    runs: tuple[str, ...]  # the <run> of every truav/<run>/ key
    paths: tuple[Path, ...] = ()  # the files, in play order


def recording_info(paths: Paths) -> RecordingInfo:
    """Span and keys of a recording, or of several files (a split recording's parts) played as one;
    ReplayUsageError when one is missing, not MCAP or they hold no message."""
    try:
        files = resolve_parts(paths)
    except SourceError as exc:
        raise ReplayUsageError(str(exc)) from None
    parts = [_file_info(p) for p in files]
    spans = [(p.first_ns, p.last_ns) for p in parts if p.first_ns is not None]
    if not spans:
        raise ReplayUsageError(f"{files[0] if len(files) == 1 else 'the files'}: the recording holds no messages")
    topics = tuple(sorted({t for p in parts for t in p.topics}))
    runs = tuple(sorted({r for r in map(keys.parse_run, topics) if r is not None}))
    return RecordingInfo(first_ns=min(a for a, _ in spans), last_ns=max(b for _, b in spans), topics=topics,
                         runs=runs, paths=tuple(files))


def _file_info(path: Path) -> "_FileInfo":
    if not path.is_file():
        raise ReplayUsageError(f"{path}: no such file")
    try:
        with open_source(path) as stream:
            probe(stream)
        topics = tuple(sorted(t for t in read_schemas(path) if not is_mirror_topic(t)))
        first = last = None
        summary = _finished_summary(path)
        if summary is not None and summary.statistics is not None and summary.statistics.message_count:
            first, last = summary.statistics.message_start_time, summary.statistics.message_end_time
        else:
            for message in iter_messages(path):
                first = message.log_time if first is None else min(first, message.log_time)
                last = message.log_time if last is None else max(last, message.log_time)
    except DamagedRecording:
        raise  # exit 1 (truav.cli.log), not a user mistake
    except ValueError as exc:  # probe: "not an MCAP file"
        raise ReplayUsageError(f"{path}: {exc}") from None
    return _FileInfo(first, last, topics)


class _FileInfo(NamedTuple):
    first_ns: Optional[int]
    last_ns: Optional[int]
    topics: tuple[str, ...]


def _finished_summary(path: Path) -> Any:
    """The checked summary of a finished file (recorder.mcap_guard), None without one or with implausible
    times (then the messages are scanned)."""
    with open(path, "rb") as f:
        state = probe(f)
        if not state.finished:
            return None
        summary = read_summary(f, state.size, Validator(ReadDamage()))
    stats = None if summary is None else summary.statistics
    if stats is None or not stats.message_start_time <= stats.message_end_time <= LOG_TIME_MAX_NS:
        return None
    return summary


def split_patterns(topics: Sequence[str], exclude: Sequence[str] = ()) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """``--topics`` entries starting with ``!`` are excludes; returns (include, exclude)."""
    include = tuple(t for t in topics if not t.startswith("!"))
    excluded = tuple(t[1:] for t in topics if t.startswith("!")) + tuple(exclude)
    for pattern in include + excluded:
        if not pattern:
            raise ReplayUsageError("empty topic pattern")
    return include, excluded


def effective_excludes(options: ReplayOptions) -> tuple[str, ...]:
    base = (SELF_CONTROL_PATTERN,) if options.with_control else (CONTROL_PATTERN,)
    return base + (SELF_STATUS_PATTERN,) + ((ACTION_PATTERN,) if options.lockstep else ()) + tuple(options.exclude)


def select_topics(info: RecordingInfo, options: ReplayOptions) -> list[str]:
    """Recorded keys the options keep; ReplayUsageError if a pattern selects nothing."""
    excludes = effective_excludes(options)
    for pattern in options.include:
        if not any(fnmatchcase(t, pattern) for t in info.topics):
            raise ReplayUsageError(f"--topics {pattern!r} matches no recorded key; keys are: "
                                   + ", ".join(info.topics[:20]) + (" ..." if len(info.topics) > 20 else ""))
    kept = [t for t in info.topics
            if (not options.include or any(fnmatchcase(t, p) for p in options.include))
            and not any(fnmatchcase(t, p) for p in excludes)]
    if not kept:
        raise ReplayUsageError("the topic filters leave nothing to replay (recorded control keys are skipped "
                               "unless --with-control)")
    return kept


def key_rewriter(target_run: Optional[str]) -> Callable[[str], Optional[str]]:
    """Key in the file -> key to publish (None: not a TRUAV key, skipped)."""
    if target_run is not None:
        try:
            keys.validate_run(target_run)
        except ValueError as exc:
            raise ReplayUsageError(f"--run: {exc}") from None

    def rewrite(key: str) -> Optional[str]:
        run = keys.parse_run(key)
        if run is None:
            return None
        if target_run is None:
            return key
        return f"{keys.prefix(target_run)}{key[len(keys.ROOT) + 1 + len(run):]}"

    return rewrite
