"""Snapshot recording: the last BEFORE seconds in memory, a file per trigger (rosbag2's snapshot mode).

:class:`SnapshotLog` keeps every message of the last ``before_s`` seconds (log time) in a ring
bounded in bytes too (the oldest go first).  A trigger (:mod:`recorder.snapshot_triggers`: a
fault window starting, a sequence gap, missed actions; or :meth:`SnapshotLog.trigger` for a
command or a signal) opens ``<stem>_snap_NNNN.mcap``, writes the ring's messages from
``before_s`` before the trigger, then every message until ``after_s`` after it; a trigger while
a snapshot is open extends it to ``after_s`` after the latest one, up to MAX_SPAN_FACTOR windows
(at least MIN_MAX_SPAN_S) after it began: then it closes, and the next trigger opens another.  The
file closes with a
``truav.snapshot`` metadata record (the first trigger's kind, time and what, the window, and
every trigger it holds) and is a finished, self-contained MCAP (schemas, channels, the
recording's metadata).  Outside a snapshot nothing is written to disk.

It offers the writing interface of :class:`recorder.mcap_log.McapLog` that the recorder uses
(write, maybe_flush, next_flush_due, flush, set_metadata, summary, close); not thread-safe.
"""

from __future__ import annotations

import time
from collections import deque
from pathlib import Path
from typing import Any, Callable, Mapping, Optional

from recorder.mcap_log import LogSummary, McapLog
from recorder.record_modes import SNAPSHOT_METADATA, snapshot_path
from recorder.snapshot_triggers import Trigger, TriggerWatch
from truav import jsonio

__all__ = ["SnapshotLog", "MAX_TRIGGERS_LISTED"]

MAX_SPAN_FACTOR = 10  # a snapshot kept open by trigger after trigger ends this many windows after it began
MIN_MAX_SPAN_S = 60.0  # ... and not before this long (a storm of gaps must not become one endless file)
MAX_TRIGGERS_LISTED = 100  # triggers named in one snapshot's metadata (a storm of gaps is counted, not listed)
RING_OVERHEAD = 64  # bytes counted per kept message on top of its payload (tuple, key reference)
S = 1_000_000_000


