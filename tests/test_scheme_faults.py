"""The comparative stress test's plans and rows (`truav experiment faults --schemes ...`); the swarm
runs themselves are those of tests/test_schemes_lockstep.py and tests/test_controller_faults.py."""

import tomllib

import pytest

from truav.experiments import scheme_faults as cmp
from truav.faults import check_plan_for, plan_from_dict


def plan(scheme, kind, level, run_s=10.0):
    return check_plan_for(plan_from_dict(tomllib.loads(cmp.plan_text(scheme, kind, level, run_s))), 5,
                          scheme=scheme)


def test_every_scheme_meets_the_same_link_faults_and_its_own_crash():
    for kind in ("loss", "latency"):
        plans = [plan(s, kind, 0.3 if kind == "loss" else 200.0) for s in cmp.SCHEMES]
        assert plans[0] == plans[1] == plans[2]  # one plan: beacons, uplink and downlink alike
        assert {f.params["keys"] for f in plans[0].faults} == set(cmp.LINK_KEYS)
    truav, central = plan("truav", "crash", 0.4), plan("central", "crash", 0.4)
    assert truav.faults[0].params == {"uav": 0, "restart_after": 4.0} and truav.faults[0].start == 2.0
    assert central.faults[0].params == {"target": "controller", "restart_after": 4.0}
    assert "restart_after" not in plan("central", "crash", 0.8).faults[0].params  # down to the end
    assert cmp.plan_text("patrol", "loss", 0.0, 10.0) == ""


def test_points_share_one_baseline_per_scheme_and_rows_count_missed_decisions():
    size = cmp.SIZES["quick"]
    pts = cmp.points(size, ("truav", "central"))
    assert pts.count(("central", "none", 0.0)) == 1 and len(pts) == 2 * 7
    summary = {"world": {"episodes": [{"coverage_pct": 10.0, "pdr": 0.5, "delay_ms": 3.0, "energy_j": 1e3}],
                         "ticks": 11, "deadline_misses": 2, "hover_answers": 3},
               "agents": [{"commands": {"fresh": 5, "held": 1, "hovered": 3}}, {"commands": {"held": 4}}]}
    row = cmp.row_of("central", "crash", 0.4, summary, 2)
    assert row["missed_actions"] == pytest.approx((2 + 3 + 5) / 20)
    assert row["coverage_pct"] == 10.0
