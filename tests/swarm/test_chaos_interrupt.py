"""`truav-swarm chaos` stopped part-way (SIGTERM in its baseline run, Ctrl-C in its faulted run) ends in one
line with 143 / 130, no traceback, no comparison and no process left; the same command with --resume keeps a
finished run as it is, runs an unfinished one again from scratch (never continued from its checkpoints), and
ends with the comparison of a run never stopped (lock-step: the numbers are exact)."""

from __future__ import annotations

import json
import re
import signal
from pathlib import Path

import pytest

from tests.support.interrupts import finish, start, stop_when, stopped_quietly

CHAOS = """import sys
from truav.cli.swarm import main
sys.exit(main(sys.argv[1:]))
"""
LINE = (r"truav-swarm: interrupted in the (baseline|faulted) run[^;]*; run the same command "
        r"(with --resume|again) to continue")
# A latency plan on the agents' beacons: under --lockstep every beacon is still waited for, so both runs are
# exact and repeatable (a loss plan's lost beacons are waited for up to --lockstep-wait each: the run turns
# inexact). Only agents receive it: the supervisor, behind on delayed beacons of fast lock-step ticks, says so
# on stderr.
PLAN = '[[fault]]\nkind = "latency"\nstart = 0.0\nfixed_ms = 2.0\nkeys = "uav/*/beacon"\ndst = "uav/*"\n'
RESUMED = "resumed from checkpoint"
RESUMED_STEPS = 100  # steps an episode of the runs stopped, resumed and compared


def _finished(sub: Path) -> bool:
    path = sub / "summary.json"
    if not path.is_file():
        return False
    summary = json.loads(path.read_text())
    return (not summary["interrupted"] and summary["outcome"]["result"] == "ok"
            and len(summary["world"]["episodes"]) == 2)


def _ticking(sub: Path) -> bool:
    """The run's world has started its lock-step ticks (its agents have a table to checkpoint)."""
    log = sub / "logs" / "world.log"
    return log.is_file() and "starting lock-step" in log.read_text()


def _agent_logs(sub: Path) -> str:
    return "".join(p.read_text() for p in sorted((sub / "logs").glob("agent*.log")))


def _numbers(path: Path) -> str:
    """degradation.txt without its tick-lateness row (wall-clock timing, not a result of the runs)."""
    return "\n".join(line for line in path.read_text().splitlines() if not line.startswith("tick lateness"))


def _args(tmp_path: Path, out: Path, steps: int = 300) -> list[str]:
    plan = tmp_path / "latency.toml"
    plan.write_text(PLAN)
    return ["chaos", "--plan", str(plan), "--lockstep", "--agents", "2", "--steps", str(steps), "--episodes", "2",
            "--quiet", "--set", "scenario.n_vehicles=40", "--set", "roads.warmup_steps=5", "--out", str(out)]


def _no_comparison(out: Path) -> bool:
    return not any((out / name).exists() for name in ("degradation.txt", "invariants.txt", "chaos.png"))


def test_chaos_stopped_by_sigterm_in_its_baseline_run_ends_in_one_line(tmp_path):
    out = tmp_path / "chaos"
    rc, so, se, left = stop_when(start(CHAOS, _args(tmp_path, out), tmp_path), lambda: _ticking(out / "baseline"),
                                 signal.SIGTERM, 240)
    stopped_quietly(rc, so, se, 143, LINE)
    assert not left, f"processes outlived chaos: {left}"
    assert re.fullmatch(LINE, se.strip()).groups() == ("baseline", "with --resume"), se
    assert not _finished(out / "baseline")
    assert not (out / "faulted" / "summary.json").exists()
    assert _no_comparison(out), so


@pytest.mark.timeout(600)  # five swarm runs, three after one another: beyond the suite's 300 s on a loaded host
def test_chaos_stopped_by_ctrl_c_in_its_faulted_run_resumes_to_the_uninterrupted_comparison(tmp_path):
    stopped, whole = tmp_path / "stopped", tmp_path / "whole"
    # Five runs, every tick of them paid for (a faulted lock-step tick waits out the beacons' latency, ~60 ms
    # on a loaded host): 100 steps an episode leave the faulted run seconds of ticks to be stopped in.
    args = _args(tmp_path, stopped, RESUMED_STEPS)

    # the run never stopped goes alongside the others: lock-step, its numbers do not depend on the host's speed
    whole_args = _args(tmp_path, whole, RESUMED_STEPS)
    never_stopped = start(CHAOS, whole_args, tmp_path)
    try:
        # Ctrl-C while the faulted run ticks (its agents have tables to checkpoint)
        rc, so, se, left = stop_when(start(CHAOS, args, tmp_path),
                                     lambda: _finished(stopped / "baseline") and _ticking(stopped / "faulted"),
                                     signal.SIGINT, 240)
        stopped_quietly(rc, so, se, 130, LINE)
        assert not left, f"processes outlived chaos: {left}"
        assert re.fullmatch(LINE, se.strip()).groups() == ("faulted", "with --resume"), se
        assert "finished and kept" in se, se
        assert "invariants" not in so and "degradation" not in so, so
        assert _no_comparison(stopped), so
        assert not _finished(stopped / "faulted")
        kept = (stopped / "baseline" / "summary.json").read_bytes()

        # the same command with --resume: the finished baseline kept, the faulted run made again from scratch
        rc, so, se = finish(start(CHAOS, [*args, "--resume"], tmp_path))
        assert rc == 0 and "Traceback" not in so + se, so + se
        assert "== baseline run ==" not in so and "baseline run: finished before, kept" in so, so
        assert (stopped / "baseline" / "summary.json").read_bytes() == kept
        assert _finished(stopped / "faulted")
        assert RESUMED not in _agent_logs(stopped / "faulted"), "the interrupted faulted run was continued"

        # the comparison equals that of a run never stopped
        rc, so, se = finish(never_stopped)
        assert rc == 0, so + se
    finally:
        if never_stopped.poll() is None:  # an assertion above failed: SIGTERM ends it and its swarm (exit 143)
            never_stopped.terminate()
            never_stopped.communicate(timeout=120)
    assert _numbers(stopped / "degradation.txt") == _numbers(whole / "degradation.txt")
    for name in ("baseline", "faulted"):
        a, b = (json.loads((d / name / "summary.json").read_text())["world"]["episodes"] for d in (stopped, whole))
        assert a == b, name
