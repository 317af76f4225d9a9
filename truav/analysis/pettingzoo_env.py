"""The TRUAV scenario as a PettingZoo `ParallelEnv` (the `pettingzoo` extra), so the field's multi-agent RL
libraries can train on it, observing what an agent process sees.

    from truav.analysis.pettingzoo_env import parallel_env
    env = parallel_env(preset="paper", sense_range_m=1500)   # or parallel_env(cfg) for any Config
    obs, infos = env.reset(seed=0)
    while env.agents:
        actions = {a: env.action_space(a).sample() for a in env.agents}
        obs, rewards, terminations, truncations, infos = env.step(actions)

- Scenario: ``cfg`` (the defaults without it), then ``preset``'s choices (truav.presets) on top, then
  ``sense_range_m`` as learner.sense_range_m (None keeps the config's; 0 turns sensing off; else above
  scenario.comm_range_m). The project's comparisons fly ``preset="paper", sense_range_m=1500``.
- Agents: "uav_0" ... "uav_{U-1}", all acting every step.
- Actions: Discrete(16), the paper's 8 headings x half/full speed; an agent missing from the action dict
  hovers (as in the swarm).
- Observations: each UAV's agents.api.LocalView, the view an API agent class is given (its own sensing
  and the beacons it heard), as a float32 vector (agents.view_features.ViewEncoder): own position,
  speed, vehicles in range, covered, exclusive, queued, relayed, energy, nearest RSU distance, peers
  heard, episode progress; the densest sensed sector one-hot over learner.sense_sectors (all 0 with
  sensing off); the ``peers`` (K, default 4) nearest heard peers' relative position, velocity, distance
  and a mask (padding: documented fills, mask 0). Each scaled to O(1), in the Box's bounds.
  ``env.observation_features()`` names each with its unit and scale; docs/reference/pettingzoo-observation.md
  is generated from it. With ``memory=True`` (env name truav_memory_v1) each observation also holds what
  the UAV did at the previous step: its action one-hot, its velocity, the change of its vehicles in range
  (agents.view_features.Memory; an agent process remembers it itself, agents/ppo_agent.py). With
  ``disc=True`` (learner.sense_disc on; env name truav_disc_v1, or truav_memory_disc_v1) each also ends with
  the densest sensed disc: its offset and vehicles (LocalView.disc_offset, disc_vehicles).
- One algorithm, two drivers: the views are built by the in-process API driver
  (agents.api_controller.ApiController, whose API agent here acts what ``step`` is given), so an
  observation is the encoding of exactly the view an API agent receives in process at the same seed and
  step, and of the view an agent process builds from its observation and beacons (agents.api_decision).
- Rewards: the reward an API agent is given: TRUAV's local reward, eq. (1) of the paper (agents.reward).
- Episodes end by time limit: every agent is truncated after scenario.steps_per_episode steps, never
  terminated.
- Seeding: reset(seed=s) builds a fresh city from world seed s (the same streams as `truav train` seed s);
  reset() without a seed starts the next episode in the same city (traffic flows on, UAVs re-placed).
- infos[agent] holds that UAV's raw counts; at the last step each info also carries "episode": the
  world's episode summary (coverage, PDR, delay, ...).
"""

from __future__ import annotations

import functools

import numpy as np

try:
    from gymnasium import spaces
    from pettingzoo import ParallelEnv
except ImportError as exc:  # pragma: no cover - depends on the install
    raise ImportError("the PettingZoo adapter needs pettingzoo: pip install -e '.[pettingzoo]'") from exc

from agents.api import UavAgent
from agents.api_controller import ApiController
from agents.view_features import DEFAULT_PEERS, NO_ACTION, Feature, Memory, ViewEncoder
from truav import seeding
from truav.analysis.sumo_traffic import make_world
from truav.config import Config
from truav.presets import preset_overrides
from world.env import LocalObs, World
from world.uavs import HOVER, N_ACTIONS


class _StepActions(UavAgent):
    """The API agent of each UAV the environment drives: it acts what ``step`` was given (``actions``, shared
    by the environment) and keeps the reward it is given (``rewards``)."""

    actions: np.ndarray
    rewards: np.ndarray

    def act(self, view) -> int:
        return int(self.actions[self.uav])

    def learn(self, view, reward: float, done: bool) -> None:
        self.rewards[self.uav] = reward


