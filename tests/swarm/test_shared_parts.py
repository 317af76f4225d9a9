"""A process hosting several agents shares what need not be per agent (agents.process.agent_host._SharedParts):
one peer watch, one health thread, one shutdown subscription, one fault-plan listener, one router
watchdog. The run must stay what it was with one process per agent: lock-step Q-tables equal to the
trainer's, every agent reporting its health on its own key, a peer killed seen as lost by hosted agents.

Small real swarms on loopback; only PIDs the supervisor names are signalled.
"""

from __future__ import annotations

import json
import os
import signal
from pathlib import Path

import numpy as np

from tests.support.waits import wait_until
from tests.support.runs import up_to_end
from tests.support.swarm_up import Up
from truav.analysis.trainer import run_chunk
from truav.config import Config

SWARM_TIMEOUT_S = 300.0


def _up(tmp: Path, name: str, cfg: Config, *args: str) -> Path:
    return up_to_end(tmp, name, cfg, *args, timeout_s=SWARM_TIMEOUT_S)


def test_agents_hosted_three_per_process_with_shared_parts_learn_what_the_trainer_learns(tmp_path):
    """Lock-step, 6 agents in two processes of 3 (shared beacon subscription, shared watch, health,
    shutdown): every Q-table np.array_equal to `truav train`'s, every decision with every peer's beacon,
    every agent's health reported on its own bus, every peer's join seen by the hosted agents."""
    seed, episodes, n = 5, 3, 6
    cfg = Config().replace(scenario={"n_vehicles": 60, "steps_per_episode": 10, "n_uavs": n},
                           roads={"warmup_steps": 10}, learner={"episodes": episodes})
    expected = run_chunk("truav", cfg, [seed], episodes).q[0]
    out = _up(tmp_path, "parts", cfg, "--lockstep", "--seed", str(seed), "--episodes", str(episodes),
              "--agents-per-process", "3", "--share-beacons")
    summary = json.loads((out / "summary.json").read_text())
    assert summary["outcome"]["result"] == "ok" and summary["outcome"]["lockstep"]["exact"], summary["outcome"]
    for i in range(n):
        with np.load(out / f"agent{i}.npz") as ck:
            assert int(ck["steps"]) == episodes * 10
            assert np.array_equal(ck["q"], expected[i])
        stats = json.loads((out / f"agent{i}.json").read_text())
        assert stats["lockstep"]["decisions_without_peer"] == 0
        assert stats["sent"]["health"] >= 1, stats["sent"]  # the process's health thread, on this agent's bus
        assert {s for s, _ in stats["beacon_latency_from"]} == set(range(n)) - {i}
    for name, peers in (("agents0-2", (3, 4, 5)), ("agents3-5", (0, 1, 2))):
        log = (out / "logs" / f"{name}.log").read_text()
        assert all(f"peer uav {j} joined" in log for j in peers), log[-3000:]
        assert log.count("shutdown from world") == 3, log[-3000:]  # one subscription, every hosted agent stops


def test_a_peer_killed_is_seen_lost_by_the_agents_hosted_together(tmp_path):
    """7 agents in processes of 3, 3 and 1: agent 6 (alone in its process) SIGKILLed mid-run is seen as
    lost through the hosted processes' one shared watch, and the run still ends (the supervisor restarts it)."""
    u = Up(tmp_path, "partslost", "--agents", "7", "--steps", "100", "--episodes", "4", "--rate", "20",
           "--agents-per-process", "3", "--share-beacons", "--max-missed", "1")
    try:
        u.wait_ticking()
        assert wait_until(lambda: (u.out / "agent6.npz").is_file(), 90.0, 0.1), u.output()
        os.kill(u.pids["agent6"], signal.SIGKILL)
        logs = [u.out / "logs" / "agents0-2.log", u.out / "logs" / "agents3-5.log"]
        assert wait_until(lambda: all("peer uav 6 lost" in p.read_text() for p in logs), 60.0, 0.2), u.output()
        rc = u.wait(timeout=240)
        out = u.output()
        assert rc == 0, out
        assert "restarted agent6" in out, out
        assert not u.left_running(), out
    finally:
        u.close()
