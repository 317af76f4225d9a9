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
(PpoBatched: the same arithmetic on the batched views). PpoDiscAgent (``ppo-disc``) picks its weights by the run's
speed: DISC_WEIGHTS (observing the densest sensed disc, learner.sense_disc) below DISC_BELOW_MPS, else CLAIM_WEIGHTS.
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
DISC_WEIGHTS = WEIGHTS.with_name("ppo_disc_paper_5mps.npz")
"""The network taught by the privileged teacher at 5 m/s, observing the densest sensed disc
(docs/scripts/privileged_dagger.py --disc; docs/results/learned-policy.md, "A learner that flies the sensed disc")."""
DISC_BELOW_MPS = 10.0
"""PpoDiscAgent flies DISC_WEIGHTS below this speed and CLAIM_WEIGHTS from it on: where each was measured
above the heuristics (docs/results/velocity.md)."""


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
        self.weights = self.weights_for(cfg)
        self.policy = load_policy(str(self.weights))
        self.encoder = encoder_for(self.weights, self.policy, cfg)
        self.last = Memory()
        self.shadow = ClaimAgent(cfg, uav, rng) if self.policy.claim else None

    @classmethod
    def weights_for(cls, cfg: Config) -> Path:
        """The weights this class flies in a run of ``cfg``: ``weights`` (a subclass may choose by the run)."""
        return cls.weights

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


def encoder_for(weights: Path, policy: NumpyPolicy, cfg: Config) -> ViewEncoder:
    """The observation ``policy`` was trained on, for a run of ``cfg``; ValueError when the run cannot give it."""
    if policy.disc and not (cfg.learner.sense_disc and cfg.learner.sense_range_m > 0.0):
        raise ValueError(f"{weights.name} observes the densest sensed disc: fly it with sensing on and "
                         f"learner.sense_disc true (--set learner.sense_disc=true)")
    encoder = ViewEncoder(cfg, policy.peers if policy.peers is not None else 4, policy.memory, policy.claim,
                          policy.disc)
    check_size(weights, policy, encoder, cfg)
    return encoder


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
        self.weights = self.weights_for(cfg)
        self.policy = load_policy(str(self.weights))
        B, U = len(rngs), len(rngs[0])
        self.encoder = encoder_for(self.weights, self.policy, cfg)
        self.shadow = ClaimBatched(cfg, rngs) if self.policy.claim else None
        self.last = Memory(np.full((B, U), NO_ACTION, np.int64), np.zeros((B, U)))

    @classmethod
    def weights_for(cls, cfg: Config) -> Path:
        """As PpoAgent.weights_for."""
        return cls.weights

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


def disc_weights_for(cfg: Config) -> Path:
    """DISC_WEIGHTS below DISC_BELOW_MPS, CLAIM_WEIGHTS from it on."""
    return DISC_WEIGHTS if cfg.scenario.uav_speed_mps < DISC_BELOW_MPS else CLAIM_WEIGHTS


class PpoDiscBatched(PpoBatched):
    @classmethod
    def weights_for(cls, cfg: Config) -> Path:
        return disc_weights_for(cfg)


class PpoDiscAgent(PpoAgent):
    """The best learned policy at every speed (registered as ``ppo-disc``): below DISC_BELOW_MPS the network
    observing the densest sensed disc (DISC_WEIGHTS; fly it with learner.sense_disc on, as the comparisons and
    `truav-swarm up` do), from it on ppo-claim's (CLAIM_WEIGHTS)."""

    batched = PpoDiscBatched

    @classmethod
    def weights_for(cls, cfg: Config) -> Path:
        return disc_weights_for(cfg)


__all__ = ["CLAIM_WEIGHTS", "DISC_BELOW_MPS", "DISC_WEIGHTS", "PpoAgent", "PpoBatched", "PpoClaimAgent",
           "PpoClaimBatched", "PpoDiscAgent", "PpoDiscBatched", "WEIGHTS", "check_size", "disc_weights_for",
           "encoder_for", "load_policy"]
