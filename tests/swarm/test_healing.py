"""`truav-swarm up --restart`: a process that dies outside any fault plan is restarted.

Small real swarms on loopback; only PIDs the supervisor names in pids.json are
signalled, and none may outlive its test.  Real time: the tests assert what
real time guarantees under load (the restart happens, the agent resumes from
its checkpoint, the run ends ok), not how fast.
"""

from __future__ import annotations

import json
import os
import signal
import time

import pytest

from tests.support.waits import wait_until
from tests.support.swarm_up import up  # noqa: F401  (the fixture: `up` runs, each closed at the end)
from truav.swarm.healing import Healer, backoff_s


# Long enough that a restart on a busy machine comes back before the world's last tick (20 s at 20 Hz:
# the kill comes after the first checkpoint, 2.5 s in; a restart takes 3-10 s on a busy machine).
RUN = ["--agents", "2", "--steps", "100", "--episodes", "4", "--rate", "20",
       "--max-missed", "1"]  # a restart's missed actions (3-10 s of one agent) are not what these tests are about


def test_an_agent_killed_outside_any_plan_is_restarted_and_resumes_from_its_checkpoint(up, tmp_path):
    record = tmp_path / "heal.mcap"
    u = up("healagent", *RUN, "--record", str(record))
    u.wait_ticking()
    # agent 0 checkpoints every 50 steps (SwarmOptions.checkpoint_every): wait for its first one
    assert wait_until(lambda: (u.out / "agent0.npz").is_file(), 60.0, 0.1), u.output()
    os.kill(u.pids["agent0"], signal.SIGKILL)
    rc = u.wait(timeout=240)
    out = u.output()
    assert rc == 0, out
    # how it ended, and the last log line labelled as such (not read as the cause)
    assert "agent0 died mid-run (killed by SIGKILL)" in out and "its last log line: " in out, out
    assert "restarted agent0" in out, out
    summary = json.loads((u.out / "summary.json").read_text())
    (restart,) = summary["outcome"]["restarts"]
    assert restart["process"] == "agent0" and restart["cause"] == "killed by SIGKILL" and restart["number"] == 1
    assert summary["outcome"]["result"] == "ok"
    log = (u.out / "logs" / "agent0.log").read_text()
    assert "resumed from checkpoint" in log, log[-2000:]
    # summary.json names every process started, the dead incarnation with its exit
    agent0 = [p for p in summary["processes"] if p["name"] == "agent0"]
    assert [p["exit_code"] for p in agent0] == [-signal.SIGKILL, 0]
    assert not u.left_running(), out
    # the recording shows the restart as a span, from the death to the new process
    from recorder.reader import iter_messages
    from truav.wire import schema
    spans = [schema.decode(payload) for key, payload, _, _ in iter_messages(record, include=["*/fault/restart"])]
    assert [(m.phase, m.target, m.params["cause"]) for m in spans] == [
        ("start", "uav/0", "killed by SIGKILL"), ("end", "uav/0", "killed by SIGKILL")], spans
    assert spans[1].params["new_pid"] == agent0[1]["pid"]


def test_a_router_killed_mid_run_is_restarted_on_its_endpoint_and_the_run_ends_ok(up):
    u = up("healrouter", *RUN)
    endpoint = u.wait_ticking()
    os.kill(u.pids["router"], signal.SIGKILL)
    rc = u.wait(timeout=240)
    out = u.output()
    assert rc == 0, out
    assert f"restarted router (pid " in out and f"on {endpoint}" in out, out
    summary = json.loads((u.out / "summary.json").read_text())
    assert summary["outcome"]["result"] == "ok"
    assert [r["process"] for r in summary["outcome"]["restarts"]] == ["router"]
    for i in (0, 1):  # the agents lived through it: one incarnation each, final statistics written
        assert [p["exit_code"] for p in summary["processes"] if p["name"] == f"agent{i}"] == [0], out
        assert (u.out / f"agent{i}.json").is_file()
    assert not u.left_running(), out


def test_restarts_back_off_and_stop_at_the_limit():
    h = Healer("on-failure", limit=2)
    assert [backoff_s(n) for n in range(6)] == [0.5, 1.0, 2.0, 4.0, 8.0, 8.0]
    r = h.died("agent1", 100, "killed by SIGKILL", 3.0, now=10.0)
    assert r is not None and r.number == 1 and h.due(10.4) == [] and h.due(10.5) == [r]
    h.done(r, 101, 4.0)
    r2 = h.died("agent1", 101, "exit code 1", 5.0, now=20.0)
    assert r2.number == 2 and h.due(20.9) == [] and h.due(21.0) == [r2]
    h.done(r2, 102, 6.0)
    assert h.died("agent1", 102, "exit code 1", 7.0, now=30.0) is None and h.given_up == ["agent1"]
    assert Healer("never").died("agent1", 1, "exit code 1", 0.0, 0.0) is None
    assert time.time_ns() >= r.restarted_wall_ns >= r.died_wall_ns > 0


def test_after_a_router_outage_the_guard_follows_the_world_again(monkeypatch):
    """A router restart took longer than the guard's tick window: without the resync every later tick and
    observation was refused as out of window, and the agents hovered to the end (68% missed)."""
    from truav.config import Config
    from truav.wire import guard, schema
    now = [100.0]
    monkeypatch.setattr(guard.time, "monotonic", lambda: now[0])
    g = guard.for_config(Config())

    def tick(t: int):
        return g.check("k", schema.Tick(src="world", seq=t, t=0, tick=t, episode=0, sim_time=0.0, deadline_ms=50.0,
                                        n_uavs=Config().scenario.n_uavs))

    assert tick(10) is None
    assert tick(10 + guard.TICK_WINDOW + 50)[0] == guard.R_TICK  # a jump while the world is heard: refused
    now[0] += 7.0  # 7 s of silence: the world went on by 70 ticks at 10 Hz
    assert tick(2 ** 40)[0] == guard.R_TICK  # no further than the silence allows
    assert tick(10 + 70 + guard.TICK_WINDOW) is None and g.tick == 10 + 70 + guard.TICK_WINDOW
    assert tick(10)[0] == guard.R_TICK  # and the old window is gone
    # the supervisor hears step metrics first: they move the window too, once
    from truav.wire import schema as sc
    now[0] += 3.0
    before = g.tick
    metrics = sc.Metrics(src="world", seq=1, t=0, scope="step", tick=before + 100, episode=0, values={})
    assert g.check("k", metrics) is None and g.tick == before + 100
