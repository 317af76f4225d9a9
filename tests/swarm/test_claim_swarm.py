"""The climbing heuristic on the bus: `truav-swarm up --lockstep --agent claim` (one agent process per UAV, the
per-UAV form, goals claimed in the beacons over Zenoh) flies what the in-process greedy evaluation (its batched
form) flies: the same action at every step, the same metrics and end positions."""

from __future__ import annotations

import json

import numpy as np

from agents.api_controller import ApiController
from agents.claim_agent import ClaimAgent
from agents.spread_agent import with_sensing
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


def test_lockstep_swarm_of_claim_equals_the_in_process_run(tmp_path, monkeypatch):
    cfg = with_sensing("claim", agent_api_swarm.CFG)
    rec = _Seen(ApiController("claim", ClaimAgent, cfg, [SEED], train=False))
    expected = run_episodes(cfg, [SEED], rec, EPISODES)
    assert len(rec.seen) > 1  # it flies, not one action
    monkeypatch.setattr(agent_api_swarm, "CFG", cfg)  # the swarm's scenario file: the same config, sensing on
    out = agent_api_swarm.up(tmp_path, "claim", "--agent", "claim", "--greedy")
    world = json.loads((out / "world.json").read_text())
    assert world["deadline_misses"] == 0
    assert world["actions_digest"] == rec.digests  # every action of every step
    assert np.array_equal(np.array(world["end_positions"]), np.array(rec.end_pos))
    for e, got in enumerate(world["episodes"]):
        for k in METRICS:
            assert np.array_equal(got[k], expected[k][e, 0], equal_nan=True), (e, k)