class SnapshotLog:
    """Ring of the last ``before_s`` seconds (at most ``max_bytes``) and the snapshot files it writes.

    ``make_log(path)`` opens a snapshot's McapLog; ``now_ns`` is the log-time clock (wall, ns).
    """

    def __init__(self, out: str | Path, before_s: float, after_s: float, max_bytes: int,
                 make_log: Callable[[Path], McapLog], *, now_ns: Callable[[], int] = time.time_ns) -> None:
        self.out = Path(out)
        self._before = int(before_s * S)
        self._after = int(after_s * S)
        self._max_bytes = max_bytes
        self._make_log = make_log
        self._now = now_ns
        self._ring: deque[tuple[str, bytes, int, Optional[int]]] = deque()
        self._ring_bytes = 0
        self.evicted_for_bytes = 0  # messages dropped from memory early because of the byte cap
        self._watch = TriggerWatch()
        self._metadata: dict[str, dict[str, Any]] = {}  # written into every snapshot
        self._open: Optional[McapLog] = None
        self._end_ns = 0
        self._last_ns = 0  # the latest a trigger may extend the open snapshot to
        self._triggers: list[Trigger] = []
        self._n_triggers = 0
        self.paths: list[Path] = []  # finished snapshot files
        self._finished = LogSummary()  # what the finished files hold
        self._channels: dict[str, int] = {}  # messages seen per key
        self._seen = 0
        self.closed = False

    # --- McapLog's interface ---------------------------------------------------------------------
    def write(self, key: str, payload: bytes, log_time_ns: int, publish_time_ns: Optional[int] = None) -> None:
        if self.closed:
            raise ValueError("write() on a closed SnapshotLog")
        if self._open is not None and log_time_ns > self._end_ns:
            self._finish(cut_short=False)
        self._seen += 1
        self._channels[key] = self._channels.get(key, 0) + 1
        self._keep((key, payload, log_time_ns, publish_time_ns))
        if self._open is not None:
            self._open.write(key, payload, log_time_ns, publish_time_ns)
        for trig in self._watch.observe(payload, log_time_ns):
            self.trigger(trig)

    def maybe_flush(self, now: Optional[float] = None) -> bool:
        if self._open is None:
            return False
        if self._now() > self._end_ns:  # the after-window is over even if the bus is quiet
            self._finish(cut_short=False)
            return True
        return self._open.maybe_flush(now)

    def next_flush_due(self) -> Optional[float]:
        return None if self._open is None else self._open.next_flush_due()

    def flush(self) -> None:
        if self._open is not None:
            self._open.flush()

    def set_metadata(self, name: str, data: Mapping[str, Any]) -> None:
        """Kept for every snapshot file (the run config, the recording's facts); into the open one too."""
        self._metadata[name] = dict(data)
        if self._open is not None:
            self._open.set_metadata(name, data)

    def summary(self) -> LogSummary:
        """Messages seen (written or not) per key; bytes, chunks and mirror figures of the snapshot files."""
        done = self._finished
        out = LogSummary(messages=self._seen, mirror_messages=done.mirror_messages, mirror_errors=done.mirror_errors,
                         chunks=done.chunks, bytes_written=done.bytes_written, channels=dict(self._channels))
        if self._open is not None:
            now = self._open.summary()
            out.mirror_messages += now.mirror_messages
            out.chunks += now.chunks
            out.bytes_written += now.bytes_written
        return out

    def close(self) -> None:
        """Finish an open snapshot (marked cut short). Idempotent."""
        if self.closed:
            return
        if self._open is not None:
            self._finish(cut_short=True)
        self._ring.clear()
        self._ring_bytes = 0
        self.closed = True

    # --- snapshots ------------------------------------------------------------------------------------
    @property
    def active(self) -> bool:
        return self._open is not None

    def trigger(self, trig: Trigger) -> None:
        """Open a snapshot around ``trig`` (ring from ``before_s`` earlier), or extend the open one."""
        self._n_triggers += 1
        if len(self._triggers) < MAX_TRIGGERS_LISTED:
            self._triggers.append(trig)
        if self._open is not None:
            self._end_ns = min(max(self._end_ns, trig.at_ns + self._after), self._last_ns)
            return
        path = snapshot_path(self.out, len(self.paths) + 1)
        log = self._open = self._make_log(path)
        self._path = path
        self._end_ns = trig.at_ns + self._after
        span = max(MAX_SPAN_FACTOR * (self._before + self._after), int(MIN_MAX_SPAN_S * S))
        self._last_ns = trig.at_ns - self._before + span  # however many triggers follow
        for name, data in self._metadata.items():
            log.set_metadata(name, data)
        start = trig.at_ns - self._before
        for key, payload, log_time, pub in self._ring:
            if log_time >= start:
                log.write(key, payload, log_time, pub)

    def _finish(self, cut_short: bool) -> None:
        log = self._open
        assert log is not None
        first = self._triggers[0]
        record = {
            "trigger": first.kind, "trigger_time_ns": str(first.at_ns), "what": first.what,
            "before_s": repr(self._before / S), "after_s": repr(self._after / S),
            "window_start_ns": str(first.at_ns - self._before), "window_end_ns": str(self._end_ns),
            "triggers": jsonio.dumps([[t.kind, t.at_ns, t.what] for t in self._triggers]),
            "trigger_count": str(self._n_triggers), "cut_short": "true" if cut_short else "false",
            "at_span_limit": "true" if self._end_ns >= self._last_ns else "false",
        }
        log.set_metadata(SNAPSHOT_METADATA, record)
        log.close()
        this = log.summary()
        done = self._finished
        done.mirror_messages += this.mirror_messages
        done.mirror_errors += this.mirror_errors
        done.chunks += this.chunks
        done.bytes_written += this.bytes_written
        self.paths.append(self._path)
        self._open = None
        self._triggers = []
        self._n_triggers = 0

    def _keep(self, item: tuple[str, bytes, int, Optional[int]]) -> None:
        ring = self._ring
        ring.append(item)
        self._ring_bytes += len(item[1]) + RING_OVERHEAD
        oldest = item[2] - self._before
        while ring and (ring[0][2] < oldest or self._ring_bytes > self._max_bytes):
            dropped = ring.popleft()
            self._ring_bytes -= len(dropped[1]) + RING_OVERHEAD
            if dropped[2] >= oldest:
                self.evicted_for_bytes += 1
