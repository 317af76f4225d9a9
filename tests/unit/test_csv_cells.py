"""No `nan` or `inf` in a CSV the project writes: a missing number is an empty field (what CSV readers take as
missing), as it is null in JSON (truav.jsonio). A legal minimal scenario delivers no packet, so its PDR, delay and
wait are NaN in memory."""

from __future__ import annotations

import csv
import math
import re
from pathlib import Path

import numpy as np

from truav import jsonio
from truav.csvio import cell, cells, row_cells

NON_FINITE = re.compile(r"(?<![A-Za-z_])-?(nan|inf|infinity)(?![A-Za-z_])", re.I)


def non_finite_cells(path: Path) -> list[str]:
    with open(path, newline="") as f:
        return [f"{path.name}:{n}: {v!r}" for n, row in enumerate(csv.reader(f), 1) for v in row
                if NON_FINITE.fullmatch(v.strip())]


def test_a_non_finite_number_is_an_empty_cell_and_the_rest_unchanged():
    assert cells([math.nan, np.float32("inf"), -math.inf, None, np.float64(0.5), 3, "x"]) == ["", "", "", "", 0.5, 3, "x"]
    assert cell(np.float64(1 / 3), ".6g") == "0.333333" and cell(np.nan, ".6g") == "" and cell(np.int64(7)) == 7
    assert cell(True) is True and cell(2, ".1f") == "2.0"
    assert row_cells({"pdr": math.nan, "scheme": "truav", "level": 0.25}) == {"pdr": "", "scheme": "truav",
                                                                             "level": 0.25}


def test_a_minimal_training_run_writes_no_nan_in_any_csv_or_json(tmp_path, capsys):
    from truav.analysis.runio import read_metrics
    from truav.cli.main import main

    run = tmp_path / "run"
    # one vehicle, a few steps: nothing is delivered, so pdr, delay_ms and wait_s have no value
    assert main(["train", "--seeds", "2", "--episodes", "2", "--workers", "1", "--quiet", "--out", str(run),
                 "--set", "scenario.n_vehicles=1", "--set", "scenario.steps_per_episode=6",
                 "--set", "roads.warmup_steps=2", "--set", "scenario.n_uavs=2"]) == 0
    capsys.readouterr()
    csvs, jsons = sorted(run.rglob("*.csv")), sorted(run.rglob("*.json"))
    assert any(p.name == "metrics.csv" for p in csvs), csvs
    assert [bad for p in csvs for bad in non_finite_cells(p)] == []
    for p in jsons:
        jsonio.loads_strict(p.read_text())
    rows = list(csv.DictReader(open(run / "metrics.csv", newline="")))
    assert {r["delay_ms"] for r in rows} == {""}  # nothing delivered: no delay, an empty field
    seeds, metrics = read_metrics(run / "metrics.csv")
    assert seeds == [0, 1] and np.isnan(metrics["delay_ms"]).all() and np.isfinite(metrics["energy_j"]).all()
