"""The agent API's lock-step swarms (tests/swarm/test_agent_api_swarm.py, test_deep_iql_swarm.py): a small
4-UAV scenario and ``up``, a `truav-swarm up --lockstep` of it run to its end."""

from __future__ import annotations

import os
import sys
from pathlib import Path

from tests.support.runs import run_to_end
from truav.config import Config, to_toml
from tests.support.swarm_up import learners

SEED = 4
EPISODES = 4
CFG = Config().replace(scenario={"n_vehicles": 60, "steps_per_episode": 10, "n_uavs": 4}, roads={"warmup_steps": 10})
SWARM_TIMEOUT_S = 240.0
METRICS = ("coverage_pct", "pdr", "delay_ms", "energy_j", "generated", "delivered", "dropped")


def up(tmp: Path, name: str, *extra: str, env: dict | None = None, cli_default: bool = False) -> Path:
    """The run's --out; ``cli_default``: no --scheme added (`up`'s own default), else --scheme truav unless
    ``extra`` chooses (swarm_up.learners)."""
    scenario = tmp / f"{name}.toml"
    scenario.write_text(to_toml(CFG))
    out = tmp / name
    cmd = [sys.executable, "-m", "truav.cli.swarm", "up", *([] if cli_default else learners(extra)),
           "--lockstep", "--seed", str(SEED), "--run", name,
           "--episodes", str(EPISODES), "--scenario", str(scenario), "--out", str(out), "--quiet", "--no-plot", *extra]
    rc = run_to_end(cmd, tmp / f"{name}.log", SWARM_TIMEOUT_S, env=env or dict(os.environ), term_wait_s=30)
    assert rc == 0, (tmp / f"{name}.log").read_text(errors="replace")
    return out
