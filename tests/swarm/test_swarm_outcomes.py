"""`truav-swarm up` as an instrument: fresh state, honest exit codes and summaries,
shutdowns that lose nothing.

Small real swarms (2-3 agents, a small city) on loopback; every process is
tracked by PID (the supervisor's pids.json) and none may outlive its test.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from tests.support.swarm_up import SMALL, up  # noqa: F401  (the fixture: `up` runs, each closed at the end)
from truav.bus.transport import Bus, make_config
from truav.cli import swarm as swarm_cli
from truav.config import Config
from truav.swarm.children import free_loopback_endpoint
from truav.swarm.outdir import prepare_swarm_dir
from truav.swarm.supervisor import SwarmOptions, run_swarm
from truav.wire import keys, schema


def small_cfg(agents: int = 2, steps: int = 10) -> Config:
    return Config().replace(scenario={"n_vehicles": 40, "steps_per_episode": steps, "n_uavs": agents},
                            roads={"warmup_steps": 5})


# -- fresh state -------------------------------------------------------------------------
def test_second_run_into_the_same_out_is_refused_and_resume_continues_it(tmp_path, capsys):
    out = tmp_path / "swarm"
    argv = ["up", "--scheme", "truav", "--run", "fresh", "--agents", "2", "--steps", "10", "--episodes", "1", "--lockstep", *SMALL,
            "--out", str(out), "-l", free_loopback_endpoint(), "--quiet", "--no-plot"]
    assert swarm_cli.main(argv) == 0
    with np.load(out / "agent0.npz") as ck:
        steps_first = int(ck["steps"])
    assert "starts from a fresh table" in (out / "logs" / "agent0.log").read_text()
    capsys.readouterr()

    assert swarm_cli.main(argv) == 2  # the same command again: refused, nothing started
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--resume" in err and "--force" in err and str(out) in err
    assert (out / "summary.json").is_file() and (out / "agent0.npz").is_file()  # the first run's files untouched

    argv[argv.index("-l") + 1] = free_loopback_endpoint()
    assert swarm_cli.main([*argv, "--resume"]) == 0
    with np.load(out / "agent0.npz") as ck:
        assert int(ck["steps"]) == 2 * steps_first  # continued the first run's table
    assert "resumed from checkpoint" in (out / "logs" / "agent0.log").read_text()


def test_force_clears_every_file_of_the_earlier_run(tmp_path):
    out = tmp_path / "swarm"
    (out / "logs").mkdir(parents=True)
    old = ["agent0.npz", "agent4.npz", "agent4.json", "world.json", "summary.json", "pids.json", "scenario.toml",
           "logs/agent4.log"]
    for name in old:
        (out / name).write_text("from a 5-agent run")
    (out / "notes.txt").write_text("mine")  # not a swarm file: kept
    prepare_swarm_dir(out, "[scenario]\n", resume=False, force=True)
    assert not [name for name in old if name != "scenario.toml" and (out / name).exists()]
    assert (out / "scenario.toml").read_text() == "[scenario]\n" and (out / "notes.txt").is_file()


def test_resume_refuses_a_run_of_another_scenario(tmp_path, capsys):
    out = tmp_path / "swarm"
    out.mkdir()
    (out / "scenario.toml").write_text("[scenario]\nn_uavs = 5\n")
    (out / "truav-run.json").write_text("{}")
    rc = run_swarm(small_cfg(3), SwarmOptions(run="other", out=str(out), resume=True, quiet=True, plot=False))
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1 and "another scenario" in err


def test_recording_onto_an_existing_file_is_refused(tmp_path, capsys):
    mcap = tmp_path / "old.mcap"
    mcap.write_bytes(b"precious")
    (tmp_path / "a-file").write_text("not a directory")
    for record in (str(mcap), str(tmp_path / "a-file" / "x.mcap")):
        t0 = time.monotonic()
        rc = run_swarm(small_cfg(), SwarmOptions(run="rec", out=str(tmp_path / "swarm"), record=record, quiet=True))
        err = capsys.readouterr().err.strip()
        assert rc == 2 and len(err.splitlines()) == 1 and "--record" in err
        assert time.monotonic() - t0 < 2.0  # refused before anything started
    assert mcap.read_bytes() == b"precious" and not (tmp_path / "swarm").exists()


def test_an_unusable_listen_endpoint_fails_before_anything_starts(tmp_path, capsys):
    import socket
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        endpoint = f"tcp/127.0.0.1:{busy.getsockname()[1]}"
        rc = run_swarm(small_cfg(), SwarmOptions(run="busy", out=str(tmp_path / "swarm"), listen=endpoint, quiet=True))
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1 and endpoint in err and "in use" in err


# -- honest outcomes ---------------------------------------------------------------------
def test_agents_that_cannot_start_fail_the_run_at_once_with_their_error(tmp_path, capsys):
    t0 = time.monotonic()
    rc = run_swarm(small_cfg(), SwarmOptions(run="badq", out=str(tmp_path / "swarm"), qtable=str(tmp_path / "nope"),
                                             listen=free_loopback_endpoint(), quiet=True, plot=False))
    elapsed = time.monotonic() - t0
    captured = capsys.readouterr()
    assert rc == 1
    assert "could not start" in captured.err and "no Q-tables at" in captured.err  # the agent's own words
    assert elapsed < 30.0  # not the world's 60 s wait for agents that will never come
    outcome = json.loads((tmp_path / "swarm" / "summary.json").read_text())["outcome"]
    assert outcome["result"] == "failed" and outcome["exit_code"] == 1


@pytest.mark.parametrize("victim", ["router", "recorder"])
def test_losing_the_router_or_the_recorder_fails_the_run_and_leaves_no_process(up, tmp_path, victim):
    args = ["--agents", "2", "--steps", "50", "--episodes", "40", "--rate", "20"]
    if victim == "router":  # by default the router is restarted (tests/swarm/test_healing.py)
        args += ["--restart", "never"]
    if victim == "recorder":
        args += ["--record", str(tmp_path / "run.mcap")]
    u = up(f"lose{victim}", *args)
    u.wait_ticking()
    os.kill(u.pids[victim], signal.SIGKILL)
    rc = u.wait(timeout=90)
    out = u.output()
    assert rc == 1, out
    assert f"the {victim} exited mid-run (killed by SIGKILL)" in out and "result: FAILED" in out
    assert not u.left_running(), out
    summary = json.loads((u.out / "summary.json").read_text())
    assert summary["outcome"]["result"] == "failed" and victim in summary["outcome"]["ended_by"]
    for i in (0, 1):  # the agents still stopped cleanly: final checkpoint and statistics
        assert (u.out / f"agent{i}.json").is_file() and (u.out / f"agent{i}.npz").is_file(), out


@pytest.mark.parametrize("sender", ["intruder", "down"])
def test_the_summary_says_which_shutdown_ended_the_run_and_who_sent_it(up, sender):
    u = up(f"shut{sender}", "--agents", "2", "--steps", "50", "--episodes", "40", "--rate", "20")
    endpoint = u.wait_ticking()
    if sender == "intruder":
        # Only the supervisor's identity may send control (issue 14): the intruder's shutdown is refused
        # and counted by every process, the run goes on, and `down` still ends it.
        with Bus("intruder", u.run, make_config(connect=[endpoint], connect_timeout_ms=5000)) as bus:
            bus.publish(keys.control(u.run, "shutdown"), schema.Control(command="shutdown", args={}))
            time.sleep(1.0)
        assert u.proc.poll() is None, u.output()
    # as the README says: no endpoint given, `down` finds it in --out
    assert swarm_cli.main(["down", "--run", u.run, "--out", str(u.out)]) == 0
    rc = u.wait(timeout=90)
    out = u.output()
    outcome = json.loads((u.out / "summary.json").read_text())["outcome"]
    assert rc == 130 and "truav-swarm down" in outcome["ended_by"], out
    assert outcome["interrupted_by"] == "`truav-swarm down`"
    assert [src for _, src in outcome["shutdowns"] if src != "world"] == ["supervisor"]
    if sender == "intruder":
        world = json.loads((u.out / "world.json").read_text())
        assert world["rejected"]["forbidden_sender"]["intruder"] == 1, out
    assert not u.left_running(), out


# -- shutdown that loses nothing ---------------------------------------------------------
PLAN = """
seed = 1
[[fault]]
kind = "crash"
start = 0.6
uav = 0
restart_after = 0.5
[[fault]]
kind = "freeze"
start = 3.0
duration = 1000.0
uav = 1
"""


def test_after_a_freeze_and_a_crash_every_agent_wrote_its_final_checkpoint_and_statistics(tmp_path):
    """...and the actions the plan's crashed and frozen UAVs missed are said, not held against --max-missed."""
    plan = tmp_path / "plan.toml"
    plan.write_text(PLAN)  # agent 1 is still frozen when the world ends: the supervisor must thaw it
    out = tmp_path / "swarm"
    rc = run_swarm(small_cfg(3, 100), SwarmOptions(run="freeze", episodes=1, rate_hz=20.0, out=str(out), plot=False,
                                                   quiet=True, fault_plan=str(plan), checkpoint_every=5,
                                                   listen=free_loopback_endpoint(), max_missed_share=0.05))
    summary = json.loads((out / "summary.json").read_text())
    # a crashed agent and one frozen for the last 2 s miss well over 5% of the actions: by the plan's design, so
    # a warning counts them and the limit judges UAV 2's alone (which only a very busy host makes miss)
    assert any("action(s) missed by the UAV(s) the fault plan crashes or freezes (0, 1)" in w
               for w in summary["outcome"]["warnings"]), summary["outcome"]
    failures = summary["outcome"]["failures"]
    assert (rc == 0 and not failures) or (rc == 1 and len(failures) == 1 and "of the actions were missing (more "
                                          "than --max-missed 0.05)" in failures[0]), summary["outcome"]
    events = {(kind, phase) for _, kind, phase in summary["fault_events"]}
    assert {("crash", "start"), ("crash", "end"), ("freeze", "start")} <= events
    for i in range(3):
        stats = json.loads((out / f"agent{i}.json").read_text())
        with np.load(out / f"agent{i}.npz") as ck:
            assert int(ck["steps"]) == stats["steps"], i  # the checkpoint written at the very end
    assert "resumed from checkpoint" in (out / "logs" / "agent0.log").read_text()


