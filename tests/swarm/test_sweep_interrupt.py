"""A fault sweep stopped part-way (Ctrl-C, SIGTERM) ends in one line with 130 / 143, no traceback and no
process left; the same command then runs exactly the unfinished points (the interrupted one from scratch),
never taking an interrupted point's summary for a finished one."""

from __future__ import annotations

import csv
import json
import re
import signal

import numpy as np

from tests.support.interrupts import finish, start, stop_when, stopped_quietly

SWEEP = """import sys
from truav.swarm import fault_sweep
fault_sweep.SIZES["quick"] = fault_sweep.SweepSize((0.0, 0.25, 0.5), (0.0, 300.0), 2, 8, 2)
from truav.cli.main import main
sys.exit(main(sys.argv[1:]))
"""
POINTS = ["loss-0", "loss-0.25", "loss-0.5", "latency-0", "latency-300"]
LINE = r"truav: interrupted at point (\d)/5 \((\S+)\); run the same command to resume"


def _complete(summary: dict, episodes: int) -> bool:
    """A run that ended by itself, ok, with every episode asked for."""
    return (not summary["interrupted"] and summary["outcome"]["result"] == "ok"
            and len(summary["world"]["episodes"]) == episodes)


def _ran(out: str) -> list[int]:
    return [int(m) for m in re.findall(r"^\[(\d)/5\]", out, re.M)]


def test_fault_sweep_resumes_exactly_the_unfinished_points(tmp_path):
    out = tmp_path / "sweep"
    args = ["experiment", "faults", "--quick", "--out", str(out), "--rate", "10",
            "--set", "scenario.n_uavs=2", "--set", "scenario.n_vehicles=40", "--set", "roads.warmup_steps=5"]

    def finished(name: str) -> bool:
        path = out / name / "summary.json"
        return path.is_file() and _complete(json.loads(path.read_text()), 2)

    def running_after(done: str) -> bool:  # `done` finished, and the next point's swarm is up
        nxt = POINTS[POINTS.index(done) + 1]
        return finished(done) and (out / nxt / "swarm.json").is_file()

    # Ctrl-C during the second point's swarm run
    rc, so, se, left = stop_when(start(SWEEP, args, tmp_path), lambda: running_after("loss-0"), signal.SIGINT, 240)
    stopped_quietly(rc, so, se, 130, LINE)
    assert not left, f"processes outlived the sweep: {left}"
    first_stop = int(re.fullmatch(LINE, se.strip()).group(1))
    assert first_stop >= 2 and not finished(POINTS[first_stop - 1])
    kept = {name: (out / name / "summary.json").read_bytes() for name in POINTS[:first_stop - 1]}

    # the same command: starts at the interrupted point; SIGTERM during the one after it
    proc = start(SWEEP, args, tmp_path)
    rc, so, se, left = stop_when(proc, lambda: running_after(POINTS[first_stop - 1]), signal.SIGTERM, 240)
    stopped_quietly(rc, so, se, 143, LINE)
    assert not left, f"processes outlived the sweep: {left}"
    second_stop = int(re.fullmatch(LINE, se.strip()).group(1))
    assert _ran(so) == list(range(first_stop, second_stop + 1)), so
    kept.update({name: (out / name / "summary.json").read_bytes() for name in POINTS[:second_stop - 1]})

    # and again, to the end: only the points not finished run
    rc, so, se = finish(start(SWEEP, args, tmp_path))
    assert rc == 0, so + se
    assert "Traceback" not in so + se
    assert _ran(so) == list(range(second_stop, 6)), so
    for name, text in kept.items():  # finished points were kept, not run again
        assert (out / name / "summary.json").read_bytes() == text, name
    rows = list(csv.DictReader(open(out / "faults.csv")))
    assert [f"{r['kind']}-{float(r['level']):g}" for r in rows] == POINTS
    for name, row in zip(POINTS, rows):  # every row from a finished run of the point, none from a partial one
        summary = json.loads((out / name / "summary.json").read_text())
        assert _complete(summary, 2), name
        eps = summary["world"]["episodes"]
        assert len(eps) == 2
        assert float(row["coverage_pct"]) == float(np.mean([e["coverage_pct"] for e in eps])), name


CELLS = """import sys
import time
from truav.experiments import runner
_save = runner.save_cell
def _paced(*args, **kwargs):  # cells this small take milliseconds: paced, a signal lands mid-sweep
    _save(*args, **kwargs)
    time.sleep(0.5)
runner.save_cell = _paced  # (the forked workers inherit it)
from truav.cli.main import main
sys.exit(main(sys.argv[1:]))
"""
CELL_LINE = r"truav: interrupted with (\d) of 8 cells finished and kept in \S+; run the same command to resume"


def _cell_sweep(tmp_path, experiment: str, signum: int, code: int, workers: str, tables: tuple[str, ...]) -> None:
    """Stopped after its first cell, the same command runs the cells not finished, and its tables equal
    those of a run never stopped (the same seeds)."""
    setting = ["--speeds", "5", "15"] if experiment == "velocity" else ["--uavs", "2", "3", "--vehicles", "30"]
    base = ["experiment", experiment, "--quick", "--schemes", "truav", "patrol", *setting, "--seeds", "2",
            "--seeds-per-cell", "1", "--episodes", "60", "--eval-episodes", "2", "--window", "50",
            "--workers", workers, "--quiet"]
    stopped, whole = tmp_path / "stopped", tmp_path / "whole"
    cells = stopped / "cells"
    rc, so, se, left = stop_when(start(CELLS, [*base, "--out", str(stopped)], tmp_path),
                                 lambda: cells.is_dir() and any(cells.glob("*.npz")), signum, 240)
    stopped_quietly(rc, so, se, code, CELL_LINE)
    assert not left, f"processes outlived the sweep: {left}"
    kept = int(re.fullmatch(CELL_LINE, se.strip()).group(1))
    assert 1 <= kept < 8 and len(list(cells.glob("*.npz"))) == kept, se
    stamps = {p.name: p.stat().st_mtime_ns for p in cells.glob("*.npz")}
    rc, so, se = finish(start(CELLS, [*base, "--out", str(stopped)], tmp_path))
    assert rc == 0 and "Traceback" not in so + se, so + se
    assert f"8 cells, {kept} already finished, {8 - kept} to run" in so, so
    assert len(re.findall(r"^  cell \d/", so, re.M)) == 8 - kept, so
    assert {p.name: p.stat().st_mtime_ns for p in cells.glob("*.npz") if p.name in stamps} == stamps
    rc, so, se = finish(start(CELLS, [*base, "--out", str(whole)], tmp_path))
    assert rc == 0, so + se
    for table in tables:  # the numbers, not only the rows
        assert (stopped / table).read_text() == (whole / table).read_text(), table


def test_velocity_sweep_stopped_by_ctrl_c_resumes_to_the_same_tables(tmp_path):
    _cell_sweep(tmp_path, "velocity", signal.SIGINT, 130, "1", ("velocity.csv", "summary.csv"))


def test_scale_sweep_stopped_by_sigterm_resumes_to_the_same_tables(tmp_path):
    _cell_sweep(tmp_path, "scale", signal.SIGTERM, 143, "2", ("scale.csv", "summary.csv"))
