"""The decentralized heuristic (agents/spread_agent.py): its decisions on hand-built views, its determinism,
its batched form flying what its per-UAV form flies, and its place in every comparison."""

from __future__ import annotations

import numpy as np

from agents.api import HOVER, HeardBeacon, LocalView
from agents.api_controller import ApiController
from agents.spread_agent import SENSE_RANGE_M, SpreadAgent, with_sensing
from truav.analysis.driver import run_episodes
from truav.config import Config
from truav.seeding import agent_rng
from world.uavs import ACTION_UNIT_VELOCITY

CFG = Config().replace(learner={"sense_range_m": SENSE_RANGE_M})  # 5 UAVs, 200 vehicles: fair share 40


def view(uav=1, pos=(2500.0, 2500.0), in_range=0, exclusive=0, densest=0, beacons=(), step=5) -> LocalView:
    return LocalView(uav=uav, episode=0, step=step, pos=pos, vehicles_in_range=in_range, queued_packets=0, relayed=0,
                     covered=exclusive, energy_j=0.0, speed_max=15.0, densest_sector=densest, exclusive=exclusive,
                     nearest_rsu_m=1000.0, beacons=tuple(beacons), sense_range_m=SENSE_RANGE_M, sense_sectors=4)


def beacon(uav, pos, goal=None) -> HeardBeacon:
    return HeardBeacon(uav=uav, pos=pos, vel=(0.0, 0.0),
                       fields={} if goal is None else {"goal_x": goal[0], "goal_y": goal[1]})


def heading_deg(action: int) -> float:
    vx, vy = ACTION_UNIT_VELOCITY[action]
    return float(np.degrees(np.arctan2(vy, vx)) % 360.0)


def agent(uav=1) -> SpreadAgent:
    return SpreadAgent(CFG, uav, agent_rng(0, uav))


def test_it_flies_toward_the_densest_sector_at_full_speed_and_says_its_goal():
    for sector, middle in ((1, 45.0), (2, 135.0), (3, 225.0), (4, 315.0)):
        a = agent()
        action = a.act(view(densest=sector))
        assert action >= 8 and heading_deg(action) == middle, (sector, action)
        gx, gy = a.beacon_fields()["goal_x"], a.beacon_fields()["goal_y"]
        assert np.degrees(np.arctan2(gy - 2500.0, gx - 2500.0)) % 360.0 == np.float64(middle)


def test_it_leaves_a_goal_to_a_lower_id_peer_heading_there_and_keeps_it_from_a_higher_id():
    a = agent(uav=2)
    free = a.act(view(uav=2, densest=1))
    goal = (a.beacon_fields()["goal_x"], a.beacon_fields()["goal_y"])
    far = (4900.0, 100.0)  # the claimer's own position: far from the goal and from UAV 2
    yielded = agent(uav=2)
    got = yielded.act(view(uav=2, densest=1, in_range=3, beacons=[beacon(0, far, goal)]))
    assert got == HOVER and yielded.beacon_fields()["goal_x"] == -1.0  # keeps what it has in range, claims nothing
    kept = agent(uav=2)
    assert kept.act(view(uav=2, densest=1, in_range=3, beacons=[beacon(4, far, goal)])) == free
    assert kept.beacon_fields()["goal_x"] == goal[0]


def test_it_does_not_chase_a_sector_a_peer_already_sits_in():
    a = agent()
    a.act(view(densest=1))
    goal = (a.beacon_fields()["goal_x"], a.beacon_fields()["goal_y"])
    b = agent()
    got = b.act(view(densest=1, in_range=2, beacons=[beacon(3, goal)]))
    assert heading_deg(got) == 225.0 and b.beacon_fields()["goal_x"] == -1.0  # spreads away from it, no claim


def test_it_stays_while_serving_exclusive_vehicles_and_moves_off_a_lower_id_peer_only():
    a = agent(uav=1)
    assert a.act(view(uav=1, in_range=35, exclusive=30, densest=2)) == HOVER  # 30 >= 0.75 x 40: serving
    near = (2500.0 + 300.0, 2500.0)  # an overlapping peer to the east
    assert agent(uav=1).act(view(uav=1, in_range=35, exclusive=30, densest=2, beacons=[beacon(3, near)])) == HOVER
    pushed = agent(uav=1).act(view(uav=1, in_range=35, exclusive=30, densest=2, beacons=[beacon(0, near)]))
    assert pushed != HOVER and heading_deg(pushed) == 180.0  # away from UAV 0, west
    # below the threshold it goes for the denser sector
    assert agent(uav=1).act(view(uav=1, in_range=25, exclusive=20, densest=2)) != HOVER


def test_it_pushes_off_peers_whose_discs_overlap_when_not_serving():
    got = agent().act(view(in_range=1, beacons=[beacon(0, (2500.0, 2500.0 + 200.0))]))
    assert got >= 8 and heading_deg(got) == 270.0  # south, away from the peer to its north


def test_it_is_deterministic_and_its_batched_form_flies_its_per_uav_form():
    cfg = CFG.replace(scenario={"n_vehicles": 80, "steps_per_episode": 25}, roads={"warmup_steps": 10})

    class PerUav(SpreadAgent):
        batched = None
    runs = [run_episodes(cfg, [3, 4], ApiController("spread", cls, cfg, [3, 4], train=False), 3)
            for cls in (SpreadAgent, SpreadAgent, PerUav)]
    for k in ("coverage_pct", "pdr", "energy_j"):
        assert np.array_equal(runs[0][k], runs[1][k], equal_nan=True), k
        assert np.array_equal(runs[0][k], runs[2][k], equal_nan=True), k


def test_comparisons_fly_it_with_sensing_on():
    assert with_sensing("spread", Config()).learner.sense_range_m == SENSE_RANGE_M
    assert with_sensing("spread", CFG.replace(learner={"sense_range_m": 2000.0})).learner.sense_range_m == 2000.0
    assert with_sensing("patrol", Config()).learner.sense_range_m == 0.0


def test_the_comparison_commands_fly_the_heuristic_by_default():
    from truav.cli.main import build_parser
    from truav.experiments import scale, velocity
    from truav.experiments.cells import Cell
    parser = build_parser()
    for argv in (["experiment", "velocity"], ["experiment", "scale"]):
        assert "spread" in parser.parse_args(argv).schemes, argv
    assert "spread" in velocity.SCHEMES and "spread" in scale.SCHEMES
    # its cells fly with its sensing on, and only its cells
    assert Cell("spread", 15.0, (0,), 1, 1).config(Config()).learner.sense_range_m == SENSE_RANGE_M
    assert Cell("patrol", 15.0, (0,), 1, 1).config(Config()).learner.sense_range_m == 0.0
    helps = {a.dest: a.help for p in (parser._subparsers._group_actions[0].choices["evaluate"],) for a in p._actions}
    assert "spread" in helps["against"]