def test_parts_started_by_hand_checkpoint_and_exit_when_their_router_is_gone(tmp_path):
    cfg_args = ["--run", "byhand", "--set", "scenario.n_uavs=2", "--set", "scenario.steps_per_episode=50", *SMALL]
    ep = free_loopback_endpoint()
    procs: dict[str, subprocess.Popen] = {}

    def start(name: str, *args: str) -> None:
        with open(tmp_path / f"{name}.log", "wb") as log:
            procs[name] = subprocess.Popen([sys.executable, "-m", "truav.cli.swarm", *args], stdout=log,
                                           stderr=subprocess.STDOUT)

    try:
        start("router", "router", "-l", ep)
        deadline = time.monotonic() + 30
        while b"router listening" not in (tmp_path / "router.log").read_bytes():
            assert time.monotonic() < deadline and procs["router"].poll() is None
            time.sleep(0.05)
        start("world", "world", *cfg_args, "-e", ep, "--episodes", "40", "--rate", "20", "--router-timeout", "1")
        for i in (0, 1):
            start(f"agent{i}", "agent", "--id", str(i), *cfg_args, "-e", ep, "--rate", "20", "--router-timeout", "1",
                  "--checkpoint", str(tmp_path / f"agent{i}.npz"), "--stats-out", str(tmp_path / f"agent{i}.json"))
        while "starting 20 Hz" not in (tmp_path / "world.log").read_text():
            assert time.monotonic() < deadline + 60 and procs["world"].poll() is None
            time.sleep(0.1)
        procs["router"].kill()
        for name in ("world", "agent0", "agent1"):
            assert procs[name].wait(timeout=30) == 1, (tmp_path / f"{name}.log").read_text()  # bounded, not forever
            assert "router lost" in (tmp_path / f"{name}.log").read_text()
        for i in (0, 1):
            assert (tmp_path / f"agent{i}.npz").is_file() and (tmp_path / f"agent{i}.json").is_file()
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.kill()
            p.wait(timeout=10)


