"""The vectorized environment the learned policy trains in (truav.analysis.ppo_vec_env) observes and rewards what
the PettingZoo environment does for the same seed, step and actions; the batched view encoding equals the
per-UAV one; the numpy network an agent flies gives the trained torch policy's greedy actions."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

from agents.ppo_policy import NumpyPolicy  # noqa: E402
from truav.actions import HOVER  # noqa: E402
from truav.analysis.pettingzoo_env import parallel_env  # noqa: E402
from truav.analysis.ppo_vec_env import HOVER_INDEX, TruavVecEnv, to_world_actions  # noqa: E402
from truav.config import Config  # noqa: E402

CFG = Config().replace(scenario={"n_vehicles": 60, "steps_per_episode": 12, "n_uavs": 4},
                       roads={"warmup_steps": 10}, learner={"sense_range_m": 1500.0})


def test_vector_of_one_env_equals_the_pettingzoo_env_step_for_step():
    vec, pz = TruavVecEnv(CFG, [7]), parallel_env(CFG)
    obs, (pobs, _) = vec.reset(), pz.reset(seed=7)
    rng = np.random.default_rng(1)
    ends = 0
    for t in range(30):  # past two episode ends: the next episode starts in the same city in both
        assert np.array_equal(obs, np.stack([pobs[a] for a in pz.possible_agents])), t
        a = rng.integers(0, HOVER_INDEX + 1, 4)
        obs, rew, done, infos = vec.step(a)
        pobs, prew, _, trunc, pinfo = pz.step({f"uav_{k}": int(a[k]) for k in range(4) if a[k] != HOVER_INDEX})
        assert np.allclose(rew, [prew[f"uav_{k}"] for k in range(4)], rtol=1e-6, atol=1e-6)
        assert bool(done[0]) == trunc["uav_0"]
        if done[0]:
            ends += 1
            term = np.stack([i["terminal_observation"] for i in infos])
            assert np.array_equal(term, np.stack([pobs[a] for a in pz.possible_agents]))
            assert infos[0]["TimeLimit.truncated"]
            assert infos[0]["episode_coverage"] == pytest.approx(pinfo["uav_0"]["episode"]["coverage_pct"])
            pobs, _ = pz.reset()
    assert ends == 2


def test_batched_encoding_equals_each_uavs_encoding_over_several_envs():
    vec = TruavVecEnv(CFG, [1, 2, 3])
    obs = vec.reset()
    for seed_index, seed in enumerate([1, 2, 3]):
        pz = parallel_env(CFG)
        pobs, _ = pz.reset(seed=seed)
        assert np.array_equal(obs.reshape(3, 4, -1)[seed_index], np.stack([pobs[a] for a in pz.possible_agents]))


def test_hover_is_the_last_slot_action():
    assert to_world_actions(np.array([0, 15, HOVER_INDEX])).tolist() == [0, 15, HOVER]


def test_numpy_export_gives_the_torch_policys_greedy_actions():
    torch = pytest.importorskip("torch")
    from stable_baselines3 import PPO

    from truav.analysis.ppo_train import export
    torch.manual_seed(0)
    vec = TruavVecEnv(CFG, [5])
    model = PPO("MlpPolicy", vec, n_steps=12, batch_size=48, seed=0, device="cpu")
    obs = np.random.default_rng(0).uniform(vec.encoder.low, np.minimum(vec.encoder.high, 2.0), (500, vec.encoder.size))
    want, _ = model.predict(obs.astype(np.float32), deterministic=True)
    got = NumpyPolicy(export(model, CFG, 4)).greedy(obs.astype(np.float32))
    assert np.array_equal(to_world_actions(want), got)
