"""The learner cloned with the claim features on the bus: `truav-swarm up --lockstep --agent ppo-claim`
(agents.ppo_agent:PpoClaimAgent; one agent process per UAV, each running the climbing heuristic's rule beside its
network and saying its claimed goal in its beacon) flies what the in-process greedy run flies."""

from __future__ import annotations

from agents.ppo_agent import PpoClaimAgent
from tests.support import agent_api_swarm


def test_lockstep_swarm_of_the_claim_learner_equals_the_in_process_run(tmp_path):
    cfg = agent_api_swarm.CFG.replace(learner={"sense_range_m": 1500.0})  # the sensing it was trained with
    agent_api_swarm.assert_swarm_flies_as_in_process(tmp_path, "ppo-claim", PpoClaimAgent, cfg, moves=True,
                                                     agent="ppo-claim")
