"""The batched world: accounting, energy, determinism and batch equivalence."""

import numpy as np
import pytest

from truav import seeding
from truav.config import Config
from world.env import World
from world.network import relay_params, routes, uplink_rate
from world.channel import a2g_rate
from world.uavs import HOVER


def run(cfg, seeds, steps, actions_rng_seed=0):
    world = World(cfg, len(seeds))
    world.reset([seeding.world_rng(s) for s in seeds])
    rng = np.random.default_rng(actions_rng_seed)
    out = []
    for _ in range(steps):
        a = rng.integers(-1, 16, (len(seeds), cfg.scenario.n_uavs))
        obs, m, done = world.step(a)
        out.append((obs, m))
        if done:
            world.start_episode()
    return world, out


def test_packet_accounting_closes_every_episode(small_cfg):
    world = World(small_cfg, 3)
    world.reset([seeding.world_rng(s) for s in (0, 1, 2)])
    rng = np.random.default_rng(0)
    for _ in range(3):
        done = False
        while not done:
            _, _, done = world.step(rng.integers(0, 16, (3, small_cfg.scenario.n_uavs)))
        s = world.episode_summary()
        assert np.all(s["generated"] > 0)
        np.testing.assert_array_equal(s["generated"], s["delivered"] + s["dropped"] + s["queued_end"])
        assert np.all((s["pdr"] >= 0) & (s["pdr"] <= 1))
        world.start_episode()


def test_hovering_costs_exactly_hover_power(small_cfg):
    cfg = small_cfg.replace(traffic={"packet_rate_hz": 0.0})
    world = World(cfg, 1)
    world.reset([seeding.world_rng(0)])
    _, m, _ = world.step(np.full((1, cfg.scenario.n_uavs), HOVER))
    np.testing.assert_allclose(m.energy_j, cfg.energy.hover_w * cfg.scenario.step_s)
    _, m, _ = world.step(np.full((1, cfg.scenario.n_uavs), 8))  # full speed, no packets
    expected = cfg.energy.hover_w + (cfg.energy.move_w - cfg.energy.hover_w) * cfg.scenario.uav_speed_mps / 25.0
    moved = m.energy_j[0] > cfg.energy.hover_w + 1e-9
    np.testing.assert_allclose(m.energy_j[0][moved], expected)


def test_same_seed_same_result(small_cfg):
    _, a = run(small_cfg, [5], 30)
    _, b = run(small_cfg, [5], 30)
    for (oa, ma), (ob, mb) in zip(a, b):
        np.testing.assert_array_equal(oa.pos, ob.pos)
        np.testing.assert_array_equal(ma.delivered, mb.delivered)
        np.testing.assert_array_equal(ma.energy_j, mb.energy_j)


def test_batch_gives_what_each_seed_gives_alone(small_cfg):
    seeds = [3, 11, 42]
    w_all, batch = run(small_cfg, seeds, 45)
    for b, seed in enumerate(seeds):
        # same per-env action stream: replay the batch's actions for this env alone
        world = World(small_cfg, 1)
        world.reset([seeding.world_rng(seed)])
        rng = np.random.default_rng(0)
        for obs_b, m_b in batch:
            a = rng.integers(-1, 16, (len(seeds), small_cfg.scenario.n_uavs))[b:b + 1]
            obs, m, done = world.step(a)
            np.testing.assert_array_equal(obs.pos[0], obs_b.pos[b])
            np.testing.assert_array_equal(obs.relayed[0], obs_b.relayed[b])
            assert m.delivered[0] == m_b.delivered[b] and m.covered[0] == m_b.covered[b]
            np.testing.assert_array_equal(m.energy_j[0], m_b.energy_j[b])
            if done:
                world.start_episode()


def test_bad_actions_are_rejected(small_cfg):
    world = World(small_cfg, 1)
    world.reset([seeding.world_rng(0)])
    with pytest.raises(ValueError, match="actions"):
        world.step(np.full((1, small_cfg.scenario.n_uavs), 16))
    with pytest.raises(ValueError, match="shaped"):
        world.step(np.zeros((2, small_cfg.scenario.n_uavs), int))


def test_uplink_table_matches_formula():
    cfg = Config()
    ch, p = relay_params(cfg)
    for h in (0.0, 0.25, 123.4, 499.9, 500.0):
        assert uplink_rate(p, h) == pytest.approx(a2g_rate(h, 100.0, 0.1, ch), rel=1e-4)


def test_routes_relay_through_a_uav_near_an_rsu():
    cfg = Config()
    ch, p = relay_params(cfg)
    rsu = p.rsu[0]
    # UAV 0 hovers over an RSU, UAV 1 is 2 km away from every RSU, UAV 2 far on its own.
    pos = np.array([rsu, rsu + [1414.0, 1414.0], [2500.0, 2500.0]])
    best, next_hop, hop = routes(pos, p, ch)
    assert next_hop[0] == -1  # straight down to the RSU
    assert next_hop[1] in (0, 2) or next_hop[1] == -1
    assert best[0] < best[1]
    assert np.all(hop <= best + 1e-12)


