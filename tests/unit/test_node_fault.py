"""The nemesis's node kill (truav.faults: a crash with target "node"): a Ray node of `up --ray` killed by
a fault plan, checked on load like every fault."""

import pytest

from truav.faults import PlanError, plan_from_dict, node_faults


def _plan(**fault):
    return plan_from_dict({"fault": [{"kind": "crash", "start": 5.0, **fault}]})


def test_a_crash_of_a_node_names_it_by_its_index_in_the_plan():
    plan = _plan(target="node", node=2)
    assert node_faults(plan) == [(0, 2)]
    assert node_faults(_plan(uav=1)) == []


@pytest.mark.parametrize("fault, message", [
    ({"target": "node"}, "missing node"),
    ({"target": "node", "node": 0}, "node 0 holds the world and the recorder"),
    ({"target": "node", "node": "b"}, "node must be"),
    ({"target": "node", "node": 1, "restart_after": 2.0}, "restart_after"),
    ({"uav": 1, "node": 1}, "node: only with target"),
])
def test_a_node_crash_that_cannot_be_is_refused_on_load(fault, message):
    with pytest.raises(PlanError, match=message):
        _plan(**fault)
