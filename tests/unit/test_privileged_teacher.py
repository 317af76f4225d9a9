"""The privileged teacher (truav/analysis/privileged_teacher.py): the oracle's discs, the UAVs matched to them,
each flying toward its own; and DAgger's teacher_data showing it the world."""

from __future__ import annotations

import numpy as np
import pytest

from agents.api import HOVER
from truav.analysis.privileged_teacher import LocalOracleTeacher, OracleTeacher, greedy_discs, match, toward
from truav.config import Config
from truav.presets import preset_overrides


def test_the_greedy_discs_take_the_densest_clusters_first_and_ignore_vehicles_off_the_road():
    big = np.array([[1000.0, 1000.0]] * 5 + [[1100.0, 1000.0]] * 3)
    small = np.array([[4000.0, 4000.0]] * 2)
    off = np.full((3, 2), np.nan)
    discs = greedy_discs(np.concatenate([small, off, big]), 2, 500.0)
    assert discs[0][0] in (1000.0, 1100.0) and discs[0][1] == 1000.0
    np.testing.assert_array_equal(discs[1], [4000.0, 4000.0])
    assert greedy_discs(off, 2, 500.0).shape == (0, 2)
    assert len(greedy_discs(big, 3, 500.0)) == 1  # all covered by one: no second disc


def test_match_gives_each_uav_the_nearest_disc_by_least_total_distance():
    pos = np.array([[0.0, 0.0], [1000.0, 0.0], [2000.0, 0.0]])
    targets = np.array([[2100.0, 0.0], [-100.0, 0.0], [900.0, 0.0]])
    np.testing.assert_array_equal(match(pos, targets), targets[[1, 2, 0]])
    # fewer discs than UAVs: the nearest UAV takes it, the rest keep their own position
    np.testing.assert_array_equal(match(pos, targets[:1]), [[0.0, 0.0], [1000.0, 0.0], [2100.0, 0.0]])
    np.testing.assert_array_equal(match(pos, targets[:0]), pos)


def test_toward_flies_full_speed_then_half_then_hovers_on_the_disc():
    pos = np.zeros((4, 2))
    target = np.array([[100.0, 0.0], [0.0, 10.0], [-6.0, -6.0], [1.0, 1.0]])
    # 100 m east: full speed east (8); 10 m north: half speed north (2); 8.5 m south-west, half a step 7.5:
    # half speed (5); 1.4 m: hover
    np.testing.assert_array_equal(toward(pos, target, 15.0), [8, 2, 5, HOVER])


def test_the_teacher_needs_the_world_and_with_a_reach_a_fallback():
    cfg = Config().replace(**preset_overrides("paper"))
    views = type("V", (), {"pos": np.array([[[0.0, 0.0]] * cfg.scenario.n_uavs])})()
    with pytest.raises(RuntimeError, match="see"):
        OracleTeacher(cfg, [[None] * cfg.scenario.n_uavs]).act(views)
    local = LocalOracleTeacher(cfg, [[None] * cfg.scenario.n_uavs])
    local.see(np.zeros((1, 10, 2)))
    with pytest.raises(RuntimeError, match="fallback"):
        local.act(views)


def test_a_local_teacher_leaves_far_discs_to_the_fallback():
    cfg = Config().replace(**preset_overrides("paper"))
    U = cfg.scenario.n_uavs
    pos = np.array([[[1000.0 * u, 0.0] for u in range(U)]])
    vehicles = np.concatenate([np.tile([[4900.0, 4900.0]], (20, 1)), pos[0]])[None]
    fallback = np.full((1, U), 3)
    local = LocalOracleTeacher(cfg, [[None] * U])
    local.see(vehicles, fallback)
    far = OracleTeacher(cfg, [[None] * U])
    far.see(vehicles)
    got, oracle = local.act(type("V", (), {"pos": pos})()), far.act(type("V", (), {"pos": pos})())
    chasing = oracle[0] >= 8  # the UAV sent to the far cluster; the others hover on their own vehicle or go to one
    assert chasing.sum() == 1
    np.testing.assert_array_equal(got[0], np.where(chasing, 3, oracle[0]))


def test_teacher_data_shows_a_privileged_teacher_the_world():
    pytest.importorskip("stable_baselines3")
    pytest.importorskip("numba")
    from agents.spread_agent import SENSE_RANGE_M
    from truav.analysis.ppo_train import teacher_data
    from truav.analysis.ppo_vec_env import TruavVecEnv, to_slot_actions
    from truav.analysis.privileged_teacher import oracle_actions

    cfg = Config().replace(**preset_overrides("paper")).replace(learner={"sense_range_m": SENSE_RANGE_M},
                                                                scenario={"steps_per_episode": 5})
    env = TruavVecEnv(cfg, [3, 4], claim=True)
    seen = []

    class Recording(OracleTeacher):
        def act(self, views):
            out = super().act(views)
            seen.append((self.vehicle_xy.copy(), np.asarray(views.pos).copy(), out))
            return out

    _, labels, _ = teacher_data(env, 1, 0.9, teacher_cls=Recording)
    assert len(seen) == 5
    sc = cfg.scenario
    for xy, pos, out in seen:
        np.testing.assert_array_equal(out, oracle_actions(xy, pos, sc.comm_range_m, sc.uav_speed_mps * sc.step_s))
    np.testing.assert_array_equal(labels, np.concatenate([to_slot_actions(o).reshape(-1) for _, _, o in seen]))
