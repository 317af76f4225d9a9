"""Range-limited beacons: map cells in the beacon key, subscriptions only to cells within range.

All-to-all beacons cost U x (U - 1) deliveries per beacon round.  A beacon
only matters to a receiver that could use it: TRUAV's state takes from its
neighbours the *level* of the nearest one's distance (edges
``learner.neighbour_edges_m``, 1 and 2 km) and the coverage overlap (zero
beyond 2 x ``comm_range_m``).  A neighbour at or beyond
:func:`feature_range_m` (2 km by default) changes neither: the distance
level is saturated, as with no neighbour at all, and its overlap term is an
exact +0.0 (agents.state.neighbour_one).  So a UAV that hears every beacon
sent from within that range of it decides exactly as one that hears all.

With cells, agent i sends its beacon on ``uav/<i>/beacon/<cx>_<cy>`` (the
cell of its position) and subscribes to the cells that come within
:meth:`BeaconCells.radius_m` of its position, re-subscribing as it moves.
The radius adds to the feature range a margin of how far two UAVs can close
in on each other while a beacon is in use (beacon interval plus the
real-time agent's maximum beacon age plus a tick of subscription lag), so a
neighbour is in a subscribed cell for several beacons before it comes
within range.  A receiver drops any beacon farther than the radius (a
neighbour heard before it left the subscribed cells, or before an episode
redeployed everyone): such a beacon is beyond the feature range, so
dropping it changes nothing, and it keeps a stale one from coming into
range as the receiver flies towards where it was.

What can still differ from all-to-all (real time only; lock-step refuses
cells): right after a jump of the receiver's position (an episode's random
redeployment), beacons sent before its new subscriptions reach the router
are not heard; the agent then decides as it would after a lost beacon.

Pure computation: no bus here (agents.process.agent_process subscribes).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from truav.config import Config


def feature_range_m(cfg: Config) -> float:
    """The distance at and beyond which a neighbour's beacon cannot change a TRUAV state or reward;
    infinite when the state holds the nearest neighbour's direction (learner.neighbour_sectors),
    which a neighbour at any distance sets."""
    if cfg.learner.neighbour_sectors > 0:
        return math.inf
    return max(max(cfg.learner.neighbour_edges_m, default=0.0), 2.0 * cfg.scenario.comm_range_m)


def subscription_radius_m(cfg: Config, beacon_every_ticks: int, max_age_ticks: int) -> float:
    """Feature range plus how far two UAVs can close in while a beacon is in use: each flies
    ``uav_speed_mps * step_s`` per tick, over a beacon interval, its maximum age and one tick of lag."""
    per_tick = cfg.scenario.uav_speed_mps * cfg.scenario.step_s
    return feature_range_m(cfg) + 2.0 * per_tick * (beacon_every_ticks + max_age_ticks + 1)


@dataclass(frozen=True)
class BeaconCells:
    """Square cells of ``cell_m`` over the ``area_m`` x ``area_m`` map, and which lie within ``radius_m``."""

    cell_m: float
    area_m: float
    radius_m: float

    def __post_init__(self) -> None:
        if not (self.cell_m > 0 and self.area_m > 0 and self.radius_m >= 0):
            raise ValueError(f"need cell_m > 0, area_m > 0, radius_m >= 0, got {self.cell_m}, {self.area_m}, "
                             f"{self.radius_m}")

    @property
    def per_axis(self) -> int:
        return max(1, math.ceil(self.area_m / self.cell_m - 1e-9))

    def cell_of(self, x: float, y: float) -> tuple[int, int]:
        """The cell holding (x, y); positions on or past the map's edge go to the edge cell."""
        top = self.per_axis - 1
        return (min(max(int(x // self.cell_m), 0), top), min(max(int(y // self.cell_m), 0), top))

    def within(self, x: float, y: float, extra_m: float = 0.0) -> frozenset[tuple[int, int]]:
        """Every cell with a point within ``radius_m + extra_m`` of (x, y) (closest-point test per cell)."""
        r, c, n = self.radius_m + extra_m, self.cell_m, self.per_axis
        lo_x, hi_x = self.cell_of(x - r, y)[0], self.cell_of(x + r, y)[0]
        lo_y, hi_y = self.cell_of(x, y - r)[1], self.cell_of(x, y + r)[1]
        out = set()
        for cx in range(lo_x, hi_x + 1):
            # The edge cells also hold positions past the map's edge (cell_of clamps).
            x0, x1 = (-math.inf if cx == 0 else cx * c), (math.inf if cx == n - 1 else (cx + 1) * c)
            dx = max(x0 - x, 0.0, x - x1)
            for cy in range(lo_y, hi_y + 1):
                y0, y1 = (-math.inf if cy == 0 else cy * c), (math.inf if cy == n - 1 else (cy + 1) * c)
                dy = max(y0 - y, 0.0, y - y1)
                if dx * dx + dy * dy <= r * r:
                    out.add((cx, cy))
        return frozenset(out)

    def in_range(self, own: tuple[float, float], other: tuple[float, float]) -> bool:
        """Whether a beacon from ``other`` is within the subscription radius of ``own`` (else dropped)."""
        return (own[0] - other[0]) ** 2 + (own[1] - other[1]) ** 2 <= self.radius_m ** 2


class CellFollower:
    """Which cells a moving receiver subscribes to: always every cell within the radius, changed rarely.

    On a change it takes every cell within the radius plus one cell's width around its position
    (the anchor), so it needs nothing new until it is a cell's width from the anchor, and drops
    only cells beyond the radius plus two.  A 2.4 km disc moving 15 m per tick would otherwise
    change a subscription every fourth tick, and each change is announced to the sessions
    publishing there; this way it changes about every 33 ticks (500 m cells)."""

    def __init__(self, cells: BeaconCells) -> None:
        self.cells = cells
        self.held: frozenset = frozenset()
        self._anchor: tuple[float, float] | None = None

    def move(self, x: float, y: float) -> tuple[frozenset, frozenset]:
        """(cells to subscribe to, cells to drop) now that the receiver is at (x, y)."""
        c = self.cells.cell_m
        if self._anchor is not None and (x - self._anchor[0]) ** 2 + (y - self._anchor[1]) ** 2 <= c * c:
            return frozenset(), frozenset()  # within(x, y) lies inside within(anchor, + one cell): held
        self._anchor = (x, y)
        add = self.cells.within(x, y, c) - self.held
        drop = self.held - self.cells.within(x, y, 2 * c)
        self.held = (self.held | add) - drop
        return add, drop
