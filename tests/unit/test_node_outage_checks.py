"""The chaos checker's reading of a run that lost a Ray node (truav.swarm.invariants): the node's outage is a
window where losses are expected, and an --agent class's resume line counts as a resume."""

import json

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


def _agent2_run(tmp_path, log: str, summary: dict | None) -> invariants.Invariant:
    """agent2 (UAV 2 of 4, checkpoints every 50 steps: at steps 25, 75, 125, ...) restarted with ``log``."""
    (tmp_path / "logs").mkdir(exist_ok=True)
    (tmp_path / "logs" / "agent2.log").write_text(log)
    if summary is not None:
        (tmp_path / "summary.json").write_text(json.dumps(summary))
    procs = [{"name": "agent2", "pid": p} for p in range(1, 2 + log.count("resumed from"))]
    return invariants._resumed(tmp_path, procs)


CK = "INFO uav 2: checkpoint at step {} -> /x/agent2.npz\n"
RESUMED = "INFO uav 2 resumed from checkpoint /x/agent2.npz at step {}\nINFO uav 2 joined run r (learning)\n"
JOINED = "INFO uav 2 joined run r (learning)\n"
CADENCE = {"checkpoints": {"every_steps": 50, "uavs": 4}}


def test_a_node_kill_between_the_first_logged_checkpoints_replace_and_its_line_is_no_violation(tmp_path):
    """Seen in CI (tests/swarm/test_ray_node_loss.py, fault_plan): the plan killed agent2's node at 15 s, tick 75,
    as UAV 2 wrote its checkpoint of step 75, after the file's replace and before its log line; the restart resumed
    at step 75 with only step 25 logged. UAV 2 never checkpoints at step 50: one line was cut off, not two, and
    the run's cadence (summary.json) says which checkpoint came next."""
    row = _agent2_run(tmp_path, JOINED + CK.format(25) + RESUMED.format(75), CADENCE)
    assert row.held, row.detail
    assert "steps 75" in row.detail
    for step in (50, 125, 100):  # not UAV 2's checkpoint steps, or two checkpoints on
        row = _agent2_run(tmp_path, JOINED + CK.format(25) + RESUMED.format(step), CADENCE)
        assert row.held is False and f"resumed at step {step}" in row.detail, (step, row)


def test_the_checkpoint_a_restart_resumed_from_is_the_one_the_next_restart_may_resume_from(tmp_path):
    """Killed again before its next checkpoint (step 125), the agent resumes from step 75 again."""
    row = _agent2_run(tmp_path, JOINED + CK.format(25) + RESUMED.format(75) + RESUMED.format(75), CADENCE)
    assert row.held, row.detail
    row = _agent2_run(tmp_path, JOINED + CK.format(25) + RESUMED.format(75) + RESUMED.format(25), CADENCE)
    assert row.held is False and "resumed at step 25, its last checkpoint was at step 75" in row.detail, row


def test_a_first_checkpoint_whose_line_the_kill_cut_off_is_resumed_from(tmp_path):
    assert _agent2_run(tmp_path, JOINED + RESUMED.format(25), CADENCE).held
    row = _agent2_run(tmp_path, JOINED + RESUMED.format(75), CADENCE)
    assert row.held is False and "resumed at step 75, its last checkpoint was none" in row.detail, row


def test_without_the_runs_cadence_the_checker_infers_it_from_two_logged_checkpoints(tmp_path):
    """A summary.json without "checkpoints" (an older run): the cadence is the last two logged lines' distance."""
    assert _agent2_run(tmp_path, JOINED + CK.format(25) + CK.format(75) + RESUMED.format(125), None).held
    assert _agent2_run(tmp_path, JOINED + CK.format(25) + RESUMED.format(25), {}).held
    assert not _agent2_run(tmp_path, JOINED + CK.format(25) + CK.format(75) + RESUMED.format(175), {}).held


def test_uavs_sharing_an_agent_process_and_its_log_are_judged_each_from_its_own_checkpoints(tmp_path):
    (tmp_path / "logs").mkdir()
    (tmp_path / "logs" / "agent2.log").write_text(
        "INFO uav 2 joined run r (learning)\nINFO uav 3 joined run r (learning)\n" + CK.format(25)
        + "INFO uav 3: checkpoint at step 63 -> /x/agent3.npz\n"
        + RESUMED.format(75) + "INFO uav 3 resumed from checkpoint /x/agent3.npz at step 63\n"
        + "INFO uav 3 joined run r (learning)\n")
    (tmp_path / "summary.json").write_text(json.dumps(CADENCE))
    procs = [{"name": "agent2", "pid": 1}, {"name": "agent2", "pid": 2}]
    row = invariants._resumed(tmp_path, procs)
    assert row.held, row.detail
