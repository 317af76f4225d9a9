"""The learned policy on the bus: `truav-swarm up --lockstep --agent ppo` (one agent process per UAV, the numpy
network of agents.ppo_policy on each UAV's encoded view) flies what the in-process greedy evaluation flies: the
same action at every step, the same metrics and end positions."""

from __future__ import annotations

from agents.ppo_agent import PpoAgent
from tests.support import agent_api_swarm


def test_lockstep_swarm_of_the_learned_policy_equals_the_in_process_run(tmp_path):
    cfg = agent_api_swarm.CFG.replace(learner={"sense_range_m": 1500.0})  # the sensing it was trained with
    agent_api_swarm.assert_swarm_flies_as_in_process(tmp_path, "ppo", PpoAgent, cfg, moves=True)
