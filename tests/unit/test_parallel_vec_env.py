"""The shared-parameter vector over any PettingZoo ParallelEnv (truav.analysis.parallel_vec_env): slots in
the layout SB3 expects, episode ends with terminal observations, and SB3's PPO learns on it, on TRUAV's own
PettingZoo environment and on MPE's simple_spread (the peer task of bench/bench_ppo_training.py)."""

from __future__ import annotations

import numpy as np
import pytest
from gymnasium import spaces

pytest.importorskip("stable_baselines3")

from truav.analysis.parallel_vec_env import ParallelVecEnv  # noqa: E402
from truav.analysis.pettingzoo_env import parallel_env  # noqa: E402
from truav.analysis.ppo_train import make_ppo  # noqa: E402
from truav.config import Config  # noqa: E402

CFG = Config().replace(scenario={"n_vehicles": 40, "steps_per_episode": 5, "n_uavs": 3},
                       roads={"warmup_steps": 5}, learner={"sense_range_m": 1500.0})


def test_slots_are_each_copys_agents_in_order_and_episodes_end_together():
    vec = ParallelVecEnv(lambda: parallel_env(CFG), [7, 8])
    obs = vec.reset()
    want = []
    for seed in (7, 8):
        pobs, _ = parallel_env(CFG).reset(seed=seed)
        want += [pobs[f"uav_{u}"] for u in range(3)]
    assert vec.num_envs == 6 and obs.shape == (6,) + vec.observation_space.shape
    assert np.array_equal(obs, np.stack(want))
    rng = np.random.default_rng(0)
    for t in range(5):
        obs, rew, done, infos = vec.step(rng.integers(0, vec.action_space.n, 6))
        assert rew.shape == (6,) and rew.dtype == np.float32 and obs.shape == (6,) + vec.observation_space.shape
        assert done.tolist() == [t == 4] * 6
    assert all(i["TimeLimit.truncated"] and i["terminal_observation"].shape == vec.observation_space.shape
               for i in infos)


def test_ppo_learns_on_it_and_on_mpe_simple_spread():
    simple_spread = pytest.importorskip("mpe2.simple_spread_v3")
    for make, steps in ((lambda: parallel_env(CFG), 5),
                        (lambda: simple_spread.parallel_env(N=5, max_cycles=6, continuous_actions=False), 6)):
        vec = ParallelVecEnv(make, [0, 1])
        model = make_ppo(vec, n_steps=steps)
        model.learn(total_timesteps=2 * steps * vec.num_envs)
        assert model.num_timesteps == 2 * steps * vec.num_envs


class _Mixed:
    """A ParallelEnv-shaped object whose two agents do not share an action space."""

    possible_agents = ["a", "b"]

    def observation_space(self, agent):
        return spaces.Box(-1, 1, (2,), np.float32)

    def action_space(self, agent):
        return spaces.Discrete(2 if agent == "a" else 3)


def test_agents_with_different_spaces_are_refused():
    with pytest.raises(ValueError, match="agent b has other spaces"):
        ParallelVecEnv(_Mixed, [0])
