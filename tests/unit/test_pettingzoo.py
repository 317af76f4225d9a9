"""The PettingZoo adapter passes PettingZoo's own API and seed tests, and observes what an agent process
sees: its LocalView and the beacons it heard, encoded by agents.view_features (issue 56)."""

import numpy as np
import pytest

pytest.importorskip("pettingzoo", reason="the PettingZoo adapter is the optional extra 'pettingzoo'")

from pettingzoo.test import parallel_api_test, parallel_seed_test  # noqa: E402

from agents.api import UavAgent  # noqa: E402
from agents.api_controller import ApiController  # noqa: E402
from agents.view_features import DEFAULT_PEERS, ViewEncoder, observation_features  # noqa: E402
from truav.analysis.driver import run_episodes  # noqa: E402
from truav.analysis.pettingzoo_env import parallel_env  # noqa: E402
from truav.presets import preset_overrides  # noqa: E402

SENSE_M = 1500.0


@pytest.fixture
def pz_cfg(small_cfg):
    return small_cfg.replace(scenario={"n_vehicles": 40, "steps_per_episode": 12}, roads={"warmup_steps": 5})


@pytest.fixture(params=[0.0, SENSE_M], ids=["sensing-off", "sensing-on"])
def sense_m(request):
    return request.param


def test_parallel_api(pz_cfg, sense_m):
    parallel_api_test(parallel_env(pz_cfg, sense_range_m=sense_m), num_cycles=30)


def test_parallel_seed(pz_cfg, sense_m):
    parallel_seed_test(lambda: parallel_env(pz_cfg, sense_range_m=sense_m), num_cycles=30)


def test_episode_matches_the_world(pz_cfg):
    env = parallel_env(pz_cfg)
    obs, infos = env.reset(seed=3)
    assert env.agents == [f"uav_{i}" for i in range(pz_cfg.scenario.n_uavs)]
    size = len(observation_features(pz_cfg, DEFAULT_PEERS))
    assert all(o.shape == (size,) and o.dtype == np.float32 for o in obs.values())
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


def test_the_constructor_sets_the_preset_the_sensing_and_the_peers(pz_cfg):
    env = parallel_env(pz_cfg, preset="paper", sense_range_m=SENSE_M, peers=2)
    for section, keys in preset_overrides("paper").items():
        for key, value in keys.items():
            assert getattr(getattr(env.cfg, section), key) == value
    assert env.cfg.learner.sense_range_m == SENSE_M and env.cfg.scenario.n_vehicles == 40
    names = [f.name for f in env.observation_features()]
    assert names == [f.name for f in observation_features(env.cfg, 2)] and "peer2_mask" in names
    assert "peer3_mask" not in names
    assert env.observation_space("uav_0").shape == (len(names),)
    assert parallel_env(pz_cfg).cfg.learner.sense_range_m == pz_cfg.learner.sense_range_m  # None: the cfg's


class _Recorder(UavAgent):
    """An API agent in process: records every view and reward it is given, acts by a fixed rule."""

    seen: dict = {}

    def act(self, view):
        _Recorder.seen[("view", self.uav, view.step)] = view
        return _action(self.uav, view.step)

    def learn(self, view, reward, done):
        _Recorder.seen[("view", self.uav, view.step)] = view
        _Recorder.seen[("reward", self.uav, view.step)] = reward


def _action(uav: int, step: int) -> int:
    return (3 * uav + 5 * step) % 17 - 1  # every action and HOVER (-1)


@pytest.mark.parametrize("sense", [0.0, SENSE_M])
def test_the_observation_is_the_view_an_api_agent_receives_in_process(pz_cfg, sense):
    cfg = pz_cfg.replace(learner={"sense_range_m": sense})
    seed, T, U = 7, cfg.scenario.steps_per_episode, cfg.scenario.n_uavs
    _Recorder.seen = {}
    run_episodes(cfg, [seed], ApiController("recorder", _Recorder, cfg, [seed], train=False), 1)
    encode = ViewEncoder(cfg)
    env = parallel_env(cfg)
    obs, _ = env.reset(seed=seed)
    for t in range(T + 1):
        for u in range(U):
            np.testing.assert_array_equal(obs[f"uav_{u}"], encode(_Recorder.seen[("view", u, t)]))
        if t == T:
            break
        obs, rewards, _, _, _ = env.step({f"uav_{u}": _action(u, t) for u in range(U)})
        assert [rewards[f"uav_{u}"] for u in range(U)] == [_Recorder.seen[("reward", u, t + 1)] for u in range(U)]
    assert not env.agents


