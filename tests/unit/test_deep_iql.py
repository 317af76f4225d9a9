"""The deep independent learner (agents.deep_iql) keeps the agent API's promises: its batched form computes
what its per-UAV form computes, bit for bit; a seed fixes its run; its state_dict resumes it exactly (at an
episode's end and in the middle of one, into either form); it trains through `truav train --agent` and
passes the loader's checks; and its numpy network's gradient is the derivative of its output."""

from __future__ import annotations

import tomllib
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from agents import deep_iql
from agents.api_controller import ApiController
from agents.deep_iql_net import QNets
from truav import seeding
from truav.analysis import agent_loader
from truav.cli import main as cli
from truav.analysis.agent_loader import trial_view
from truav.config import Config
from truav.analysis.driver import run_episodes
from tests.support.small_iql import SMALL, Small

REPO = Path(__file__).resolve().parents[2]
CFG = Config().replace(scenario={"n_vehicles": 60, "steps_per_episode": 10}, roads={"warmup_steps": 10},
                       learner={"geofence": True, "episodes": 4})
SEEDS = [0, 1]


class SmallPerUav(Small):
    batched = None  # the trainer then loops over one instance per seed and UAV


def trained(cls, episodes=4, seeds=SEEDS, state=None):
    ctl = ApiController("iql", cls, CFG, seeds, state=state)
    metrics = run_episodes(CFG, seeds, ctl, episodes)
    return ctl, metrics


def assert_same_state(a: dict, b: dict) -> None:
    assert sorted(a) == sorted(b)
    for k in a:
        assert a[k].shape == b[k].shape and np.array_equal(a[k], b[k]), k


def test_the_batched_form_computes_what_the_per_uav_form_computes():
    batched, m_batched = trained(Small)
    per_uav, m_per_uav = trained(SmallPerUav)
    assert batched.batched is not None and per_uav.batched is None
    state = batched.state_arrays()
    assert state["updates"][0, 0] > 2 * SMALL.target_every and state["filled"][0, 0] == SMALL.replay_capacity
    assert_same_state(state, per_uav.state_arrays())
    for k in m_batched:
        assert np.array_equal(m_batched[k], m_per_uav[k], equal_nan=True), k


def test_a_seed_fixes_the_run_and_networks_are_independent():
    a, b = trained(Small)[0].state_arrays(), trained(Small)[0].state_arrays()
    assert_same_state(a, b)
    other = trained(Small, seeds=[7, 1])[0].state_arrays()
    assert not np.array_equal(other["params"][0], a["params"][0])
    # seed 1 does not share a network with seed 7 or 0 in its batch: its networks end as alone
    assert np.array_equal(other["params"][1], a["params"][1])
    assert not np.array_equal(a["params"][0, 0], a["params"][0, 1])  # no parameter sharing across UAVs


@pytest.mark.parametrize("into", [Small, SmallPerUav])
def test_state_dict_resumes_at_an_episode_end_exactly(into):
    ctl, _ = trained(Small, episodes=2)
    resumed = ApiController("iql", into, CFG, SEEDS, state=ctl.state_arrays())
    run_episodes(CFG, SEEDS, ctl, 2)  # both go on with the same two episodes
    run_episodes(CFG, SEEDS, resumed, 2)
    assert_same_state(ctl.state_arrays(), resumed.state_arrays())


