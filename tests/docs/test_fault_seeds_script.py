"""docs/scripts/fault_seeds.py: schemes added to the fault comparison later, and runs not made, in its tables."""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "docs" / "scripts"))
try:
    import fault_seeds
finally:
    sys.path.pop(0)  # the scripts' folder is not left on the path of the other tests


def rows(scheme: str, faults: list[str], seeds: int = 3) -> list[dict]:
    return [{"scheme": scheme, "seed": k, "fault": f, "coverage_pct": 20.0 + k - (f != "none"), "pdr_pct": 50.0,
             "missed_actions_pct": 0.0, "beacons_heard_pct": 90.0} for k in range(seeds) for f in faults]


def test_a_fault_not_run_for_a_scheme_reads_not_run_and_the_others_are_paired() -> None:
    all_faults = [f for f, _, _ in fault_seeds.FAULTS]
    text = fault_seeds.tables(rows("truav", all_faults) + rows("claim", ["none", "loss", "partition"]))
    coverage, drops, _ = [line for line in text.splitlines() if line.startswith("| claim (heuristic) |")]
    assert coverage.count("not run") == 2 and "21.0 ±" in coverage
    assert drops.count("not run") == 2 and drops.count("-1.0") == 2  # loss and partition paired with no fault
    clone = next(line for line in text.splitlines() if line.startswith("| ppo-claim - truav |"))
    assert clone.count("not run") == 4


def test_the_figure_is_drawn_with_schemes_missing(tmp_path) -> None:
    fault_seeds.figure(rows("truav", [f for f, _, _ in fault_seeds.FAULTS]), tmp_path / "f.png")
    assert (tmp_path / "f.png").stat().st_size > 0


def test_speed_sets_the_runs_config_and_the_figure_title_and_ppo_disc_flies_the_disc() -> None:
    from agents.spread_agent import with_sensing
    assert fault_seeds.config().scenario.uav_speed_mps == 15.0  # the page's default
    cfg = fault_seeds.config(5.0)
    assert cfg.scenario.uav_speed_mps == 5.0
    assert "5 m/s" in fault_seeds.title(8, 5.0) and "15 m/s" not in fault_seeds.title(8, 5.0)
    assert "15 m/s" in fault_seeds.title(8, 15.0)
    assert "ppo-disc" in dict(fault_seeds.SCHEMES)
    flown = with_sensing("ppo-disc", cfg)  # as truav.swarm.scheme_faults.run_point flies each scheme
    assert flown.learner.sense_disc and flown.learner.sense_range_m > 0.0


def test_the_figure_draws_only_the_schemes_in_the_rows(tmp_path) -> None:
    faults = [f for f, _, _ in fault_seeds.FAULTS]
    drawn = fault_seeds.figure(rows("ppo-disc", faults) + rows("spread", faults), tmp_path / "f.png", speed=5.0)
    assert drawn == ["spread", "ppo-disc"]  # in SCHEMES order
