"""A real three-node Ray cluster on this machine (ray.cluster_utils.Cluster: a raylet per node, each on
loopback, one CPU each), for the tests of `truav-swarm up --ray`, and the environment its drivers need."""

from __future__ import annotations

import contextlib

LOOPBACK_DRIVER = {"RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0"}
"""Ray resolves a loopback head address to the machine's address unless told the cluster is this machine's."""
NODE = {"num_cpus": 1, "object_store_memory": 80 * 1024 ** 2, "node_ip_address": "127.0.0.1"}
ATTEMPTS = 3
"""A raylet has 30 s to register: a loaded host can miss that, so a cluster's start is tried this many times."""


def _started(cluster_utils):
    for attempt in range(ATTEMPTS):
        cluster = cluster_utils.Cluster()
        try:
            cluster.add_node(**NODE, include_dashboard=False)
            for _ in range(2):
                cluster.add_node(**NODE)
            cluster.wait_for_nodes()
            return cluster
        except Exception:
            cluster.shutdown()  # only the raylets this cluster started
            if attempt == ATTEMPTS - 1:
                raise
    raise AssertionError("unreachable")


@contextlib.contextmanager
def three_ray_nodes(cluster_utils):
    """The cluster (``cluster.address`` for --ray), shut down at the end: only the raylets it started.
    ``cluster_utils``: ray.cluster_utils, from the test's pytest.importorskip (ray is an optional extra)."""
    cluster = _started(cluster_utils)
    try:
        yield cluster
    finally:
        cluster.shutdown()
