"""Per-sender sequence statistics of a recording, counted online as messages arrive.

Every sender numbers its messages per kind (envelope ``seq``) and per
incarnation (``inc``: a restarted process numbers from 0 again), so a forward
jump in one stream is a message that never reached the recorder.
:class:`SenderStats` keeps one :class:`SeqStats` per (src, kind, incarnation)
stream, bounded in memory (:data:`MAX_TRACKED_SENDERS`); ``recorder.check``
recomputes exact figures offline.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable, Optional

__all__ = ["SeqStats", "SenderStats", "MAX_TRACKED_SENDERS", "OTHER_SENDERS"]

MAX_TRACKED_SENDERS = 4096
"""(src, kind, incarnation) streams tracked one by one; further ones pool under OTHER_SENDERS (bounded memory)."""
OTHER_SENDERS = "(other senders)"

StreamKey = tuple[str, str, int]  # (src, kind, incarnation)


@dataclass(slots=True)
class SeqStats:
    """Online sequence tracking for one (src, kind, incarnation) stream.

    Counted as messages arrive, so a reordered message that later fills a
    gap still counts as ``missing`` and ``backwards``; ``recorder.check``
    recomputes exact figures offline.
    """

    count: int = 0
    first_seq: Optional[int] = None
    last_seq: Optional[int] = None  # highest seq seen
    gaps: int = 0  # forward jumps by more than one
    missing: int = 0  # seq numbers those jumps skipped
    backwards: int = 0  # seq <= highest seen (duplicate or reordered)
    paused: int = 0  # messages left out on purpose while the recorder was paused (not a loss, not in count)


class SenderStats:
    """The :class:`SeqStats` of every stream, fed one message at a time by :meth:`observe`.

    ``on_join(src, log_time, pub)`` is called the first time a sender is seen
    and ``on_loss(src, kind, skipped, log_time, pub)`` at every forward gap
    (the recorder logs both to Foxglove); either may be None.
    """

    def __init__(self, on_join: Optional[Callable[[str, int, int], None]] = None,
                 on_loss: Optional[Callable[[str, str, int, int, int], None]] = None) -> None:
        self._streams: dict[StreamKey, SeqStats] = {}
        self._first_inc: dict[str, int] = {}  # src -> its first incarnation recorded (the one that may predate us)
        self._srcs_seen: set[str] = set()
        self._on_join = on_join
        self._on_loss = on_loss

    def observe(self, src: str, kind: str, inc: int, seq: int, log_time: int, pub: int) -> None:
        """Count one message of stream (src, kind, inc) numbered ``seq`` (hot path)."""
        # a restarted sender numbers from 0 again under a new incarnation: a stream of its own
        streams = self._streams
        stats = streams.get((src, kind, inc))
        if stats is None and len(streams) >= MAX_TRACKED_SENDERS:  # src and inc are the sender's choice
            src, inc = OTHER_SENDERS, 0
            stats = streams.get((src, kind, inc))
        if stats is None:
            stats = streams[(src, kind, inc)] = SeqStats(count=1, first_seq=seq, last_seq=seq)
            if self._first_inc.setdefault(src, inc) != inc and seq:  # a later process starts at seq 0
                stats.gaps, stats.missing = 1, seq
            if self._on_join is not None and src not in self._srcs_seen:
                self._srcs_seen.add(src)
                self._on_join(src, log_time, pub)
        else:
            stats.count += 1
            last = stats.last_seq
            if seq == last + 1:  # type: ignore[operator]
                stats.last_seq = seq
            elif seq > last:  # type: ignore[operator]
                stats.gaps += 1
                stats.missing += seq - last - 1  # type: ignore[operator]
                stats.last_seq = seq
                if self._on_loss is not None:
                    self._on_loss(src, kind, seq - last - 1, log_time, pub)  # type: ignore[operator]
            else:
                stats.backwards += 1

    def skip(self, src: str, kind: str, inc: int, seq: int) -> None:
        """A message of stream (src, kind, inc) left out on purpose (the recorder paused): counted as
        ``paused``, and its seq moves the stream on, so the first message recorded after the pause is no gap
        (as ``truav log check`` counts the pause's seq ranges as paused, not missing)."""
        streams = self._streams
        stats = streams.get((src, kind, inc))
        if stats is None:
            if len(streams) >= MAX_TRACKED_SENDERS:
                return
            self._first_inc.setdefault(src, inc)
            streams[(src, kind, inc)] = SeqStats(first_seq=seq, last_seq=seq, paused=1)
            return
        stats.paused += 1
        if stats.last_seq is None or seq > stats.last_seq:
            stats.last_seq = seq

    def snapshot(self) -> dict[StreamKey, SeqStats]:
        """A copy of every stream's figures, safe to keep."""
        return {k: replace(v) for k, v in self._streams.items()}
