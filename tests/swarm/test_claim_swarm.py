"""The climbing heuristic on the bus: `truav-swarm up --lockstep --agent claim` (one agent process per UAV, the
per-UAV form, goals claimed in the beacons over Zenoh) flies what the in-process greedy evaluation (its batched
form) flies: the same action at every step, the same metrics and end positions."""

from __future__ import annotations

from agents.claim_agent import ClaimAgent
from agents.spread_agent import with_sensing
from tests.support import agent_api_swarm


def test_lockstep_swarm_of_claim_equals_the_in_process_run(tmp_path):
    cfg = with_sensing("claim", agent_api_swarm.CFG)  # the swarm's scenario file: the same config, sensing on
    agent_api_swarm.assert_swarm_flies_as_in_process(tmp_path, "claim", ClaimAgent, cfg, moves=True)
