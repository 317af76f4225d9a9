"""The baselines: the patrol follows its pre-planned route, the centralized
critic sees the joint state, the control-plane counters and effects add up."""

import numpy as np
import pytest

from agents.patrol import PatrolController, assign_slots, orbit_sites, orbit_slots, plan_trajectories
from truav import seeding
from truav.analysis.driver import run_episodes
from truav.config import Config
from world.env import World
from world.uavs import HOVER


@pytest.fixture
def fast_cfg(small_cfg) -> Config:
    return small_cfg.replace(scenario={"uav_speed_mps": 25.0, "steps_per_episode": 60, "n_vehicles": 30})


def _fly_patrol(cfg, seeds, episodes=2):
    world = World(cfg, len(seeds))
    obs = world.reset([seeding.world_rng(s) for s in seeds])
    ctrl = PatrolController(cfg, seeds)
    tracks = []
    for ep in range(episodes):
        if ep:
            obs = world.start_episode()
        ctrl.begin_episode(ep, obs)
        pos = [obs.pos.copy()]
        for t in range(cfg.scenario.steps_per_episode):
            obs, _, _ = world.step(ctrl.act(t))
            ctrl.observe(obs, False)
            pos.append(obs.pos.copy())
        tracks.append((np.stack(pos), ctrl.plan.copy(), ctrl.meet.copy(), ctrl.slot.copy()))
    return ctrl, tracks


def test_patrol_plan_lies_on_its_route(fast_cfg):
    """Planned positions: a straight transit, then exactly on the orbit circle."""
    cfg = fast_cfg
    centre, phase = orbit_slots(cfg)
    start = np.array([[100.0, 4900.0], [2500.0, 2600.0], [4000.0, 1000.0], [0.0, 0.0], [5000.0, 2500.0]])
    r, v = cfg.patrol.radius_m, 20.0
    plan, meet = plan_trajectories(start, centre, phase, r, v, 1.0, 400)
    for u in range(len(start)):
        on = plan[meet[u]:, u]
        np.testing.assert_allclose(np.linalg.norm(on - centre[u], axis=1), r, rtol=1e-9)
        steps = np.linalg.norm(np.diff(plan[:, u], axis=0), axis=1)
        assert steps.max() <= v * (1 + 1e-9)  # never faster than cruise speed
        line = plan[: meet[u] + 1, u]
        direction = line[-1] - line[0]
        cross = direction[0] * (line[:, 1] - line[0, 1]) - direction[1] * (line[:, 0] - line[0, 0])
        np.testing.assert_allclose(cross, 0.0, atol=1e-6 * max(1.0, np.linalg.norm(direction)) ** 2)


def test_patrol_follows_its_route(fast_cfg):
    """Flown with the 16 discrete actions, UAVs stay within the action
    lattice's reach of the plan and, after the rendezvous, of the orbit."""
    cfg = fast_cfg
    v, dt, r = cfg.scenario.uav_speed_mps, cfg.scenario.step_s, cfg.patrol.radius_m
    ctrl, tracks = _fly_patrol(cfg, [0, 3])
    reached = 0
    for pos, plan, meet, slot in tracks:
        err = np.linalg.norm(pos - plan, axis=-1)  # (T+1, B, U)
        assert err.max() <= 0.75 * v * dt
        for b in range(pos.shape[1]):
            for u in range(pos.shape[2]):
                after = pos[meet[b, u]:, b, u]
                dev = np.abs(np.linalg.norm(after - ctrl.centre[slot[b, u]], axis=1) - r)
                assert dev.size == 0 or dev.max() <= 0.75 * v * dt
                reached += dev.size > 0
    assert reached > 0
    assert set(np.unique(tracks[0][3][0])) == set(range(cfg.scenario.n_uavs))  # a permutation of slots


def test_patrol_slots_and_assignment():
    cfg = Config().replace(scenario={"n_uavs": 12})
    centre, phase = orbit_slots(cfg)
    sites = orbit_sites(cfg)
    assert len(sites) == 5 and centre.shape == (12, 2)
    for k in range(len(sites)):  # UAVs sharing a site are evenly phased
        ph = np.sort(phase[np.all(centre == sites[k], axis=1)])
        np.testing.assert_allclose(np.diff(np.r_[ph, 2 * np.pi]), 2 * np.pi / len(ph))
    start = centre + 10.0
    assert list(assign_slots(start, centre, 0.0, "fixed")) == list(range(12))
    near = assign_slots(start[::-1], centre, 0.0, "nearest")
    np.testing.assert_array_equal(np.sort(near), np.arange(12))
    np.testing.assert_allclose(np.linalg.norm(start[::-1] - centre[near], axis=1), np.hypot(10, 10))


