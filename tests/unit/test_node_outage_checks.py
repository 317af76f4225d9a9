"""The chaos checker's reading of a run that lost a Ray node (truav.swarm.invariants): the node's outage is a
window where losses are expected, and an --agent class's resume line counts as a resume."""

from truav.swarm import invariants


def test_a_lost_nodes_outage_runs_from_its_loss_to_its_agents_acting_again_or_the_runs_end():
    summary = {"t0_wall_ns": 1_000_000_000, "elapsed_s": 60.0,
               "node_losses": [{"lost_wall_ns": 11_000_000_000, "outage_s": 4.5},
                               {"lost_wall_ns": 31_000_000_000, "outage_s": None}]}
    assert invariants.node_outages(summary) == [[11_000_000_000, 15_500_000_000], [31_000_000_000, 61_000_000_000]]
    assert invariants.node_outages({}) == []


def test_an_agent_class_that_resumed_from_its_last_checkpoint_is_seen_to(tmp_path):
    (tmp_path / "logs").mkdir()
    (tmp_path / "logs" / "agent2.log").write_text(
        "INFO uav 2 joined run r (agent:ppo)\n"
        "INFO uav 2: checkpoint at step 25 -> /x/agent2.npz\n"
        "INFO uav 2 (agent ppo) resumed from checkpoint /x/agent2.npz at step 25\n"
        "INFO uav 2 joined run r (agent:ppo)\n")
    procs = [{"name": "agent2", "pid": 1}, {"name": "agent2", "pid": 2}]
    row = invariants._resumed(tmp_path, procs)
    assert row.held, row.detail
    assert "steps 25" in row.detail
