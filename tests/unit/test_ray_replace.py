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


class _Proc:
    def __init__(self, code=None, ended=None):
        self.returncode, self.ended_wall_ns = code, ended

    def poll(self):
        return self.returncode


class _Children:
    """What truav.swarm.ray_recovery reads of RayChildren: its plan, start counts and processes."""

    def __init__(self, plan):
        self.plan, self.starts, self.procs = plan, {}, {}


def test_a_restart_on_a_dead_node_replans_once_and_names_the_loss():
    from truav.swarm.ray_recovery import NodeRecovery, loss_entries, loss_lines
    plan = place(NODES, n_uavs=6, agents_per_process=1, port=7447)  # a: 0 3, b: 1 4, c: 2 5
    children = _Children(plan)
    alive = {"a", "b", "c"}
    said = []
    recovery = NodeRecovery(lambda: alive, say=lambda line, **_: said.append(line))
    children.starts = {f"agent{i}": 1 for i in range(6)}
    children.procs = {"agent1": _Proc(-9, 1_000), "agent4": _Proc(-9, 900), "router-b": _Proc(None)}
    assert recovery.plan_for(children, "agent1") is plan and not recovery.losses  # b alive, its router up: here
    alive.discard("b")
    assert recovery.plan_for(_Children(plan), "agent1") is plan  # a first start: no check
    new = recovery.plan_for(children, "agent1")
    assert children.plan is new and new.node_of("agent1") == "a" and new.node_of("agent4") == "c"
    [loss] = recovery.losses
    assert (loss.node_id, loss.cause, loss.lost_wall_ns, loss.uavs) == ("b", "its Ray node died", 900, [1, 4])
    assert recovery.plan_for(children, "agent4") is new and len(recovery.losses) == 1  # the same loss, once
    assert said == ["Ray node b (10.0.0.2) lost (its Ray node died); its agents placed again: agent1 -> node a, "
                    "agent4 -> node c"]
    costs = [{"process": "agent4", "down_s": 0.5, "to_first_action_s": 3.0, "missed_total": 18},
             {"process": "agent1", "down_s": 0.6, "to_first_action_s": 4.0, "missed_total": 23},
             {"process": "agent1", "down_s": 0.5, "to_first_action_s": 1.0, "missed_total": 5}]  # a later death
    [entry] = loss_entries(recovery.losses, costs, t0_wall_ns=0)
    assert entry["outage_s"] == 4.6 and entry["missed_actions"] == 41
    assert entry["agents_moved"] == {"agent1": "a", "agent4": "c"}
    assert loss_lines([entry]) == ["Ray node b (10.0.0.2) lost at 0.0 s (its Ray node died): agent1 -> node a, "
                                   "agent4 -> node c, resumed from their checkpoints; 4.6 s outage, 41 action(s) "
                                   "missed by its 2 UAV(s)"]


def test_a_node_whose_router_died_is_lost_and_under_secure_its_agents_stay_down():
    from truav.swarm.ray_recovery import NodeRecovery
    plan = place(NODES, n_uavs=3, agents_per_process=1, port=7447)
    children = _Children(plan)
    children.starts = {"agent2": 1}
    children.procs = {"router-c": _Proc(-9)}
    recovery = NodeRecovery(lambda: {"a", "b", "c"}, secure=True, say=lambda *a, **k: None)
    assert recovery.plan_for(children, "agent2") is plan  # not moved: its keys are on c only
    [loss] = recovery.losses
    assert loss.cause == "its router's process died (killed by SIGKILL); the node is up"
    assert loss.refused and "--secure" in loss.refused and not loss.moved
