"""Any PettingZoo ``ParallelEnv`` as a Stable-Baselines3 ``VecEnv`` of shared-parameter slots (the `marl` extra).

B copies of the environment x U agents each: B x U slots, slot i is agent i % U (in ``possible_agents``
order) of copy i // U, the same layout as truav.analysis.ppo_vec_env.TruavVecEnv, so one SB3 loop trains
independent PPO with shared parameters on either (bench/bench_ppo_training.py runs it on PettingZoo's
MPE ``simple_spread`` beside TRUAV). No SuperSuit: the copies step one after another in this process.

- Every agent must have the same observation and action space (one network acts for all of them).
- An episode of a copy ends for all its agents together, when any agent is terminated or truncated or
  the environment's agent list empties; its slots then carry ``terminal_observation`` and
  ``TimeLimit.truncated`` (truncated and not terminated), and the copy starts its next episode.
- Seeding: copy b's first reset is ``reset(seed=seeds[b])``, later ones continue its own generator
  (``reset()``); SB3's ``seed()`` is not used, the seeds are the constructor's.
"""

from __future__ import annotations

from typing import Any, Callable

import numpy as np
from stable_baselines3.common.vec_env import VecEnv


class ParallelVecEnv(VecEnv):
    """See the module's docstring. ``make_env()`` returns a new ParallelEnv copy."""

    def __init__(self, make_env: Callable[[], Any], seeds: list[int]):
        self.seeds = list(seeds)
        self.envs = [make_env() for _ in self.seeds]
        self.agents = list(self.envs[0].possible_agents)
        self.B, self.U = len(self.envs), len(self.agents)
        obs_space, act_space = (self.envs[0].observation_space(self.agents[0]),
                                self.envs[0].action_space(self.agents[0]))
        for a in self.agents:
            if self.envs[0].observation_space(a) != obs_space or self.envs[0].action_space(a) != act_space:
                raise ValueError(f"agent {a} has other spaces than {self.agents[0]}: no shared parameters")
        self.render_mode = None
        super().__init__(self.B * self.U, obs_space, act_space)
        self.started = [False] * self.B
        self._pending: np.ndarray | None = None

    def _stack(self, obs: dict) -> np.ndarray:
        return np.stack([np.asarray(obs[a], dtype=self.observation_space.dtype) for a in self.agents])

    def _reset_one(self, b: int) -> np.ndarray:
        obs, _ = self.envs[b].reset(seed=None if self.started[b] else self.seeds[b])
        self.started[b] = True
        return self._stack(obs)

    def reset(self) -> np.ndarray:
        return np.concatenate([self._reset_one(b) for b in range(self.B)])

    def step_async(self, actions: np.ndarray) -> None:
        self._pending = np.asarray(actions).reshape(self.B, self.U, *self.action_space.shape)

    def step_wait(self):
        observations = np.empty((self.B, self.U) + self.observation_space.shape, self.observation_space.dtype)
        rewards = np.zeros((self.B, self.U), np.float32)
        dones = np.zeros((self.B, self.U), bool)
        infos: list[dict] = [{} for _ in range(self.num_envs)]
        for b, env in enumerate(self.envs):
            act = self._pending[b]
            obs, rew, term, trunc, _ = env.step({a: act[u] for u, a in enumerate(self.agents)})
            observations[b] = self._stack(obs)
            rewards[b] = [rew[a] for a in self.agents]
            if not env.agents or any(term.values()) or any(trunc.values()):
                dones[b] = True
                for u, a in enumerate(self.agents):
                    infos[b * self.U + u].update({"terminal_observation": observations[b, u].copy(),
                                                  "TimeLimit.truncated": bool(trunc[a] and not term[a])})
                observations[b] = self._reset_one(b)
        observations = observations.reshape((self.num_envs,) + self.observation_space.shape)
        return observations, rewards.reshape(-1), dones.reshape(-1), infos

    def close(self) -> None:
        for env in self.envs:
            env.close()

    # One ParallelEnv holds U slots: attributes are the vector's own, as in TruavVecEnv.
    def get_attr(self, attr_name, indices=None):
        return [getattr(self, attr_name)] * len(self._get_indices(indices))

    def set_attr(self, attr_name, value, indices=None) -> None:
        setattr(self, attr_name, value)

    def env_method(self, method_name, *method_args, indices=None, **method_kwargs):
        raise AttributeError(f"ParallelVecEnv has no per-slot environments ({method_name})")

    def env_is_wrapped(self, wrapper_class, indices=None):
        return [False] * len(self._get_indices(indices))


__all__ = ["ParallelVecEnv"]
