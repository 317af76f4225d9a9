"""Reference policies for sanity checks: a uniformly random swarm and a
hovering one. Their randomness comes from per-seed generators."""

from __future__ import annotations

import numpy as np

from truav import seeding
from truav.config import Config
from world.env import LocalObs
from world.uavs import HOVER, N_ACTIONS


class RandomController:
    """Every UAV picks one of the 16 actions uniformly at each step."""

    def __init__(self, cfg: Config, seeds: list[int]):
        self.shape = (len(seeds), cfg.scenario.n_uavs)
        self.rngs = [seeding.baseline_rng(s) for s in seeds]
        self.steps = cfg.scenario.steps_per_episode
        self._actions = np.zeros((self.steps,) + self.shape, np.int64)

    def begin_episode(self, episode: int, obs: LocalObs) -> None:
        draws = [rng.integers(0, N_ACTIONS, (self.steps, self.shape[1])) for rng in self.rngs]
        self._actions = np.stack(draws, axis=1)

    def act(self, t: int) -> np.ndarray:
        return self._actions[t]

    def observe(self, obs: LocalObs, done: bool) -> None:
        pass

    def episode_stats(self) -> dict[str, np.ndarray]:
        return {}


class HoverController:
    """Every UAV hovers where it starts."""

    def __init__(self, cfg: Config, seeds: list[int]):
        self.actions = np.full((len(seeds), cfg.scenario.n_uavs), HOVER, np.int64)

    def begin_episode(self, episode: int, obs: LocalObs) -> None:
        pass

    def act(self, t: int) -> np.ndarray:
        return self.actions

    def observe(self, obs: LocalObs, done: bool) -> None:
        pass

    def episode_stats(self) -> dict[str, np.ndarray]:
        return {}