class TruavParallelEnv(ParallelEnv):
    """U UAV agents over one environment of the world model (see the module's docstring)."""

    metadata = {"name": "truav_v1", "render_modes": [], "is_parallelizable": True}

    def __init__(self, cfg: Config | None = None, render_mode: str | None = None, *, preset: str | None = None,
                 sense_range_m: float | None = None, peers: int = DEFAULT_PEERS, memory: bool = False,
                 disc: bool = False):
        cfg = cfg or Config()
        if preset is not None:
            cfg = cfg.replace(**preset_overrides(preset))
        if sense_range_m is not None:
            cfg = cfg.replace(learner={"sense_range_m": float(sense_range_m)})
        if disc:
            cfg = cfg.replace(learner={"sense_disc": True})
        self.cfg = cfg
        self.render_mode = render_mode
        self.encoder = ViewEncoder(cfg, peers, memory, disc=disc)
        if memory or disc:
            name = "truav" + ("_memory" if memory else "") + ("_disc" if disc else "") + "_v1"
            self.metadata = {**self.metadata, "name": name}
        self._last = Memory(np.full(cfg.scenario.n_uavs, NO_ACTION, np.int64), np.zeros(cfg.scenario.n_uavs))
        self.possible_agents = [f"uav_{i}" for i in range(cfg.scenario.n_uavs)]
        self.agents: list[str] = []
        self._index = {a: i for i, a in enumerate(self.possible_agents)}
        self._actions = np.full(cfg.scenario.n_uavs, HOVER, np.int64)
        self._rewards = np.zeros(cfg.scenario.n_uavs)
        self._world: World | None = None
        self._driver: ApiController | None = None
        self._episode = 0

    def observation_features(self) -> tuple[Feature, ...]:
        """Each feature of an observation, in order: name, unit, scale, bounds, meaning, padding fill."""
        return self.encoder.features

    @functools.lru_cache(maxsize=None)
    def observation_space(self, agent: str) -> spaces.Box:
        return spaces.Box(self.encoder.low, self.encoder.high, (self.encoder.size,), np.float32)

    @functools.lru_cache(maxsize=None)
    def action_space(self, agent: str) -> spaces.Discrete:
        return spaces.Discrete(N_ACTIONS)

    def _observations(self) -> dict[str, np.ndarray]:
        views = self._driver.views[0]
        return {a: self.encoder(views[i], Memory(int(self._last.action[i]), int(self._last.in_range[i])))
                for i, a in enumerate(self.agents)}

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
            self._driver = ApiController("pettingzoo", _StepActions, self.cfg, [int(seed)], train=False)
            for agent in self._driver.agents[0]:
                agent.actions, agent.rewards = self._actions, self._rewards
            self._episode = 0
        else:
            obs = self._world.start_episode()
            self._episode += 1
        self._driver.begin_episode(self._episode, obs)
        self._last.action[:], self._last.in_range[:] = NO_ACTION, 0
        self.agents = list(self.possible_agents)
        return self._observations(), {a: self._info(obs, i) for i, a in enumerate(self.agents)}

    def step(self, actions: dict[str, int]):
        if not self.agents:
            raise RuntimeError("episode over: call reset()")
        self._actions[:] = HOVER
        for agent, action in actions.items():
            if agent in self._index:
                self._actions[self._index[agent]] = int(action)
        self._last.in_range[:] = [v.vehicles_in_range for v in self._driver.views[0]]
        self._last.action[:] = self._actions
        obs, _, done = self._world.step(self._driver.act(self._driver.t))
        self._driver.observe(obs, done)
        observations = self._observations()
        rewards = {ag: float(self._rewards[i]) for i, ag in enumerate(self.agents)}
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
        self._world = self._driver = None


def parallel_env(cfg: Config | None = None, **kwargs) -> TruavParallelEnv:
    """PettingZoo-style constructor: parallel_env(cfg, preset=..., sense_range_m=..., peers=..., memory=...,
    disc=...)."""
    return TruavParallelEnv(cfg, **kwargs)
