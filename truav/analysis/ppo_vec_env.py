"""B environments of the world model x U UAVs as one Stable-Baselines3 ``VecEnv`` of B x U slots (the `marl` extra).

Parameter sharing, the standard independent PPO with shared parameters (IPPO): every UAV of every environment
is one slot of the vector, acting on its own observation only. Slot i is UAV i % U of environment i // U.

- Observations: each UAV's LocalView encoded as the PettingZoo environment encodes it
  (agents.view_features.ViewEncoder, here its batched form ``batch``), built by the in-process API driver
  (agents.api_controller.ApiController) from one World stepping all B environments at once: the same
  numbers as ``truav.analysis.pettingzoo_env`` for the same seed and step (tests/unit/test_ppo_vec_env.py),
  with ``memory`` its memory features too (each UAV's previous action and vehicles in range), with ``claim`` the
  climbing heuristic's state (agents.claim_agent.ClaimBatched run beside the UAVs on their views, once per step),
  with ``disc`` the densest sensed disc (learner.sense_disc on in ``cfg`` for it to hold anything).
- Actions: Discrete(17): the 16 of truav.actions, and 16 for HOVER (the heuristic hovers; a policy imitating
  it needs to).
- Rewards: the paper's local reward (agents.reward), plus ``coverage_bonus`` x the share of all vehicles the
  environment covers (a shaped team term; 0: off).
- Episodes: every environment ends together after scenario.steps_per_episode steps, truncated (never
  terminated: ``TimeLimit.truncated``, with ``terminal_observation``), and the next starts in the same city
  (World.start_episode); ``infos[i]["episode_coverage"]`` then holds the environment's coverage (%).
- Seeding: environment b is world seed ``seeds[b]`` (truav.seeding.world_rng), the streams of `truav train`.
"""

from __future__ import annotations

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.vec_env import VecEnv

from agents.api import BatchedAgents, BatchedViews
from agents.api_controller import ApiController
from agents.claim_agent import ClaimBatched
from agents.view_features import DEFAULT_PEERS, NO_ACTION, Memory, ViewEncoder
from truav import seeding
from truav.actions import HOVER, N_ACTIONS
from truav.analysis.sumo_traffic import make_world
from truav.config import Config

HOVER_INDEX = N_ACTIONS
"""The slot action meaning HOVER (the last of Discrete(N_ACTIONS + 1))."""


def to_world_actions(a: np.ndarray) -> np.ndarray:
    """Slot actions (0..N_ACTIONS, N_ACTIONS: hover) -> the world's (0..N_ACTIONS-1 or HOVER)."""
    a = np.asarray(a, np.int64)
    return np.where(a == HOVER_INDEX, HOVER, a)


def to_slot_actions(a: np.ndarray) -> np.ndarray:
    """The world's actions -> slot actions."""
    a = np.asarray(a, np.int64)
    return np.where(a == HOVER, HOVER_INDEX, a)


class _Given(BatchedAgents):
    """The batched agent the vector drives: it acts what step_async was given; it keeps its rewards."""

    actions: np.ndarray
    rewards: np.ndarray

    def act(self, views: BatchedViews) -> np.ndarray:
        return self.actions.copy()

    def learn(self, views: BatchedViews, reward: np.ndarray, done: bool) -> None:
        self.rewards = np.asarray(reward, np.float64)


class _GivenClass:
    batched = _Given


