"""The PettingZoo adapter passes PettingZoo's own API and seed tests."""

import numpy as np
import pytest

pytest.importorskip("pettingzoo")

from pettingzoo.test import parallel_api_test, parallel_seed_test  # noqa: E402

from truav.analysis.pettingzoo_env import OBS_DIM, parallel_env  # noqa: E402


@pytest.fixture
def pz_cfg(small_cfg):
    return small_cfg.replace(scenario={"n_vehicles": 40, "steps_per_episode": 12}, roads={"warmup_steps": 5})


def test_parallel_api(pz_cfg):
    parallel_api_test(parallel_env(pz_cfg), num_cycles=30)


def test_parallel_seed(pz_cfg):
    parallel_seed_test(lambda: parallel_env(pz_cfg), num_cycles=30)


def test_episode_matches_the_world(pz_cfg):
    env = parallel_env(pz_cfg)
    obs, infos = env.reset(seed=3)
    assert env.agents == [f"uav_{i}" for i in range(pz_cfg.scenario.n_uavs)]
    assert all(o.shape == (OBS_DIM,) and o.dtype == np.float32 for o in obs.values())
    steps = 0
    while env.agents:
        obs, rew, term, trunc, infos = env.step({a: 8 for a in env.agents[1:]})  # uav_0 missing: hovers
        steps += 1
    assert steps == pz_cfg.scenario.steps_per_episode and all(trunc.values()) and not any(term.values())
    summary = infos["uav_0"]["episode"]
    assert summary["generated"] == summary["delivered"] + summary["dropped"] + summary["queued_end"]
    # reset without a seed: the next episode of the same city
    obs2, _ = env.reset()
    assert env.agents and set(obs2) == set(env.possible_agents)
