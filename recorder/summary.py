"""What a recorder run did: :class:`RecorderSummary`, printed when the recorder stops and stored in the file.

Pure (no bus): the recorder process (:mod:`recorder.process.recorder`) fills it from
its :class:`recorder.mcap_log.LogSummary` and its Bus's statistics.
"""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass, field
from typing import Any, Optional

from recorder.mcap_log import LogSummary

__all__ = ["RecorderSummary", "MAX_SUMMARY_ROWS"]

MAX_SUMMARY_ROWS = 200  # channel / sender rows in the printed summary
MAX_FILES_NAMED = 4  # parts / snapshots named in the printed summary (more: the first and the last)


@dataclass
class RecorderSummary:
    """What the recorder did; :meth:`format` is the text printed at the end."""

    run: str
    path: str
    started_ns: int
    stopped_ns: int
    stop_reason: str
    log: LogSummary
    bus: Any  # a truav.bus.transport.BusStats (read here, not imported: the bus sits above this module)
    max_backlog: int = 0  # most messages waiting for the writer at once
    error: Optional[str] = None
    compacted: Optional[tuple[int, int]] = None  # file size before and after the compaction at the finish
    files: list[str] = field(default_factory=list)  # the files written: parts or snapshots (or the one file)
    paused_s: float = 0.0  # time spent paused by request (nothing written then: not a loss)
    not_recorded_paused: int = 0  # messages received while paused

    @property
    def duration_s(self) -> float:
        return max(self.stopped_ns - self.started_ns, 0) / 1e9

    @property
    def recorder_dropped(self) -> int:
        """Messages that reached this process but are not in the file (Bus queue full)."""
        return self.bus.overflow + self.bus.callback_errors

    def to_json(self) -> dict[str, Any]:
        """Plain-JSON form (for ``--summary-json`` and the summary metadata)."""
        return {
            "run": self.run, "path": self.path, "started_ns": self.started_ns, "stopped_ns": self.stopped_ns,
            "duration_s": self.duration_s, "stop_reason": self.stop_reason, "error": self.error,
            "messages": self.log.messages, "mirror_messages": self.log.mirror_messages,
            "undecodable": self.log.undecodable, "bytes": self.log.bytes_written, "chunks": self.log.chunks,
            "missing_by_seq": self.log.missing, "recorder_dropped": self.recorder_dropped,
            "bus_overflow": self.bus.overflow, "bus_filtered": self.bus.filtered, "max_backlog": self.max_backlog,
            "channels": dict(sorted(self.log.channels.items())),
            "senders": {f"{src} {kind} {inc:016x}": asdict(s)
                        for (src, kind, inc), s in sorted(self.log.senders.items())},
            "rejected": self.bus.rejected,
            "files": list(self.files), "paused_s": self.paused_s, "not_recorded_paused": self.not_recorded_paused,
        }

    def format(self) -> str:
        """Headline, then messages per channel, then per-sender sequence gaps."""
        log_ = self.log
        rate = log_.messages / self.duration_s if self.duration_s > 0 else 0.0
        lines = [
            f"recorder: run {self.run} -> {self.path} ({self.stop_reason})",
            f"  {log_.messages} messages on {len(log_.channels)} channels in {self.duration_s:.1f} s "
            f"({rate:,.0f} msgs/s), {log_.mirror_messages} mirror messages, {log_.bytes_written:,} bytes, "
            f"{log_.chunks} chunks" + (f"; compacted at the finish to {self.compacted[1]:,} bytes"
                                       if self.compacted else ""),
            f"  lost before the recorder (sequence gaps): {log_.missing}; lost in the recorder: "
            f"{self.recorder_dropped}; undecodable: {log_.undecodable}; peak backlog {self.max_backlog}",
        ]
        if self.files and self.files != [self.path]:
            names = [os.path.basename(f) for f in self.files]
            shown = ", ".join(names) if len(names) <= MAX_FILES_NAMED else f"{names[0]} ... {names[-1]}"
            lines.append(f"  files: {len(names)} ({shown}, beside {self.path})")
        if self.paused_s:
            lines.append(f"  paused by request for {self.paused_s:.1f} s: {self.not_recorded_paused} messages not "
                         "recorded (noted in the file's truav.pause metadata)")
        if self.error:
            lines.append(f"  ERROR: {self.error}")
        if log_.channels:
            lines.append("  messages per channel:")
            items = sorted(log_.channels.items())
            width = max(len(k) for k, _ in items[:MAX_SUMMARY_ROWS])
            lines += [f"    {k:<{width}}  {n:>9}" for k, n in items[:MAX_SUMMARY_ROWS]]
            if len(items) > MAX_SUMMARY_ROWS:
                lines.append(f"    ... {len(items) - MAX_SUMMARY_ROWS} more channels")
        gappy = sorted((k, s) for k, s in log_.senders.items() if s.missing or s.backwards)
        lines.append(f"  senders: {len(log_.senders)}, with sequence gaps: {len(gappy)}"
                     + (" (run `truav log check FILE` for the ranges)" if gappy else ""))
        for (src, kind, inc), s in gappy[:MAX_SUMMARY_ROWS]:
            lines.append(f"    {src:<12} {kind:<10} inc {inc:016x} msgs {s.count:>8}  missing {s.missing:>6} "
                         f"in {s.gaps} gaps" + (f", {s.backwards} out of order/duplicate" if s.backwards else ""))
        return "\n".join(lines)
