"""When a real-time agent sends its beacon: a fixed slot in the world's tick, by UAV id.

The UAVs share a few send slots per tick (``slots``; UAV ``i`` sends in slot
``i % slots``), after the burst of observation deliveries at the start of each
tick, not into it.  Few slots is what makes beacons cheap to receive: the
beacons of one slot reach each receiver together, so Zenoh carries them in a
few batches and the receiver wakes once for many of them, where one slot per
UAV woke every receiver once per beacon (measured with ``bench/bench_swarm.py``
and ``bench/bench_beacon_burst.py``: 50 agents, 2 cores, see docs/results/history.md
"Scale").  The slot is anchored to the *start of
the tick* rather than to when this agent got round to its observation: with
20 agents the observations reach the last agent 5-30 ms after the first, and
anchoring to that pushes late slots into the next tick's burst (measured with
``bench/bench_swarm.py``).

The tick start is estimated from the world's own send stamps (the ``t`` of
its Tick and Obs messages, world clock): the world ticks every ``period_s``,
so ``stamp - tick * period_s`` is its time origin plus how late that stamp
was, and the minimum over recent ticks is the origin.  Every agent hears the
same Tick stamps, so all slots hang off one anchor and stay evenly spaced.
Across hosts this needs synchronized clocks (NTP/PTP), as the fault plan's
timing and the beacon-latency figures already do.  The estimate restarts
when a stamp is more than a period after its estimated tick start (a stalled
or a new world).

Pure computation: no clocks are read here; callers pass times in.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

DEFAULT_WINDOW = 50
"""Ticks of arrival history the tick-start estimate takes its minimum over (5 s at 10 Hz)."""


@dataclass
class BeaconSchedule:
    """The beacon slot of UAV ``uav`` of ``n_uavs``: ``phase + spread * (uav % slots) / slots`` of the period
    after tick start."""

    period_s: float
    """The world's tick period."""
    phase: float
    """Fraction of the period after tick start at which UAV 0 sends."""
    spread: float
    """Fraction of the period the slots are spread over."""
    uav: int
    n_uavs: int
    slots: int = 1
    """Distinct send times per tick; UAV ``i`` sends in slot ``i % slots`` (``n_uavs``: one slot per UAV)."""
    window: int = DEFAULT_WINDOW
    _origins: deque = field(default_factory=deque, init=False, repr=False)

    def __post_init__(self) -> None:
        if not self.period_s > 0:
            raise ValueError(f"period_s must be > 0, got {self.period_s}")
        if not (0 <= self.phase and 0 <= self.spread and self.phase + self.spread <= 1):
            raise ValueError(f"need 0 <= phase, 0 <= spread and phase + spread <= 1, got {self.phase}, {self.spread}")
        if not 0 <= self.uav < max(self.n_uavs, 1):
            raise ValueError(f"uav {self.uav} not in [0, {self.n_uavs})")
        if self.slots < 1:
            raise ValueError(f"slots must be >= 1, got {self.slots}")
        if self.window < 1:
            raise ValueError(f"window must be >= 1, got {self.window}")
        self._origins = deque(maxlen=self.window)

    @property
    def offset_s(self) -> float:
        """This UAV's slot, in seconds after tick start."""
        slots = min(self.slots, max(self.n_uavs, 1))
        return (self.phase + self.spread * (self.uav % slots) / slots) * self.period_s

    def observe(self, tick: int, stamp_s: float) -> None:
        """Record a world message of ``tick`` sent at ``stamp_s`` (world clock, seconds), in any order."""
        origin = stamp_s - tick * self.period_s
        if self._origins and origin > min(self._origins) + self.period_s:
            self._origins.clear()
        self._origins.append(origin)

    def tick_start(self, tick: int) -> float:
        """Estimated start of ``tick`` (world clock, seconds); needs one :meth:`observe` first."""
        if not self._origins:
            raise RuntimeError("no observation yet")
        return min(self._origins) + tick * self.period_s

    def due(self, tick: int) -> float:
        """When this UAV's beacon for ``tick`` should go out (world clock, seconds)."""
        return self.tick_start(tick) + self.offset_s


def sends_beacon(tick: int, uav: int, every: int) -> bool:
    """Whether UAV ``uav`` sends a beacon in ``tick`` when it beacons every ``every`` ticks (1: every tick).

    Offset by id, so at 1 Hz (every 10 ticks at 10 Hz, the Remote ID rate) a tenth of the
    swarm sends in each tick instead of all of it in one."""
    return (tick + uav) % every == 0
