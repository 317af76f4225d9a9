"""The fused TRUAV episode kernel against the step-by-step reference path
(World.step + TruavController.act/observe): every metric and Q-table entry."""

import numpy as np
import pytest

from agents.controller import TruavController
from truav.analysis.driver import run_episodes
from world.step import pairwise_sum


def _run(cfg, seeds, fused, train=True, q=None, episodes=3):
    ctrl = TruavController(cfg, seeds, train=train, q=q)
    ctrl.fused = fused
    return run_episodes(cfg, seeds, ctrl, episodes), ctrl.learners.q


@pytest.mark.parametrize("scenario, learner", [
    ({}, {}),
    ({"n_uavs": 10, "uav_start": "persist"}, {}),  # > 8 UAVs: the pairwise (not sequential) sums
    ({"n_uavs": 1, "uav_speed_mps": 25.0}, {}),
    # the selectable state refinements: neighbour direction and sensed densest direction
    ({"n_uavs": 4}, {"neighbour_sectors": 4, "sense_range_m": 900.0, "sense_sectors": 8, "grid_cells": 4}),
    # issue 32's designs: difference reward, potential-based shaping, the prediction map's direction
    ({"n_uavs": 4, "uav_start": "persist"}, {"w_coverage": 0.0, "w_overlap": 0.0, "w_difference": 0.25,
                                             "w_shaping": 0.5, "predict_sectors": 4, "predict_cells": 5,
                                             "grid_cells": 2}),
])
def test_fused_episode_equals_the_step_path(small_cfg, scenario, learner):
    cfg = small_cfg.replace(scenario=scenario, learner=learner)
    seeds = [0, 5, 11]
    ref, q_ref = _run(cfg, seeds, fused=False)
    got, q_got = _run(cfg, seeds, fused=True)
    assert ref.keys() == got.keys()
    for k in ref:
        np.testing.assert_array_equal(got[k], ref[k], err_msg=k)
    np.testing.assert_array_equal(q_got, q_ref)
    # Greedy evaluation from the trained tables, on other traffic.
    ev_ref, _ = _run(cfg, [100, 101], fused=False, train=False, q=q_ref[:2], episodes=2)
    ev_got, _ = _run(cfg, [100, 101], fused=True, train=False, q=q_ref[:2], episodes=2)
    for k in ev_ref:
        np.testing.assert_array_equal(ev_got[k], ev_ref[k], err_msg=k)


@pytest.mark.parametrize("roads, traffic", [
    ({"hotspot_move_prob": 0.5, "hotspot_step_blocks": 1}, {}),  # hotspot moves drawn and applied in the kernel
    ({}, {"packet_rate_hz": 0.0}),  # numpy's Poisson draws nothing at lam = 0
    ({}, {"packet_rate_hz": 12.0}),  # lam >= 10: PTRS, drawn by numpy in start_episode instead
])
def test_fused_episode_draws_equal_the_step_paths(small_cfg, roads, traffic):
    cfg = small_cfg.replace(roads=roads, traffic=traffic, scenario={"uav_start": "persist"})
    seeds = [1, 6]
    ref, q_ref = _run(cfg, seeds, fused=False)
    got, q_got = _run(cfg, seeds, fused=True)
    for k in ref:
        np.testing.assert_array_equal(got[k], ref[k], err_msg=k)
    np.testing.assert_array_equal(q_got, q_ref)


@pytest.mark.parametrize("n", [0, 1, 5, 8, 9, 17, 128, 129, 300, 1024])
def test_pairwise_sum_is_numpys(n):
    rng = np.random.default_rng(n)
    for _ in range(20):
        x = rng.random(n) * rng.choice([1e-3, 1.0, 1e3], n)
        assert pairwise_sum(x, 0, n) == np.add.reduce(x)


@pytest.mark.parametrize("scenario", [{}, {"n_uavs": 9, "uav_speed_mps": 25.0}])
def test_fused_patrol_equals_the_step_path(small_cfg, scenario):
    from agents.patrol import PatrolController
    cfg = small_cfg.replace(scenario=scenario)
    seeds = [2, 4]
    runs = []
    for fused in (False, True):
        ctrl = PatrolController(cfg, seeds)
        ctrl.fused = fused
        runs.append(run_episodes(cfg, seeds, ctrl, 3))
    ref, got = runs
    assert ref.keys() == got.keys()
    for k in ref:
        np.testing.assert_array_equal(got[k], ref[k], err_msg=k)
