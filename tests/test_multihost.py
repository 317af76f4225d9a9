"""Three hosts, a router on each: the secure lock-step swarm of deploy/README.md, for real.

Each host is a network namespace with its own address from 198.51.100.0/24
(deploy/three-hosts.toml, no route out), all joined by veth pairs through one
bridge (tests/netns.py).  Host a runs the world and the recorder, hosts b and
c two agents each, every host its own router, the routers linked over mutual
TLS with the access control of the security work, from credentials made by
`truav-swarm certs --deployment deploy/three-hosts.toml`.  Mid-run host b's
cable is pulled (its bridge port down) for CUT_S seconds and put back.

What a user relies on, checked here:
* every agent's Q-table equals the in-process trainer's with the same seed,
  entry for entry (which tests/test_lockstep.py shows equal to a single-host
  lock-step run), and the world's episode metrics too: spreading the swarm
  over hosts changes nothing;
* during the cut the lock-step swarm stalls (no episode completes: the world
  waits for b's agents, c's agents wait for b's beacons), nobody is declared
  lost, and after the restore it resumes where it stopped, with nothing
  skipped (no "going on without them" in any log) and a recording with no gap;
* the configs in deploy/three-hosts/ are what the command writes.

Skipped when not root or when namespaces cannot be made; every process is
started by this test and stopped by PID, every namespace (with its veths and
the bridge) is deleted, also when the test fails.
"""

from __future__ import annotations

import json
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from tests import netns
from truav.config import Config, to_toml
from truav.swarm import deploy
from truav.trainer import run_chunk

REPO = Path(__file__).resolve().parents[1]
DEPLOYMENT = REPO / "deploy" / "three-hosts.toml"
COMMITTED_CONFIGS = REPO / "deploy" / "three-hosts"
PLAN = deploy.load(DEPLOYMENT)
SEED = 5
EPISODES = 24
CFG = Config().replace(scenario={"n_vehicles": 60, "steps_per_episode": 10, "n_uavs": PLAN.agents},
                       roads={"warmup_steps": 10}, learner={"episodes": EPISODES})
METRICS = ("coverage_pct", "pdr", "delay_ms", "energy_j", "generated", "delivered", "dropped")
CUT_AFTER_EPISODES = 4
CUT_HOST = "b"
CUT_S = 2.0
START_TIMEOUT_S = 30.0
RUN_TIMEOUT_S = 90.0
EPISODE_LINE = re.compile(r"^(\S+ \S+) truav\.world\S* INFO episode (\d+):", re.M)
LOST_OR_SKIPPED = re.compile(r"going on without them|deciding without them|agent lost|peer uav \d+ lost|router lost")
CLI = [sys.executable, "-m", "truav.swarm.cli"]


@pytest.fixture
def hosts():
    why = netns.unavailable()
    if why:
        pytest.skip(why)
    made = netns.Hosts.create({h.name: h.address for h in PLAN.hosts})
    try:
        yield made
    finally:
        made.close()
        assert netns.leftovers(made.tag) == [], "namespaces left behind"


def test_deploy_configs_are_what_the_command_writes(tmp_path):
    out = tmp_path / "configs"
    subprocess.run([*CLI, "deploy-configs", str(DEPLOYMENT), "--out", str(out)], check=True, capture_output=True)
    written = sorted(p.relative_to(out) for p in out.rglob("*.json5"))
    committed = sorted(p.relative_to(COMMITTED_CONFIGS) for p in COMMITTED_CONFIGS.rglob("*.json5"))
    assert written == committed
    for rel in written:
        assert (out / rel).read_text() == (COMMITTED_CONFIGS / rel).read_text(), rel


def _wait_for(what: str, check, timeout: float, procs=()) -> None:
    deadline = time.monotonic() + timeout
    while not check():
        dead = [p.args for p in procs if p.poll() is not None]
        assert not dead, f"exited while waiting for {what}: {dead}"
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.05)


def _episodes_done(log: Path) -> list[tuple[str, int]]:
    return [(stamp, int(n)) for stamp, n in EPISODE_LINE.findall(log.read_text(errors="replace"))] \
        if log.exists() else []


def _stamp_s(stamp: str) -> float:
    """A logging asctime ('2026-01-01 10:00:00,123') as seconds of the day."""
    hms, ms = stamp.split(" ")[1].split(",")
    h, m, s = map(int, hms.split(":"))
    return h * 3600 + m * 60 + s + int(ms) / 1e3


