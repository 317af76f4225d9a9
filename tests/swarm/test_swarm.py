"""The swarm as real processes on a loopback router: lock-step equivalence with
the in-process trainer, crash tolerance and checkpoint resume.

Every process is started here, tracked by PID and killed + reaped at the end.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from agents.controller import TruavController
from agents.process.agent_process import checkpoint_due
from truav.analysis.driver import run_episodes
from truav.bus.transport import Bus, make_config
from truav.cli import swarm as swarm_cli
from truav.config import Config, to_toml
from truav.swarm.supervisor import free_loopback_endpoint, wait_for_port
from truav.wire import keys
from tests.support.waits import wait_until

SMALL = {"scenario": {"n_vehicles": 60, "steps_per_episode": 15, "n_uavs": 5}, "roads": {"warmup_steps": 10}}


class Procs:
    """Processes started by a test; all are killed and reaped by `close`."""

    def __init__(self, tmp: Path):
        self.tmp = tmp
        self.procs: dict[str, subprocess.Popen] = {}

    def start(self, name: str, *args: str) -> subprocess.Popen:
        log = open(self.tmp / f"{name}.log", "wb")
        p = subprocess.Popen([sys.executable, "-m", "truav.cli.swarm", *args], stdout=log, stderr=subprocess.STDOUT)
        log.close()
        self.procs[name] = p
        return p

    def log(self, name: str) -> str:
        return (self.tmp / f"{name}.log").read_text(errors="replace")

    def close(self) -> None:
        for p in self.procs.values():
            if p.poll() is None:
                p.kill()
        for p in self.procs.values():
            p.wait(timeout=10)


@pytest.fixture
def procs(tmp_path):
    ps = Procs(tmp_path)
    yield ps
    ps.close()
    assert all(p.poll() is not None for p in ps.procs.values())


def start_swarm(procs: Procs, cfg: Config, run: str, *, lockstep: bool, episodes: int,
                agent_args=lambda i: ()) -> str:
    scenario = procs.tmp / "scenario.toml"
    scenario.write_text(to_toml(cfg))
    ep = free_loopback_endpoint()
    procs.start("router", "router", "-l", ep)
    assert wait_for_port(ep, 15.0), f"router at {ep} did not come up"
    common = ["--run", run, "--seed", "3", "--scenario", str(scenario), "-e", ep] + (["--lockstep"] if lockstep else [])
    procs.start("world", "world", *common, "--episodes", str(episodes), "--stats-out", str(procs.tmp / "world.json"),
                "--wait-agents", "60",
                "--max-missed", "1")  # a killed agent's and a busy host's missed actions are not what these test
    for i in range(cfg.scenario.n_uavs):
        procs.start(f"agent{i}", "agent", "--id", str(i), *common, *agent_args(i))
    return ep


def test_lockstep_swarm_equals_in_process_run(procs):
    cfg = Config().replace(**SMALL)
    # In-process first: it also fills numba's cache for the processes below.
    expected = run_episodes(cfg, [3], TruavController(cfg, [3]), 2)
    start_swarm(procs, cfg, "eq", lockstep=True, episodes=2)
    assert procs.procs["world"].wait(timeout=120) == 0, procs.log("world")
    got = json.loads((procs.tmp / "world.json").read_text())
    assert got["deadline_misses"] == 0
    for e in range(2):
        for k in ("coverage_pct", "pdr", "delay_ms", "energy_j", "generated", "delivered", "dropped"):
            assert got["episodes"][e][k] == expected[k][e, 0], (e, k)
    for i in range(cfg.scenario.n_uavs):  # agents leave on the world's shutdown
        assert procs.procs[f"agent{i}"].wait(timeout=20) == 0


def test_killed_agent_never_stalls_the_world_and_resumes_from_its_checkpoint(procs):
    cfg = Config().replace(scenario={"n_vehicles": 60, "steps_per_episode": 80, "n_uavs": 5},
                           roads={"warmup_steps": 10})
    run_episodes(cfg.replace(scenario={"steps_per_episode": 2}), [0], TruavController(cfg, [0]), 1)  # warm cache
    ck = procs.tmp / "agent2.npz"

    def agent_args(i):
        return ("--checkpoint", str(ck), "--checkpoint-every", "5", "-v") if i == 2 else ()

    ep = start_swarm(procs, cfg, "crash", lockstep=False, episodes=1, agent_args=agent_args)
    ticks: list[tuple[float, int]] = []
    lost: list[float] = []
    with Bus("observer", "crash", make_config(connect=[ep], connect_timeout_ms=5000)) as bus:
        bus.subscribe(keys.metrics_step("crash"), lambda k, m, r, t: ticks.append((time.monotonic(), m.tick)))
        bus.watch_liveliness(keys.alive_uav("crash", 2), lambda k: None, lambda k: lost.append(time.monotonic()))
        deadline = time.monotonic() + 60
        while (len(ticks) < 20 or not ck.exists()) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert ck.exists() and len(ticks) >= 20, procs.log("world")
        with np.load(ck) as saved:
            steps_saved = int(saved["steps"])
        killed_at = time.monotonic()
        procs.procs["agent2"].send_signal(signal.SIGKILL)
        procs.procs["agent2"].wait(timeout=5)
        while not lost and time.monotonic() < killed_at + 10:
            time.sleep(0.01)
        # the loss is seen through liveliness (its session's socket closes: milliseconds; a busy host, more)
        assert lost and lost[0] - killed_at < 5.0, lost
        # the world kept ticking while the agent was dead (waiting for it, it would stop for good; a busy
        # host delays a tick by tens of milliseconds, rarely more)
        wait_until(lambda: len([t for t, _ in ticks if t > killed_at]) >= 10, 15.0)
        after = [t for t, _ in ticks if t > killed_at]
        assert len(after) >= 10 and np.max(np.diff([killed_at] + after)) < 2.0, np.diff([killed_at] + after)
        procs.start("agent2b", "agent", "--id", "2", "--run", "crash", "--seed", "3", "--scenario",
                    str(procs.tmp / "scenario.toml"), "-e", ep, "--checkpoint", str(ck), "--checkpoint-every", "5",
                    "-v")
        deadline = time.monotonic() + 30
        while "resumed from checkpoint" not in procs.log("agent2b") and time.monotonic() < deadline:
            time.sleep(0.1)
    log = procs.log("agent2b")
    assert "resumed from checkpoint" in log
    resumed_step = int(log.split("resumed from checkpoint")[1].split("at step")[1].split()[0])
    assert resumed_step >= steps_saved > 0
    assert procs.procs["world"].wait(timeout=60) == 0
    world = json.loads((procs.tmp / "world.json").read_text())
    assert world["deadline_misses"] > 0  # the dead agent's UAV hovered
    assert any("uav/2" in k for k in world["losses"])


def test_agents_take_turns_to_checkpoint() -> None:
    n, every = 20, 50
    writers = [[u for u in range(n) if checkpoint_due(step, u, n, every)] for step in range(1, every + 1)]
    assert sorted(u for w in writers for u in w) == list(range(n))  # each agent once per `every` steps
    assert max(len(w) for w in writers) == 1  # never two in the same step
    assert [s for s in range(1, 3 * every + 1) if checkpoint_due(s, 0, n, every)] == [every, 2 * every, 3 * every]


@pytest.mark.parametrize("argv, fragment", [
    (["up", "--rate", "0"], "--rate: must be a finite number > 0"),
    (["agent", "--id", "0", "--checkpoint-every", "0"], "--checkpoint-every: must be an integer >= 1"),
    (["world", "--episodes", "two"], "'two' is not an integer"),
])
def test_bad_numbers_are_usage_errors(argv, fragment, capsys) -> None:
    with pytest.raises(SystemExit) as exc:
        swarm_cli.main(argv)
    assert exc.value.code == 2 and fragment in capsys.readouterr().err


def test_no_router_is_a_clear_error_not_a_traceback(capsys) -> None:
    endpoint = free_loopback_endpoint()  # nothing listens there
    assert swarm_cli.main(["status", "-e", endpoint]) == 1
    err = capsys.readouterr().err
    assert "is a router running there?" in err and "Traceback" not in err


def _running(pid: int) -> bool:
    """True while ``pid`` runs (a zombie awaiting its reaper counts as stopped)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGKILL], ids=["sigterm", "sigkill"])
