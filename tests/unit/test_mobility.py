"""Car-following on the grid: no collisions, leaders respected, clustering."""

import numpy as np

from truav.config import Config
from world.roads import HEADING_DIR, RoadGrid, Vehicles


def spawn(cfg, seeds):
    grid = RoadGrid(cfg)
    return grid, Vehicles.concat([grid.spawn(np.random.default_rng(s), cfg.scenario.n_vehicles) for s in seeds])


def test_no_collisions_and_no_overtaking_within_a_lane():
    cfg = Config()
    grid, veh = spawn(cfg, [0, 1, 2])
    rng = np.random.default_rng(7)
    for _ in range(400):
        before = (veh.heading.copy(), veh.road.copy(), veh.s.copy())
        grid.step(veh, 1.0, rng.random(veh.s.shape + (2,)))
        assert np.all(grid.lane_gaps(veh) >= 0.0), "two vehicles overlap on a lane"
        # Vehicles that stayed on their lane keep their order: nobody passes its leader.
        h0, r0, s0 = before
        for b in range(veh.s.shape[0]):
            stay = (veh.heading[b] == h0[b]) & (veh.road[b] == r0[b])
            lane = h0[b] * 1000 + r0[b]
            for key in np.unique(lane[stay]):
                idx = np.flatnonzero(stay & (lane == key))
                d = HEADING_DIR[h0[b, idx[0]]]
                assert np.array_equal(np.argsort(d * s0[b, idx]), np.argsort(d * veh.s[b, idx]))


def test_vehicles_stay_on_the_grid_and_obey_speed_limits():
    cfg = Config()
    grid, veh = spawn(cfg, [3])
    rng = np.random.default_rng(1)
    for _ in range(300):
        grid.step(veh, 1.0, rng.random(veh.s.shape + (2,)))
        assert np.all((veh.s >= 0) & (veh.s <= grid.extent))
        assert np.all((veh.road >= 0) & (veh.road < grid.n_roads))
        assert np.all((veh.v >= 0) & (veh.v <= cfg.idm.desired_speed_mps + 1e-9))
    assert veh.v.mean() > 3.0  # traffic flows


def test_leader_slows_follower():
    """A vehicle right behind a stopped one brakes and stops short of it."""
    cfg = Config()
    grid = RoadGrid(cfg)
    # Two vehicles on lane heading +x of road 1, between intersections (0, 250): leader stopped at 150 m.
    veh = Vehicles(heading=np.array([[0, 0]]), road=np.array([[1, 1]]), s=np.array([[100.0, 150.0]]),
                   v=np.array([[12.0, 0.0]]), home=grid.major_index[[[0, 0]]], next_turn=np.array([[0, 0]]),
                   cluster=np.array([[0, 0]]))
    grid.params.is_major[:] = False
    u = np.full((1, 2, 2), 0.99)
    speeds = []
    for _ in range(12):
        veh.v[0, 1] = 0.0
        veh.s[0, 1] = 150.0  # hold the leader
        grid.step(veh, 1.0, u)
        speeds.append(veh.v[0, 0])
    assert np.all(np.diff(speeds) <= 0)  # brakes smoothly all the way
    assert veh.v[0, 0] < 0.1
    gap = 150.0 - veh.s[0, 0] - cfg.idm.vehicle_length_m
    assert 0.0 <= gap <= cfg.idm.min_gap_m + 0.5  # stops about the jam distance behind


def test_traffic_clusters_near_major_intersections():
    """The densest 10% of 250 m cells hold far more than 10% of the vehicles."""
    cfg = Config()
    grid, veh = spawn(cfg, [0, 1])
    rng = np.random.default_rng(2)
    for _ in range(500):
        grid.step(veh, 1.0, rng.random(veh.s.shape + (2,)))
    x, y = veh.xy(grid.block)
    n_cells = 20
    cell = (np.clip(x // 250, 0, n_cells - 1) * n_cells + np.clip(y // 250, 0, n_cells - 1)).astype(int)
    for b in range(2):
        counts = np.sort(np.bincount(cell[b], minlength=n_cells * n_cells))[::-1]
        share = counts[: n_cells * n_cells // 10].sum() / cfg.scenario.n_vehicles
        assert share > 0.5
