"""Exact lock-step: `truav-swarm up --lockstep` learns exactly what the in-process trainer learns.

Two swarms of 5 agents run 30 short episodes with the same seed, one of them with
agent 2 deliberately slowed (TRUAV_AGENT_DELAY_MS), so that its peers are always
ahead of it: the episode's `done` observation, the next episode's first tick and
the shutdown are where a fast peer could overtake a slow one. Every agent's final
Q-table must equal the other run's and the trainer's, entry for entry, and the
world's episode metrics the trainer's.

Each swarm is one `truav-swarm up` process on a free loopback port; its supervisor
starts and reaps the router, world and agents; the test stops it (SIGTERM, then
SIGKILL) only if it overruns.
"""

from __future__ import annotations

import json

import numpy as np

from tests.support.lockstep import CFG, EPISODES, METRICS, SEED, agent_tables, run_swarm
from truav.analysis import runio
from truav.analysis.trainer import run_chunk


def test_lockstep_runs_and_trainer_learn_identical_q_tables(tmp_path):
    # In-process first: it also fills numba's cache for the processes below.
    expected = run_chunk("truav", CFG, [SEED], EPISODES)
    q_expected = expected.q[0]
    slowed = run_swarm(tmp_path, "slowed", delay="2:25")
    plain = run_swarm(tmp_path, "plain")
    steps_expected = [EPISODES * CFG.scenario.steps_per_episode] * CFG.scenario.n_uavs
    for out in (slowed, plain):
        q, steps = agent_tables(out)
        assert steps == steps_expected, out  # every step learned from, the last episode's end included
        differing = [int(np.sum(q[i] != q_expected[i])) for i in range(len(q))]
        assert differing == [0] * len(q), f"{out.name}: entries differing from the trainer, per agent: {differing}"
        assert np.array_equal(q, q_expected)
        world = json.loads((out / "world.json").read_text())
        assert world["deadline_misses"] == 0
        assert len(world["episodes"]) == EPISODES
        for e, got in enumerate(world["episodes"]):
            for k in METRICS:
                assert np.array_equal(got[k], expected.metrics[k][e, 0], equal_nan=True), (out.name, e, k)
    assert np.array_equal(agent_tables(slowed)[0], agent_tables(plain)[0])


def test_lockstep_swarm_learns_the_trainers_tables_with_the_state_refinements(tmp_path):
    """The selectable state factors (nearest neighbour's direction, the densest
    direction the world senses and sends in Obs) reach the swarm agents: the
    same tables as the fused trainer, entry for entry."""
    cfg = CFG.replace(scenario={"n_uavs": 3}, learner={"episodes": 10, "grid_cells": 4, "neighbour_sectors": 4,
                                                        "sense_range_m": 1500.0, "sense_sectors": 4})
    expected = run_chunk("truav", cfg, [SEED], cfg.learner.episodes)
    out = run_swarm(tmp_path, "refined", cfg=cfg)
    q, steps = agent_tables(out, cfg)
    assert steps == [cfg.learner.episodes * cfg.scenario.steps_per_episode] * cfg.scenario.n_uavs
    assert q.shape[1] == 16 * 4 * 4 * 3 * 3 * 4 * 5  # the refined state space
    runio.write_qtables(tmp_path, [SEED], expected.q)  # what `truav train` writes: compared as it is, no cast
    with np.load(tmp_path / runio.QTABLE_FILE) as saved:
        assert saved["q"].dtype == q.dtype and np.array_equal(q, saved["q"][0])


def test_lockstep_swarm_learns_the_trainers_tables_with_the_reward_designs(tmp_path):
    """Issue 32's designs reach the swarm agents: the difference reward (from the world's
    Obs.exclusive), potential-based shaping and the prediction map's direction; persistent
    UAVs, so a map and the shaping's last density carry over episodes. Same tables as the
    fused trainer, entry for entry."""
    cfg = CFG.replace(scenario={"n_uavs": 3, "uav_start": "persist"},
                      learner={"episodes": 8, "grid_cells": 3, "w_coverage": 0.0, "w_overlap": 0.0,
                               "w_difference": 0.25, "w_shaping": 0.5, "predict_sectors": 4, "predict_cells": 5})
    expected = run_chunk("truav", cfg, [SEED], cfg.learner.episodes)
    out = run_swarm(tmp_path, "designs", cfg=cfg)
    q, steps = agent_tables(out, cfg)
    assert steps == [cfg.learner.episodes * cfg.scenario.steps_per_episode] * cfg.scenario.n_uavs
    assert q.shape[1] == 9 * 4 * 4 * 3 * 3 * 5  # the grid, the paper's four factors, the predicted direction
    differing = [int(np.sum(q[i] != expected.q[0][i])) for i in range(len(q))]
    assert differing == [0] * len(q), f"entries differing from the trainer, per agent: {differing}"
