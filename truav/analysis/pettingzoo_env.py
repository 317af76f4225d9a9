"""The TRUAV scenario as a PettingZoo `ParallelEnv` (the `pettingzoo` extra),
so any multi-agent RL library can train its own agents on it.

    from truav.analysis.pettingzoo_env import parallel_env
    env = parallel_env()                      # the paper's scenario; parallel_env(cfg) for any Config
    obs, infos = env.reset(seed=0)
    while env.agents:
        actions = {a: env.action_space(a).sample() for a in env.agents}
        obs, rewards, terminations, truncations, infos = env.step(actions)

- Agents: "uav_0" ... "uav_{U-1}", all acting every step.
- Actions: Discrete(16), the paper's 8 headings x half/full speed; an agent
  missing from the action dict hovers (as in the swarm).
- Observations: Box(0, 10, (9,), float32): the UAV's local state as the
  centralized baseline's state report (`agents.central.STATE_FEATURES`:
  own position, vehicles in range, queued packets, packets relayed and
  vehicles served last step, energy last step, distance to the nearest RSU,
  each scaled to O(1)) plus the distance to the nearest neighbour heard in
  beacons (/ area). Only what a UAV senses locally, as in TRUAV.
- Rewards: TRUAV's local reward, eq. (1) of the paper (`agents.reward`).
- Episodes end by time limit: every agent is truncated after
  `scenario.steps_per_episode` steps, never terminated.
- Seeding: reset(seed=s) builds a fresh city from world seed s (the same
  streams as `truav train` seed s); reset() without a seed starts the next
  episode in the same city (traffic flows on, UAVs re-placed).
- infos[agent] holds that UAV's raw counts; at the last step each info also
  carries "episode": the world's episode summary (coverage, PDR, delay, ...).
"""

from __future__ import annotations

import functools

import numpy as np

try:
    from gymnasium import spaces
    from pettingzoo import ParallelEnv
except ImportError as exc:  # pragma: no cover - depends on the install
    raise ImportError("the PettingZoo adapter needs pettingzoo: pip install -e '.[pettingzoo]'") from exc

from agents.central import STATE_DIM, uav_states
from agents.reward import Reward
from agents.state import all_peers, neighbour_features
from truav import seeding
from truav.analysis.sumo_traffic import make_world
from truav.config import Config
from world import network
from world.env import LocalObs, World
from world.uavs import HOVER, N_ACTIONS

OBS_DIM = STATE_DIM + 1
OBS_HIGH = 10.0


class TruavParallelEnv(ParallelEnv):
    """U UAV agents over one environment of the world model."""

    metadata = {"name": "truav_v0", "render_modes": [], "is_parallelizable": True}

    def __init__(self, cfg: Config | None = None, render_mode: str | None = None):
        self.cfg = cfg or Config()
        self.render_mode = render_mode
        self.possible_agents = [f"uav_{i}" for i in range(self.cfg.scenario.n_uavs)]
        self.agents: list[str] = []
        self._index = {a: i for i, a in enumerate(self.possible_agents)}
        self._reward = Reward(self.cfg)
        self._rsu = network.rsu_positions(self.cfg)
        self._world: World | None = None
        self._t = 0
        self._prev_in_range = np.zeros(self.cfg.scenario.n_uavs)  # the shaping's phi(s) (learner.w_shaping)

    @functools.lru_cache(maxsize=None)
    def observation_space(self, agent: str) -> spaces.Box:
        return spaces.Box(0.0, OBS_HIGH, (OBS_DIM,), np.float32)

    @functools.lru_cache(maxsize=None)
    def action_space(self, agent: str) -> spaces.Discrete:
        return spaces.Discrete(N_ACTIONS)

    def _observations(self, obs: LocalObs) -> tuple[dict[str, np.ndarray], np.ndarray]:
        nearest, overlap = neighbour_features(obs.pos, *all_peers(obs.pos), self.cfg.scenario.comm_range_m)
        feats = np.concatenate([uav_states(self.cfg, obs, self._rsu)[0],
                                np.minimum(nearest[0] / self.cfg.scenario.area_m, OBS_HIGH)[:, None]], axis=1)
        feats = np.clip(feats, 0.0, OBS_HIGH).astype(np.float32)
        return {a: feats[i] for i, a in enumerate(self.agents)}, overlap

    @staticmethod
    def _info(obs: LocalObs, i: int) -> dict[str, float]:
        return {"vehicles_in_range": int(obs.vehicles_in_range[0, i]), "queued": int(obs.queued[0, i]),
                "relayed": int(obs.relayed[0, i]), "covered": int(obs.covered[0, i]),
                "energy_j": float(obs.energy_j[0, i])}

    def reset(self, seed: int | None = None, options: dict | None = None):
        if seed is not None or self._world is None:
            if seed is None:
                seed = int(np.random.SeedSequence().entropy % (2 ** 63))
            self._world = make_world(self.cfg, 1)
            obs = self._world.reset([seeding.world_rng(int(seed))])
        else:
            obs = self._world.start_episode()
        self.agents = list(self.possible_agents)
        self._t = 0
        self._prev_in_range = obs.vehicles_in_range[0].astype(np.float64)
        observations, _ = self._observations(obs)
        return observations, {a: self._info(obs, i) for i, a in enumerate(self.agents)}

    def step(self, actions: dict[str, int]):
        if not self.agents:
            raise RuntimeError("episode over: call reset()")
        a = np.full((1, len(self.possible_agents)), HOVER, np.int64)
        for agent, action in actions.items():
            if agent in self._index:
                a[0, self._index[agent]] = int(action)
        obs, _, done = self._world.step(a)
        self._t += 1
        observations, overlap = self._observations(obs)
        r = self._reward(obs.relayed, obs.covered, obs.energy_j, overlap, obs.exclusive, obs.vehicles_in_range,
                         self._prev_in_range[None])[0]
        self._prev_in_range = obs.vehicles_in_range[0].astype(np.float64)
        rewards = {ag: float(r[i]) for i, ag in enumerate(self.agents)}
        terminations = {ag: False for ag in self.agents}
        truncations = {ag: bool(done) for ag in self.agents}
        infos = {ag: self._info(obs, i) for i, ag in enumerate(self.agents)}
        if done:
            summary = {k: float(v[0]) for k, v in self._world.episode_summary().items()}
            for info in infos.values():
                info["episode"] = summary
            self.agents = []
        return observations, rewards, terminations, truncations, infos

    def render(self) -> None:
        return None

    def close(self) -> None:
        self._world = None


def parallel_env(cfg: Config | None = None, **kwargs) -> TruavParallelEnv:
    """PettingZoo-style constructor."""
    return TruavParallelEnv(cfg, **kwargs)
