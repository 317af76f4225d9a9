"""Lock-step `truav-swarm up` runs of a small scenario and the agents' final Q-tables (swarm tier)."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np

from world.process.world_process import action_digest

from agents.process.agent_process import DELAY_ENV
from tests.support.runs import run_to_end
from truav.config import Config, to_toml

METRICS = ("coverage_pct", "pdr", "delay_ms", "energy_j", "generated", "delivered", "dropped")
"""The per-episode metrics a lock-step swarm and the trainer must agree on."""
SEED = 3
EPISODES = 30
CFG = Config().replace(scenario={"n_vehicles": 60, "steps_per_episode": 10, "n_uavs": 5},
                       roads={"warmup_steps": 10}, learner={"episodes": EPISODES})
SWARM_TIMEOUT_S = 180.0


def run_swarm(tmp: Path, name: str, delay: str = "", cfg: Config = CFG) -> Path:
    """One lock-step `truav-swarm up` run; its output directory."""
    scenario = tmp / f"{name}.toml"
    scenario.write_text(to_toml(cfg))
    out = tmp / name
    env = {**os.environ, DELAY_ENV: delay}
    cmd = [sys.executable, "-m", "truav.cli.swarm", "up", "--scheme", "truav", "--lockstep", "--seed", str(SEED), "--run", name,
           "--episodes", str(cfg.learner.episodes), "--scenario", str(scenario), "--out", str(out), "--quiet", "--no-plot"]
    rc = run_to_end(cmd, tmp / f"{name}.log", SWARM_TIMEOUT_S, env=env, term_wait_s=30)
    assert rc == 0, (tmp / f"{name}.log").read_text(errors="replace")
    return out


def agent_tables(out: Path, cfg: Config = CFG) -> tuple[np.ndarray, list[int]]:
    """(q (U, S, 16), steps learned per agent) from the agents' final checkpoints."""
    qs, steps = [], []
    for i in range(cfg.scenario.n_uavs):
        with np.load(out / f"agent{i}.npz") as ck:
            qs.append(ck["q"])
            steps.append(int(ck["steps"]))
    return np.stack(qs), steps


class Recorder:
    """Wraps a driver controller: the digest of the actions it gives the world, and where the UAVs end."""

    def __init__(self, inner):
        self.inner, self.digests, self.end_pos = inner, [], []
        if hasattr(inner, "control"):
            self.control = inner.control

    def begin_episode(self, episode, obs):
        self._digest = action_digest()
        self.inner.begin_episode(episode, obs)

    def act(self, t):
        actions = self.inner.act(t)
        self._digest.update(np.ascontiguousarray(actions[0], np.int64).tobytes())
        return actions

    def observe(self, obs, done):
        self.inner.observe(obs, done)
        if done:
            self.digests.append(self._digest.hexdigest())
            self.end_pos.append(obs.pos[0].tolist())

    def episode_stats(self):
        return self.inner.episode_stats()