def test_chaos_refuses_an_earlier_chaos_run_and_force_clears_both_runs(tmp_path, capsys):
    from truav.swarm.chaos import run_chaos
    from truav.swarm.outdir import prepare_chaos_dir
    plan = tmp_path / "plan.toml"
    plan.write_text(PLAN)
    out = tmp_path / "chaos"
    for name in ("baseline/agent0.npz", "faulted/agent0.npz", "baseline/summary.json", "degradation.txt"):
        (out / name).parent.mkdir(parents=True, exist_ok=True)
        (out / name).write_text("old")
    assert run_chaos(small_cfg(), SwarmOptions(run="ch", out=str(out), quiet=True), str(plan)) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--force" in err
    assert (out / "baseline" / "agent0.npz").read_text() == "old"  # refused: nothing touched
    prepare_chaos_dir(out, resume=False, force=True)
    assert not [p for p in out.rglob("*") if p.is_file()]  # the baseline cannot resume the old one's tables


def test_chaos_warns_when_its_own_baseline_is_degraded():
    from truav.swarm.chaos import baseline_warning
    episodes = [{"coverage_pct": 7.0}] * 2
    quiet = {"world": {"ticks": 202, "episodes": episodes, "actions_received": 1000,
                       "tick_lateness_ms": {"p99": 3.0}}}
    assert baseline_warning(quiet, 5, 10.0) is None
    busy = {"world": {"ticks": 202, "episodes": episodes, "actions_received": 900,
                      "tick_lateness_ms": {"p99": 70.0}}}
    warning = baseline_warning(busy, 5, 10.0)
    assert "10.0% of its actions were missing" in warning and "70 ms late" in warning and "loaded" in warning


