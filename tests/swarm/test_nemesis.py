"""The random nemesis (truav.nemesis) and the checker (truav.swarm.invariants), without a swarm:
the schedule is seeded and survives its plan file exactly; the checker reads a run's outputs."""

from __future__ import annotations

import json
import signal

import pytest

from truav.faults import PlanError, load_plan, plan_from_dict
from truav.nemesis import FIRST_FAULT_S, RESTART_SETTLE_S, heal_at, quiet_tail_s, random_plan
from truav.cli import swarm as swarm_cli
from truav.swarm import invariants


def _end(f) -> float:
    return f.start + f.params["restart_after"] if f.kind == "crash" else f.end


def _process(f) -> str | None:
    if f.kind not in ("crash", "freeze"):
        return None
    return f.params.get("target") or f"agent{f.params['uav']}"


def test_the_schedule_is_seeded_and_its_plan_file_gives_the_same_schedule(tmp_path):
    plan = random_plan(600.0, 5, seed=11, recording=True)
    assert plan == random_plan(600.0, 5, seed=11, recording=True)  # same seed, same plan
    assert plan.faults != random_plan(600.0, 5, seed=12, recording=True).faults
    path = tmp_path / "nemesis-plan.toml"
    path.write_text(plan.to_toml("a header\nof two lines"))
    assert load_plan(path) == plan  # every fault, time and parameter, and the link filter's seed


def test_the_schedule_hits_every_part_and_heals_before_the_end():
    d = 600.0
    plan = random_plan(d, 5, seed=1, central=True, recording=True)
    kinds = {(f.kind, f.params.get("target", "agent" if "uav" in f.params else "")) for f in plan.faults}
    assert {("crash", "agent"), ("freeze", "agent"), ("freeze", "world"), ("freeze", "recorder"),
            ("freeze", "controller"), ("crash", "controller"), ("crash", "router"), ("loss", ""), ("latency", ""),
            ("obs_loss", ""), ("partition", "")} <= kinds
    assert heal_at(d) == d - 60.0 and quiet_tail_s(90.0) == 30.0
    assert min(f.start for f in plan.faults) >= FIRST_FAULT_S[0]
    assert max(_end(f) for f in plan.faults) <= heal_at(d)  # the last minute is quiet
    assert all(f.params.get("restart_after", 1.0) > 0 for f in plan.faults)  # every crash is restarted
    busy: dict[str, float] = {}
    for f in sorted(plan.faults, key=lambda f: f.start):  # never two faults on one process at once
        who = _process(f)
        if who is not None:
            assert busy.get(who, -1.0) <= f.start, f
            busy[who] = _end(f) + (RESTART_SETTLE_S if f.kind == "crash" else 0.0)  # a restart rejoins first
    # only what the swarm has: no controller without scheme central, no recorder without a recording
    plain = random_plan(d, 5, seed=1)
    assert not {f.params.get("target") for f in plain.faults} & {"controller", "recorder"}


@pytest.mark.parametrize("fault, fragment", [
    ({"kind": "crash", "start": 1.0, "target": "router"}, "needs restart_after"),
    ({"kind": "crash", "start": 1.0, "target": "world", "restart_after": 1.0}, "target must be one of"),
    ({"kind": "freeze", "start": 1.0, "duration": 1.0, "target": "router"}, "target must be one of"),
])
def test_bad_process_faults_are_one_line_errors(fault, fragment):
    with pytest.raises(PlanError, match=fragment):
        plan_from_dict({"fault": [fault]})
    plan_from_dict({"fault": [{"kind": "freeze", "start": 1.0, "duration": 1.0, "target": "world"},
                              {"kind": "crash", "start": 1.0, "target": "router", "restart_after": 0.5}]})


@pytest.mark.parametrize("argv, fragment", [
    (["chaos"], "--plan FILE or --nemesis random"),
    (["chaos", "--nemesis", "random"], "give --duration"),
    (["chaos", "--nemesis", "random", "--duration", "1m", "--lockstep"], "--lockstep"),
    (["chaos", "--nemesis", "random", "--duration", "1m", "--episodes", "3"], "--episodes"),
    (["chaos", "--nemesis", "random", "--duration", "ten"], "--duration"),
])
def test_nemesis_mistakes_are_one_line_errors_before_anything_starts(argv, fragment, capsys, tmp_path):
    try:
        rc = swarm_cli.main([*argv, "--out", str(tmp_path / "c")])
    except SystemExit as exc:  # argparse's own one-line errors
        rc = exc.code
    assert rc == 2
    err = capsys.readouterr().err
    assert fragment in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "c").exists()


