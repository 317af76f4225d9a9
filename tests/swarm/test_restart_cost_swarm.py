"""Issue 45: `truav-swarm up` explains what a plan's crash and restart cost: time down, time to start, time
to the first action, and the ticks missed in each, which add up to all the UAV missed."""

from __future__ import annotations

import json
import re

from tests.support.runs import up_to_end
from tests.support.swarm_up import SMALL
from truav.config import Config

PLAN = """[[fault]]
kind = "crash"
start = 2.0
uav = 1
restart_after = 1.0
"""


def test_a_crash_and_restart_is_explained_phase_by_phase(tmp_path) -> None:
    plan = tmp_path / "crash.toml"
    plan.write_text(PLAN)
    out = up_to_end(tmp_path, "rc", Config(), "--episodes", "1", "--steps", "80", "--fault-plan", str(plan), *SMALL,
                    "--max-missed", "1")  # the crash's missed actions are what the explanation is of, not a failure
    summary = json.loads((out / "summary.json").read_text())
    [cost] = summary["restart_costs"]
    assert cost["process"] == "agent1" and cost["uavs"] == [1]
    assert 0.9 <= cost["down_s"] <= 1.5, cost
    assert cost["starting_s"] > 0 and cost["joining_s"] >= 0, cost
    assert 5 <= cost["missed_down"] <= 20, cost  # 1 s down at 10 Hz (and the kill's own tick, on a loaded machine)
    assert cost["missed_starting"] >= 1, cost  # the new process takes a while to join the bus
    missed = {u["uav"]: u["missed"] for u in summary["world"]["per_uav"]}
    # the phases explain the UAV's misses (a loaded machine may add a late answer elsewhere)
    assert missed[1] - 3 <= cost["missed_total"] <= missed[1], (cost, missed)
    log = (tmp_path / "rc.log").read_text()
    assert re.search(rf"restart of agent1 \(UAV 1; died at \d+\.\d s\) cost {cost['missed_total']} missed tick\(s\): "
                     r"down \(death to restart\) \d", log), log
