"""A centralized swarm whose controller is SIGKILLed by the fault plan: the world runs all its
episodes, the UAVs fall back (hold the last command, then hover), the run ends ok and its
summary says what happened. One real-time `truav-swarm up` on a free loopback port."""

from __future__ import annotations

import json
import signal
import subprocess
import sys

import pytest

from truav.config import Config, to_toml

STEPS = 40
CFG = Config().replace(scenario={"n_vehicles": 60, "steps_per_episode": STEPS, "n_uavs": 3},
                       roads={"warmup_steps": 10}, central={"hidden": 16})
TIMEOUT_S = 180.0


def test_world_survives_a_controller_sigkill_and_the_summary_says_so(tmp_path):
    pytest.importorskip("torch")
    scenario = tmp_path / "scenario.toml"
    scenario.write_text(to_toml(CFG))
    plan = tmp_path / "plan.toml"
    plan.write_text('[[fault]]\nkind = "crash"\nstart = 1.5\ntarget = "controller"\n')  # never restarted
    out = tmp_path / "run"
    cmd = [sys.executable, "-m", "truav.cli.swarm", "up", "--scheme", "central", "--scenario", str(scenario),
           "--episodes", "1", "--out", str(out), "--fault-plan", str(plan), "--command-hold", "1", "--quiet",
           "--no-plot",
           # a busy host makes real-time agents miss actions: not what this test is about (it finishes, and
           # the summary says what the controller's loss did)
           "--max-missed", "1"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    try:
        text, _ = proc.communicate(timeout=TIMEOUT_S)
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)  # its supervisor stops every process it started
            proc.communicate(timeout=60)
    text = text.decode(errors="replace")
    assert proc.returncode == 0, text
    assert "controller killed by the fault plan" in text and "the UAVs fly on without commands" in text
    summary = json.loads((out / "summary.json").read_text())
    assert summary["outcome"]["result"] == "ok"
    assert any("the controller was lost" in w for w in summary["outcome"]["warnings"]), summary["outcome"]
    world = summary["world"]
    assert len(world["episodes"]) == 1 and world["ticks"] == STEPS + 1  # the world ran its episode to the end
    assert len(world["controller_losses"]) == 1
    commands = [a["commands"] for a in summary["agents"]]
    # Before the crash commands (fresh in their round, or late and held for the next), after it at most
    # one held tick (hold 1 s = one 1 s step), then hovering. Real time promises none of the commands
    # before the crash: on a loaded host (two test workers) the world's first ticks came 1.5 s apart and
    # the crash, 1.5 s after the first, fell before any command landed. Every UAV hovers once it is gone,
    # and every decision is counted as one of the three.
    assert all(c["hovered"] > 0 for c in commands), commands
    assert all(c["fresh"] + c["held"] + c["hovered"] <= STEPS for c in commands), commands
    assert 0 < world["hover_answers"] <= sum(c["hovered"] for c in commands)  # some late, under load
    assert [(kind, phase) for _, kind, phase in summary["fault_events"]] == [("crash", "start")]


def test_central_summary_counts_every_controller_incarnation(bus_factory, capsys):
    """A crashed controller writes no statistics, so its restart's controller.json counts only itself
    (chaos --scheme central said "90 ticks decided"): the supervisor counts the commands every
    incarnation sent, as heard on the bus, and says how many incarnations there were."""
    from truav.swarm.monitor import Monitor
    from truav.swarm.supervisor import SwarmOptions, _print_central
    from truav.wire import keys, schema
    run = "incarnations"
    monitor = Monitor(n_uavs=2)
    monitor.attach(bus_factory("supervisor", run=run), run, central=True)
    for first, last in ((0, 5), (6, 9)):  # one incarnation, killed after tick 5, then its restart
        ctl = bus_factory("controller", run=run)
        assert all(ctl.await_subscribers(keys.controller_cmd(run, uav), 30.0) for uav in range(2))
        for tick in range(first, last + 1):
            for uav in range(2):
                ctl.publish(keys.controller_cmd(run, uav), schema.Command(uav=uav, tick=tick, action=1, pad=b""))
        ctl.close()
    from tests.support.waits import wait_until
    assert wait_until(lambda: monitor.control_plane()["command_ticks"] == 10, 30.0)
    cp = monitor.control_plane()
    restarted = {"ticks": 4, "commands": 8, "stale_states": 0, "policy": "online learning"}
    _print_central(CFG.replace(scenario={"n_uavs": 2}), SwarmOptions(scheme="central"), {}, [], restarted, cp, 2)
    line = capsys.readouterr().out.splitlines()[0]
    assert "2 incarnations: commands for 10 tick(s), 20 command(s) heard on the bus" in line, line
    assert "the last incarnation: 4 tick(s) decided" in line, line