def test_coverage_counts_vehicles_within_range(small_cfg):
    world = World(small_cfg, 1)
    world.reset([seeding.world_rng(1)])
    world.uav_pos[:] = world.vehicle_xy()[0, :small_cfg.scenario.n_uavs]  # each UAV over a vehicle
    world._run_relay(world._no_arrivals, serve_packets=False)
    xy = world.vehicle_xy()[0]
    d = np.linalg.norm(xy[:, None, :] - world.uav_pos[0][None], axis=-1)
    assert world._out_env[0, 0] == np.sum(d.min(axis=1) <= small_cfg.scenario.comm_range_m)


def test_control_plane_hooks_cost_airtime_energy_and_delay(small_cfg):
    U = small_cfg.scenario.n_uavs

    def one(cfg, control, delay):
        world = World(cfg, 1)
        world.reset([seeding.world_rng(4)])
        world.uav_pos[:] = world.vehicle_xy()[0, :U]  # every UAV serves someone
        start = world.uav_pos.copy()
        _, m, _ = world.step(np.full((1, U), 8), control_airtime_s=control, action_delay_s=delay)
        return m, world.uav_pos - start

    loaded = small_cfg.replace(traffic={"packet_rate_hz": 5.0})
    base, moved = one(loaded, None, 0.0)
    busy, _ = one(loaded, np.full((1, U), 0.9), 0.0)
    assert busy.delivered[0] < base.delivered[0]  # less radio time left for data
    idle = small_cfg.replace(traffic={"packet_rate_hz": 0.0})
    quiet, _ = one(idle, None, 0.0)
    talk, _ = one(idle, np.full((1, U), 0.25), 0.0)
    np.testing.assert_allclose(talk.energy_j - quiet.energy_j, idle.channel.uav_tx_w * 0.25)
    _, late = one(loaded, None, 0.5)  # the previous action was "stand still": half the step lost
    np.testing.assert_allclose(np.linalg.norm(late, axis=-1), 0.5 * np.linalg.norm(moved, axis=-1), rtol=1e-9)


@pytest.mark.parametrize("lam", [0.0, 0.05, 0.2, 3.0, 9.99, 12.0])
def test_compiled_draws_consume_the_generator_as_numpy_does(lam):
    from world.draws import poisson_into, uniform_into
    ours, theirs = np.random.default_rng(7), np.random.default_rng(7)
    arrivals, turns = np.empty((30, 3, 40), np.int64), np.empty((30, 3, 40, 2))
    for b in range(3):  # strided views, as start_episode fills them
        poisson_into(ours, lam, arrivals[:, b])
        uniform_into(ours, turns[:, b])
        assert np.array_equal(arrivals[:, b], theirs.poisson(lam, (30, 40)))
        assert np.array_equal(turns[:, b], theirs.random((30, 40, 2)))
    assert ours.random() == theirs.random()  # the streams end in the same place


@pytest.mark.parametrize("lam", [0.0, 0.2, 3.0, 9.99])
def test_kernel_pcg64_draws_are_numpys_stream(lam):
    import math

    from world.draws import pcg64_episode_draws, pcg64_state, set_pcg64_state
    for seed in range(4):
        ours, theirs = np.random.default_rng(seed), np.random.default_rng(seed)
        for rng in (ours, theirs):
            rng.integers(0, 16, 3)  # a buffered 32-bit half, which doubles leave alone
        words = pcg64_state(ours)
        arrivals, turns, moves = np.empty((30, 3, 40), np.int64), np.empty((30, 3, 40, 2)), np.empty((4, 2))
        pcg64_episode_draws(words, math.exp(-lam), arrivals[:, 1], turns[:, 1], moves)  # strided, as the kernel
        set_pcg64_state(ours, words)
        assert np.array_equal(arrivals[:, 1], theirs.poisson(lam, (30, 40)))
        assert np.array_equal(turns[:, 1], theirs.random((30, 40, 2)))
        assert np.array_equal(moves, theirs.random((4, 2)))
        assert ours.bit_generator.state == theirs.bit_generator.state
        assert np.array_equal(ours.integers(0, 16, 9), theirs.integers(0, 16, 9))
    assert pcg64_state(np.random.Generator(np.random.MT19937(0))) is None


def test_routes_evaluating_the_nearest_rsu_only_change_no_number():
    cfg = Config()
    ch, p = relay_params(cfg)
    assert p.nearest_rsu_only
    full = p._replace(nearest_rsu_only=False)
    rng = np.random.default_rng(3)
    area = cfg.scenario.area_m
    mid = (p.rsu.min(axis=0) + p.rsu.max(axis=0)) / 2.0  # equidistant from RSU pairs: ties
    for trial in range(300):
        pos = rng.random((cfg.scenario.n_uavs, 2)) * area
        if trial % 3 == 0:
            pos[:, 0] = mid[0] + rng.normal(0.0, 1e-7, pos.shape[0]) * (trial % 2)
        if trial % 5 == 0:
            pos[0] = mid
        for a, b in zip(routes(pos, p, ch), routes(pos, full, ch)):
            assert np.array_equal(a, b)
