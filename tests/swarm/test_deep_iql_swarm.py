"""The deep learner (agents.deep_iql) on the bus: a lock-step `truav-swarm up --agent` of it (one agent process
per UAV, each its per-UAV form) flies what `truav train --agent` of it (its batched form) flies, episode for
episode, and every agent process ends with the state training ends with: network, target, Adam moments,
replay buffer, counters and generator, array for array."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from tests.support import small_iql
from tests.support.agent_api_swarm import CFG, EPISODES, METRICS, SEED, up


def test_a_lockstep_swarm_of_the_deep_learner_ends_with_the_state_training_reaches(tmp_path):
    import sys
    from truav.analysis.trainer import run_chunk
    mods = tmp_path / "mods"
    mods.mkdir()
    (mods / "smalliql.py").write_text(Path(small_iql.__file__).read_text())  # for the agent processes
    sys.path.insert(0, str(mods))
    try:
        trained = run_chunk("agent:smalliql:Small", CFG, [SEED], EPISODES)  # the batched form, in process
    finally:
        sys.path.remove(str(mods))
        sys.modules.pop("smalliql", None)
    assert trained.policy["updates"][0, 0] > 0
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(mods), os.environ.get("PYTHONPATH", "")])}
    out = up(tmp_path, "deepiql", "--agent", "smalliql:Small", env=env)
    world = json.loads((out / "world.json").read_text())
    assert world["deadline_misses"] == 0 and world["hover_answers"] == 0
    for e, got in enumerate(world["episodes"]):
        for k in METRICS:
            assert np.array_equal(got[k], trained.metrics[k][e, 0], equal_nan=True), (e, k)
    for uav in range(CFG.scenario.n_uavs):
        with np.load(out / f"agent{uav}.npz") as ck:
            names = {k[len("state."):] for k in ck.files if k.startswith("state.")}
            assert names == set(trained.policy), uav
            for k in names:
                assert np.array_equal(ck[f"state.{k}"], trained.policy[k][0, uav]), (uav, k)
