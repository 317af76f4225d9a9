"""The learned decentralized policy (registered as ``ppo``; agents.api): PPO with shared parameters, flown greedy.

Each UAV encodes its own LocalView (agents.view_features.ViewEncoder: its sensing and the beacons it heard, the
PettingZoo environment's observation) and flies the action of the largest logit of the network trained by
truav/analysis/ppo_train.py (docs/results/learned-policy.md), exported to numpy (agents.ppo_policy): no torch at
run time, the same arithmetic in an agent process and in the in-process evaluation. It learns nothing while it
flies (``truav train --agent ppo`` flies it greedy); its weights are ``weights`` (a class attribute: a subclass
names another file). Trained under --preset paper at 15 m/s with learner.sense_range_m = 1500: fly it with
that sensing (``--set learner.sense_range_m=1500``), without which its sector features are all zero. Weights
trained with the memory features (``memory`` in the file) have each instance remember its own last action and
vehicles in range (agents.view_features.Memory), reset at each episode's start. Weights trained with the claim
features (``claim`` in the file) have each instance run the climbing heuristic (agents.claim_agent.ClaimAgent)
beside it on its own views, for its state (the features) and its beacon's claimed goal; the network picks the
action. PpoClaimAgent (registered as ``ppo-claim``; by class path ``agents.ppo_agent:PpoClaimAgent``) flies
CLAIM_WEIGHTS, cloned from that heuristic (docs/results/learned-policy.md, "Toward 60%"), with a batched form
(PpoBatched: the same arithmetic on the batched views).
"""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np

from agents.api import BatchedAgents, BatchedViews, LocalView, UavAgent
from agents.claim_agent import ClaimAgent, ClaimBatched
from agents.ppo_policy import NumpyPolicy
from agents.view_features import NO_ACTION, Memory, ViewEncoder
from truav.config import Config

WEIGHTS = Path(__file__).with_name("weights") / "ppo_paper_15mps.npz"
"""The shipped weights (the command that made them: docs/results/learned-policy.md)."""
CLAIM_WEIGHTS = WEIGHTS.with_name("ppo_claim_paper_15mps.npz")
"""The network cloned from the climbing heuristic with the claim features (docs/scripts/toward60_claim.py)."""


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
        self.encoder = ViewEncoder(cfg, self.policy.peers if self.policy.peers is not None else 4, self.policy.memory,
                                   self.policy.claim)
        self.last = Memory()
        self.shadow = ClaimAgent(cfg, uav, rng) if self.policy.claim else None
        check_size(self.weights, self.policy, self.encoder, cfg)

    def begin_episode(self, episode: int, train: bool) -> None:
        self.last = Memory()

    def act(self, view: LocalView) -> int:
        if view.step == 0:  # the episode's first view: nothing to remember yet
            self.last = Memory()
        claim = None
        if self.shadow is not None:
            self.shadow.act(view)
            claim = self.shadow.features()
        action = int(self.policy.greedy(self.encoder(view, self.last, claim)[None, :])[0])
        self.last = Memory(action, view.vehicles_in_range)
        return action

    def beacon_fields(self) -> dict[str, float]:
        return self.shadow.beacon_fields() if self.shadow is not None else {}


def check_size(weights: Path, policy: NumpyPolicy, encoder: ViewEncoder, cfg: Config) -> None:
    if encoder.size != policy.n_features:
        raise ValueError(f"{weights.name} expects {policy.n_features} features, this run's view has "
                         f"{encoder.size} (learner.sense_sectors {cfg.learner.sense_sectors}; trained with "
                         f"{policy.sense_sectors})")


class PpoBatched(BatchedAgents):
    """PpoAgent (``weights``) for every UAV of every seed at once: the same arithmetic on the batched views."""

    weights: Path = WEIGHTS

    def __init__(self, cfg: Config, rngs):
        super().__init__(cfg, rngs)
        self.policy = load_policy(str(self.weights))
        B, U = len(rngs), len(rngs[0])
        self.encoder = ViewEncoder(cfg, self.policy.peers if self.policy.peers is not None else 4, self.policy.memory,
                                   self.policy.claim)
        self.shadow = ClaimBatched(cfg, rngs) if self.policy.claim else None
        self.last = Memory(np.full((B, U), NO_ACTION, np.int64), np.zeros((B, U)))
        check_size(self.weights, self.policy, self.encoder, cfg)

    def act(self, views: BatchedViews) -> np.ndarray:
        B, U = self.last.action.shape
        if views.step == 0:
            self.last = Memory(np.full((B, U), NO_ACTION, np.int64), np.zeros((B, U)))
        claim = None
        if self.shadow is not None:
            self.shadow.act(views)
            claim = self.shadow.features()
        obs = self.encoder.batch(views, self.last, claim).reshape(B * U, -1)
        action = self.policy.greedy(obs).reshape(B, U)
        self.last = Memory(action, np.asarray(views.vehicles_in_range).copy())
        return action


class PpoClaimBatched(PpoBatched):
    weights = CLAIM_WEIGHTS


class PpoClaimAgent(PpoAgent):
    """The network cloned from the climbing heuristic, with the claim features (CLAIM_WEIGHTS)."""

    weights = CLAIM_WEIGHTS
    batched = PpoClaimBatched


__all__ = ["CLAIM_WEIGHTS", "PpoAgent", "PpoBatched", "PpoClaimAgent", "PpoClaimBatched", "WEIGHTS", "check_size",
           "load_policy"]
