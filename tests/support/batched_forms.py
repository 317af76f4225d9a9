"""One check shared by the built-in agent classes' unit tests: a class flies the same actions for the same
seed twice, and its batched form (``cls.batched``) flies what its per-UAV form flies, action for action."""

from __future__ import annotations

import numpy as np

from agents.api_controller import ApiController
from truav.analysis.driver import run_episodes
from truav.config import Config


class _Actions(ApiController):
    """The controller, keeping every action it gives the world."""

    def act(self, t):
        a = super().act(t)
        self.seen = getattr(self, "seen", []) + [np.array(a)]
        return a


def assert_batched_flies_per_uav(name: str, cls: type, cfg: Config, seeds=(3, 4), episodes: int = 3) -> None:
    """``cls`` twice and its per-UAV form (``batched = None``) give equal actions and metrics on ``seeds``."""
    per_uav = type(f"PerUav{cls.__name__}", (cls,), {"batched": None})
    runs = []
    for form in (cls, cls, per_uav):
        ctl = _Actions(name, form, cfg, list(seeds), train=False)
        runs.append((run_episodes(cfg, list(seeds), ctl, episodes), np.stack(ctl.seen)))
    assert len(np.unique(runs[0][1])) > 3  # it flies, not one action
    for got, actions in runs[1:]:
        assert np.array_equal(actions, runs[0][1])
        for k in ("coverage_pct", "pdr", "energy_j"):
            assert np.array_equal(got[k], runs[0][0][k], equal_nan=True), k
