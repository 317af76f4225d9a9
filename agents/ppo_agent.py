"""The learned decentralized policy (registered as ``ppo``; agents.api): PPO with shared parameters, flown greedy.

Each UAV encodes its own LocalView (agents.view_features.ViewEncoder: its sensing and the beacons it heard, the
PettingZoo environment's observation) and flies the action of the largest logit of the network trained by
truav/analysis/ppo_train.py (docs/results/learned-policy.md), exported to numpy (agents.ppo_policy): no torch at
run time, the same arithmetic in an agent process and in the in-process evaluation. It learns nothing while it
flies (``truav train --agent ppo`` flies it greedy); its weights are ``weights`` (a class attribute: a subclass
names another file). Trained under --preset paper at 15 m/s with learner.sense_range_m = 1500: fly it with
that sensing (``--set learner.sense_range_m=1500``), without which its sector features are all zero. Weights
trained with the memory features (``memory`` in the file) have each instance remember its own last action and
vehicles in range (agents.view_features.Memory), reset at each episode's start.
"""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np

from agents.api import LocalView, UavAgent
from agents.ppo_policy import NumpyPolicy
from agents.view_features import NO_ACTION, Memory, ViewEncoder
from truav.config import Config

WEIGHTS = Path(__file__).with_name("weights") / "ppo_paper_15mps.npz"
"""The shipped weights (the command that made them: docs/results/learned-policy.md)."""


@functools.lru_cache(maxsize=4)
def load_policy(path: str) -> NumpyPolicy:
    """The network stored at ``path`` (an .npz of agents.ppo_policy's layout), read once per process."""
    with np.load(path, allow_pickle=False) as z:
        return NumpyPolicy({k: z[k] for k in z.files})


class PpoAgent(UavAgent):
    """One UAV's greedy learned policy (see the module's docstring)."""

    weights: Path = WEIGHTS

    def __init__(self, cfg: Config, uav: int, rng: np.random.Generator):
        super().__init__(cfg, uav, rng)
        self.policy = load_policy(str(self.weights))
        self.encoder = ViewEncoder(cfg, self.policy.peers if self.policy.peers is not None else 4, self.policy.memory)
        self.last = Memory()
        if self.encoder.size != self.policy.n_features:
            raise ValueError(f"{self.weights.name} expects {self.policy.n_features} features, this run's view has "
                             f"{self.encoder.size} (learner.sense_sectors {cfg.learner.sense_sectors}; trained with "
                             f"{self.policy.sense_sectors})")

    def begin_episode(self, episode: int, train: bool) -> None:
        self.last = Memory()

    def act(self, view: LocalView) -> int:
        if view.step == 0:  # the episode's first view: nothing to remember yet
            self.last = Memory()
        action = int(self.policy.greedy(self.encoder(view, self.last)[None, :])[0])
        self.last = Memory(action, view.vehicles_in_range)
        return action


__all__ = ["PpoAgent", "WEIGHTS", "load_policy"]
