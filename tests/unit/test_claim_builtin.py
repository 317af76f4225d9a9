"""Issue 56: the climbing heuristic (agents/claim_agent.py) is a built-in scheme as ``spread`` is: registered as
``claim`` (entry-point group truav.agents), flown with its sensing on wherever a run leaves sensing off, and taken
by name by `truav evaluate --against`, `truav train --agent`, `truav experiment velocity|scale --schemes`,
`truav experiment faults --schemes` and `truav-swarm up --agent`; the comparisons' defaults are as they were, and
the demo's summary puts its coverage beside this heuristic's (truav.swarm.references)."""

from __future__ import annotations

import pytest

from agents.claim_agent import ClaimAgent
from agents.spread_agent import SENSE_RANGE_M, with_sensing
from truav.analysis import agent_loader
from truav.cli.args import UserError
from truav.config import Config
from truav.swarm.swarm_options import DEMO_AGENT, SENSING_AGENTS, with_agent_sensing


def test_claim_is_registered_as_an_agent_class() -> None:
    assert agent_loader.registered()["claim"] == "agents.claim_agent:ClaimAgent"
    assert agent_loader.load("claim", Config().replace(learner={"sense_range_m": SENSE_RANGE_M})) is ClaimAgent


def test_comparisons_and_swarms_fly_it_with_its_sensing_on() -> None:
    for name in ("claim", "agents.claim_agent:ClaimAgent"):
        assert with_sensing(name, Config()).learner.sense_range_m == SENSE_RANGE_M, name
    assert with_sensing("claim", Config().replace(learner={"sense_range_m": 2000.0})).learner.sense_range_m == 2000.0
    assert "claim" in SENSING_AGENTS
    assert with_agent_sensing("agent:claim", Config()).learner.sense_range_m == SENSE_RANGE_M
    from truav.experiments.cells import Cell
    assert Cell("claim", 15.0, (0,), 1, 1).config(Config()).learner.sense_range_m == SENSE_RANGE_M


def test_the_command_lines_take_it_by_name(tmp_path) -> None:
    from truav.cli.main import _against_kinds, build_parser
    from truav.cli.experiment import _check_schemes
    assert _against_kinds(["claim", "spread"], Config(), "truav") == {"claim": "agent:claim", "spread": "agent:spread"}
    parser = build_parser()
    for argv in (["experiment", "velocity", "--schemes", "claim", "spread"],
                 ["experiment", "scale", "--schemes", "claim"]):
        args = parser.parse_args(argv)
        assert "claim" in args.schemes
        _check_schemes(args.schemes, Config())  # found and checked: no UserError
    assert parser.parse_args(["train", "--agent", "claim"]).agent == "claim"
    from truav.cli.swarm import build_parser as swarm_parser
    from truav.cli.swarm_up import swarm_options
    cfg, opts = swarm_options(swarm_parser().parse_args(["up", "--out", str(tmp_path / "a"), "--agent", "claim"]))
    assert opts.scheme == "agent:claim" and cfg.learner.sense_range_m == SENSE_RANGE_M
    with pytest.raises(UserError, match="registered: .*claim"):  # the one-line error lists it
        agent_loader.resolve("claim2")


def test_comparison_defaults_are_as_they_were_and_the_demo_references_claim() -> None:
    from truav.cli.main import build_parser
    from truav.experiments import scale, velocity
    from truav.swarm.references import REFERENCE_SCHEMES
    parser = build_parser()
    assert parser.parse_args(["experiment", "velocity"]).schemes == list(velocity.SCHEMES)
    assert velocity.SCHEMES == ("truav", "central", "patrol", "spread")
    assert scale.SCHEMES == ("truav", "central", "spread")
    assert REFERENCE_SCHEMES == ("hover", "claim", "patrol")
    assert DEMO_AGENT == "ppo-claim"


def test_reports_name_it() -> None:
    from truav.experiments.report import SCHEME_STYLE
    assert "claim" in SCHEME_STYLE["claim"][0] and SCHEME_STYLE["claim"][1] not in {
        c for k, (_, c, _) in SCHEME_STYLE.items() if k != "claim"}  # a colour of its own
