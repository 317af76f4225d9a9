"""Lock-step keeps its promise under a paused agent: `truav-swarm up --lockstep` with agent 1
SIGSTOPped for 5 s (a fault plan's freeze) learns exactly the in-process trainer's tables (the
clean run of the same seed, as tests/swarm/test_lockstep.py shows); a pause beyond `--lockstep-wait`
makes the run say that it is no longer exact, from which tick and how many decisions, and exit 1.

Agent 0 is slowed a little per observation (TRUAV_AGENT_DELAY_MS) so that the run outlasts the
freeze however fast the machine is; a busy machine only makes it longer. Each swarm is one
`truav-swarm up` process whose supervisor reaps everything it started.
"""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

import numpy as np

from tests.support.runs import run_to_end
from agents.process.agent_process import AgentNode, AgentOptions, DELAY_ENV
from truav.analysis.trainer import run_chunk
from truav.config import Config, to_toml
from truav.wire import keys
from truav.wire.schema import LOCKSTEP_JOIN_GRACE_S
from tests.support.swarm_up import learners

SEED = 5
EPISODES = 40
# Every peer heard at any distance, and the nearest one's direction in the state: a decision taken
# without a peer's beacon then changes the state (and the table) nearly always.
CFG = Config().replace(scenario={"n_vehicles": 40, "steps_per_episode": 10, "n_uavs": 3, "comm_range_m": 1e5},
                       roads={"warmup_steps": 10}, learner={"episodes": EPISODES, "neighbour_sectors": 4})
SLOW = "0:20"  # 440 ticks x 20 ms: the ticking lasts at least 8.8 s, past any freeze below
SWARM_TIMEOUT_S = 240.0


def run_up(tmp: Path, name: str, freeze_s: float, *extra: str) -> tuple[int, Path, str]:
    scenario = tmp / f"{name}.toml"
    scenario.write_text(to_toml(CFG))
    plan = tmp / f"{name}-plan.toml"
    plan.write_text(f'[[fault]]\nkind = "freeze"\nstart = 1.0\nduration = {freeze_s}\nuav = 1\n')
    out = tmp / name
    cmd = [sys.executable, "-m", "truav.cli.swarm", "up", *learners(extra), "--lockstep", "--seed", str(SEED), "--run", name,
           "--episodes", str(EPISODES), "--scenario", str(scenario), "--out", str(out), "--fault-plan", str(plan),
           "--quiet", "--no-plot", *extra]
    log = tmp / f"{name}.log"
    rc = run_to_end(cmd, log, SWARM_TIMEOUT_S, env={**os.environ, DELAY_ENV: SLOW}, term_wait_s=30)
    return rc, out, log.read_text(errors="replace")


def assert_freeze_while_ticking(out: Path, freeze_s: float) -> None:
    """The freeze really happened mid-run: both its ends executed, and the ticking outlasted it."""
    summary = json.loads((out / "summary.json").read_text())
    phases = [(kind, phase) for _, kind, phase in summary["fault_events"]]
    assert ("freeze", "start") in phases and ("freeze", "end") in phases, summary["fault_events"]
    world = summary["world"]
    assert world["last_tick_wall_s"] - world["first_tick_wall_s"] > 1.0 + freeze_s, world


def test_agent_paused_5s_leaves_lockstep_exact(tmp_path):
    expected = run_chunk("truav", CFG, [SEED], EPISODES)  # also fills numba's cache for the processes
    rc, out, text = run_up(tmp_path, "paused", 5.0)
    assert rc == 0, text
    assert_freeze_while_ticking(out, 5.0)
    for i in range(CFG.scenario.n_uavs):
        with np.load(out / f"agent{i}.npz") as ck:
            assert np.array_equal(ck["q"], expected.q[0, i]), f"agent{i}'s table differs from the clean run's"
    summary = json.loads((out / "summary.json").read_text())
    assert summary["outcome"]["lockstep"]["exact"] is True
    assert summary["world"]["lockstep_missed"] == 0 and summary["world"]["deadline_misses"] == 0
    assert "lock-step: exact" in text
    for i in range(CFG.scenario.n_uavs):
        assert "deciding without" not in (out / "logs" / f"agent{i}.log").read_text()


def test_pause_beyond_the_bound_says_not_exact_and_fails(tmp_path):
    rc, out, text = run_up(tmp_path, "beyond", 4.0, "--lockstep-wait", "1")
    assert rc == 1, text
    # The pause began mid-run and the ticking went on past the 1 s bound. Its end need not come before the
    # run's: once the world stops waiting for the paused agent (and, on a busy host, for the slowed one),
    # the run may finish inside the freeze.
    summary = json.loads((out / "summary.json").read_text())
    assert ("freeze", "start") in [(kind, phase) for _, kind, phase in summary["fault_events"]], summary
    assert summary["world"]["last_tick_wall_s"] - summary["world"]["first_tick_wall_s"] > 1.0 + 1.0, summary["world"]
    outcome = json.loads((out / "summary.json").read_text())["outcome"]
    ex = outcome["lockstep"]
    assert ex["exact"] is False and outcome["result"] == "failed", outcome
    # the paused agent's peers went on without it (with a 1 s bound on a busy host it may itself too)
    assert ex["decisions_without_peer"] >= 1 and set(ex["by_agent"]) & {"agent0", "agent2"}, ex
    assert ex["world_went_on_without"] >= 1 and ex["inexact_from_tick"] > 0, ex
    assert f"lock-step is no longer exact from tick {ex['inexact_from_tick']}" in text
    assert "NOT exact" in text


def test_agent_waits_the_bound_for_a_heard_peer_and_a_grace_for_one_not_heard_since_it_joined(bus_factory):
    """A paused peer (heard before) is waited for up to --lockstep-wait; a peer that (re)joined but was
    never heard (a restarted agent the world did not send this tick to) only LOCKSTEP_JOIN_GRACE_S.
    Each decision taken without it is counted. Only lower bounds on time are asserted."""
    cfg = Config().replace(scenario={"n_uavs": 2})
    node = AgentNode(cfg, AgentOptions(run="waits", uav=0, lockstep=True, lockstep_wait_s=30.0),
                     bus_factory("uav/0", run="waits"))
    node._on_join(keys.alive_uav("waits", 1))
    t0 = time.monotonic()
    assert node._lockstep_beacons(5) == {}
    grace = time.monotonic() - t0
    assert LOCKSTEP_JOIN_GRACE_S <= grace < 30.0, grace  # not the bound
    assert node.inexact.as_dict() == {"decisions_without_peer": 1, "inexact_from_tick": 5}
    node._heard.add(1)  # as once its first beacon came
    node.opts.lockstep_wait_s = 4.0
    t0 = time.monotonic()
    assert node._lockstep_beacons(6) == {}
    assert time.monotonic() - t0 >= 4.0
    assert node.inexact.as_dict() == {"decisions_without_peer": 2, "inexact_from_tick": 5}
    node._on_leave(keys.alive_uav("waits", 1))  # gone: not waited for at all
    t0 = time.monotonic()
    node._lockstep_beacons(7)
    assert node.inexact.decisions == 2 and time.monotonic() - t0 < 4.0
