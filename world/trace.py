"""A mobility trace: vehicle positions recorded once per world step (by SUMO,
truav/analysis/sumo_traffic.py), replayed by the world instead of its own car
following (scenario.mobility = "sumo"). Pure: arrays and their checks.

Layout: positions (R, N, 2) float64 in the world's metres, vehicle slot n
always the same vehicle; active (R, N) whether slot n was on the road at row
r (positions are NaN where not). The rows hold W = (R - 1) // T windows of T
steps (T = scenario.steps_per_episode) end to end: window w starts at row
w * T (the positions at the episode's start) and step t of its episode ends
at row w * T + t + 1, so consecutive windows continue each other.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from truav.config import Config


@dataclass(frozen=True)
class Trace:
    positions: np.ndarray
    """(R, N, 2) float64 vehicle positions (m), NaN where a slot is not on the road."""
    active: np.ndarray
    """(R, N) bool."""
    step_s: float
    """Time between rows (s): the world's scenario.step_s."""
    steps_per_episode: int
    """T: steps of one window (scenario.steps_per_episode)."""

    @property
    def windows(self) -> int:
        return (self.positions.shape[0] - 1) // self.steps_per_episode

    def mismatch(self, cfg: Config) -> str | None:
        """Why this trace cannot drive cfg's world, or None."""
        sc = cfg.scenario
        r, n = self.positions.shape[:2]
        if self.positions.shape != (r, n, 2) or self.active.shape != (r, n):
            return f"positions {self.positions.shape} and active {self.active.shape} do not match"
        if n != sc.n_vehicles:
            return f"it holds {n} vehicles, scenario.n_vehicles is {sc.n_vehicles}"
        if self.step_s != sc.step_s:
            return f"its step is {self.step_s:g} s, scenario.step_s is {sc.step_s:g} s"
        if self.steps_per_episode != sc.steps_per_episode or self.windows < 1:
            return (f"it holds {r} rows of {self.steps_per_episode}-step windows, the scenario's episodes have "
                    f"{sc.steps_per_episode} steps")
        return None

    def episode_row0(self, offset: int, episode: int) -> int:
        """Row of the start of an env's episode `episode`, its windows starting at `offset`."""
        return ((offset + episode) % self.windows) * self.steps_per_episode


def rows_needed(cfg: Config) -> int:
    """Rows of a trace of cfg.sumo.trace_episodes windows."""
    return cfg.sumo.trace_episodes * cfg.scenario.steps_per_episode + 1
