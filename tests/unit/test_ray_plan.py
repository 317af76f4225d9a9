"""The placement of a swarm on Ray nodes (truav.swarm.ray_plan): pure, no Ray needed."""

import pytest

from truav.swarm.ray_plan import PlanError, RayNode, place


NODES = [RayNode("a", "10.0.0.1", 4), RayNode("b", "10.0.0.2", 2), RayNode("c", "10.0.0.3", 2)]


def test_one_router_per_node_each_linked_to_the_first():
    plan = place(NODES, n_uavs=6, agents_per_process=1, port=7447)
    assert [r.node_id for r in plan.routers] == ["a", "b", "c"]
    assert [r.endpoint for r in plan.routers] == ["tcp/10.0.0.1:7447", "tcp/10.0.0.2:7447", "tcp/10.0.0.3:7447"]
    assert plan.routers[0].connect is None
    assert all(r.connect == "tcp/10.0.0.1:7447" for r in plan.routers[1:])
    assert plan.core_node == "a" and plan.core_endpoint == "tcp/10.0.0.1:7447"


def test_nodes_sharing_an_address_get_a_port_each():
    nodes = [RayNode(k, "127.0.0.1", 1) for k in "xyz"]
    plan = place(nodes, n_uavs=3, agents_per_process=1, port=20000)
    assert [r.endpoint for r in plan.routers] == [f"tcp/127.0.0.1:{20000 + k}" for k in range(3)]


def test_agents_spread_evenly_in_the_runs_groups():
    plan = place(NODES, n_uavs=7, agents_per_process=2, port=7447)
    groups = [(g.node_id, g.uavs) for g in plan.agents]
    assert groups == [("a", (0, 1)), ("b", (2, 3)), ("c", (4, 5)), ("a", (6,))]
    assert plan.agents[0].name == "agents0-1" and plan.agents[3].name == "agent6"
    assert plan.endpoint_of("agents2-3") == "tcp/10.0.0.2:7447"
    assert plan.endpoint_of("world") == plan.endpoint_of("recorder") == "tcp/10.0.0.1:7447"
    assert plan.node_of("agents4-5") == "c" and plan.node_of("world") == "a"


def test_external_uavs_have_no_process():
    plan = place(NODES, n_uavs=4, agents_per_process=1, port=7447, external=(1,))
    assert [g.uavs for g in plan.agents] == [(0,), (2,), (3,)]


def test_the_first_node_given_is_the_core_whatever_its_order():
    plan = place(list(reversed(NODES)), n_uavs=3, agents_per_process=1, port=7447)
    assert plan.core_node == "c" and plan.routers[0].node_id == "c"


def test_lines_say_where_everything_runs():
    lines = place(NODES[:2], n_uavs=2, agents_per_process=1, port=7447).lines()
    assert lines[0] == "node a (10.0.0.1): router tcp/10.0.0.1:7447, world, recorder, agent0"
    assert lines[1] == "node b (10.0.0.2): router tcp/10.0.0.2:7447 -> tcp/10.0.0.1:7447, agent1"


@pytest.mark.parametrize("nodes, port, what", [([], 7447, "no alive Ray node"),
                                               (NODES, 0, "port"),
                                               ([RayNode(k, "127.0.0.1", 1) for k in "xy"], 65535, "port")])
def test_mistakes_are_one_line(nodes, port, what):
    with pytest.raises(PlanError, match=what):
        place(nodes, n_uavs=3, agents_per_process=1, port=port)