# -- the checker, on hand-made outputs ----------------------------------------------------
def test_the_checker_sees_a_restart_that_did_not_resume_from_its_last_checkpoint(tmp_path):
    logs = tmp_path / "logs"
    logs.mkdir()
    procs = [{"name": "agent1", "pid": 1}, {"name": "agent1", "pid": 2}]
    good = ("uav 1 joined run r (learning)\nuav 1: checkpoint at step 50 -> a.npz\n"
            "uav 1 resumed from checkpoint a.npz at step 50\nuav 1 joined run r (learning)\n")
    (logs / "agent1.log").write_text(good)
    row = invariants._resumed(tmp_path, procs)
    assert row.held and "steps 50" in row.detail, row
    # a process killed while starting leaves only its resume line: still from the last checkpoint
    (logs / "agent1.log").write_text(good + "uav 1 resumed from checkpoint a.npz at step 50\n" + good.split("\n", 2)[2])
    assert invariants._resumed(tmp_path, procs + [{"name": "agent1", "pid": 3}]).held
    (logs / "agent1.log").write_text(good.replace("at step 50\nuav 1 joined", "at step 0\nuav 1 joined"))
    row = invariants._resumed(tmp_path, procs)
    assert not row.held and "resumed at step 0, its last checkpoint was at step 50" in row.detail, row


def test_the_checker_accepts_the_checkpoint_whose_log_line_the_kill_cut_off(tmp_path):
    """Seen in a 10-minute nemesis soak: SIGKILL between a checkpoint's atomic replace and its log line; the
    restart resumes from that checkpoint, one cadence after the last logged one. Two cadences on is not one."""
    logs = tmp_path / "logs"
    logs.mkdir()
    procs = [{"name": "agent0", "pid": 1}, {"name": "agent0", "pid": 2}]
    head = ("uav 0 joined run r (learning)\nuav 0: checkpoint at step 3250 -> a.npz\n"
            "uav 0: checkpoint at step 3300 -> a.npz\n")
    for step, held in ((3350, True), (3300, True), (3400, False), (3325, False)):
        (logs / "agent0.log").write_text(head + f"uav 0 resumed from checkpoint a.npz at step {step}\n"
                                                "uav 0 joined run r (learning)\n")
        row = invariants._resumed(tmp_path, procs)
        assert row.held == held, (step, row)


def test_the_checker_explains_every_exit_code_or_says_which_it_cannot():
    plan = plan_from_dict({"fault": [{"kind": "crash", "start": 5.0, "uav": 0, "restart_after": 2.0}]})
    outcome = {"exit_code": 0, "result": "ok", "restarts": [{"old_pid": 20}]}
    procs = [{"name": "agent0", "pid": 10, "exit_code": -signal.SIGKILL},  # the plan's crash
             {"name": "agent0", "pid": 11, "exit_code": 0},
             {"name": "agent1", "pid": 20, "exit_code": 1},  # died, restarted by the supervisor
             {"name": "agent1", "pid": 21, "exit_code": 0}]
    assert invariants._exit_codes(procs, plan, outcome, 0).held
    procs.append({"name": "agent2", "pid": 30, "exit_code": -signal.SIGKILL})  # killed by nobody we know
    row = invariants._exit_codes(procs, plan, outcome, 0)
    assert not row.held and "agent2 (pid 30)" in row.detail
    assert not invariants._exit_codes(procs[:4], plan, outcome, 1).held  # the supervisor's code vs its summary
    # a router that lost the default port to another process (exit 1) and was started again at once on a free
    # port: named in the summary as superseded, so explained; the same exit unexplained is a violation
    routers = [*procs[:4], {"name": "router", "pid": 40, "exit_code": 1}, {"name": "router", "pid": 41, "exit_code": 0}]
    assert not invariants._exit_codes(routers, plan, outcome, 0).held
    superseded = {**outcome, "superseded": [{"process": "router", "pid": 40, "cause": "in use"}]}
    assert invariants._exit_codes(routers, plan, superseded, 0).held


def test_the_checker_looks_for_missed_actions_only_after_the_heal(tmp_path):
    plan = plan_from_dict({"fault": [{"kind": "loss", "start": 5.0, "duration": 30.0, "probability": 0.5}]})
    hovering = [[t, 1.0 if t < 350 else 0.0] for t in range(600)]  # 10 Hz: misses until 35 s, 60 s run
    row = invariants._quiet_tail({"timeline": {"hovering": hovering}}, plan, 10.0)
    assert row.held and row.name == "no missed action in the last 12 s (after the heal)", row
    hovering[-1][1] = 2.0
    early = invariants._quiet_tail({"timeline": {"hovering": hovering[:300]}}, plan, 10.0)  # ended at 30 s
    # a --plan run shorter than its plan: nothing after the heal to check (the run's length, not the swarm)
    assert early.held is None and early.status == "not checked" and "heal (35.0 s)" in early.detail, early
    bad = invariants._quiet_tail({"timeline": {"hovering": hovering}}, plan, 10.0)
    assert not bad.held and bad.detail.startswith("2 UAV-tick(s) without an action")
    assert "1 of 2 checked held: the run is NOT sound" in invariants.table([row, bad])
    invariants.write(tmp_path, [row, bad])
    assert json.loads((tmp_path / "invariants.json").read_text())["sound"] is False


