"""The agent API's lock-step swarms (tests/swarm/test_agent_api_swarm.py, test_deep_iql_swarm.py): a small
4-UAV scenario and ``up``, a `truav-swarm up --lockstep` of it run to its end; ``assert_swarm_flies_as_in_process``,
the check of an agent class on the bus against its in-process run (test_spread_swarm.py, test_ppo_swarm.py,
test_claim_swarm.py)."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import numpy as np

from agents.api_controller import ApiController
from tests.support.lockstep import Recorder
from tests.support.runs import run_to_end
from truav.analysis.driver import run_episodes
from truav.config import Config, to_toml
from tests.support.swarm_up import learners

SEED = 4
EPISODES = 4
CFG = Config().replace(scenario={"n_vehicles": 60, "steps_per_episode": 10, "n_uavs": 4}, roads={"warmup_steps": 10})
SWARM_TIMEOUT_S = 240.0
METRICS = ("coverage_pct", "pdr", "delay_ms", "energy_j", "generated", "delivered", "dropped")


def up(tmp: Path, name: str, *extra: str, env: dict | None = None, cli_default: bool = False,
       cfg: Config | None = None) -> Path:
    """The run's --out; ``cli_default``: no --scheme added (`up`'s own default), else --scheme truav unless
    ``extra`` chooses (swarm_up.learners); ``cfg``: the scenario file's config (default CFG)."""
    scenario = tmp / f"{name}.toml"
    scenario.write_text(to_toml(CFG if cfg is None else cfg))
    out = tmp / name
    cmd = [sys.executable, "-m", "truav.cli.swarm", "up", *([] if cli_default else learners(extra)),
           "--lockstep", "--seed", str(SEED), "--run", name,
           "--episodes", str(EPISODES), "--scenario", str(scenario), "--out", str(out), "--quiet", "--no-plot", *extra]
    rc = run_to_end(cmd, tmp / f"{name}.log", SWARM_TIMEOUT_S, env=env or dict(os.environ), term_wait_s=30)
    assert rc == 0, (tmp / f"{name}.log").read_text(errors="replace")
    return out


class SeenRecorder(Recorder):
    """A Recorder that also keeps the actions it saw."""

    def __init__(self, inner):
        super().__init__(inner)
        self.seen: set = set()

    def act(self, t):
        actions = super().act(t)
        self.seen |= set(np.ravel(actions).tolist())
        return actions


def assert_swarm_flies_as_in_process(tmp: Path, name: str, agent_cls, cfg: Config, *, moves: bool = False,
                                     agent: str | None = None) -> None:
    """`up --lockstep --agent NAME --greedy` on ``cfg`` flies what the in-process greedy run of ``agent_cls`` flies:
    the same action at every step (no deadline missed), the same metrics and end positions; ``moves``: and the
    in-process run gives more than one action (it flies, it does not hover); ``agent``: --agent's value if not
    NAME (a class path; NAME then names the run)."""
    rec = SeenRecorder(ApiController(name, agent_cls, cfg, [SEED], train=False))
    expected = run_episodes(cfg, [SEED], rec, EPISODES)
    if moves:
        assert len(rec.seen) > 1, rec.seen
    out = up(tmp, name, "--agent", agent or name, "--greedy", cfg=cfg)
    world = json.loads((out / "world.json").read_text())
    assert world["deadline_misses"] == 0  # (a heuristic's hovers are its own: HOVER answers, counted by the world)
    assert world["actions_digest"] == rec.digests  # every action of every step
    assert np.array_equal(np.array(world["end_positions"]), np.array(rec.end_pos))
    for e, got in enumerate(world["episodes"]):
        for k in METRICS:
            assert np.array_equal(got[k], expected[k][e, 0], equal_nan=True), (e, k)
