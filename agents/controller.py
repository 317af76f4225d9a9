"""TRUAV as a controller of the in-process driver: B x U independent agents.

Per step each agent encodes its local state (own observation + neighbours'
beacon positions), picks an epsilon-greedy action, and after the step
computes its reward and updates its own table. The swarm's agent process
runs the same `AgentStep` logic for one agent.
"""

from __future__ import annotations

import numpy as np

from agents.federated import federate, share_due
from agents.prediction import new_maps, predict_batch, predict_params
from agents.qlearning import QLearners, geofence
from agents.reward import Reward
from agents.state import StateEncoder, all_peers, neighbour_features
from truav import seeding
from truav.config import Config
from world.env import LocalObs
from world.link_phy import IDEAL, heard_masks, link_params


class TruavController:
    """Independent tabular Q-learning agents, one per UAV and seed."""

    def __init__(self, cfg: Config, seeds: list[int], train: bool = True, q: np.ndarray | None = None,
                 rngs: list[np.random.Generator] | None = None):
        """rngs: the agents' generators, seed-major (default: truav.seeding.agent_rng of each seed and UAV)."""
        self.cfg, self.train = cfg, train
        self.encoder, self.reward = StateEncoder(cfg), Reward(cfg)
        U = cfg.scenario.n_uavs
        if rngs is None:
            rngs = [seeding.agent_rng(s, i) for s in seeds for i in range(U)]
        self.learners = QLearners(cfg.learner, self.encoder.n_states, rngs, len(seeds), U, q=q, fence=geofence(cfg))
        self.state = np.zeros((len(seeds), U), np.int64)
        self.pos = np.zeros((len(seeds), U, 2))
        self.action = np.zeros((len(seeds), U), np.int64)
        self._reward_sum = np.zeros(len(seeds))
        self._steps = 0
        self._episode = 0
        self.visits = np.zeros((len(seeds), U, self.encoder.n_states), np.int64)
        """Each agent's updates per state (federated TRUAV weighs shared rows by them: agents.federated)."""
        self.visits_at_share = np.zeros_like(self.visits)
        """visits at the agents' last share: a share holds the rows visited since."""
        self.predict = predict_params(cfg)
        self.maps = new_maps(self.predict, len(seeds), U)
        """Each agent's decayed density map (agents/prediction.py; no cells with prediction off)."""
        self.prev_in_range = np.zeros((len(seeds), U))
        """Vehicles in range at each agent's last observation (the shaping's phi(s))."""
        self.fused = True
        """The driver runs whole episodes through run_episode; False steps through act/observe."""
        self.draws_in_kernel = True
        """run_episode's kernel makes the world's per-episode draws (in parallel over envs)."""
        self.links = link_params(cfg)
        """Who hears whose beacon (world.link_phy): IDEAL, or the channel's table."""
        self.link_seeds = np.array(seeds, np.int64)
        """Each env's run seed: the channel's draws are those of a swarm run with it (--seed)."""

    def __setstate__(self, state: dict) -> None:
        """A controller pickled before federated TRUAV (a training checkpoint of an earlier version) gets
        its visit counts, from zero: it never shared."""
        self.__dict__.update(state)
        if "visits" not in state:
            self.visits = np.zeros(self.learners.q.shape[:3], np.int64)
            self.visits_at_share = np.zeros_like(self.visits)
            self._episode = 0
        if "links" not in state:  # pickled before channel-driven links: ideal ones
            self.links, self.link_seeds = IDEAL, np.zeros(len(self._reward_sum), np.int64)

    def _features(self, obs: LocalObs, k: int):
        """State and overlap from the beacons number k of the episode (0 at its start, t + 1 after step t)."""
        peers, heard = all_peers(obs.pos)
        if self.links.table.size:
            heard = heard_masks(self.links.table, self.links.step_m, np.ascontiguousarray(obs.pos, np.float64),
                                self.link_seeds, self._episode, k)
        nearest, overlap = neighbour_features(obs.pos, peers, heard, self.cfg.scenario.comm_range_m)
        predicted = predict_batch(self.maps, np.ascontiguousarray(obs.pos, np.float64),
                                  np.asarray(obs.vehicles_in_range, np.float64), self.predict)
        return self.encoder.encode(obs.pos, obs.vehicles_in_range, obs.queued, nearest,
                                   self.encoder.neighbour_sectors(obs.pos, peers, heard), obs.densest_sector,
                                   predicted), overlap

    def begin_episode(self, episode: int, obs: LocalObs) -> None:
        self.learners.begin_episode(episode, self.cfg.scenario.steps_per_episode, greedy=not self.train)
        self._episode = episode
        self.state, _ = self._features(obs, 0)
        self.pos = obs.pos
        self.prev_in_range = np.asarray(obs.vehicles_in_range, np.float64).copy()
        self._reward_sum[:] = 0.0
        self._steps = 0

    def run_episode(self, world) -> None:
        """Steps 0..T-1 of the world's current episode in one compiled kernel
        (agents.fused): the same numbers as act/observe through World.step."""
        from agents.fused import run_episode
        run_episode(world, self)
        self._end_episode()

    def _end_episode(self) -> None:
        """Federated TRUAV: the agents share and merge their tables after the episodes of a share round."""
        if self.train and share_due(self._episode, self.cfg.federated):
            T = self.cfg.scenario.steps_per_episode
            heard = None
            if self.links.table.size:  # a share is decided as beacon T + 1 of the episode, at its last positions
                heard = heard_masks(self.links.table, self.links.step_m, np.ascontiguousarray(self.pos, np.float64),
                                    self.link_seeds, self._episode, T + 1)
            federate(self.learners.q, self.visits, self.visits_at_share, self._episode, self.cfg.federated, T, heard)

    def act(self, t: int) -> np.ndarray:
        self.action = self.learners.act(self.state, t, self.pos)
        return self.action

    def observe(self, obs: LocalObs, done: bool) -> None:
        next_state, overlap = self._features(obs, self._steps + 1)
        r = self.reward(obs.relayed, obs.covered, obs.energy_j, overlap, obs.exclusive, obs.vehicles_in_range,
                        self.prev_in_range)
        self.prev_in_range = np.asarray(obs.vehicles_in_range, np.float64).copy()
        if self.train:
            self.learners.update(self.state, self.action, r, next_state, False)
            b, u = np.indices(self.state.shape)
            self.visits[b, u, self.state] += 1
        self._reward_sum += r.mean(axis=1)
        self._steps += 1
        self.state = next_state
        self.pos = obs.pos
        if done:
            self._end_episode()

    def episode_stats(self) -> dict[str, np.ndarray]:
        n = len(self._reward_sum)
        return {"reward": self._reward_sum / max(self._steps, 1), "epsilon": np.full(n, self.learners.epsilon)}