@pytest.mark.parametrize("sense", [0.0, SENSE_M])
def test_every_observation_of_an_episode_is_finite_and_in_the_declared_box(pz_cfg, sense):
    env = parallel_env(pz_cfg, preset="paper", sense_range_m=sense)
    space = env.observation_space("uav_0")
    names = [f.name for f in env.observation_features()]
    onehot = slice(names.index("densest_sector_1"), names.index("peer1_dx"))
    obs, _ = env.reset(seed=1)
    sensed, rng = 0.0, np.random.default_rng(0)
    while True:
        for o in obs.values():
            assert np.isfinite(o).all() and space.contains(o), o
            sensed += float(o[onehot].sum())
        if not env.agents:
            break
        obs, *_ = env.step({a: int(rng.integers(16)) for a in env.agents})
    assert (sensed > 0) == (sense > 0)  # the one-hot is all zero with sensing off, and senses when on


class _Rule(UavAgent):
    """An API agent flying the fixed rule, as an agent process runs it."""

    def act(self, view):
        return _action(self.uav, view.step)


def test_the_observation_is_the_view_an_agent_process_builds_from_its_messages(pz_cfg):
    """The swarm's path, without the bus: the world's observation messages and the tick's beacons, each UAV's
    ApiDecision (agents/api_decision.py, what the agent process runs) builds its view and reward."""
    from agents.api_decision import ApiDecision
    from truav import seeding
    from truav.analysis.sumo_traffic import make_world
    from truav.wire.world_messages import observation_messages

    cfg = pz_cfg.replace(learner={"sense_range_m": SENSE_M})
    seed, U = 5, cfg.scenario.n_uavs
    decisions = [ApiDecision(_Rule, cfg, u, seed, train=False) for u in range(U)]
    world = make_world(cfg, 1)
    world_obs, done = world.reset([seeding.world_rng(seed)]), False
    encode = ViewEncoder(cfg)
    env = parallel_env(cfg)
    env_obs, _ = env.reset(seed=seed)
    env_rewards = None
    for tick in range(cfg.scenario.steps_per_episode + 1):
        msgs = observation_messages(cfg, tick, 0, world_obs, done)
        beacons = {u: decisions[u].beacon(msgs[u]) for u in range(U)}
        for u in range(U):
            r = decisions[u].learn(msgs[u], {j: b for j, b in beacons.items() if j != u})
            np.testing.assert_array_equal(env_obs[f"uav_{u}"], encode(decisions[u].view))
            assert (r is None) == (env_rewards is None) and (r is None or r == env_rewards[f"uav_{u}"])
        if done:
            break
        actions = np.array([[decisions[u].act(msgs[u]).action for u in range(U)]])
        world_obs, _, done = world.step(actions)
        env_obs, env_rewards, *_ = env.step({f"uav_{u}": int(actions[0, u]) for u in range(U)})
    assert done and not env.agents


def test_with_the_disc_the_api_and_seed_tests_pass_and_the_disc_is_observed(pz_cfg):
    """The observation with the densest sensed disc (disc=True: learner.sense_disc on), the one ppo-disc learns."""
    parallel_api_test(parallel_env(pz_cfg, sense_range_m=SENSE_M, disc=True), num_cycles=30)
    parallel_seed_test(lambda: parallel_env(pz_cfg, sense_range_m=SENSE_M, disc=True), num_cycles=30)
    env = parallel_env(pz_cfg, sense_range_m=SENSE_M, disc=True)
    assert env.cfg.learner.sense_disc and env.metadata["name"] == "truav_disc_v1"
    names = [f.name for f in env.observation_features()]
    assert names[-3:] == ["disc_dx", "disc_dy", "disc_vehicles"]
    obs, _ = env.reset(seed=2)
    assert all(o[-1] > 0 for o in obs.values())  # 40 vehicles within 1500 m of some start: a disc is sensed
