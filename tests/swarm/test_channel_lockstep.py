"""A channel model other than the paper's reaches the world process: a lock-step swarm under
TR 36.777 UMa-AV learns the in-process trainer's Q-tables entry for entry, and its world reports
the trainer's delays (which the channel sets)."""

from __future__ import annotations

import json

import numpy as np

from tests.support.lockstep import CFG, METRICS, SEED, agent_tables, run_swarm
from truav.analysis.trainer import run_chunk


def test_lockstep_swarm_under_3gpp_uma_av_equals_the_trainer(tmp_path):
    cfg = CFG.replace(scenario={"n_uavs": 3}, learner={"episodes": 6}, channel={"model": "3gpp-uma-av"})
    expected = run_chunk("truav", cfg, [SEED], cfg.learner.episodes)
    paper = run_chunk("truav", cfg.replace(channel={"model": "paper"}), [SEED], cfg.learner.episodes)
    assert not np.array_equal(expected.metrics["delay_ms"], paper.metrics["delay_ms"])  # the model matters here
    out = run_swarm(tmp_path, "uma-av", cfg=cfg)
    q, _ = agent_tables(out, cfg)
    assert np.array_equal(q, expected.q[0])
    world = json.loads((out / "world.json").read_text())
    for e, got in enumerate(world["episodes"]):
        for k in METRICS:
            assert np.array_equal(got[k], expected.metrics[k][e, 0], equal_nan=True), (e, k)
