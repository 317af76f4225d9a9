"""What the bus refused, as the world's step metrics: the ``rejected`` values of ``metrics/step``.

The world publishes them each tick (world.process.world_process); `truav-swarm status` reads them back
(truav.cli.swarm_secure). Pure: it only reads a :class:`~truav.wire.guard.Rejections`.
"""

from __future__ import annotations

REJECTED_METRIC = "rejected"
"""Step-metrics value: messages the world refused so far; ``rejected.<reason>`` per reason."""


def rejection_metrics(rejections) -> dict[str, float]:
    """The world's step-metrics values for its :class:`~truav.wire.guard.Rejections` (bounded: one per reason)."""
    by_reason = rejections.by_reason()
    return {REJECTED_METRIC: float(sum(by_reason.values())),
            **{f"{REJECTED_METRIC}.{reason}": float(n) for reason, n in by_reason.items()}}
