"""Issue 56, "a first run that shows it": `truav-swarm up` (the README's command 1) flies the learned
decentralized policy (ppo-claim, the clone of the climbing heuristic, with the sensing it was trained with) unless
told otherwise, learning from scratch (`--scheme truav`) a flag away; its summary puts its coverage beside hover's and
the stronger heuristic's (claim) on one line."""

from __future__ import annotations

import pytest

from agents.spread_agent import SENSE_RANGE_M
from truav.cli.swarm import build_parser
from truav.cli.swarm_up import swarm_options
from truav.config import Config
from truav.swarm.references import references_for, references_line
from truav.swarm.swarm_options import DEMO_AGENT, DEMO_SCHEME


def _options(*argv: str):
    return swarm_options(build_parser().parse_args(list(argv)))


def test_the_demo_flies_the_learned_policy_with_its_sensing_by_default(tmp_path) -> None:
    assert DEMO_AGENT == "ppo-claim" and DEMO_SCHEME == "agent:ppo-claim"
    cfg, opts = _options("up", "--out", str(tmp_path / "a"))
    assert opts.scheme == DEMO_SCHEME
    assert cfg.learner.sense_range_m == SENSE_RANGE_M  # ppo-claim was trained with 1.5 km sensing
    assert cfg.scenario == Config().scenario  # the scenario itself is the defaults'


@pytest.mark.parametrize("argv, scheme", [(["--scheme", "truav"], "truav"), (["--agent", "truav"], "agent:truav")])
def test_learning_from_scratch_is_a_flag_away(tmp_path, argv, scheme) -> None:
    cfg, opts = _options("up", "--out", str(tmp_path / "a"), *argv)
    assert opts.scheme == scheme
    assert cfg.learner.sense_range_m == 0.0  # as before: the Q-learners' scenario, sensing off


def test_other_schemes_and_agents_are_chosen_as_before(tmp_path) -> None:
    assert _options("up", "--out", str(tmp_path / "a"), "--scheme", "patrol")[1].scheme == "patrol"
    cfg, opts = _options("up", "--out", str(tmp_path / "b"), "--agent", "spread")
    assert opts.scheme == "agent:spread" and cfg.learner.sense_range_m == SENSE_RANGE_M  # it needs its sensing
    cfg, opts = _options("up", "--out", str(tmp_path / "c"), "--agent", "ppo", "--set", "learner.sense_range_m=2000")
    assert cfg.learner.sense_range_m == 2000.0  # the user's own sensing wins
    # chaos runs TRUAV's learners as before
    assert _options("chaos", "--out", str(tmp_path / "d"))[1].scheme == "truav"


def test_the_help_says_the_default_and_the_flag_that_learns_from_scratch() -> None:
    up = build_parser()._subparsers._group_actions[0].choices["up"]
    text = " ".join(up.format_help().split())
    assert "default: agent:ppo-claim" in text and "--scheme truav" in text and "from scratch" in text


def test_the_summary_line_puts_the_swarm_beside_hover_and_the_heuristic() -> None:
    cfg = Config().replace(scenario={"n_vehicles": 40, "steps_per_episode": 40}, roads={"warmup_steps": 5})
    world = {"episodes": [{"coverage_pct": 30.0, "pdr": 0.5}, {"coverage_pct": 32.0, "pdr": 0.52}]}
    refs, why = references_for(cfg, DEMO_SCHEME, 0, world, True)
    assert why is None and {"hover", "claim", "patrol"} <= set(refs)
    first = references_line(DEMO_SCHEME, world, refs, None, faults=False).splitlines()[0]
    assert first.startswith("coverage: this swarm (agent:ppo-claim) 31.0%, hover ")
    assert f"hover {refs['hover']['coverage_pct']:.1f}%" in first
    assert f"the heuristic claim {refs['claim']['coverage_pct']:.1f}%" in first


def test_a_q_table_run_without_a_scheme_is_told_to_add_scheme_truav(tmp_path, capsys) -> None:
    """The demo's old habit, `up --qtable RUN` of a `truav train` run, is one line naming the flag that flies it."""
    from truav.cli.swarm import main
    run = tmp_path / "run"
    run.mkdir()
    (run / "qtables.npz").write_bytes(b"")  # what marks a `truav train` run; never read: the line comes first
    assert main(["up", "--qtable", str(run), "--greedy", "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--qtable" in err[0] and "add --scheme truav" in err[0], err