def test_after_the_heal_a_busy_hosts_sporadic_misses_are_not_a_fault_but_a_uav_that_never_recovers_is():
    plan = plan_from_dict({"fault": [{"kind": "loss", "start": 5.0, "duration": 10.0, "probability": 0.5}]})
    world = {"per_uav": [{"uav": i} for i in range(5)]}
    hovering = [[t, 0.0] for t in range(600)]  # 10 Hz, 60 s: the last 22.5 s are checked (225 ticks x 5 UAVs)
    hovering[590][1] = hovering[595][1] = 1.0  # two late actions on a loaded laptop
    row = invariants._quiet_tail({"world": world, "timeline": {"hovering": hovering}}, plan, 10.0)
    assert row.held and "2 UAV-tick(s) without an action" in row.detail and "at most 22 allowed" in row.detail, row
    for tick in hovering[400:]:  # one UAV hovers on every tick after the heal: it did not recover
        tick[1] += 1.0
    row = invariants._quiet_tail({"world": world, "timeline": {"hovering": hovering}}, plan, 10.0)
    assert not row.held, row


# -- one short real soak --------------------------------------------------------------------
SOAK_SEED = 22
SOAK_S = 40.0
"""With 3 agents over 40 s this seed crashes an agent, partitions the swarm and kills the router
(the plan is asserted below, so a change shows); the last third, after the heal, is checked."""
TIMING_ROWS = ("no missed action",)
"""Rows a loaded machine may violate in real time (the checker then says so and chaos exits 1)."""


def test_a_short_nemesis_run_heals_and_its_checker_reports_every_invariant(tmp_path):
    from tests.support.runs import run_to_end
    from truav.swarm.children import free_loopback_endpoint
    import sys
    out = tmp_path / "chaos"
    rc = run_to_end([sys.executable, "-m", "truav.cli.swarm", "chaos", "--nemesis", "random",
                     "--duration", f"{SOAK_S:g}s", "--seed", str(SOAK_SEED), "--agents", "3", "--run", "soak",
                     "--out", str(out), "--quiet",
                     "-l", free_loopback_endpoint(), "--set", "scenario.n_vehicles=40",
                     "--set", "roads.warmup_steps=5"], tmp_path / "chaos.log", timeout_s=420)
    text = (tmp_path / "chaos.log").read_text(errors="replace")
    plan = load_plan(out / "nemesis-plan.toml")
    assert plan == random_plan(SOAK_S, 3, seed=SOAK_SEED, recording=True), text  # the file is the schedule
    assert {(f.kind, f.params.get("target")) for f in plan.faults} >= {("crash", None), ("crash", "router")}
    # the schedule ran as written: every start and end, in the plan's order
    summary = json.loads((out / "faulted" / "summary.json").read_text())
    from types import SimpleNamespace
    from truav.swarm.fault_control import FaultController
    no_bus = SimpleNamespace(subscribe=lambda *args, **kwargs: None)  # the schedule alone: nothing sent live
    expected = [(f.kind, phase) for _, _, phase, f in sorted(FaultController(no_bus, "soak", plan, {})._heap,
                                                             key=lambda e: e[:2])]
    assert [(k, ph) for _, k, ph in summary["fault_events"]] == expected, text
    report = json.loads((out / "invariants.json").read_text())
    rows = {r["name"]: r for r in report["invariants"]}
    assert len(rows) == 8 and (out / "invariants.txt").read_text().startswith("invariant"), text
    assert rc == (0 if report["sound"] else 1), text  # the exit code tells the table's verdict
    for name, row in rows.items():
        if name.startswith(TIMING_ROWS):
            continue
        assert row["status"] == "held", (name, row, text)
    assert rows["every restarted agent resumed from its checkpoint"]["detail"].startswith("1 restart(s)"), text


def test_only_losses_while_the_router_was_down_are_forgiven():
    line = ("truav log check: r.mcap: 197 message(s) missing by seq (supervisor fault, incarnation 1 (inc 00): "
            "seq 3; uav/0 action, incarnation 1: seq 217)")
    assert invariants.only_losses(line, "r.mcap")
    assert not invariants.only_losses(line + "; 143 duplicate(s) (uav/2 action: 68)", "r.mcap")
    assert not invariants.only_losses("truav log check: r.mcap: unfinished (the recorder died; run ...)", "r.mcap")
