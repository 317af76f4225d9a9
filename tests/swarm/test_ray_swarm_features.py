"""`truav-swarm up --ray` offers what the local `up` does, on a real three-node Ray cluster on this machine:
real time keeping time, a fault plan, a recording `truav log check` passes, `status` and `down` finding the run
through its swarm.json, and `--resume` continuing from the checkpoints."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from tests.support.ray_cluster import LOOPBACK_DRIVER, three_ray_nodes
from tests.support.swarm_up import SMALL
from truav.bus.transport import Bus, make_config
from truav.swarm.children import free_loopback_endpoint
from truav.wire import keys

N = 4
COMMON = ["--scheme", "truav", "--agents", str(N), "--agents-per-process", "2", "--seed", "11", "--no-plot",
          "--no-references", "--wait-agents", "300", *SMALL]
"""--wait-agents: tick 0 waits for every agent, however long a busy host takes to start them on the nodes."""
PLAN = """seed = 1

[[fault]]
kind = "loss"
start = 1.0
duration = 1.5
probability = 1.0
keys = "uav/*/beacon"
"""
"""Every beacon lost from 1 s to 2.5 s."""
RUN_TIMEOUT_S = 400.0
"""A run's bound: actor starts on a busy 2-core host that also runs three raylets are slow."""
ENV = {**os.environ, **LOOPBACK_DRIVER}


@pytest.fixture(scope="module")
def cluster():
    cluster_utils = pytest.importorskip("ray.cluster_utils", reason="ray is not installed (the ray extra)")
    with three_ray_nodes(cluster_utils) as c:
        yield c


def _ray_args(cluster, run: str, out: Path, port: int | None = None) -> list[str]:
    port = port or int(free_loopback_endpoint().rsplit(":", 1)[1])
    return ["--run", run, "--out", str(out), "--ray", cluster.address, "--ray-port", str(port)]


def _up(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "truav.cli.swarm", "up", *COMMON, *args], capture_output=True,
                          text=True, timeout=RUN_TIMEOUT_S, env=ENV)


def _explain(res: subprocess.CompletedProcess, out: Path) -> str:
    return res.stdout + res.stderr + "".join(f"\n--- {p.name}\n{p.read_text(errors='replace')[-1500:]}"
                                             for p in sorted((out / "logs").glob("*.log")))


def _ran_to_its_end(res: subprocess.CompletedProcess, out: Path) -> bool:
    """The run ticked to its end; True if it also kept time. Real time guarantees no deadline on a host loaded
    past its cores: there the run may miss more than --max-missed, and must then fail saying the load is the
    likely cause (exit 1), never end in a bare ok."""
    assert "ended by: the world finished its 1 episode(s)" in res.stdout, _explain(res, out)
    if res.returncode == 0:
        return True
    assert res.returncode == 1 and "actions were missing" in res.stderr and "the host was loaded" in res.stderr, \
        _explain(res, out)
    return False


@pytest.fixture(scope="module")
def recorded(cluster, tmp_path_factory):
    """One real-time run (5 Hz, 40 steps) with a fault plan and a recording, for the three tests below."""
    tmp = tmp_path_factory.mktemp("ray-rt")
    (tmp / "plan.toml").write_text(PLAN)
    out, mcap = tmp / "swarm", tmp / "run.mcap"
    res = _up(*_ray_args(cluster, "rayrt", out), "--steps", "40", "--rate", "5", "--episodes", "1",
              "--record", str(mcap), "--fault-plan", str(tmp / "plan.toml"))
    return res, out, mcap


@pytest.mark.slow  # ~60 s on a busy host: the cluster's start, then an 8 s real-time run
def test_a_real_time_swarm_on_ray_keeps_time(recorded):
    res, out, _ = recorded
    kept_time = _ran_to_its_end(res, out)
    summary = json.loads((out / "summary.json").read_text())
    world = summary["world"]
    assert world["ticks"] == 41 and world["actions_received"] > 0
    if kept_time:
        assert summary["outcome"]["result"] == "ok", summary["outcome"]
        assert world["deadline_misses"] <= 0.05 * world["ticks"] * N  # within the default --max-missed


@pytest.mark.slow
def test_a_recording_on_ray_has_every_uavs_beacons_and_checks(recorded):
    from mcap.reader import make_reader
    res, out, mcap = recorded
    _ran_to_its_end(res, out)  # on a loaded host it may miss deadlines: what this test checks does not depend on them
    with open(mcap, "rb") as f:
        summary = make_reader(f).get_summary()
    by_topic = {summary.channels[cid].topic: n for cid, n in summary.statistics.channel_message_counts.items()}
    for i in range(N):  # agents of every node reached the core node's recorder through the linked routers
        assert by_topic.get(keys.uav_beacon("rayrt", i), 0) >= 30, (i, by_topic)
    check = subprocess.run([sys.executable, "-m", "truav.cli", "log", "check", str(mcap)], capture_output=True,
                           text=True, timeout=120)
    assert check.returncode == 0, check.stdout + check.stderr
    assert "0 missing by seq" in check.stdout, check.stdout


