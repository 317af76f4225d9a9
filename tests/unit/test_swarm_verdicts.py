"""The closing verdict's texts (truav.swarm.summary): the host's load named when it is the likely cause of missed
actions, a class's failures summed up by UAV, and never a bare "ok" under warnings."""

from __future__ import annotations

from truav.swarm.summary import agent_errors_text, missed_text, result_line
from truav.swarm.swarm_options import Outcome, SwarmOptions


def test_the_default_missed_share_is_a_few_percent():
    assert SwarmOptions().max_missed_share == 0.05


def test_missed_actions_name_the_load_only_when_the_host_was_loaded():
    quiet = missed_text(0.49, 0.05, 0.4, 2)
    assert quiet == "49% of the actions were missing (more than --max-missed 0.05)"
    loaded = missed_text(0.49, 0.05, 7.3, 2)
    assert loaded.startswith(quiet) and "load average 7.3 over the last minute on 2 core(s)" in loaded
    assert "likely cause" in loaded
    assert missed_text(0.49, 0.05, None, 2) == quiet  # no load average on this OS: nothing claimed
    planned = missed_text(0.49, 0.05, 7.3, 2, cause="the fault plan's freeze faults")
    assert planned == quiet + ": the fault plan's freeze faults, the likely cause"  # not the load, then


def test_a_class_failure_names_the_uavs_the_calls_and_the_first_message():
    line = agent_errors_text("pkg.mod:Cls", {"0": 3, "1": 4}, "learn raised ValueError: x", 0, tolerated=False)
    assert "agent class pkg.mod:Cls failed 7 call(s) on uav 0, 1" in line
    assert "first: learn raised ValueError: x (uav 0)" in line and "--tolerate-agent-errors" in line
    many = agent_errors_text("c", {str(i): 1 for i in range(25)}, None, 0, tolerated=True)
    assert "and 15 more" in many and "tolerated" in many


def test_the_closing_line_is_bare_ok_only_without_warnings():
    assert result_line(Outcome()) == "result: ok"
    o = Outcome()
    o.warnings.append("agent class c failed 1 call(s)")
    assert result_line(o) == "result: ok, with 1 warning(s) above"
