"""The learner that senses the densest disc on the bus: `truav-swarm up --lockstep --agent ppo-disc` at 5 m/s (one
agent process per UAV, each building its view's disc from the world's observation message) flies what the
in-process greedy run flies, action for action."""

from __future__ import annotations

from agents.ppo_agent import DISC_WEIGHTS, PpoDiscAgent
from tests.support import agent_api_swarm


def test_lockstep_swarm_of_the_disc_learner_equals_the_in_process_run(tmp_path):
    cfg = agent_api_swarm.CFG.replace(scenario={"uav_speed_mps": 5.0},
                                      learner={"sense_range_m": 1500.0, "sense_disc": True})
    assert PpoDiscAgent.weights_for(cfg) == DISC_WEIGHTS  # the disc network, not ppo-claim's
    agent_api_swarm.assert_swarm_flies_as_in_process(tmp_path, "ppo-disc", PpoDiscAgent, cfg, moves=True)
