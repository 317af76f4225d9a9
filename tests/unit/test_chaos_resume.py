"""Which of a chaos run's two runs `chaos --resume` keeps: a finished one made with the same settings; other
settings are refused in one line, and an earlier chaos run that recorded none keeps nothing."""

import dataclasses
import json

import pytest

from truav.config import load_config
from truav.swarm.chaos_resume import Progress, kept_runs, settings, start_fresh_comparison
from truav.swarm.outdir import OutDirError
from truav.swarm.swarm_options import SwarmOptions


def _summary(result="ok", episodes=2, interrupted=False) -> str:
    return json.dumps({"interrupted": interrupted, "outcome": {"result": result},
                       "world": {"episodes": [{"coverage_pct": 1.0}] * episodes}})


def _chaos_dir(tmp_path, baseline: str | None, faulted: str | None):
    plan = tmp_path / "plan.toml"
    plan.write_text('[[fault]]\nkind = "loss"\nstart = 0.0\nprobability = 0.3\nkeys = "uav/*/beacon"\n')
    out = tmp_path / "chaos"
    for name, text in (("baseline", baseline), ("faulted", faulted)):
        (out / name).mkdir(parents=True)
        if text is not None:
            (out / name / "summary.json").write_text(text)
    return out, plan


def test_resume_keeps_only_a_finished_run_made_with_the_same_settings(tmp_path):
    out, plan = _chaos_dir(tmp_path, _summary(), _summary("interrupted", 1, True))
    cfg, opts = load_config(), SwarmOptions(seed=3, episodes=2, lockstep=True)
    now = settings(cfg, opts, str(plan))
    assert kept_runs(out, now, 2) == {}  # no settings recorded: nothing is kept
    (out / "degradation.txt").write_text("an earlier comparison")
    start_fresh_comparison(out, now)
    assert not (out / "degradation.txt").exists()  # made again from the two runs at the end
    assert kept_runs(out, now, 2) == {"baseline": _summary()}  # the interrupted faulted run is made again
    # options that leave the numbers as they are may change
    assert kept_runs(out, settings(cfg, dataclasses.replace(opts, quiet=True, run="other"), str(plan)), 2)
    with pytest.raises(OutDirError, match=r"^--resume: --out .* other settings \(seed differs "):
        kept_runs(out, settings(cfg, dataclasses.replace(opts, seed=4), str(plan)), 2)
    with pytest.raises(OutDirError, match=r"\(scenario differs "):
        kept_runs(out, settings(cfg.replace(scenario={"n_uavs": 3}), opts, str(plan)), 2)
    plan.write_text(plan.read_text().replace("0.3", "0.4"))
    with pytest.raises(OutDirError, match=r"\(plan differs "):
        kept_runs(out, settings(cfg, opts, str(plan)), 2)


def test_the_stopped_line_names_the_run_and_what_is_kept():
    progress = Progress(stage="the faulted run", finished=["baseline"])
    assert progress.stopped_line(False) == ("truav-swarm: interrupted in the faulted run (the baseline run finished "
                                            "and kept); run the same command with --resume to continue")
    assert progress.stopped_line(True).endswith("; run the same command again to continue")
