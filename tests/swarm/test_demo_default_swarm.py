"""Issue 56: `truav-swarm up` given neither --scheme nor --agent (the README's command 1) flies the learned
policy (ppo-claim) with the sensing it was trained with: in lock-step, every action of every step equals the
in-process greedy run of agents.ppo_agent.PpoClaimAgent under the same scenario with learner.sense_range_m 1500; no
action is missed."""

from __future__ import annotations

import json

from agents.api_controller import ApiController
from agents.ppo_agent import PpoClaimAgent
from agents.spread_agent import SENSE_RANGE_M
from tests.support import agent_api_swarm
from tests.support.agent_api_swarm import EPISODES, SEED
from tests.support.lockstep import Recorder
from truav.analysis.driver import run_episodes


def test_up_without_a_scheme_flies_the_learned_policy_with_its_sensing(tmp_path):
    assert agent_api_swarm.CFG.learner.sense_range_m == 0.0  # the scenario file leaves sensing off
    cfg = agent_api_swarm.CFG.replace(learner={"sense_range_m": SENSE_RANGE_M})
    rec = Recorder(ApiController("ppo-claim", PpoClaimAgent, cfg, [SEED], train=False))
    run_episodes(cfg, [SEED], rec, EPISODES)
    out = agent_api_swarm.up(tmp_path, "default", cli_default=True)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["scheme"] == "agent:ppo-claim"
    world = json.loads((out / "world.json").read_text())
    assert world["actions_digest"] == rec.digests  # every action of every step
    # the live table's "missed actions" and the picture's "UAVs without an action" count only the UAVs the world
    # heard nothing from (none here); a hover the policy chooses (its 17th action) is an answer
    # (tests/swarm/test_agent_api_swarm.py and others check those)
    assert world["deadline_misses"] == 0
    assert sum(h for _, h in summary["timeline"]["hovering"]) == 0
