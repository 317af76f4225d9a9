"""A paused recording: what was left out on purpose, so nobody takes it for loss.

While the recorder is paused (a ``pause`` command on ``control/recorder``) it writes nothing;
:class:`PauseLedger` notes, per sender stream (src, kind, incarnation), the range of sequence
numbers it left out.  At ``resume`` the recorder writes a ``truav.pause`` metadata record
(:func:`PauseLedger.record`): when, who asked, how many messages, and those ranges as JSON, so
``truav log check`` counts the gap as paused rather than missing (:func:`skipped_ranges`).  Pure.
"""

from __future__ import annotations

import json
from typing import Mapping, Optional

from recorder.schemas import envelope_fields
from truav import jsonio

__all__ = ["PauseLedger", "skipped_ranges", "MAX_STREAMS"]

MAX_STREAMS = 4096  # streams whose ranges are kept (as recorder.seq_stats bounds them)
SKIPPED_KEY = "skipped"  # the record's JSON: {"<src> <kind> <inc hex>": [lo, hi], ...}

StreamKey = tuple[str, str, int]


def stream_label(src: str, kind: str, inc: int) -> str:
    return f"{src} {kind} {inc:016x}"


class PauseLedger:
    """What one pause left out; :meth:`skip` for each message not written."""

    def __init__(self, started_ns: int, by: str) -> None:
        self.started_ns = started_ns
        self.by = by
        self.messages = 0
        self.undecodable = 0
        self._ranges: dict[StreamKey, list[int]] = {}
        self.overflow = 0  # messages of streams past MAX_STREAMS (counted, not ranged)

    def skip(self, key: str, payload: bytes, log_time_ns: int, publish_time_ns: Optional[int] = None) -> None:
        """McapLog.write's signature: the recorder calls this instead while paused."""
        self.messages += 1
        env = envelope_fields(payload)
        if env is None:
            self.undecodable += 1
            return
        kind, src, seq, _t, _body, inc = env
        stream = (src, kind, inc)
        span = self._ranges.get(stream)
        if span is None:
            if len(self._ranges) >= MAX_STREAMS:
                self.overflow += 1
                return
            self._ranges[stream] = [seq, seq]
        else:
            span[0], span[1] = min(span[0], seq), max(span[1], seq)

    def record(self, ended_ns: int, resumed_by: str) -> dict[str, str]:
        """The ``truav.pause`` metadata of this pause, ended at ``ended_ns``."""
        return {"paused_ns": str(self.started_ns), "resumed_ns": str(ended_ns), "paused_by": self.by,
                "resumed_by": resumed_by, "messages_not_recorded": str(self.messages),
                "undecodable": str(self.undecodable), "streams_not_ranged": str(self.overflow),
                SKIPPED_KEY: jsonio.dumps({stream_label(*k): v for k, v in sorted(self._ranges.items())})}


def skipped_ranges(record: Mapping[str, str]) -> dict[str, tuple[int, int]]:
    """A ``truav.pause`` record's ranges: {"<src> <kind> <inc hex>": (lo, hi)}; {} if unreadable."""
    try:
        raw = json.loads(record.get(SKIPPED_KEY, "{}"))
        return {str(k): (int(v[0]), int(v[1])) for k, v in raw.items()}
    except (ValueError, TypeError, IndexError, AttributeError):
        return {}
