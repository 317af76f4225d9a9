"""The climbing heuristic (agents/claim_agent.py): its climb and its peer rule on hand-built views, its
determinism (the same seed, the same actions) and its batched form flying its per-UAV form, action for action."""

from __future__ import annotations

import numpy as np

from agents.api import HOVER, HeardBeacon, LocalView
from agents.claim_agent import ClaimAgent, ClimbParams, climb_step
from agents.spread_agent import SENSE_RANGE_M, SpreadAgent
from truav.config import Config
from truav.seeding import agent_rng
from tests.support.batched_forms import assert_batched_flies_per_uav
from world.uavs import ACTION_UNIT_VELOCITY

CFG = Config().replace(learner={"sense_range_m": SENSE_RANGE_M})


def view(uav=1, pos=(2500.0, 2500.0), in_range=0, exclusive=0, densest=0, beacons=()) -> LocalView:
    return LocalView(uav=uav, episode=0, step=5, pos=pos, vehicles_in_range=in_range, queued_packets=0, relayed=0,
                     covered=exclusive, energy_j=0.0, speed_max=15.0, densest_sector=densest, exclusive=exclusive,
                     nearest_rsu_m=1000.0, beacons=tuple(beacons), sense_range_m=SENSE_RANGE_M, sense_sectors=4)


def heading_deg(action: int) -> float:
    vx, vy = ACTION_UNIT_VELOCITY[action]
    return float(np.degrees(np.arctan2(vy, vx)) % 360.0)


def test_where_spread_hovers_over_its_vehicles_it_climbs_and_turns_when_they_fall():
    assert SpreadAgent(CFG, 1, agent_rng(0, 1)).act(view(in_range=35, exclusive=30)) == HOVER
    a = ClaimAgent(CFG, 1, agent_rng(0, 1))
    first = a.act(view(in_range=35, exclusive=30))
    assert first >= 8  # full speed, on its climb heading
    assert a.act(view(in_range=36, exclusive=31)) == first  # more: on it goes
    turned = a.act(view(in_range=30, exclusive=25))  # fewer: it turns by 135 degrees
    assert (heading_deg(turned) - heading_deg(first)) % 360.0 == 135.0


def test_the_climb_keeps_a_heading_while_the_objective_holds_and_starts_afresh_when_inactive():
    c = ClimbParams(window=2, turn_deg=90.0)
    climb, window = np.array([[1.0, 0.0]]), np.array([[0.0, 0.0, -1.0]])
    active = np.array([True])
    for value in (10.0, 10.0, 12.0, 12.0):  # two full windows, the second above the first
        action, climb, window = climb_step(c, active, np.array([value]), climb, window)
    assert np.allclose(climb, [[1.0, 0.0]]) and window[0, 2] == 12.0
    for value in (5.0, 5.0):  # fell: a quarter turn
        action, climb, window = climb_step(c, active, np.array([value]), climb, window)
    assert np.allclose(climb, [[0.0, 1.0]]) and heading_deg(int(action[0])) == 90.0
    action, climb, window = climb_step(c, np.array([False]), np.array([5.0]), climb, window)
    assert action[0] == HOVER and window.tolist() == [[0.0, 0.0, -1.0]]


def test_it_leaves_a_sensed_sector_holding_a_peer_to_that_peer():
    east_north = (2500.0 + 1200.0, 2500.0 + 600.0)  # in sector 1, 1.3 km away
    peer = HeardBeacon(uav=3, pos=east_north, vel=(0.0, 0.0), fields={})
    spread = SpreadAgent(CFG, 1, agent_rng(0, 1))
    assert heading_deg(spread.act(view(in_range=2, densest=1, beacons=[peer]))) == 45.0  # spread chases it
    a = ClaimAgent(CFG, 1, agent_rng(0, 1))
    got = a.act(view(in_range=2, densest=1, beacons=[peer]))
    assert a.beacon_fields()["goal_x"] == -1.0 and heading_deg(got) != 45.0  # no claim, climbs where it is
    b = ClaimAgent(CFG, 1, agent_rng(0, 1))
    assert heading_deg(b.act(view(in_range=2, densest=2, beacons=[peer]))) == 135.0  # another sector: chased


def test_the_same_seed_flies_the_same_actions_and_the_batched_form_flies_the_per_uav_form():
    cfg = CFG.replace(scenario={"n_vehicles": 80, "steps_per_episode": 25}, roads={"warmup_steps": 10})
    assert_batched_flies_per_uav("claim", ClaimAgent, cfg)


def test_its_state_round_trips():
    a = ClaimAgent(CFG, 2, agent_rng(0, 2))
    for n in (30, 31, 25):
        a.act(view(uav=2, in_range=n + 5, exclusive=n))
    b = ClaimAgent(CFG, 2, agent_rng(0, 2))
    b.load_state_dict(a.state_dict())
    for n in (20, 22, 26, 21):
        assert a.act(view(uav=2, in_range=n + 5, exclusive=n)) == b.act(view(uav=2, in_range=n + 5, exclusive=n))