def test_state_dict_resumes_mid_episode_exactly():
    cfg, steps = CFG, CFG.scenario.steps_per_episode
    draws = np.random.default_rng(3)
    base = trial_view(cfg)
    views = [replace(base, step=t, pos=tuple(draws.uniform(0, cfg.scenario.area_m, 2)),
                     vehicles_in_range=int(draws.integers(0, 20)), covered=int(draws.integers(0, 20)))
             for t in range(steps + 1)]
    rewards = draws.normal(size=steps + 1)

    def fly(agent, episodes, start=0):
        for e in range(episodes):
            if not (e == 0 and start):  # a restarted agent goes on inside its episode: no new begin
                agent.begin_episode(e, True)
            for t in range(start if e == 0 else 0, steps):
                agent.act(views[t])
                agent.learn(views[t + 1], float(rewards[t + 1]), t + 1 == steps)

    whole = Small(cfg, 2, seeding.agent_rng(5, 2))
    fly(whole, 3)
    half = Small(cfg, 2, seeding.agent_rng(5, 2))
    half.begin_episode(0, True)
    for t in range(4):  # stop after step 4's learn: mid-episode, exploration draws and last action pending
        half.act(views[t])
        half.learn(views[t + 1], float(rewards[t + 1]), False)
    restarted = Small(cfg, 2, np.random.default_rng(99))  # another generator: its state comes from the dict
    restarted.load_state_dict(half.state_dict())
    fly(restarted, 3, start=4)
    assert_same_state(whole.state_dict(), restarted.state_dict())


def test_a_state_of_other_hyper_parameters_is_refused_by_name():
    small = Small(CFG, 0, np.random.default_rng(0)).state_dict()
    with pytest.raises(ValueError, match=r"'replay_x' is shaped \(24, 45\)"):
        deep_iql.DeepIql(CFG, 0, np.random.default_rng(0)).load_state_dict(small)


def test_the_networks_gradient_is_the_derivative_of_its_output():
    nets = QNets((4, 6, 5, 3), [np.random.default_rng(i) for i in range(2)])
    params = nets.params + np.random.default_rng(9).normal(0.0, 0.3, nets.params.shape)
    x, c = np.random.default_rng(1).normal(size=(2, 3, 4)), np.random.default_rng(2).normal(size=(2, 3, 3))
    _, inputs = nets.forward(params, x)
    grad = nets.backward(params, inputs, c)
    numeric, eps = np.zeros_like(grad), 1e-6
    for idx in np.ndindex(*params.shape):
        up, down = params.copy(), params.copy()
        up[idx] += eps
        down[idx] -= eps
        numeric[idx] = ((nets.forward(up, x)[0] - nets.forward(down, x)[0]) * c).sum() / (2 * eps)
    assert np.abs(numeric - grad).max() < 1e-6 * max(1.0, np.abs(grad).max())


def test_the_geofence_keeps_every_action_inside_the_area():
    edge = np.array([[0.0, 0.0], [CFG.scenario.area_m, 10.0], [2500.0, 2500.0]])
    allowed = deep_iql.allowed_actions(CFG, edge)
    assert allowed[2].all() and allowed[0].any() and not allowed[0].all()
    assert not allowed[0, 4] and allowed[0, 0] and not allowed[1, 8]  # west at the origin, east at the east wall


def test_it_is_registered_and_passes_the_loaders_checks():
    entry = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["entry-points"]["truav.agents"]["iql"]
    assert entry == "agents.deep_iql:DeepIql"
    cls = agent_loader.load(entry, Config().replace(learner={"geofence": True}))
    assert cls is deep_iql.DeepIql and cls.batched is deep_iql.DeepIqlBatched
    assert agent_loader.checkpoint_problem(cls, CFG) is None  # its trainings checkpoint and resume


def test_truav_train_with_the_deep_learner_writes_its_state(tmp_path):
    out = tmp_path / "run"
    args = ["train", "--agent", "tests.support.small_iql:Small", "--seeds", "2", "--episodes", "3", "--set",
            "scenario.n_vehicles=60", "--set", "scenario.steps_per_episode=10", "--set", "roads.warmup_steps=10",
            "--workers", "1", "--quiet", "--out", str(out)]
    assert cli.main(args) == 0
    with np.load(out / "agent.npz") as saved:
        params = saved["state.params"]
    assert params.shape[:2] == (2, CFG.scenario.n_uavs) and np.isfinite(params).all()
    assert not (out / "resume").exists()
