"""Issue 56: the learner cloned from the climbing heuristic (agents.ppo_agent.PpoClaimAgent) is a built-in scheme as
``claim`` and ``ppo`` are: registered as ``ppo-claim`` (entry-point group truav.agents), flown with its sensing on
wherever a run leaves sensing off, and taken by name by `truav evaluate --against` and `truav-swarm up --agent`."""

from __future__ import annotations

from agents.ppo_agent import PpoClaimAgent
from agents.spread_agent import SENSE_RANGE_M, with_sensing
from truav.analysis import agent_loader
from truav.config import Config
from truav.swarm.swarm_options import SENSING_AGENTS, with_agent_sensing

SENSED = Config().replace(learner={"sense_range_m": SENSE_RANGE_M})


def test_ppo_claim_is_registered_as_an_agent_class() -> None:
    assert agent_loader.registered()["ppo-claim"] == "agents.ppo_agent:PpoClaimAgent"
    assert agent_loader.load("ppo-claim", SENSED) is PpoClaimAgent


def test_comparisons_and_swarms_fly_it_with_its_sensing_on() -> None:
    for name in ("ppo-claim", "agents.ppo_agent:PpoClaimAgent"):
        assert with_sensing(name, Config()).learner.sense_range_m == SENSE_RANGE_M, name
    assert "ppo-claim" in SENSING_AGENTS
    assert with_agent_sensing("agent:ppo-claim", Config()).learner.sense_range_m == SENSE_RANGE_M


def test_the_command_lines_take_it_by_name(tmp_path) -> None:
    from truav.cli.main import _against_kinds
    assert _against_kinds(["ppo-claim"], Config(), "truav") == {"ppo-claim": "agent:ppo-claim"}
    from truav.cli.swarm import build_parser as swarm_parser
    from truav.cli.swarm_up import swarm_options
    cfg, opts = swarm_options(swarm_parser().parse_args(["up", "--out", str(tmp_path / "a"), "--agent", "ppo-claim"]))
    assert opts.scheme == "agent:ppo-claim" and cfg.learner.sense_range_m == SENSE_RANGE_M


def test_reports_name_it_in_a_colour_of_its_own() -> None:
    from truav.experiments.report import SCHEME_STYLE
    assert "ppo-claim" in SCHEME_STYLE["ppo-claim"][0] and SCHEME_STYLE["ppo-claim"][1] not in {
        c for k, (_, c, _) in SCHEME_STYLE.items() if k != "ppo-claim"}
