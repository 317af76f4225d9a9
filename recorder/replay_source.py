"""What a replay reads: one recording, or a split recording's parts played as one.

:func:`resolve_parts` turns what the user named into the ordered files of one run:

* ``<stem>.parts.json`` (the recorder's index of a split recording) -> its parts, in part order;
* ``<stem>_0001.mcap`` (any part) or ``<stem>.mcap`` (the path given to the recorder, which a split
  recording never creates) with ``<stem>.parts.json`` beside it -> the same;
* several files -> ordered by the ``truav.part`` metadata record each finished part carries (its
  ``part`` number), else by the ``_NNNN`` of the name, else by their first message;
* one plain recording -> itself.

:class:`ReplaySource` reads the messages of those files in order as one stream, and builds the
:class:`Timeline` a seek needs: the receive time of every message and where each world tick starts.
"""

from __future__ import annotations

import json
import os
import re
from array import array
from bisect import bisect_right
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Union

import msgpack

from recorder.reader import RecordedMessage, iter_messages, read_metadata
from recorder.record_modes import PART_METADATA, PARTS_INDEX_SUFFIX  # what the recorder writes (recorder.parts)

MAX_PARTS = 100_000
MAX_INDEX_BYTES = 16 << 20
_PART_NAME = re.compile(r"^(?P<stem>.+)_(?P<n>\d{4,})\.mcap$")
TICK_PATTERN = "truav/*/world/tick"

Paths = Union[str, "os.PathLike[str]", Sequence[Union[str, "os.PathLike[str]"]]]


class SourceError(ValueError):
    """The files named cannot be played (missing, a bad index, parts of different recordings)."""


def _as_list(paths: Paths) -> list[Path]:
    if isinstance(paths, (str, os.PathLike)):
        return [Path(paths)]
    return [Path(p) for p in paths]


def index_beside(path: Path) -> Optional[Path]:
    """``<stem>.parts.json`` for ``<stem>.mcap`` or ``<stem>_NNNN.mcap``, if it exists."""
    m = _PART_NAME.match(path.name)
    stems = ([m["stem"]] if m else []) + [path.stem]
    for stem in stems:
        index = path.with_name(stem + PARTS_INDEX_SUFFIX)
        if index.is_file():
            return index
    return None


def read_index(index: Path) -> list[Path]:
    """The parts an index lists, in part order (paths relative to the index's folder)."""
    try:
        if index.stat().st_size > MAX_INDEX_BYTES:
            raise SourceError(f"{index}: larger than {MAX_INDEX_BYTES >> 20} MB, not a parts index")
        data = json.loads(index.read_text())
        rows = data["parts"] if isinstance(data, dict) else data
        if not isinstance(rows, list) or not 0 < len(rows) <= MAX_PARTS:
            raise SourceError(f"{index}: 'parts' must list 1 to {MAX_PARTS} parts")
        named = []
        for k, row in enumerate(rows):
            name = row.get("path") if isinstance(row, dict) else row
            number = row.get("part", k + 1) if isinstance(row, dict) else k + 1
            if not isinstance(name, str) or not name or isinstance(number, bool) or not isinstance(number, int):
                raise SourceError(f"{index}: part {k + 1} has no file name (\"path\") or no integer \"part\"")
            named.append((number, index.parent / name))
    except (OSError, json.JSONDecodeError, KeyError, AttributeError) as exc:
        raise SourceError(f"{index}: not a readable parts index ({type(exc).__name__}: {exc})") from None
    named.sort(key=lambda row: row[0])
    missing = [str(p) for _, p in named if not p.is_file()]
    if missing:
        raise SourceError(f"{index}: part file(s) missing: {', '.join(missing[:3])}")
    return [p for _, p in named]


def _part_order(path: Path) -> tuple[Optional[str], Optional[int]]:
    """(session, part) from the part's ``truav.part`` record, else (None, the ``_NNNN`` of its name)."""
    try:
        record = read_metadata(path).get(PART_METADATA)
    except Exception:  # an unreadable metadata section: order by the name
        record = None
    if record is not None and str(record.get("part", "")).isdigit():
        return record.get("session"), int(record["part"])
    m = _PART_NAME.match(path.name)
    return None, (int(m["n"]) if m else None)


