"""The learned policy on the bus: `truav-swarm up --lockstep --agent ppo` (one agent process per UAV, the numpy
network of agents.ppo_policy on each UAV's encoded view) flies what the in-process greedy evaluation flies: the
same action at every step, the same metrics and end positions."""

from __future__ import annotations

import json

import numpy as np

from agents.api_controller import ApiController
from agents.ppo_agent import PpoAgent
from tests.support import agent_api_swarm
from tests.support.agent_api_swarm import EPISODES, METRICS, SEED
from tests.support.lockstep import Recorder
from truav.analysis.driver import run_episodes


class _Seen(Recorder):
    """A Recorder that also keeps the actions it saw."""

    seen: set = set()

    def act(self, t):
        actions = super().act(t)
        self.seen |= set(np.ravel(actions).tolist())
        return actions


def test_lockstep_swarm_of_the_learned_policy_equals_the_in_process_run(tmp_path, monkeypatch):
    cfg = agent_api_swarm.CFG.replace(learner={"sense_range_m": 1500.0})  # the sensing it was trained with
    rec = _Seen(ApiController("ppo", PpoAgent, cfg, [SEED], train=False))
    expected = run_episodes(cfg, [SEED], rec, EPISODES)
    assert len(rec.seen) > 1  # it flies, not one action
    monkeypatch.setattr(agent_api_swarm, "CFG", cfg)
    out = agent_api_swarm.up(tmp_path, "ppo", "--agent", "ppo", "--greedy")
    world = json.loads((out / "world.json").read_text())
    assert world["deadline_misses"] == 0
    assert world["actions_digest"] == rec.digests  # every action of every step
    assert np.array_equal(np.array(world["end_positions"]), np.array(rec.end_pos))
    for e, got in enumerate(world["episodes"]):
        for k in METRICS:
            assert np.array_equal(got[k], expected[k][e, 0], equal_nan=True), (e, k)
