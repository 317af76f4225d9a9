"""Three hosts, a router on each: the secure lock-step swarm of deploy/README.md, for real.

Each host is a network namespace with its own address from 198.51.100.0/24
(deploy/three-hosts.toml, no route out), all joined by veth pairs through one
bridge (tests/support/netns.py).  Host a runs the world and the recorder, hosts b and
c two agents each, every host its own router, the routers linked over mutual
TLS with the access control of the security work, from credentials made by
`truav-swarm certs --deployment deploy/three-hosts.toml`.  Mid-run host b's
cable is pulled (its bridge port down) for CUT_S seconds and put back.

What a user relies on, checked here:
* every agent's Q-table equals the in-process trainer's with the same seed,
  entry for entry (which tests/swarm/test_lockstep.py shows equal to a single-host
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

from tests.support import netns
from truav.analysis.trainer import run_chunk
from truav.bus.secure_configs import inline_material
from truav.config import Config, to_toml
from truav.lifecycle import child_env
from truav.swarm import deploy

REPO = Path(__file__).resolve().parents[2]
DEPLOYMENT = REPO / "deploy" / "three-hosts.toml"
COMMITTED_CONFIGS = REPO / "deploy" / "three-hosts"
PLAN = deploy.load(DEPLOYMENT)
REGENERATE = "truav-swarm deploy-configs deploy/three-hosts.toml --out deploy/three-hosts --force"
SEED = 5
EPISODES = 24
CFG = Config().replace(scenario={"n_vehicles": 60, "steps_per_episode": 10, "n_uavs": PLAN.agents},
                       roads={"warmup_steps": 10}, learner={"episodes": EPISODES})
METRICS = ("coverage_pct", "pdr", "delay_ms", "energy_j", "generated", "delivered", "dropped")
CUT_AFTER_EPISODES = 4
CUT_HOST = "b"
CUT_S = 1.0  # with TCP's retransmission back-off, far under --lockstep-wait and Zenoh's 10 s lease
START_TIMEOUT_S = 30.0
RUN_TIMEOUT_S = 90.0
EPISODE_LINE = re.compile(r"^(\S+ \S+) truav\.world\S* INFO episode (\d+):", re.M)
LOST_OR_SKIPPED = re.compile(r"going on without them|deciding without them|agent lost|peer uav \d+ lost|router lost")
CLI = [sys.executable, "-m", "truav.cli.swarm"]


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
    stale = f"deploy/three-hosts/ is stale: {REGENERATE}"
    assert written == committed, stale
    for rel in written:
        assert (out / rel).read_text() == (COMMITTED_CONFIGS / rel).read_text(), (rel, stale)


def _run_cli(*argv: str) -> subprocess.CompletedProcess:
    return subprocess.run([*CLI, *argv], capture_output=True, text=True, timeout=60)


@pytest.mark.parametrize("edit, complaint", [
    (lambda t: t.replace('port = 7447', 'port = 7447\nsecure = false'), "unknown key 'secure'"),
    (lambda t: t.replace('runs = ["uav/2-3"]', 'runs = ["uav/1-3"]'), "uav/1 is already placed on host 'b'"),
    (lambda t: t.replace('runs = ["uav/2-3"]', 'runs = ["uav/2-4"]'), "uav/4 is outside uav/0..uav/3"),
    (lambda t: t.replace('"world", ', ''), "world runs on no host"),
    (lambda t: t.replace('198.51.100.3', '198.51.100.2'), "already the address of another host"),
    (lambda t: t.replace('name = "c"', 'name = "C"'), "host[2].name"),
    (lambda t: t.replace('"recorder"', '"recorda"'), "unknown component 'recorda'"),
])
def test_deployment_mistakes_are_one_line_naming_the_key(tmp_path, edit, complaint):
    bad = tmp_path / "bad.toml"
    bad.write_text(edit(DEPLOYMENT.read_text()))
    for argv in (["certs", "--deployment", str(bad), "--out", str(tmp_path / "creds")],
                 ["deploy-configs", str(bad), "--out", str(tmp_path / "configs")]):
        got = _run_cli(*argv)
        assert got.returncode == 2 and got.stderr.count("\n") == 1 and complaint in got.stderr, got.stderr
        assert str(bad) in got.stderr and not (tmp_path / "creds").exists()


def test_each_host_bundle_holds_only_its_own_keys_and_moves_anywhere(tmp_path):
    from cryptography import x509
    from cryptography.x509.oid import NameOID

    from truav.bus import security, transport
    creds = tmp_path / "creds"
    assert _run_cli("certs", "--deployment", str(DEPLOYMENT), "--out", str(creds)).returncode == 0
    assert sorted(p.name for p in creds.iterdir()) == ["a", "b", "c", "ca.key", "ca.pem"]
    for h in PLAN.hosts:
        keys_there = sorted(p.stem for p in (creds / h.name).glob("*.key"))
        assert keys_there == sorted(["router", *(security.file_stem(i) for i in h.runs)]), h.name
        cert = x509.load_pem_x509_certificate((creds / h.name / "router.pem").read_bytes())
        assert cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value == f"router/{h.name}"
        sans = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
        assert h.address in [str(ip) for ip in sans.get_values_for_type(x509.IPAddress)]
        assert oct((creds / h.name).stat().st_mode & 0o777) == "0o700"
    # A bundle copied elsewhere still holds its material: each config has its certificates and key inline.
    moved = tmp_path / "elsewhere" / "truav-creds"
    moved.parent.mkdir()
    (creds / "b").rename(moved)
    conf = transport.make_config(None, config_file=moved / "uav-0.json5")
    assert json.loads(conf.get_json("transport/link/tls/connect_certificate_base64"))
    explained = _run_cli("acl", "explain", "--creds", str(moved))
    assert "router/a, router/c (the other routers): relay everything" in explained.stdout
    # The scenario must fly the agents the credentials were made for.
    wrong = _run_cli("agent", "--id", "0", "--run", PLAN.run, "--creds", str(moved))
    assert wrong.returncode == 2 and "made for 4 agents, the scenario has 5" in wrong.stderr, wrong.stderr


def test_routers_relay_between_hosts_and_each_enforces_its_own_clients(tmp_path):
    """Two routers on loopback ports: what uav/0 on b may put reaches the recorder on a, the rest never leaves b."""
    import zenoh

    from tests.support.waits import free_port
    from truav.bus import security, transport
    from truav.wire import keys
    sites = (security.Site("a", "127.0.0.1", free_port(), ("recorder",)),
             security.Site("b", "127.0.0.1", free_port(), ("uav/0",)))
    security.issue(tmp_path, PLAN.run, 2, sites=sites)

    def open_(host: str, name: str) -> zenoh.Session:
        return zenoh.open(transport.make_config(None, config_file=tmp_path / host / name))

    opened = [open_("a", "router.json5"), open_("b", "router.json5")]
    try:
        recorder, agent0 = open_("a", "recorder.json5"), open_("b", "uav-0.json5")
        opened += [recorder, agent0]
        got: list[str] = []
        recorder.declare_subscriber(keys.everything(PLAN.run), lambda sample: got.append(str(sample.key_expr)))
        own = keys.uav_beacon(PLAN.run, 0)
        deadline = time.monotonic() + 10  # the routers link and learn of the subscription
        while own not in got and time.monotonic() < deadline:
            agent0.put(own, b"own")
            time.sleep(0.05)
        assert own in got
        for key in (keys.uav_beacon(PLAN.run, 1), keys.uav_action(PLAN.run, 1), keys.control(PLAN.run, "shutdown"),
                    keys.world_tick(PLAN.run)):
            agent0.put(key, b"forged")
        time.sleep(1.0)
        assert set(got) == {own}
    finally:
        for s in reversed(opened):
            s.close()


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
    for h in PLAN.hosts:  # the bundles carry the committed configs, with the files they name inline
        for f in (COMMITTED_CONFIGS / h.name).glob("*.json5"):
            inlined = inline_material(json.loads(f.read_text()), creds / h.name)
            assert json.loads((creds / h.name / f.name).read_text()) == inlined, (f, REGENERATE)
    scenario = tmp_path / "scenario.toml"
    scenario.write_text(to_toml(CFG))
    logs = tmp_path / "logs"
    logs.mkdir()

    def start(host: str, name: str, *argv: str) -> subprocess.Popen:
        log = open(logs / f"{name}.log", "wb")
        try:
            # child_env: each process also stops by itself if this test process dies (truav/lifecycle.py).
            return hosts.popen(host, [*CLI, *argv, "--creds", str(creds / host)], stdout=log,
                               stderr=subprocess.STDOUT, cwd=tmp_path, env=child_env())
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
    world = start("a", "world", "world", *common, "--episodes", str(EPISODES), "--stats-out", "world.json",
                  "--wait-agents", str(RUN_TIMEOUT_S))  # agents compile for a while on a loaded machine
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