class TruavVecEnv(VecEnv):
    """See the module's docstring."""

    def __init__(self, cfg: Config, seeds: list[int], peers: int = DEFAULT_PEERS, coverage_bonus: float = 0.0,
                 memory: bool = False, claim: bool = False, disc: bool = False):
        self.cfg, self.seeds, self.coverage_bonus = cfg, list(seeds), float(coverage_bonus)
        self.B, self.U = len(seeds), cfg.scenario.n_uavs
        self.encoder = ViewEncoder(cfg, peers, memory, claim, disc)
        self.shadow = ClaimBatched(cfg, [[seeding.agent_rng(s, u) for u in range(self.U)] for s in self.seeds]) \
            if claim else None
        self.last = Memory(np.full((self.B, self.U), NO_ACTION, np.int64), np.zeros((self.B, self.U)))
        self.render_mode = None
        box = spaces.Box(self.encoder.low, self.encoder.high, (self.encoder.size,), np.float32)
        super().__init__(self.B * self.U, box, spaces.Discrete(N_ACTIONS + 1))
        self.world = make_world(cfg, self.B)
        self.driver = ApiController("ppo-vec", _GivenClass, cfg, self.seeds, train=True)
        self.group: _Given = self.driver.group
        self.group.actions = np.full((self.B, self.U), HOVER, np.int64)
        self.group.rewards = np.zeros((self.B, self.U))
        self.episode = -1
        self._pending: np.ndarray | None = None

    @property
    def views(self) -> BatchedViews:
        """The current step's views (B, U): what a batched agent (a teacher) would act on."""
        return self.driver.views

    def _obs(self, advance: bool = True) -> np.ndarray:
        """``advance``: the claim features' rule acts on this step's views (not on an episode's terminal
        observation, on which no agent acts)."""
        claim = None
        if self.shadow is not None:
            if advance:
                self.shadow_actions = self.shadow.act(self.driver.views)
            claim = self.shadow.features()
        return self.encoder.batch(self.driver.views, self.last, claim).reshape(self.B * self.U, -1)

    def reset(self) -> np.ndarray:
        if self.episode < 0:
            obs = self.world.reset([seeding.world_rng(s) for s in self.seeds])
        else:
            obs = self.world.start_episode()
        self.episode += 1
        self.driver.begin_episode(self.episode, obs)
        self.last.action[:], self.last.in_range[:] = NO_ACTION, 0
        return self._obs()

    def step_async(self, actions: np.ndarray) -> None:
        self._pending = np.asarray(actions).reshape(self.B, self.U)

    def step_wait(self):
        self.group.actions = to_world_actions(self._pending)
        self.last.action[:], self.last.in_range[:] = self.group.actions, self.driver.views.vehicles_in_range
        obs, _, done = self.world.step(self.driver.act(self.driver.t))
        self.driver.observe(obs, done)
        reward = self.group.rewards
        if self.coverage_bonus:
            share = np.asarray(obs.covered, np.float64).sum(axis=1, keepdims=True) / self.cfg.scenario.n_vehicles
            reward = reward + self.coverage_bonus * share
        rewards = reward.reshape(-1).astype(np.float32)
        observations = self._obs(advance=not done)
        dones = np.full(self.num_envs, bool(done))
        infos: list[dict] = [{} for _ in range(self.num_envs)]
        if done:
            coverage = np.asarray(self.world.episode_summary()["coverage_pct"], np.float64)
            for i, info in enumerate(infos):
                info.update({"terminal_observation": observations[i], "TimeLimit.truncated": True,
                             "episode_coverage": float(coverage[i // self.U])})
            observations = self.reset()
        return observations, rewards, dones, infos

    def close(self) -> None:
        self.world = None

    # The per-environment calls of the VecEnv interface: one World holds every slot, so there is no
    # per-slot environment object; attributes are the vector's own.
    def get_attr(self, attr_name, indices=None):
        return [getattr(self, attr_name)] * len(self._get_indices(indices))

    def set_attr(self, attr_name, value, indices=None) -> None:
        setattr(self, attr_name, value)

    def env_method(self, method_name, *method_args, indices=None, **method_kwargs):
        raise AttributeError(f"TruavVecEnv has no per-slot environments ({method_name})")

    def env_is_wrapped(self, wrapper_class, indices=None):
        return [False] * len(self._get_indices(indices))


__all__ = ["HOVER_INDEX", "TruavVecEnv", "to_slot_actions", "to_world_actions"]
