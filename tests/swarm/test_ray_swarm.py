"""`truav-swarm up --ray`: a lock-step swarm across a real three-node Ray cluster on this machine (each node
its own raylet on loopback, its own router on a port of its own) equals the one-host run of the same seed."""

import json
import os
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import zenoh

from tests.support.waits import wait_matched
from truav.bus.acl import file_stem
from truav.wire import keys

from tests.support.ray_cluster import LOOPBACK_DRIVER, three_ray_nodes
from tests.support.swarm_up import SMALL
from truav.swarm.children import free_loopback_endpoint

RUN = ["--scheme", "truav", "--agents", "4", "--agents-per-process", "2", "--steps", "6", "--episodes", "1", "--lockstep", "--seed", "11",
       "--quiet", "--no-plot", "--no-references", *SMALL]


def test_the_local_up_does_not_load_ray():
    code = "import sys, truav.cli.swarm, truav.cli.swarm_up, truav.swarm.supervisor; assert 'ray' not in sys.modules"
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)


def _up(out: Path, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "truav.cli.swarm", "up", "--run", out.name, "--out", str(out),
                           *RUN, *args], capture_output=True, text=True, timeout=200,
                          env={**os.environ, **LOOPBACK_DRIVER})


def test_a_ray_address_nobody_answers_is_one_line(tmp_path):
    pytest.importorskip("ray")
    port = free_loopback_endpoint().rsplit(":", 1)[1]
    res = _up(tmp_path / "x", "--ray", f"127.0.0.1:{port}")
    assert res.returncode == 2, res.stdout + res.stderr
    assert res.stderr.strip().count("\n") == 0 and "no Ray head answers there" in res.stderr, res.stderr


def test_ray_flags_are_checked_before_anything_starts(tmp_path):
    res = _up(tmp_path / "x", "--ray", "auto", "-l", "tcp/127.0.0.1:7447")
    assert res.returncode == 2 and "-l/--listen: not with --ray" in res.stderr, res.stderr
    res = _up(tmp_path / "z", "--ray", "auto", "--secure", "--external", "3")
    assert res.returncode == 2 and "--external: not with --ray --secure" in res.stderr, res.stderr
    res = _up(tmp_path / "y", "--ray-port", "9000")
    assert res.returncode == 2 and "--ray-port 9000: only with --ray" in res.stderr, res.stderr


@pytest.fixture(scope="module")
def three_nodes():
    """One cluster for the module's tests: none of them loses a node (tests/swarm/test_ray_node_loss.py does)."""
    cluster_utils = pytest.importorskip("ray.cluster_utils", reason="ray is not installed (the ray extra)")
    with three_ray_nodes(cluster_utils) as cluster:
        yield cluster


@pytest.fixture(scope="module")
def one_host(tmp_path_factory) -> Path:
    """The one-host lock-step run both cluster runs are compared with (the same seed, flags and code)."""
    out = tmp_path_factory.mktemp("one-host") / "local"
    local = _up(out, "-l", free_loopback_endpoint())
    assert local.returncode == 0, local.stdout + local.stderr
    return out


@pytest.mark.slow  # ~25 s: a three-node cluster's start, then two swarms
@pytest.mark.parametrize("secure", [(), ("--secure",)], ids=["plain", "secure"])
def test_a_swarm_across_three_ray_nodes_equals_the_one_host_run(tmp_path, three_nodes, one_host, secure):
    port = int(free_loopback_endpoint().rsplit(":", 1)[1])
    res = _up(tmp_path / "ray", "--ray", three_nodes.address, "--ray-port", str(port), *secure)
    assert res.returncode == 0, res.stdout + res.stderr + "".join(
        f"\n--- {p.name}\n{p.read_text()[-2000:]}" for p in sorted((tmp_path / "ray" / "logs").glob("*.log")))
    placed = [ln for ln in res.stdout.splitlines() if ln.startswith("  node ")]
    scheme = "tls" if secure else "tcp"
    assert len(placed) == 3 and all(f"router {scheme}/127.0.0.1:" in ln for ln in placed), res.stdout
    assert not (tmp_path / "ray" / "creds").exists()  # --secure: no key in the run's (shared) directory
    assert sum(ln.count("agents") for ln in placed) == 2  # two processes of two UAVs, on two of the nodes
    logs = {p.name for p in (tmp_path / "ray" / "logs").glob("router*.log")}
    assert len(logs) == 3, logs  # one router per node
    for i in range(4):
        a, b = np.load(one_host / f"agent{i}.npz"), np.load(tmp_path / "ray" / f"agent{i}.npz")
        assert sorted(a.files) == sorted(b.files)
        for key in a.files:
            np.testing.assert_array_equal(a[key], b[key], err_msg=f"agent{i}.npz {key}")
    digest = [json.loads((d / "world.json").read_text())["actions_digest"] for d in (one_host, tmp_path / "ray")]
    assert digest[0] and digest[0] == digest[1]