@pytest.mark.slow
def test_a_fault_plan_on_ray_shows_in_the_summary_and_the_recording(recorded):
    from mcap.reader import make_reader
    res, out, mcap = recorded
    _ran_to_its_end(res, out)  # on a loaded host it may miss deadlines: what this test checks does not depend on them
    assert "fault loss start at 1.0 s" in res.stdout and "fault loss end at 2.5 s" in res.stdout, res.stdout
    events = json.loads((out / "summary.json").read_text())["fault_events"]
    assert [(kind, what) for _, kind, what in events] == [("loss", "start"), ("loss", "end")]
    with open(mcap, "rb") as f:
        topics = [c.topic for c in make_reader(f).get_summary().channels.values()]
    assert "truav/rayrt/fault/loss" in topics, topics


def _ours(run: str, port: int) -> list[int]:
    """PIDs of this machine's processes of the run: its unique name on their command line, or (its routers)
    one of its three nodes' router endpoints."""
    marks = [run.encode(), *(f"127.0.0.1:{port + k}".encode() for k in range(3))]
    found = []
    for p in Path("/proc").iterdir():
        if p.name.isdigit():
            try:
                argv = (p / "cmdline").read_bytes().split(b"\0")
            except OSError:
                continue
            if b"truav.cli.swarm" in argv and b"up" not in argv and any(m in a for a in argv for m in marks):
                found.append(int(p.name))
    return found


def _bounded(pred, timeout: float, what: str, proc, output) -> None:
    deadline = time.monotonic() + timeout
    while not pred():
        assert proc.poll() is None, f"`up` ended before {what}:\n{output()}"
        assert time.monotonic() < deadline, f"no {what} within {timeout:.0f} s:\n{output()}"
        time.sleep(0.2)


@pytest.mark.slow  # ~60 s on a busy host
def test_status_and_down_find_a_ray_run_through_its_swarm_json(cluster, tmp_path):
    run, out = "raysd", tmp_path / "swarm"
    port = int(free_loopback_endpoint().rsplit(":", 1)[1])
    log_path = tmp_path / "up.log"
    with open(log_path, "wb") as log:
        up = subprocess.Popen([sys.executable, "-m", "truav.cli.swarm", "up", *COMMON,
                               *_ray_args(cluster, run, out, port), "--steps", "3000", "--episodes", "1"],
                              stdout=log, stderr=subprocess.STDOUT, env=ENV, start_new_session=True)
    output = lambda: log_path.read_text(errors="replace")  # noqa: E731
    try:
        _bounded(lambda: (out / "swarm.json").is_file(), RUN_TIMEOUT_S, "swarm.json", up, output)
        endpoint = json.loads((out / "swarm.json").read_text())["endpoint"]
        ticks: list[int] = []
        with Bus("observer", run, make_config(connect=[endpoint], connect_timeout_ms=5000)) as bus:
            bus.subscribe(keys.metrics_step(run), lambda k, m, r, t: ticks.append(m.tick))
            _bounded(lambda: len(ticks) >= 3, RUN_TIMEOUT_S, "tick", up, output)
        assert "tick " in output()  # the live status, as on one host
        cli = [sys.executable, "-m", "truav.cli.swarm"]
        status = subprocess.run([*cli, "status", "--out", str(out)], capture_output=True, text=True, timeout=60)
        assert status.returncode == 0, status.stdout + status.stderr
        for i in range(N):  # the agents of every node, seen through the core node's router
            assert f"truav/{run}/alive/uav/{i}" in status.stdout, status.stdout
        down = subprocess.run([*cli, "down", "--out", str(out)], capture_output=True, text=True, timeout=120)
        assert down.returncode == 0 and "shutdown sent" in down.stdout, down.stdout + down.stderr
        assert up.wait(timeout=120) == 130, output()
        assert "`truav-swarm down`" in output()
        deadline = time.monotonic() + 30
        while _ours(run, port) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert _ours(run, port) == []  # every process on every node stopped
    finally:
        if up.poll() is None:
            up.kill()
            up.wait()
        for pid in _ours(run, port):  # only this run's (its unique name), should the test have failed
            os.kill(pid, signal.SIGKILL)


@pytest.mark.slow  # ~90 s on a busy host: two lock-step runs
def test_resume_on_ray_continues_from_the_checkpoints(cluster, tmp_path):
    out = tmp_path / "swarm"
    args = ["--steps", "6", "--episodes", "1", "--lockstep", "--quiet"]
    first = _up(*_ray_args(cluster, "rayres", out), *args)
    assert first.returncode == 0, _explain(first, out)
    steps = [int(np.load(out / f"agent{i}.npz")["steps"]) for i in range(N)]
    assert steps == [6] * N
    again = _up(*_ray_args(cluster, "rayres", out), *args)
    assert again.returncode == 2 and "--resume" in again.stderr, again.stderr  # refused, as on one host
    second = _up(*_ray_args(cluster, "rayres", out), *args, "--resume")
    assert second.returncode == 0, _explain(second, out)
    assert [int(np.load(out / f"agent{i}.npz")["steps"]) for i in range(N)] == [12] * N
    for log in ("agents0-1.log", "agents2-3.log"):  # on two nodes
        assert "resumed from checkpoint" in (out / "logs" / log).read_text(), log