def test_patrol_runs_in_the_driver_and_is_deterministic(small_cfg):
    a = run_episodes(small_cfg, [1, 2], PatrolController(small_cfg, [1, 2]), 2)
    b = run_episodes(small_cfg, [2], PatrolController(small_cfg, [2]), 2)
    np.testing.assert_array_equal(a["coverage_pct"][:, 1], b["coverage_pct"][:, 0])
    assert np.all(a["plan_error_m"] >= 0)


class _HoverWithControl:
    """Hovers; spends a fixed control airtime and delay (tests the driver hook)."""

    def __init__(self, cfg, batch, airtime):
        self.shape, self.airtime = (batch, cfg.scenario.n_uavs), airtime

    def begin_episode(self, episode, obs):
        pass

    def act(self, t):
        return np.full(self.shape, HOVER)

    def control(self, t):
        return np.full(self.shape, self.airtime), 0.2

    def observe(self, obs, done):
        pass

    def episode_stats(self):
        return {}


def test_driver_charges_control_airtime(small_cfg):
    cfg = small_cfg.replace(traffic={"packet_rate_hz": 0.0})
    base = run_episodes(cfg, [0], _HoverWithControl(cfg, 1, 0.0), 1)
    busy = run_episodes(cfg, [0], _HoverWithControl(cfg, 1, 0.1), 1)
    extra = busy["energy_j"] - base["energy_j"]
    np.testing.assert_allclose(extra, 0.1 * cfg.channel.uav_tx_w * cfg.scenario.steps_per_episode)


# -- centralized baseline -------------------------------------------------------
def test_control_plane_model_delay_and_airtime():
    from agents.central import ControlPlaneModel
    from world.network import rsu_positions
    cfg = Config()
    plane = ControlPlaneModel(cfg)
    c = cfg.central
    fixed = 2 * c.backhaul_latency_s + c.compute_latency_s
    near = rsu_positions(cfg)[[0, 1, 2, 3, 0]][None] + np.array([1.0, 0.0])
    far = np.array([[[2500.0, 2500.0], [2500.0, 0.0], [0.0, 2500.0], [5000.0, 2500.0], [2500.0, 5000.0]]])
    air_near, delay_near = plane.round(near)
    air_far, delay_far = plane.round(far)
    assert np.all(delay_near >= fixed) and np.all(delay_far > delay_near)
    assert air_far.sum() > air_near.sum() > 0 and np.all(air_near > 0)
    assert plane.messages(5) == (5, 5 * c.upload_bytes, 5, 5 * c.download_bytes)


def test_central_critic_sees_the_joint_state(small_cfg):
    pytest.importorskip("torch")
    from agents.central import STATE_DIM, CentralController
    cfg = small_cfg.replace(scenario={"n_uavs": 4}, central={"hidden": 8, "batch_size": 4, "learning_starts": 5,
                                                             "buffer_size": 100})
    ctrl = CentralController(cfg, [0, 1])
    assert ctrl.critic_input_dim == cfg.scenario.n_uavs * STATE_DIM
    w1 = ctrl.sac.critic[0]
    assert tuple(w1.shape) == (2 * 2, cfg.scenario.n_uavs * STATE_DIM, 8)  # twin critics x seeds
    assert tuple(ctrl.sac.critic[4].shape)[-1] == cfg.scenario.n_uavs * 16  # Q_i(s, a_i) for every UAV
    world = World(cfg, 2)
    obs = world.reset([seeding.world_rng(s) for s in (0, 1)])
    joint = ctrl.joint_state(obs)
    assert joint.shape == (2, cfg.scenario.n_uavs * STATE_DIM)
    # one UAV's state changes the critic's output for every UAV: the critic is global
    import torch
    s = torch.as_tensor(joint[:, None, :], dtype=torch.float32)
    q0 = ctrl.sac._q(ctrl.sac.critic, s)
    s2 = s.clone()
    s2[:, :, :STATE_DIM] += 1.0  # only UAV 0's part
    q1 = ctrl.sac._q(ctrl.sac.critic, s2)
    assert torch.all((q1 - q0)[..., 1:, :].abs().sum(-1) > 0)


