"""What the world tells each agent it refused: :class:`RejectionNotices` gathers the refusals per UAV and
hands out at most one :class:`~truav.wire.messages.Rejection` per UAV every ``period_s`` (the rest counted in
the next one), and at most ``max_per_round`` per call, so a flood of bad messages costs the world a bounded
number of sends. Pure bookkeeping (a lock, no bus): the world process publishes what :meth:`due` returns."""

from __future__ import annotations

import threading
from dataclasses import dataclass, field

from truav.wire.messages import REJECTION_PERIOD_S, Rejection
from truav.wire.schema_names import MAX_DETAIL_LEN, MAX_HEALTH_REASONS, MAX_NAME_LEN, MAX_TARGET_LEN

MAX_NOTICES_PER_ROUND = 64
"""Rejections handed out per call of :meth:`RejectionNotices.due` (the others wait for the next period)."""


@dataclass
class _Pending:
    reason: str
    kind: str
    key: str
    at_tick: int
    detail: str
    counts: dict[str, int] = field(default_factory=dict)


class RejectionNotices:
    """Refusals per UAV (``note``), released as rejections at most once per UAV per period (``due``)."""

    def __init__(self, n_uavs: int, period_s: float = REJECTION_PERIOD_S,
                 max_per_round: int = MAX_NOTICES_PER_ROUND) -> None:
        self.n_uavs, self.period_s, self.max_per_round = n_uavs, period_s, max_per_round
        self._pending: dict[int, _Pending] = {}
        self._sent_at: dict[int, float] = {}
        self._lock = threading.Lock()
        self.sent = 0
        """Rejections handed out so far."""

    def note(self, uav: int, reason: str, kind: str, key: str, at_tick: int, detail: str) -> None:
        """One refused message of ``uav`` (the UAV of the key it came on; others are ignored)."""
        if not 0 <= uav < self.n_uavs:
            return
        with self._lock:
            p = self._pending.get(uav)
            if p is None:
                p = self._pending[uav] = _Pending(reason[:MAX_NAME_LEN], (kind or "")[:MAX_NAME_LEN],
                                                  _ascii(key)[:MAX_TARGET_LEN] or "?", max(-1, at_tick),
                                                  _ascii(detail)[:MAX_DETAIL_LEN])
            if reason in p.counts or len(p.counts) < MAX_HEALTH_REASONS:  # reasons are the fixed R_* codes
                p.counts[reason] = p.counts.get(reason, 0) + 1

    def pending(self) -> bool:
        with self._lock:
            return bool(self._pending)

    def due(self, now: float) -> list[Rejection]:
        """The rejections to send now: UAVs with something pending whose last one is ``period_s`` old."""
        out: list[Rejection] = []
        with self._lock:
            for uav in list(self._pending):
                if len(out) >= self.max_per_round:
                    break
                if now - self._sent_at.get(uav, -1e18) < self.period_s:
                    continue
                p = self._pending.pop(uav)
                self._sent_at[uav] = now
                out.append(Rejection(uav=uav, at_tick=p.at_tick, reason=p.reason, refused_kind=p.kind, key=p.key,
                                     detail=p.detail, counts=p.counts))
            self.sent += len(out)
        return out


def _ascii(text: str) -> str:
    """Printable ASCII (others escaped): the receiver's msgpack limits count bytes, the schema characters."""
    return "".join(c if " " <= c <= "~" else c.encode("unicode_escape").decode("ascii")
                   for c in text[:MAX_DETAIL_LEN])
