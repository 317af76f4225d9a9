"""`truav-swarm up --ray`: a lock-step swarm across a real three-node Ray cluster on this machine (each node
its own raylet on loopback, its own router on a port of its own) equals the one-host run of the same seed."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.support.swarm_up import SMALL
from truav.swarm.children import free_loopback_endpoint

RUN = ["--agents", "4", "--agents-per-process", "2", "--steps", "6", "--episodes", "1", "--lockstep", "--seed", "11",
       "--quiet", "--no-plot", "--no-references", *SMALL]


def test_the_local_up_does_not_load_ray():
    code = "import sys, truav.cli.swarm, truav.cli.swarm_up, truav.swarm.supervisor; assert 'ray' not in sys.modules"
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)


LOOPBACK_DRIVER = {"RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0"}
"""Ray resolves a loopback head address to the machine's address unless told the cluster is this machine's."""


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
    res = _up(tmp_path / "x", "--ray", "auto", "--secure")
    assert res.returncode == 2 and "--secure: not with --ray" in res.stderr, res.stderr
    res = _up(tmp_path / "y", "--ray-port", "9000")
    assert res.returncode == 2 and "--ray-port 9000: only with --ray" in res.stderr, res.stderr


@pytest.fixture
def three_nodes():
    cluster_utils = pytest.importorskip("ray.cluster_utils", reason="ray is not installed (the ray extra)")
    node = {"num_cpus": 1, "object_store_memory": 80 * 1024 ** 2, "node_ip_address": "127.0.0.1"}
    cluster = cluster_utils.Cluster(initialize_head=True, head_node_args={**node, "include_dashboard": False})
    try:
        for _ in range(2):
            cluster.add_node(**node)
        cluster.wait_for_nodes()
        yield cluster
    finally:
        cluster.shutdown()  # only the raylets this cluster started


@pytest.mark.slow  # ~25 s: a three-node cluster's start, then two swarms
def test_a_swarm_across_three_ray_nodes_equals_the_one_host_run(tmp_path, three_nodes):
    local = _up(tmp_path / "local", "-l", free_loopback_endpoint())
    assert local.returncode == 0, local.stdout + local.stderr
    port = int(free_loopback_endpoint().rsplit(":", 1)[1])
    res = _up(tmp_path / "ray", "--ray", three_nodes.address, "--ray-port", str(port))
    assert res.returncode == 0, res.stdout + res.stderr + "".join(
        f"\n--- {p.name}\n{p.read_text()[-2000:]}" for p in sorted((tmp_path / "ray" / "logs").glob("*.log")))
    placed = [ln for ln in res.stdout.splitlines() if ln.startswith("  node ")]
    assert len(placed) == 3 and all("router tcp/127.0.0.1:" in ln for ln in placed), res.stdout
    assert sum(ln.count("agents") for ln in placed) == 2  # two processes of two UAVs, on two of the nodes
    logs = {p.name for p in (tmp_path / "ray" / "logs").glob("router*.log")}
    assert len(logs) == 3, logs  # one router per node
    for i in range(4):
        a, b = np.load(tmp_path / "local" / f"agent{i}.npz"), np.load(tmp_path / "ray" / f"agent{i}.npz")
        assert sorted(a.files) == sorted(b.files)
        for key in a.files:
            np.testing.assert_array_equal(a[key], b[key], err_msg=f"agent{i}.npz {key}")
    digest = [json.loads((tmp_path / d / "world.json").read_text())["actions_digest"] for d in ("local", "ray")]
    assert digest[0] and digest[0] == digest[1]