def test_control_plane_counters_add_up(small_cfg):
    pytest.importorskip("torch")
    from agents.central import CentralController
    cfg = small_cfg.replace(central={"hidden": 8, "batch_size": 4, "learning_starts": 10, "buffer_size": 200})
    U, T, c = cfg.scenario.n_uavs, cfg.scenario.steps_per_episode, cfg.central
    m = run_episodes(cfg, [0, 1], CentralController(cfg, [0, 1]), 2)
    np.testing.assert_array_equal(m["ctrl_up_msgs"], U * T)
    np.testing.assert_array_equal(m["ctrl_down_msgs"], U * T)
    np.testing.assert_array_equal(m["ctrl_up_bytes"], m["ctrl_up_msgs"] * c.upload_bytes)
    np.testing.assert_array_equal(m["ctrl_down_bytes"], m["ctrl_down_msgs"] * c.download_bytes)
    np.testing.assert_allclose(m["ctrl_energy_j"], m["ctrl_airtime_s"] * cfg.channel.uav_tx_w)
    assert np.all(m["ctrl_airtime_s"] > 0)
    assert np.all(m["ctrl_delay_ms"] >= 1e3 * (2 * c.backhaul_latency_s + c.compute_latency_s))
    # control energy is part of the world's energy: above hover + propulsion at least
    assert np.all(m["energy_above_hover_j"] >= m["ctrl_energy_j"])
    # a round every 3 steps: a third of the messages
    cfg3 = cfg.replace(central={"update_period_steps": 3})
    m3 = run_episodes(cfg3, [0], CentralController(cfg3, [0]), 1)
    np.testing.assert_array_equal(m3["ctrl_up_msgs"], U * -(-T // 3))


def test_central_is_deterministic_and_learns(small_cfg):
    pytest.importorskip("torch")
    from agents.central import CentralController
    cfg = small_cfg.replace(central={"hidden": 8, "batch_size": 8, "learning_starts": 10, "buffer_size": 200,
                                     "update_every": 1})
    runs = []
    for seeds in ([4, 5], [4, 5], [5]):
        ctrl = CentralController(cfg, seeds)
        before = ctrl.sac.state_dict()
        m = run_episodes(cfg, seeds, ctrl, 2)
        runs.append((m, ctrl.sac.state_dict(), before, ctrl.sac.updates))
    (a, pa, before, n), (b, pb, _, _), (alone, palone, _, _) = runs
    for k in a:
        np.testing.assert_array_equal(a[k], b[k])
    np.testing.assert_array_equal(pa["actor0"], pb["actor0"])
    assert n > 0 and not np.array_equal(pa["actor0"], before["actor0"])  # it trained
    assert not np.array_equal(pa["critic0"], before["critic0"])
    # seed 5 alone gives what it gives in the batch [4, 5]
    np.testing.assert_allclose(alone["coverage_pct"][:, 0], a["coverage_pct"][:, 1])
    np.testing.assert_allclose(palone["actor0"][0], pa["actor0"][1], rtol=1e-5, atol=1e-6)


def test_control_plane_on_a_fixed_policy(small_cfg):
    """The patrol under the centralized control plane: same counters, and the
    control airtime is charged on top of what the plain patrol spends."""
    from truav.analysis.trainer import make_controller
    cfg = small_cfg.replace(traffic={"packet_rate_hz": 0.0})  # no packets: energy = flight + control
    U, T = cfg.scenario.n_uavs, cfg.scenario.steps_per_episode
    m = run_episodes(cfg, [0, 1], make_controller("patrol_ctrl", cfg, [0, 1], True, None), 1)
    np.testing.assert_array_equal(m["ctrl_up_msgs"], U * T)
    np.testing.assert_array_equal(m["ctrl_down_bytes"], U * T * cfg.central.download_bytes)
    assert np.all(m["ctrl_airtime_s"] > 0) and "plan_error_m" in m
    assert np.all(m["energy_above_hover_j"] > m["ctrl_energy_j"])  # flight + control
    plain = run_episodes(cfg, [0, 1], PatrolController(cfg, [0, 1]), 1)
    assert "ctrl_up_msgs" not in plain


def test_sac_learns_a_contextual_bandit():
    """The learner itself is sound: each UAV is paid for the one action the state names."""
    pytest.importorskip("torch")
    import dataclasses

    from agents.sac import BatchedSAC
    cfg = dataclasses.replace(Config().central, batch_size=32, hidden=32, actor_lr=3e-3, critic_lr=3e-3)
    n_uavs, n_actions, seeds = 2, 4, 2
    sac = BatchedSAC(cfg, 0.0, n_actions, n_uavs, n_actions, [np.random.default_rng(s) for s in range(seeds)])
    env = np.random.default_rng(9)

    def contexts():
        good = env.integers(0, n_actions, seeds)  # the paid action, the same for both UAVs of a seed
        return np.eye(n_actions)[good], good

    for step in range(800):
        s, good = contexts()
        a = sac.act(s, greedy=False)
        sac.store(s, a, (a == good[:, None]).astype(float), s)
        if step >= 50:
            sac.update()
    hits = []
    for _ in range(100):
        s, good = contexts()
        hits.append((sac.act(s, greedy=True) == good[:, None]).mean())
    assert np.mean(hits) > 0.95  # a uniform policy scores 0.25


def test_fenced_actions_keep_every_move_inside_the_area():
    from agents.qlearning import Fence, allowed_one, fenced_actions
    from world.uavs import ACTION_UNIT_VELOCITY
    fence = Fence(1000.0, 15.0, ACTION_UNIT_VELOCITY)
    rng = np.random.default_rng(0)
    pos = rng.choice([0.0, 5.0, 500.0, 995.0, 1000.0], size=(3, 40, 2))
    actions = rng.integers(0, 16, size=(3, 40))
    got = fenced_actions(actions, pos, fence)
    for b, u in np.ndindex(actions.shape):
        assert allowed_one(got[b, u], pos[b, u, 0], pos[b, u, 1], fence)
        if allowed_one(actions[b, u], pos[b, u, 0], pos[b, u, 1], fence):
            assert got[b, u] == actions[b, u]  # an allowed command is flown as commanded


def test_central_geofence_flies_only_allowed_moves_and_stores_the_command(small_cfg):
    pytest.importorskip("torch")
    from agents.central_fence import FencedCentralController
    from truav.analysis.trainer import make_controller
    cfg = small_cfg.replace(scenario={"uav_start": "persist"},
                            central={"hidden": 8, "batch_size": 8, "learning_starts": 10, "buffer_size": 200,
                                     "geofence": True})
    ctrl = make_controller("central", cfg, [1, 2], True, None)
    assert isinstance(ctrl, FencedCentralController)
    run_episodes(cfg, [1, 2], ctrl, 3)
    assert ctrl.sac.updates > 0
    # Every UAV in the corner (0, 0): only moves north-east-ward may be flown.
    from agents.qlearning import allowed_one
    ctrl.pos = np.zeros_like(ctrl.pos)
    flown = ctrl.act(0)
    commanded = ctrl.action
    assert all(allowed_one(a, 0.0, 0.0, ctrl.fence) for a in flown.ravel())
    assert (flown != commanded).any()  # some commands were refused, and the replay keeps what was commanded
    allowed = [allowed_one(a, 0.0, 0.0, ctrl.fence) for a in commanded.ravel()]
    assert np.array_equal(flown.ravel()[allowed], commanded.ravel()[allowed])


def test_central_evaluation_takes_the_mode_unless_asked_to_sample(small_cfg):
    """A trained SAC evaluates on its actor's mode by default; central.evaluate_sampled
    draws from pi instead, reproducibly (each seed's generator)."""
    pytest.importorskip("torch")
    from agents.central import CentralController
    cfg = small_cfg.replace(central={"hidden": 8, "batch_size": 4, "learning_starts": 5, "buffer_size": 100})
    params = CentralController(cfg, [0]).sac.state_dict()

    def actions(c):
        ctrl = CentralController(c, [0, 1], train=False, params=params)
        world = World(c, 2)
        ctrl.begin_episode(0, world.reset([seeding.world_rng(s) for s in (0, 1)]))
        return np.stack([ctrl.act(t) for t in range(20)])  # the same state 20 times: no observe()

    mode = actions(cfg)
    assert (mode == mode[0]).all()  # the mode of one state is one action
    sampled = actions(cfg.replace(central={"evaluate_sampled": True}))
    assert not (sampled == sampled[0]).all()  # an untrained actor's pi is near uniform
    np.testing.assert_array_equal(sampled, actions(cfg.replace(central={"evaluate_sampled": True})))