def _first_log_time(path: Path) -> int:
    return next((m.log_time for m in iter_messages(path)), 0)


def resolve_parts(paths: Paths) -> tuple[Path, ...]:
    """The files to play, in order (see the module docstring); SourceError when they cannot be."""
    given = _as_list(paths)
    if not given:
        raise SourceError("no recording given")
    if len(given) == 1:
        path = given[0]
        if path.name.endswith(PARTS_INDEX_SUFFIX):
            return tuple(read_index(path))
        index = index_beside(path)
        if index is not None and (not path.is_file() or _PART_NAME.match(path.name)):
            return tuple(read_index(index))
        return (path,)
    for path in given:
        if not path.is_file():
            raise SourceError(f"{path}: no such file")
    if len(set(map(os.path.realpath, given))) != len(given):
        raise SourceError("the same file is named twice")
    orders = [_part_order(p) for p in given]
    sessions = {s for s, _ in orders if s is not None}
    if len(sessions) > 1:
        raise SourceError("the files are parts of different recordings (truav.part sessions differ); "
                          "play them one at a time")
    numbers = [n for _, n in orders]
    if all(n is not None for n in numbers) and len(set(numbers)) == len(numbers):
        return tuple(p for _, p in sorted(zip(numbers, given)))
    return tuple(sorted(given, key=_first_log_time))


class ReplaySource:
    """The messages of one or more files, in order, as one stream."""

    def __init__(self, paths: Sequence[Path]) -> None:
        self.paths = tuple(paths)

    def messages(self, include: Optional[Sequence[str]] = None, start_ns: Optional[int] = None,
                 end_ns: Optional[int] = None) -> Iterator[RecordedMessage]:
        for path in self.paths:
            yield from iter_messages(path, include=include, start_ns=start_ns, end_ns=end_ns)


def tick_of(payload: bytes) -> Optional[int]:
    """The ``tick`` of a recorded world tick payload (None if unreadable)."""
    try:
        body = msgpack.unpackb(payload)
    except Exception:  # msgpack raises several kinds
        return None
    tick = body.get("tick") if isinstance(body, dict) else None
    return tick if type(tick) is int else None


@dataclass
class Timeline:
    """Positions of the replayed stream: message ``i`` (0-based, in stream order) was received at
    ``log_times[i]``; world tick ``tick_numbers[j]`` starts at message ``tick_positions[j]``."""

    log_times: array
    tick_positions: array
    tick_numbers: array

    @classmethod
    def scan(cls, messages: Iterator[RecordedMessage], is_tick: "callable") -> "Timeline":
        times, positions, numbers = array("q"), array("q"), array("q")
        for i, m in enumerate(messages):
            times.append(m.log_time)
            if is_tick(m.key):
                tick = tick_of(m.payload)
                if tick is not None:
                    positions.append(i)
                    numbers.append(tick)
        return cls(times, positions, numbers)

    def __len__(self) -> int:
        return len(self.log_times)

    def position_at(self, log_time: int) -> int:
        """The first message received at or after ``log_time`` (len: past the end)."""
        for i, t in enumerate(self.log_times):
            if t >= log_time:
                return i
        return len(self.log_times)

    def position_of_tick(self, tick: int) -> int:
        """Where world tick ``tick`` starts (its first tick message); ValueError if it is not there."""
        for pos, number in zip(self.tick_positions, self.tick_numbers):
            if number == tick:
                return pos
        if not self.tick_numbers:
            raise ValueError("the replayed messages hold no world tick (truav/<run>/world/tick): seek by time")
        raise ValueError(f"tick {tick} is not in the replayed window (ticks {self.tick_numbers[0]}.."
                         f"{self.tick_numbers[-1]})")

    def next_tick_start(self, position: int) -> int:
        """The first tick start after ``position`` (len: none, the end)."""
        j = bisect_right(self.tick_positions, position)
        return self.tick_positions[j] if j < len(self.tick_positions) else len(self.log_times)

    def tick_before(self, position: int) -> int:
        """The last tick started before ``position`` (-1: none)."""
        j = bisect_right(self.tick_positions, position - 1)
        return self.tick_numbers[j - 1] if j > 0 else -1
