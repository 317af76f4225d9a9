"""A trained policy carries its training scenario: flown in another one it is refused in one line (exit 2)
before anything starts, unless the user opts in, and then the run records the difference."""

from __future__ import annotations

import json

import numpy as np
import pytest

from truav.analysis import policy_scenario, runio
from truav.cli.main import main as truav_main
from truav.cli.swarm import main as swarm_main
from truav.config import Config

SMALL = ["--set", "scenario.n_vehicles=30", "--set", "scenario.steps_per_episode=10", "--set", "roads.warmup_steps=5",
         "--set", "scenario.n_uavs=2"]


class Started(Exception):
    pass


@pytest.fixture(scope="module")
def run25(tmp_path_factory):
    """`truav train` at 25 m/s (one seed, two episodes)."""
    run = tmp_path_factory.mktemp("train") / "run25"
    assert truav_main(["train", "--speed", "25", "--seeds", "1", "--episodes", "2", "--workers", "1", "--quiet",
                       "--out", str(run), *SMALL]) == 0
    return run


@pytest.fixture
def nothing_starts(monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)
    import truav.swarm.fault_sweep
    import truav.swarm.supervisor
    import truav.cli.main

    def trap(*_a, **_k):
        raise Started("work started before the mistake was caught")
    for module, name in ((truav.swarm.supervisor, "run_swarm"), (truav.swarm.fault_sweep, "run_sweep"),
                         (truav.cli.main, "run_with_progress")):
        monkeypatch.setattr(module, name, trap)


def one_line_error(capsys) -> str:
    err = capsys.readouterr().err
    assert "Traceback" not in err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    return lines[0]


def test_train_records_the_scenario_beside_the_tables(run25):
    rec = policy_scenario.read_record(run25 / runio.QTABLE_FILE)
    assert rec["scenario.uav_speed_mps"] == 25.0 and rec["scenario.n_uavs"] == 2
    assert rec["learner.grid_cells"] == Config().learner.grid_cells


@pytest.mark.parametrize("entry, argv", [
    ("swarm", ["up", "--scheme", "truav", "--qtable", "{run}", "--greedy", "--set", "scenario.uav_speed_mps=15"]),
    ("truav", ["experiment", "faults", "--quick", "--qtable", "{run}", "--set", "scenario.uav_speed_mps=15"]),
    ("truav", ["evaluate", "{run}", "--speed", "15"]),
], ids=["up", "experiment-faults", "evaluate"])
def test_a_25_mps_policy_flown_at_15_mps_is_one_line_naming_both_speeds(run25, nothing_starts, capsys, entry, argv):
    main = swarm_main if entry == "swarm" else truav_main
    argv = [a.format(run=run25) for a in argv]
    assert main(argv + (SMALL if entry == "swarm" or "faults" in argv else [])) == 2
    line = one_line_error(capsys)
    assert f"{run25} was trained at 25 m/s; this run flies at 15 m/s (--allow-scenario-mismatch" in line, line


def test_another_state_design_is_named_too(run25, nothing_starts, capsys):
    # the same table shape (a Q-table's size does not tell every state design apart: the edges here)
    assert swarm_main(["up", "--scheme", "truav", "--qtable", str(run25), "--greedy", "--set", "learner.density_edges=[2.0, 6.0, 20.0]",
                       "--set", "scenario.uav_speed_mps=25", *SMALL]) == 2
    assert "was trained with learner.density_edges = [1.0, 5.0, 15.0]; this run has [2.0, 6.0, 20.0]" \
        in one_line_error(capsys)


def test_a_wrong_file_as_qtable_is_one_line_not_numpys_pickle_message(run25, nothing_starts, capsys):
    for main, argv in ((swarm_main, ["up", "--scheme", "truav", "--qtable", str(run25 / "metrics.csv"), *SMALL]),
                       (truav_main, ["evaluate", str(run25 / "metrics.csv")]),
                       (truav_main, ["experiment", "faults", "--quick", "--qtable", str(run25 / "metrics.csv")])):
        assert main(argv) == 2
        line = one_line_error(capsys)
        assert "metrics.csv: not a Q-table file of 'truav train' (an .npz archive); this is a csv file" in line, line
        assert "pickle" not in line


def test_allowed_the_evaluation_runs_and_says_the_difference(run25, capsys):
    assert truav_main(["evaluate", str(run25), "--speed", "15", "--allow-scenario-mismatch", "--episodes", "1",
                       "--workers", "1", "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "flown outside its training scenario (--allow-scenario-mismatch): it was trained at 25 m/s; this run " \
           "flies at 15 m/s" in out, out


def test_tables_without_a_record_say_so_and_fly(run25, tmp_path, capsys):
    old = tmp_path / "old"
    old.mkdir()
    with np.load(run25 / runio.QTABLE_FILE) as data:
        np.savez_compressed(old / runio.QTABLE_FILE, q=data["q"], seeds=data["seeds"])
    (old / runio.CONFIG_FILE).write_bytes((run25 / runio.CONFIG_FILE).read_bytes())
    assert truav_main(["evaluate", str(old), "--speed", "15", "--episodes", "1", "--workers", "1", "--quiet"]) == 0
    assert "its training scenario is not recorded" in capsys.readouterr().out


def test_up_with_the_opt_in_records_the_mismatch_in_the_summary(run25, tmp_path):
    from tests.support.runs import up_to_end
    cfg = Config().replace(scenario={"n_vehicles": 30, "steps_per_episode": 4, "n_uavs": 2, "uav_speed_mps": 15.0},
                           roads={"warmup_steps": 5})
    out = up_to_end(tmp_path, "mismatch", cfg, "--qtable", str(run25), "--greedy", "--allow-scenario-mismatch",
                    "--episodes", "1", "--lockstep")
    summary = json.loads((out / "summary.json").read_text())
    fit = summary["policy_scenario"]
    assert fit["status"] == "mismatch allowed" and fit["differences"] == [
        "was trained at 25 m/s; this run flies at 15 m/s"], fit
    assert any("flown outside its training scenario" in w for w in summary["outcome"]["warnings"])
    assert "flown outside its training scenario" in (tmp_path / "mismatch.log").read_text()
