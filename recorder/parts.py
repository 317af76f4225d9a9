"""A recording split into parts: a new self-contained MCAP file by size, by duration or on command.

:class:`PartedLog` drives one :class:`recorder.mcap_log.McapLog` and rotates it
(:meth:`McapLog.rotate`) into ``<stem>_0001.mcap``, ``<stem>_0002.mcap``, ...
(:func:`recorder.record_modes.part_path`).  Every part declares its schemas and
channels again, carries the metadata given with ``repeat`` (the run config, the
recording's facts) and ends with a ``truav.part`` metadata record
(:data:`recorder.record_modes.PART_FIELDS`); ``<stem>.parts.json`` lists the parts
in order and is rewritten (atomically) whenever a part starts or finishes, so a
reader always finds the finished ones.  No message falls between two parts: a
rotation happens between two writes.  Not thread-safe (the recorder's writer
thread owns it), like McapLog.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping, Optional

from recorder.mcap_log import LogSummary, McapLog
from recorder.record_modes import (PART_METADATA, REASON_COMMAND, REASON_DURATION, REASON_END, REASON_SIZE,
                                   RecordModes, part_path, parts_index_path)
from truav import jsonio

__all__ = ["PartedLog", "read_parts_index"]

INDEX_VERSION = 1
MB = 1_000_000


def read_parts_index(out: str | os.PathLike[str]) -> dict[str, Any]:
    """The ``<stem>.parts.json`` of recording ``out`` (the path given to the recorder)."""
    return json.loads(parts_index_path(Path(out)).read_text())


class PartedLog:
    """The recorder's sink when splitting: McapLog's writing interface over numbered parts.

    ``make_log(path)`` opens the first part's McapLog (options and mirrors as the recorder wants).
    """

    def __init__(self, out: str | os.PathLike[str], modes: RecordModes, make_log: Callable[[Path], McapLog], *,
                 repeat: Iterable[str] = (), session: Optional[str] = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.out = Path(out)
        self.session = session or os.urandom(8).hex()
        self._max_bytes = None if modes.split_size_mb is None else int(modes.split_size_mb * MB)
        self._max_s = modes.split_duration_s
        self._repeat = frozenset(repeat)
        self._metadata: dict[str, dict[str, Any]] = {}  # the repeated records, as last set
        self._clock = clock
        self.parts: list[dict[str, Any]] = []  # the index's rows; the last is the open part
        self._log = make_log(self._start_row(1))
        self._opened = clock()
        self._write_index()

    # --- McapLog's interface, as the recorder uses it ------------------------------------------
    @property
    def closed(self) -> bool:
        return self._log.closed

    def write(self, key: str, payload: bytes, log_time_ns: int, publish_time_ns: Optional[int] = None) -> None:
        self._log.write(key, payload, log_time_ns, publish_time_ns)
        if self._max_bytes is not None and self._log.bytes_on_disk >= self._max_bytes:
            self.split(REASON_SIZE)
        elif self._max_s is not None and self._clock() - self._opened >= self._max_s:
            self.split(REASON_DURATION)

    def maybe_flush(self, now: Optional[float] = None) -> bool:
        if self._max_s is not None and self._clock() - self._opened >= self._max_s:  # a quiet bus splits too
            self.split(REASON_DURATION)
        return self._log.maybe_flush(now)

    def next_flush_due(self) -> Optional[float]:
        due = self._log.next_flush_due()
        if self._max_s is not None:
            split_at = self._opened + self._max_s
            due = split_at if due is None else min(due, split_at)
        return due

    def flush(self) -> None:
        self._log.flush()

    def set_metadata(self, name: str, data: Mapping[str, Any]) -> None:
        """Into the open part; a name given in ``repeat`` goes into every later part too."""
        if name in self._repeat:
            self._metadata[name] = dict(data)
        self._log.set_metadata(name, data)

    def summary(self) -> LogSummary:
        return self._log.summary()

    @property
    def paths(self) -> list[Path]:
        """The parts so far, in order (the last one open until :meth:`close`)."""
        return [self.out.with_name(row["path"]) for row in self.parts]

    # --- splitting ------------------------------------------------------------------------------
    def split(self, reason: str = REASON_COMMAND) -> Path:
        """Finish the open part (``reason``: why it ended) and start the next; returns the new part's path."""
        self._finish_part(reason)
        path = self._start_row(len(self.parts) + 1)
        self._log.rotate(path)
        self._opened = self._clock()
        for name, data in self._metadata.items():
            self._log.set_metadata(name, data)
        self._write_index()
        return path

    def close(self, reason: str = REASON_END) -> None:
        """Finish the last part. Idempotent."""
        if self._log.closed:
            return
        self._finish_part(reason)
        self._log.close()
        self._write_index()

    def _start_row(self, n: int) -> Path:
        path = part_path(self.out, n)
        self.parts.append({"part": n, "path": path.name, "finished": False})
        return path

    def _finish_part(self, reason: str) -> None:
        self._log.flush()  # the open chunk's messages count in the part's time range
        first, last = self._log.log_time_range()
        record = {"session": self.session, "part": str(len(self.parts)), "reason": reason,
                  "first_log_time_ns": "" if first is None else str(first),
                  "last_log_time_ns": "" if last is None else str(last)}
        self._log.set_metadata(PART_METADATA, record)
        self.parts[-1].update(finished=True, reason=reason,
                              first_log_time_ns=first, last_log_time_ns=last)

    def _write_index(self) -> None:
        """``<stem>.parts.json``, replaced atomically (a reader never sees half of it)."""
        index = parts_index_path(self.out)
        tmp = index.with_name(index.name + ".tmp")
        tmp.write_text(jsonio.dumps({"version": INDEX_VERSION, "session": self.session, "parts": self.parts},
                                  indent=1) + "\n")
        os.replace(tmp, index)