def test_three_hosts_lockstep_equals_one_host_and_rides_out_a_cut_link(hosts, tmp_path):
    expected = run_chunk("truav", CFG, [SEED], EPISODES)  # also fills numba's cache for the processes
    creds = tmp_path / "creds"
    subprocess.run([*CLI, "certs", "--deployment", str(DEPLOYMENT), "--out", str(creds)], check=True,
                   capture_output=True)
    for h in PLAN.hosts:  # the bundles carry exactly the committed configs
        for f in (COMMITTED_CONFIGS / h.name).glob("*.json5"):
            assert (creds / h.name / f.name).read_text() == f.read_text()
    scenario = tmp_path / "scenario.toml"
    scenario.write_text(to_toml(CFG))
    logs = tmp_path / "logs"
    logs.mkdir()

    def start(host: str, name: str, *argv: str) -> subprocess.Popen:
        log = open(logs / f"{name}.log", "wb")
        try:
            return hosts.popen(host, [*CLI, *argv, "--creds", str(creds / host)], stdout=log,
                               stderr=subprocess.STDOUT, cwd=tmp_path)
        finally:
            log.close()

    def log_of(name: str) -> str:
        return (logs / f"{name}.log").read_text(errors="replace")

    routers = [start(h.name, f"router-{h.name}", "router") for h in PLAN.hosts]
    _wait_for("the routers", lambda: all("router listening on" in log_of(f"router-{h.name}") for h in PLAN.hosts),
              START_TIMEOUT_S, routers)
    recorder = start("a", "recorder", "record", "--run", PLAN.run, "--out", str(tmp_path / "run.mcap"))
    _wait_for("the recorder's token",
              lambda: "alive/recorder" in hosts.run("a", [*CLI, "status", "--run", PLAN.run, "--creds",
                                                          str(creds / "a")]).stdout,
              START_TIMEOUT_S, [*routers, recorder])
    common = ["--run", PLAN.run, "--lockstep", "--seed", str(SEED), "--scenario", str(scenario)]
    world = start("a", "world", "world", *common, "--episodes", str(EPISODES), "--stats-out", "world.json")
    agents = [start(PLAN.host_of(f"uav/{i}").name, f"agent{i}", "agent", *common, "--id", str(i),
                    "--checkpoint", f"agent{i}.npz") for i in range(PLAN.agents)]
    everyone = [*routers, recorder, world, *agents]
    world_log = logs / "world.log"

    _wait_for(f"episode {CUT_AFTER_EPISODES}", lambda: len(_episodes_done(world_log)) >= CUT_AFTER_EPISODES,
              RUN_TIMEOUT_S, everyone)
    hosts.cut(CUT_HOST)
    cut_at = time.monotonic()
    before = len(_episodes_done(world_log))
    time.sleep(CUT_S)
    during = len(_episodes_done(world_log))
    hosts.restore(CUT_HOST)
    assert before < EPISODES, "the run ended before the cut: make it longer"
    # Lock-step waits for every live agent: with b cut off at most the episode under way completes.
    assert during <= before + 1, f"episodes went on during the cut: {before} -> {during}"

    assert world.wait(timeout=RUN_TIMEOUT_S) == 0, log_of("world")
    for i, proc in enumerate(agents):
        assert proc.wait(timeout=30) == 0, log_of(f"agent{i}")
    assert hosts.stop(recorder, signal.SIGINT, grace_s=60) == 0, log_of("recorder")

    done = _episodes_done(world_log)
    assert [n for _, n in done] == list(range(EPISODES))
    stall_s = max(_stamp_s(b[0]) - _stamp_s(a[0]) for a, b in zip(done, done[1:]))
    print(f"\nlongest gap between episodes {stall_s:.2f} s (host {CUT_HOST} cut for {CUT_S:.1f} s after episode "
          f"{before}); episodes finished during the cut: {during - before}")
    assert stall_s >= CUT_S * 0.9, "the cut did not stall the run: was the link really cut?"

    # Nothing was skipped or lost on the way (peers leave at the shutdown, after the last episode).
    for name, end in (("world", f"INFO episode {EPISODES - 1}:"), *((f"agent{i}", "shutdown from world")
                                                                   for i in range(PLAN.agents))):
        text = log_of(name)
        trouble = LOST_OR_SKIPPED.findall(text[:text.find(end)])
        assert end in text and trouble == [], (name, trouble)
    world_stats = json.loads((tmp_path / "world.json").read_text())
    assert world_stats["deadline_misses"] == 0
    assert len(world_stats["episodes"]) == EPISODES
    for e, got in enumerate(world_stats["episodes"]):
        for k in METRICS:
            assert np.array_equal(got[k], expected.metrics[k][e, 0], equal_nan=True), (e, k)
    for i in range(PLAN.agents):
        with np.load(tmp_path / f"agent{i}.npz") as ck:
            assert int(ck["steps"]) == EPISODES * CFG.scenario.steps_per_episode
            differing = int(np.sum(ck["q"] != expected.q[0][i]))
            assert differing == 0, f"agent {i}: {differing} Q-table entries differ from the trainer's"

    check = subprocess.run([sys.executable, "-m", "truav.cli", "log", "check", str(tmp_path / "run.mcap")],
                           capture_output=True, text=True, timeout=60)
    assert check.returncode == 0, check.stdout + check.stderr  # every message of every host recorded, no gap
    for proc in routers:
        assert hosts.stop(proc) == 0
