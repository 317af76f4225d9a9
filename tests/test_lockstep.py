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
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np

from agents.agent_process import DELAY_ENV
from truav.config import Config, to_toml
from truav.trainer import run_chunk

SEED = 3
EPISODES = 30
CFG = Config().replace(scenario={"n_vehicles": 60, "steps_per_episode": 10, "n_uavs": 5},
                       roads={"warmup_steps": 10}, learner={"episodes": EPISODES})
SWARM_TIMEOUT_S = 180.0
METRICS = ("coverage_pct", "pdr", "delay_ms", "energy_j", "generated", "delivered", "dropped")


def run_swarm(tmp: Path, name: str, delay: str = "") -> Path:
    """One lock-step `truav-swarm up` run; its output directory."""
    scenario = tmp / f"{name}.toml"
    scenario.write_text(to_toml(CFG))
    out = tmp / name
    env = {**os.environ, DELAY_ENV: delay}
    cmd = [sys.executable, "-m", "truav.swarm.cli", "up", "--lockstep", "--seed", str(SEED), "--run", name,
           "--episodes", str(EPISODES), "--scenario", str(scenario), "--out", str(out), "--quiet", "--no-plot"]
    with open(tmp / f"{name}.log", "wb") as log:
        proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=env)
    try:
        rc = proc.wait(timeout=SWARM_TIMEOUT_S)
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)  # the supervisor stops every process it started
            try:
                proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=10)
    assert rc == 0, (tmp / f"{name}.log").read_text(errors="replace")
    return out


def agent_tables(out: Path) -> tuple[np.ndarray, list[int]]:
    """(q (U, S, 16), steps learned per agent) from the agents' final checkpoints."""
    qs, steps = [], []
    for i in range(CFG.scenario.n_uavs):
        with np.load(out / f"agent{i}.npz") as ck:
            qs.append(ck["q"])
            steps.append(int(ck["steps"]))
    return np.stack(qs), steps


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
