"""Issue 45: `truav-swarm up` ends with a scale for its numbers: hover, the heuristic claim (issue 56) and patrol
flown in process on the same scenario, seed and episode count (truav.swarm.references)."""

from __future__ import annotations

import numpy as np

from agents.spread_agent import with_sensing
from truav.analysis.trainer import run_chunk
from truav.config import Config
from truav.swarm.references import references_for, references_line

CFG = Config().replace(scenario={"n_vehicles": 40, "steps_per_episode": 40}, roads={"warmup_steps": 5})
WORLD = {"episodes": [{"coverage_pct": 9.8, "pdr": 0.116}, {"coverage_pct": 10.2, "pdr": 0.124}]}


def test_references_are_the_in_process_runs_of_the_same_seed_and_episodes() -> None:
    refs, why = references_for(CFG, "truav", 3, WORLD, True)
    assert why is None and refs["seed"] == 3 and refs["episodes"] == 2
    for name, kind, cfg in (("hover", "hover", CFG), ("patrol", "patrol", CFG),
                            ("claim", "agent:claim", with_sensing("claim", CFG))):
        m = run_chunk(kind, cfg, [3], 2, train=False).metrics
        assert refs[name]["coverage_pct"] == float(np.nanmean(m["coverage_pct"]))
        assert refs[name]["pdr"] == float(np.nanmean(m["pdr"]))
    line = references_line("truav", WORLD, refs, None, faults=True)
    assert line.startswith("coverage: this swarm (truav) 10.0%, hover ")
    assert line.splitlines()[1].startswith("  references on the same scenario, seed 3, 2 episodes, without the faults")
    assert f"hover {refs['hover']['coverage_pct']:.1f}%, the heuristic claim" in line
    assert f"PDR: this swarm 0.120, hover {refs['hover']['pdr']:.3f}, claim" in line
    assert "oracle ceiling: docs/results/reproduction.md" in line


def test_no_references_when_asked_or_when_the_run_flew_one_or_finished_no_episode() -> None:
    assert references_for(CFG, "truav", 0, WORLD, False) == (None, "--no-references")
    assert references_for(CFG, "patrol", 0, WORLD, True) == (None, "the run flew patrol, itself a reference")
    assert references_for(CFG, "truav", 0, {"episodes": []}, True) == (None, "no episode finished")
    assert references_line("truav", WORLD, None, "--no-references", False) == \
        "coverage 10.0%, PDR 0.120 (references not computed: --no-references)"
    assert references_line("truav", {"episodes": []}, None, "no episode finished", False) == \
        "references: none (no episode finished)"


def test_a_metric_without_data_is_no_data_without_its_unit() -> None:
    """The live status and the summary say "coverage no data", not "no data%"; a value keeps its unit."""
    from truav.stats import shown
    assert shown(float("nan"), "5.1f", "%") == "no data" and shown(12.345, "5.1f", "%") == " 12.3%"
    assert shown(None, ".2f", " J") == "no data" and shown(2.0, ".2f", " J") == "2.00 J"
    assert references_line("truav", {"episodes": [{"coverage_pct": None, "pdr": None}]}, None, "x", False) == \
        "coverage no data, PDR no data (references not computed: x)"
