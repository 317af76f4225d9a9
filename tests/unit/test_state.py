"""The selectable state refinements (issue 16): the world's sensing of the
densest direction beyond comm range, the nearest neighbour's direction, and
how they enter the state index."""

import numpy as np
import pytest

from agents.state import StateEncoder, all_peers, nearest_sectors
from truav import seeding
from truav.config import ConfigError
from world.env import World
from world.network import sector


def _world(cfg, seed=0):
    world = World(cfg, 1)
    world.reset([seeding.world_rng(seed)])
    return world


def test_sector_counts_counter_clockwise_from_east():
    assert [sector(dx, dy, 4) for dx, dy in ((1, 0.1), (-0.1, 1), (-1, -0.1), (0.1, -1))] == [0, 1, 2, 3]
    assert sector(1.0, -1e-12, 4) == 3  # just below east is the last sector, not out of range
    assert sector(0.0, 0.0, 8) == 0


def test_world_senses_the_densest_direction_beyond_comm_range(small_cfg):
    cfg = small_cfg.replace(scenario={"n_vehicles": 150}, learner={"sense_range_m": 1500.0, "sense_sectors": 4})
    world = _world(cfg, seed=3)
    obs = None
    for t in range(3):
        obs, _, _ = world.step(np.zeros((1, cfg.scenario.n_uavs), np.int64))
    xy = world.vehicle_xy()[0]
    seen_any = False
    for u, (x, y) in enumerate(obs.pos[0]):
        d = np.hypot(xy[:, 0] - x, xy[:, 1] - y)
        ring = (d > cfg.scenario.comm_range_m) & (d <= 1500.0)
        counts = np.bincount([sector(dx, dy, 4) for dx, dy in xy[ring] - (x, y)], minlength=4)
        expected = 0 if counts.max() == 0 else 1 + int(np.argmax(counts))
        assert obs.densest_sector[0, u] == expected
        seen_any |= expected > 0
    assert seen_any


def test_sensing_off_leaves_the_column_zero(small_cfg):
    world = _world(small_cfg)
    obs, _, _ = world.step(np.zeros((1, small_cfg.scenario.n_uavs), np.int64))
    assert not obs.densest_sector.any()


def test_sense_range_must_exceed_comm_range(small_cfg):
    with pytest.raises(ConfigError, match="learner.sense_range_m"):
        small_cfg.replace(learner={"sense_range_m": 400.0})


def test_default_state_space_is_unchanged_and_refinements_multiply_it(small_cfg):
    assert StateEncoder(small_cfg).n_states == 100 * 4 * 4 * 3 * 3
    refined = small_cfg.replace(learner={"neighbour_sectors": 4, "sense_range_m": 1500.0, "sense_sectors": 8})
    assert StateEncoder(refined).n_states == 100 * 4 * 4 * 3 * 3 * 4 * 9


def test_refined_state_tells_directions_apart(small_cfg):
    cfg = small_cfg.replace(scenario={"n_uavs": 2},
                            learner={"neighbour_sectors": 4, "sense_range_m": 1500.0, "sense_sectors": 4})
    enc = StateEncoder(cfg)
    base = StateEncoder(small_cfg.replace(scenario={"n_uavs": 2}))
    # UAV 0 at the centre; its neighbour 800 m east, then 800 m north: same distance level, other direction.
    states = []
    for other in ((3300.0, 2500.0), (2500.0, 3300.0)):
        pos = np.array([[[2500.0, 2500.0], other]])
        peers, heard = all_peers(pos)
        nb = nearest_sectors(pos, peers, heard, 4)
        states.append(enc.encode(pos, np.zeros((1, 2)), np.zeros((1, 2)), np.full((1, 2), 800.0), nb,
                                 np.zeros((1, 2), np.int64))[0, 0])
        assert base.encode(pos, np.zeros((1, 2)), np.zeros((1, 2)), np.full((1, 2), 800.0))[0, 0] \
            == states[-1] // (4 * 5)  # the default index, refined by the extra factors
    assert nb[0].tolist() == [1, 3]  # north of UAV 0; UAV 0 is south of it
    assert states[0] != states[1]
    pos = np.array([[[2500.0, 2500.0], [3300.0, 2500.0]]])
    sensed = [enc.encode(pos, np.zeros((1, 2)), np.zeros((1, 2)), np.full((1, 2), 800.0), np.zeros((1, 2), np.int64),
                         np.full((1, 2), d, np.int64))[0, 0] for d in range(5)]
    assert len(set(sensed)) == 5
