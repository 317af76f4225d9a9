"""Issue 32's selectable designs: the difference reward (the world's count of the vehicles only
this UAV covers), potential-based shaping, and the prediction map's state factor."""

import numpy as np

from agents.controller import TruavController
from agents.prediction import new_maps, predict_batch, predict_one, predict_params
from agents.reward import Reward
from agents.state import StateEncoder
from truav import seeding
from truav.analysis.driver import run_episodes
from world.env import World


def _stepped_world(cfg, seed=0, steps=3):
    world = World(cfg, 1)
    world.reset([seeding.world_rng(seed)])
    obs = None
    for _ in range(steps):
        obs, _, _ = world.step(np.zeros((1, cfg.scenario.n_uavs), np.int64))
    return world, obs


def test_exclusive_counts_the_vehicles_no_other_uav_covers(small_cfg):
    # 20 UAVs at random over the city: some discs overlap, so exclusive < in range for some
    cfg = small_cfg.replace(scenario={"n_vehicles": 200, "n_uavs": 20})
    world, obs = _stepped_world(cfg, seed=2)
    xy = world.vehicle_xy()[0]
    xy = xy[np.isfinite(xy).all(axis=1)]
    d = np.hypot(xy[:, None, 0] - obs.pos[0, None, :, 0], xy[:, None, 1] - obs.pos[0, None, :, 1])
    in_range = d <= cfg.scenario.comm_range_m  # (N, U)
    only = in_range & (in_range.sum(axis=1, keepdims=True) == 1)
    np.testing.assert_array_equal(obs.exclusive[0], only.sum(axis=0))
    np.testing.assert_array_equal(obs.vehicles_in_range[0], in_range.sum(axis=0))
    assert (obs.exclusive < obs.vehicles_in_range).any()  # the case the difference reward is about


def test_difference_and_shaping_terms(small_cfg):
    off = Reward(small_cfg)
    args = (np.array([[3.0]]), np.array([[7.0]]), np.array([[240.0]]), np.array([[0.4]]))
    assert not off.extra
    np.testing.assert_array_equal(off(*args, np.array([[5.0]]), np.array([[9.0]]), np.array([[2.0]])), off(*args))
    cfg = small_cfg.replace(learner={"w_difference": 0.5, "w_shaping": 2.0, "discount": 0.9})
    on = Reward(cfg)
    share = cfg.scenario.n_vehicles / cfg.scenario.n_uavs
    got = on(*args, np.array([[5.0]]), np.array([[9.0]]), np.array([[2.0]]))
    expected = off(*args) + 0.5 * 5.0 / share + 0.9 * (2.0 * 9.0 / share) - 2.0 * 2.0 / share
    np.testing.assert_allclose(got, expected, rtol=1e-12)


def test_prediction_points_at_the_densest_cell_seen(small_cfg):
    cfg = small_cfg.replace(learner={"predict_sectors": 4, "predict_cells": 2, "predict_decay": 0.5})  # 2.5 km cells
    p = predict_params(cfg)
    m = new_maps(p, 1, 1)[0, 0]
    assert predict_one(m, 1250.0, 1250.0, 10.0, p) == 0  # the densest cell is its own
    assert predict_one(m, 3750.0, 1250.0, 4.0, p) == 1 + 2  # west: 10 x 0.5 = 5 > 4
    assert m.tolist() == [5.0, 0.0, 4.0, 0.0]
    assert predict_one(m, 3750.0, 3750.0, 0.0, p) == 1 + 2  # the first cell, south-west: sector 2 of 4 (180-270 deg)
    assert predict_one(new_maps(p, 1, 1)[0, 0], 10.0, 10.0, 0.0, p) == 0  # nothing seen yet
    off = predict_params(small_cfg)
    maps = new_maps(off, 2, 3)
    assert maps.shape == (2, 3, 0)
    assert not predict_batch(maps, np.zeros((2, 3, 2)), np.ones((2, 3)), off).any()


def test_prediction_adds_a_state_factor_and_reaches_the_state(small_cfg):
    base = StateEncoder(small_cfg).n_states
    cfg = small_cfg.replace(scenario={"uav_start": "persist"},
                            learner={"predict_sectors": 4, "predict_cells": 5, "grid_cells": 2})
    assert StateEncoder(cfg).n_states == StateEncoder(small_cfg.replace(learner={"grid_cells": 2})).n_states * 5
    assert base == StateEncoder(small_cfg).n_states
    ctrl = TruavController(cfg, [0, 1])
    run_episodes(cfg, [0, 1], ctrl, 3)
    assert ctrl.maps.shape == (2, cfg.scenario.n_uavs, 25) and (ctrl.maps > 0).any()
    levels = ctrl.learners.q.shape[2] // 5
    visited = np.argwhere((ctrl.learners.q != TruavController(cfg, [0, 1]).learners.q).any(axis=3))
    assert {int(s) % 5 for _, _, s in visited} - {0}, "no state with a predicted direction was ever learned in"
    assert levels * 5 == ctrl.learners.q.shape[2]