def _until(pred, timeout: float = 10.0) -> bool:
    deadline = time.monotonic() + timeout
    while not pred() and time.monotonic() < deadline:
        time.sleep(0.02)
    return pred()


@pytest.mark.slow  # ~15 s: a three-node cluster's start, its three secure routers
def test_secure_ray_nodes_hold_only_their_keys_and_refuse_a_forged_put(tmp_path, three_nodes, monkeypatch):
    """Each node's credentials (handed over by Ray, not a shared file) sit in a 0700 directory of its own with
    only its identities' keys; uav/1's certificate, presented to node 2's router, cannot put as uav/2 or shut
    the run down, while its own beacon crosses the routers' mutual-TLS links."""
    import ray
    from truav.swarm import ray_swarm
    run = "raysec"
    # LOOPBACK_DRIVER in this process, where Ray has already read its environment
    monkeypatch.setattr(ray._private.ray_constants, "ENABLE_RAY_CLUSTER", False)
    ray.init(address=three_nodes.address, log_to_driver=False, logging_level="ERROR")
    children = None
    try:
        port = int(free_loopback_endpoint().rsplit(":", 1)[1])
        plan = ray_swarm.place(ray_swarm.cluster_nodes(), 4, 2, port)
        children = type("Placed", (ray_swarm.RayChildren,), {"plan": plan})(tmp_path / "logs")
        router_args, _, _ = children.secure_setup(tmp_path, SimpleNamespace(run=run), 4, plan.core_endpoint)
        sites = plan.sites()
        for actor, site in zip(children.creds_actors, sites):
            mode, names = ray.get(actor.listing.remote(), timeout=30)
            assert mode == 0o700, oct(mode)
            assert {n[:-4] for n in names if n.endswith(".key")} == {"router", *map(file_stem, site.identities)}
        assert "uav/1" in sites[0].identities and "uav/1" not in sites[2].identities
        children.start("router", [sys.executable, "-m", "truav.cli.swarm", "router", *router_args])
        assert _until(lambda: all(b"router listening" in children.log_text(r.name) for r in plan.routers), 60), \
            [children.log_text(r.name)[-500:] for r in plan.routers]
        core = Path(children.creds_dirs[plan.core_node])
        forger_conf = json.loads((core / "uav-1.json5").read_text())
        forger_conf["connect"]["endpoints"] = [f"tls/{plan.routers[2].endpoint.split('/', 1)[1]}"]  # node 2's router
        recorder = zenoh.open(zenoh.Config.from_file(str(core / "recorder.json5")))
        forger = zenoh.open(zenoh.Config.from_json5(json.dumps(forger_conf)))
        try:
            got: list[str] = []
            recorder.declare_subscriber(keys.everything(run), lambda s: got.append(str(s.key_expr)))
            assert wait_matched(forger, keys.uav_beacon(run, 1))  # the subscription crossed to node 2's router
            for key in (keys.uav_action(run, 2), keys.control(run, "shutdown")):
                forger.put(key, b"forged")
            forger.put(keys.uav_beacon(run, 1), b"own")  # allowed: proves the path listens
            assert _until(lambda: keys.uav_beacon(run, 1) in got)
            time.sleep(1.0)  # a put that got through would take milliseconds
            assert got == [keys.uav_beacon(run, 1)]
        finally:
            forger.close()
            recorder.close()
        dirs = list(children.creds_dirs.values())
        children.stop(["router"], timeout=10.0)
        children.close_logs()
        children = None
        assert not any(os.path.exists(d) for d in dirs)  # removed with the run
    finally:
        if children is not None:
            children.stop(["router"], timeout=10.0)
            children.close_logs()
        ray.shutdown()
