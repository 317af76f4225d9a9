"""The memory features (agents.view_features.Memory: the UAV's previous action, its velocity, the change of its
vehicles in range): the PettingZoo environment, the vector environment and an agent instance remembering its
own last action encode the same numbers; the decision kinds of the agreement measure cover every state."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

from agents.api_controller import ApiController  # noqa: E402
from agents.ppo_agent import PpoAgent  # noqa: E402
from agents.view_features import NO_ACTION, Memory, ViewEncoder, action_velocity  # noqa: E402
from truav.actions import HOVER  # noqa: E402
from truav.analysis.driver import run_episodes  # noqa: E402
from truav.analysis.pettingzoo_env import parallel_env  # noqa: E402
from truav.analysis.ppo_vec_env import HOVER_INDEX, TruavVecEnv, to_slot_actions  # noqa: E402
from truav.config import Config  # noqa: E402

CFG = Config().replace(scenario={"n_vehicles": 60, "steps_per_episode": 12, "n_uavs": 4},
                       roads={"warmup_steps": 10}, learner={"sense_range_m": 1500.0})


def test_memory_features_follow_the_actions_and_reset_each_episode():
    vec, pz = TruavVecEnv(CFG, [7], memory=True), parallel_env(CFG, memory=True)
    assert pz.metadata["name"] == "truav_memory_v1" and parallel_env(CFG).metadata["name"] == "truav_v1"
    enc = vec.encoder
    first, hover = enc.index("last_action_0"), enc.index("last_action_16")
    assert enc.size == ViewEncoder(CFG).size + 17 + 3
    obs, (pobs, _) = vec.reset(), pz.reset(seed=7)
    rng = np.random.default_rng(3)
    a = None
    for t in range(30):  # past two episode ends
        assert np.array_equal(obs, np.stack([pobs[x] for x in pz.possible_agents])), t
        onehot = obs[:, first: hover + 1]
        if t % 12 == 0:  # an episode's first step: nothing remembered
            assert not onehot.any()
        else:
            assert np.array_equal(onehot.argmax(1), a) and (onehot.sum(1) == 1).all()
            vx, vy = action_velocity(np.where(a == HOVER_INDEX, HOVER, a))
            assert np.allclose(obs[:, enc.index("last_vx")], vx) and np.allclose(obs[:, enc.index("last_vy")], vy)
        a = rng.integers(0, HOVER_INDEX + 1, 4)
        obs, _, done, infos = vec.step(a)
        pobs, *_ = pz.step({f"uav_{k}": int(a[k]) for k in range(4) if a[k] != HOVER_INDEX})
        if done[0]:
            assert np.array_equal(np.stack([i["terminal_observation"] for i in infos]),
                                  np.stack([pobs[x] for x in pz.possible_agents]))
            pobs, _ = pz.reset()


def test_action_velocity():
    vx, vy = action_velocity(np.array([0, 2, 8, 12, HOVER, NO_ACTION]))
    assert np.allclose(vx, [0.5, 0.0, 1.0, -1.0, 0.0, 0.0]) and np.allclose(vy, [0.0, 0.5, 0.0, 0.0, 0.0, 0.0])


def test_an_agent_remembering_its_own_actions_flies_what_the_vector_flies(tmp_path, monkeypatch):
    torch = pytest.importorskip("torch")
    from stable_baselines3 import PPO

    from agents.ppo_policy import NumpyPolicy
    from truav.analysis.ppo_train import export
    torch.manual_seed(0)
    vec = TruavVecEnv(CFG, [5], memory=True)
    model = PPO("MlpPolicy", vec, n_steps=12, batch_size=48, seed=0, device="cpu")
    arrays = export(model, CFG, 4, memory=True)
    path = tmp_path / "w.npz"
    np.savez(path, **arrays)
    policy = NumpyPolicy(arrays)
    assert policy.memory
    want, obs = [], vec.reset()
    for _ in range(2 * CFG.scenario.steps_per_episode):
        a = policy.greedy(obs)
        want.append(a)
        obs, _, done, _ = vec.step(to_slot_actions(a))
    seen = []

    class Agent(PpoAgent):
        weights = path

        def act(self, view):
            action = super().act(view)
            seen.append((view.step, self.uav, action))
            return action

    run_episodes(CFG, [5], ApiController("ppo", Agent, CFG, [5], train=False), 2)
    got = np.full((2 * CFG.scenario.steps_per_episode, 4), 99)
    episode_steps = [s for s, _, _ in seen]
    row, prev = -1, None
    for (step, uav, action) in seen:
        if step != prev:
            row += 1 if step < CFG.scenario.steps_per_episode else 0
            prev = step
        if step < CFG.scenario.steps_per_episode:
            got[row, uav] = action
    assert len(set(episode_steps)) > 1
    assert np.array_equal(got, np.stack(want))
    assert len(np.unique(np.stack(want))) > 1


def test_decision_kinds_cover_every_state():
    from truav.analysis.ppo_train import KINDS, agreement, export  # noqa: F401
    torch = pytest.importorskip("torch")
    from stable_baselines3 import PPO
    torch.manual_seed(0)
    vec = TruavVecEnv(CFG, [5], memory=True)
    model = PPO("MlpPolicy", vec, n_steps=12, batch_size=48, seed=0, device="cpu")
    got = agreement(export(model, CFG, 4, memory=True), CFG, [5, 6], 1)
    assert 0.0 <= got["all"] <= 1.0
    assert sum(got[f"{k}_share"] for k in KINDS) == pytest.approx(1.0)
    assert Memory().action == NO_ACTION
