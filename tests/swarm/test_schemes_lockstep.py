"""The baselines on the bus fly exactly what the in-process driver flies: a lock-step
`truav-swarm up --scheme patrol` (agent processes flying the patrol plan) and
`--scheme central` (a controller process commanding every UAV, a fixed trained
actor) give, episode for episode, the in-process run's metrics, the same actions at
every step (the world's per-episode digest of them) and the same UAV positions.

Each swarm is one `truav-swarm up` process on a free loopback port; its supervisor
starts and reaps every process; the test stops it only if it overruns.
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.support.runs import run_to_end
from truav.analysis.driver import run_episodes
from truav.config import Config, to_toml
from truav.wire import keys, schema
from tests.support.lockstep import Recorder
from tests.support.swarm_up import learners

SEED = 4
EPISODES = 4
CFG = Config().replace(scenario={"n_vehicles": 60, "steps_per_episode": 10, "n_uavs": 4},
                       roads={"warmup_steps": 10}, central={"hidden": 16})
SWARM_TIMEOUT_S = 240.0
METRICS = ("coverage_pct", "pdr", "delay_ms", "energy_j", "generated", "delivered", "dropped")


def up(tmp: Path, name: str, *extra: str) -> Path:
    scenario = tmp / f"{name}.toml"
    scenario.write_text(to_toml(CFG))
    out = tmp / name
    cmd = [sys.executable, "-m", "truav.cli.swarm", "up", *learners(extra), "--lockstep", "--seed", str(SEED), "--run", name,
           "--episodes", str(EPISODES), "--scenario", str(scenario), "--out", str(out), "--quiet", "--no-plot", *extra]
    rc = run_to_end(cmd, tmp / f"{name}.log", SWARM_TIMEOUT_S, env=dict(os.environ), term_wait_s=30)
    assert rc == 0, (tmp / f"{name}.log").read_text(errors="replace")
    return out


def assert_same_run(out: Path, expected: dict, rec: Recorder) -> dict:
    world = json.loads((out / "world.json").read_text())
    assert world["deadline_misses"] == 0 and world["hover_answers"] == 0
    assert len(world["episodes"]) == EPISODES
    assert world["actions_digest"] == rec.digests  # every action of every step
    assert np.array_equal(np.array(world["end_positions"]), np.array(rec.end_pos))
    for e, got in enumerate(world["episodes"]):
        for k in METRICS:
            assert np.array_equal(got[k], expected[k][e, 0], equal_nan=True), (e, k)
    return world


def test_lockstep_patrol_swarm_equals_the_in_process_patrol(tmp_path):
    from agents.patrol import PatrolController
    inner = PatrolController(CFG, [SEED])
    inner.fused = False  # step by step, to see each action (the fused kernel is tested equal to it)
    rec = Recorder(inner)
    expected = run_episodes(CFG, [SEED], rec, EPISODES)
    out = up(tmp_path, "patrol", "--scheme", "patrol")
    assert_same_run(out, expected, rec)
    agents = [json.loads((out / f"agent{i}.json").read_text()) for i in range(CFG.scenario.n_uavs)]
    assert all(a["deployments"] == EPISODES and a["deployments_incomplete"] == 0 for a in agents)


def test_lockstep_central_swarm_equals_the_in_process_central_driver(tmp_path):
    """A controller process flying a fixed trained actor, UAVs uploading their state and flying its
    commands, the world applying the control-plane model: the in-process central driver's run."""
    pytest.importorskip("torch")
    from agents.central import CentralController
    from truav.analysis import runio
    from truav.analysis.trainer import run_chunk
    policy_run = tmp_path / "policy"
    policy_run.mkdir()
    trained = run_chunk("central", CFG.replace(central={"learning_starts": 50}), [SEED], 8)
    runio.write_policy(policy_run, [SEED], trained.policy)
    rec = Recorder(CentralController(CFG, [SEED], train=False, params=runio.read_policy(policy_run, 0, CFG)))
    expected = run_episodes(CFG, [SEED], rec, EPISODES)
    out = up(tmp_path, "central", "--scheme", "central", "--policy", str(policy_run))
    world = assert_same_run(out, expected, rec)
    for e, got in enumerate(world["episodes"]):  # the modelled control plane, as the in-process driver counts it
        for k in ("ctrl_up_bytes", "ctrl_down_bytes", "ctrl_airtime_s", "ctrl_delay_ms"):
            assert np.array_equal(got[k], expected[k][e, 0]), (e, k)
    agents = [json.loads((out / f"agent{i}.json").read_text()) for i in range(CFG.scenario.n_uavs)]
    steps = EPISODES * CFG.scenario.steps_per_episode
    assert [a["commands"] for a in agents] == [{"fresh": steps, "held": 0, "hovered": 0}] * CFG.scenario.n_uavs
    summary = json.loads((out / "summary.json").read_text())
    cp = summary["control_plane"]  # real messages of the model's sizes crossed the bus
    assert cp["bytes_per_state"] == CFG.central.upload_bytes
    # A command's envelope alone, with its incarnation, is 86-89 B (by the tick's width): longer than the
    # model's 78 B, so commands go unpadded.
    size = [len(schema.encode(schema.Command(uav=0, tick=tick, action=0, pad=b"", src=keys.SRC_CONTROLLER,
                                             t=1 << 60, inc=1 << 62))) for tick in (0, 65535)]
    model = CFG.central.download_bytes
    assert max(size[0], model) <= cp["bytes_per_command"] <= max(size[1], model)
    assert cp["commands"] == steps * CFG.scenario.n_uavs
