"""Issue 45: a restart's missed ticks split into down, starting and joining (truav.swarm.restart_cost)."""

from __future__ import annotations

from truav.swarm.restart_cost import restart_costs, restart_lines

STEPS = [i * 0.1 for i in range(100)]  # a step every 0.1 s from t = 0


def _missed(start: float, end: float) -> list[tuple[float, int]]:
    return [(t, 1) for t in STEPS if start <= t < end]


def test_each_phase_gets_the_ticks_missed_in_it() -> None:
    # killed at 2.0, restarted at 3.0, on the bus at 4.55, first action at 4.7 (missed until then)
    costs = restart_costs([("agent1", 1.97)], [("agent1", None, 0.0), ("agent1", None, 3.0)], {"uav/1": [0.2, 4.55]},
                          STEPS, {1: _missed(2.0, 4.65)}, {"agent1": [1], "agent2": [2]}, t0=0.0)
    assert len(costs) == 1
    c = costs[0]
    assert (c["down_s"], c["starting_s"], c["joining_s"], c["to_first_action_s"]) == (1.03, 1.55, 0.15, 1.7)
    assert (c["missed_down"], c["missed_starting"], c["missed_joining"]) == (10, 16, 1)
    assert c["missed_total"] == 27 == len(_missed(2.0, 4.65))
    line = restart_lines(costs)[0]
    assert "restart of agent1 (UAV 1; died at 2.0 s) cost 27 missed tick(s)" in line
    assert "starting (restart to its liveliness token) 1.6 s, 16 missed" in line


def test_a_restart_the_run_did_not_see_through_says_so() -> None:
    costs = restart_costs([("agent1", 9.0)], [("agent1", None, 0.0)], {"uav/1": [0.2]}, STEPS,
                          {1: _missed(9.0, 10.0)}, {"agent1": [1]}, t0=0.0)
    c = costs[0]
    assert c["down_s"] is None and c["missed_down"] == 10 and c["starting_s"] is None and c["missed_starting"] is None
    assert "down (death to restart) not over by the end, 10 missed" in restart_lines(costs)[0]
    assert "starting (restart to its liveliness token) not reached" in restart_lines(costs)[0]


def test_the_router_and_controller_have_no_ticks_of_their_own() -> None:
    assert restart_costs([("router", 1.0), ("controller", 2.0)], [], {}, STEPS, {}, {"agent0": [0]}, t0=0.0) == []