def test_no_swarm_process_outlives_its_supervisor(tmp_path, signum):
    """SIGTERM stops `truav-swarm up` as Ctrl-C does (summary, exit 143); after SIGKILL its
    children notice it is gone and stop by themselves, cleanly (agents write their statistics)."""
    out = tmp_path / "swarm"
    log = open(tmp_path / "up.log", "wb")
    sup = subprocess.Popen([sys.executable, "-m", "truav.cli.swarm", "up", "--scheme", "truav", "--run", "lifeline", "--agents", "2",
                            "--steps", "100", "--episodes", "50", "--set", "scenario.n_vehicles=40",
                            "--out", str(out), "--quiet", "--no-plot"],
                           stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    log.close()
    children: dict[str, int] = {}
    try:
        deadline = time.monotonic() + 90
        while not all((out / f"agent{i}.npz").is_file() for i in (0, 1)) and sup.poll() is None \
                and time.monotonic() < deadline:
            time.sleep(0.2)  # both agents have checkpointed once: the swarm is ticking (50 episodes take minutes)
        children = json.loads((out / "pids.json").read_text())
        assert set(children) == {"router", "world", "agent0", "agent1"} and sup.poll() is None
        sup.send_signal(signum)
        rc = sup.wait(timeout=30)
        stop_by = time.monotonic() + 15
        while any(_running(pid) for pid in children.values()) and time.monotonic() < stop_by:
            time.sleep(0.1)
        assert not [name for name, pid in children.items() if _running(pid)], (tmp_path / "up.log").read_text()
        assert (out / "agent0.json").is_file() and (out / "agent1.json").is_file()  # stopped, not killed
        if signum == signal.SIGTERM:
            assert rc == 143 and (out / "summary.json").is_file()  # 128 + SIGTERM, as shells and schedulers expect
            assert "interrupted" in (tmp_path / "up.log").read_text()
    finally:
        if sup.poll() is None:
            sup.kill()
            sup.wait()
        for pid in children.values():  # only our own children, should the test have failed
            if _running(pid) and b"truav.cli.swarm" in Path(f"/proc/{pid}/cmdline").read_bytes():
                os.kill(pid, signal.SIGKILL)