def test_a_run_that_never_ticked_is_replaced_by_the_corrected_command(tmp_path, capsys):
    out = tmp_path / "swarm"
    opts = SwarmOptions(run="badq2", out=str(out), qtable=str(tmp_path / "nope"), listen=free_loopback_endpoint(),
                        quiet=True, plot=False)
    assert run_swarm(small_cfg(), opts) == 1
    assert prepare_swarm_dir(out, "x", resume=False, force=False) is None  # no "holds an earlier run"
    (out / "agent0.npz").write_text("a checkpoint")
    with pytest.raises(Exception, match="holds an earlier run"):
        prepare_swarm_dir(out, "x", resume=False, force=False)


def test_a_world_stopped_before_its_first_tick_does_not_make_a_run(tmp_path):
    out = tmp_path / "swarm"
    (out / "logs").mkdir(parents=True)
    (out / "logs" / "world.log").write_text("waiting for agents")
    (out / "truav-run.json").write_text("{}")  # the marker every run writes first
    (out / "world.json").write_text(json.dumps({"ticks": 0, "episodes": []}))
    (out / "agent0.json").write_text("{}")
    prepare_swarm_dir(out, "x", resume=False, force=False)  # replaced, not refused
    assert not (out / "world.json").exists() and not (out / "agent0.json").exists()
    (out / "world.json").write_text(json.dumps({"ticks": 12, "episodes": []}))
    with pytest.raises(Exception, match="holds an earlier run"):
        prepare_swarm_dir(out, "x", resume=False, force=False)
