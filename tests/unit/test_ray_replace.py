"""A lost Ray node's agents placed again on the nodes left (truav.swarm.ray_plan.without_node): pure, no Ray."""

import pytest

from truav.swarm.ray_plan import PlanError, RayNode, place, without_node

NODES = [RayNode("a", "10.0.0.1", 4), RayNode("b", "10.0.0.2", 2), RayNode("c", "10.0.0.3", 2)]


def test_a_lost_nodes_agents_go_to_the_least_loaded_nodes_left_in_plan_order():
    plan = place(NODES, n_uavs=8, agents_per_process=1, port=7447)  # a: 0 3 6, b: 1 4 7, c: 2 5
    after, moved = without_node(plan, "b")
    assert moved == {"agent1": "c", "agent4": "a", "agent7": "c"}  # c held 2, a 3: c, then a (plan order), then c
    assert [n.node_id for n in after.nodes] == ["a", "c"]
    assert [r.node_id for r in after.routers] == ["a", "c"]
    assert after.routers[1].endpoint == "tcp/10.0.0.3:7447"  # the routers left keep their endpoints
    assert after.endpoint_of("agent4") == "tcp/10.0.0.1:7447" and after.endpoint_of("agent7") == "tcp/10.0.0.3:7447"
    assert [a.uavs for a in after.agents] == [a.uavs for a in plan.agents]  # the same groups, in the same order
    assert {a.name: a.node_id for a in after.agents if a.name not in moved} == \
        {a.name: a.node_id for a in plan.agents if a.node_id != "b"}  # nothing else moves


def test_the_same_loss_gives_the_same_placement():
    plan = place(NODES, n_uavs=20, agents_per_process=3, port=7447)
    assert without_node(plan, "c") == without_node(plan, "c")
    first, _ = without_node(plan, "c")
    again, moved = without_node(first, "b")
    assert {a.node_id for a in again.agents} == {"a"}
    assert set(moved) == {a.name for a in first.agents if a.node_id == "b"} and set(moved.values()) == {"a"}


def test_the_core_node_or_the_last_node_cannot_be_lost():
    plan = place(NODES, n_uavs=4, agents_per_process=1, port=7447)
    with pytest.raises(PlanError, match="the world and the recorder"):
        without_node(plan, "a")
    with pytest.raises(PlanError, match="not in the plan"):
        without_node(plan, "zz")
    single = place(NODES[:1], n_uavs=2, agents_per_process=1, port=7447)
    with pytest.raises(PlanError):
        without_node(single, "a")
