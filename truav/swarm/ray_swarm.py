"""`truav-swarm up --ray ADDRESS|auto`: the same swarm, its processes placed on the nodes of a Ray cluster.

truav.swarm.ray_plan decides where each process runs (one router per node linked to the first node's,
the world and recorder on the first node, the agent processes spread over the nodes); here each
process becomes one Ray actor pinned to its node (node-affinity scheduling, no CPU reserved: the
actor only waits on its process) that starts the very command line the local `up` would, as a
subprocess with its output in the run's logs directory, and kills it when the actor dies. The
supervisor is the local one (truav.swarm.supervisor.run_swarm): it gets :class:`RayChildren` to start
its processes, every agent's ``-e`` pointing at its node's router. Logs and the run's files are
written on each node under the same path: a shared file system (as on Slurm, or a volume on KubeRay),
or one machine. Only this module imports Ray.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import ray
from ray.exceptions import GetTimeoutError, RayActorError
from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

from truav.lifecycle import child_env
from truav.swarm import supervisor
from truav.swarm.children import Children
from truav.swarm.ray_plan import PlanError, RayNode, RayPlan, place  # noqa: F401 - PlanError: `up` catches it

CALL_TIMEOUT_S = 30.0
"""A call to a process's actor that takes longer counts its node as lost."""
ENV_PREFIXES = ("TRUAV_",)
"""The supervisor's environment variables handed to every process on the nodes."""


def _die_with_parent() -> None:  # in the child, before exec: SIGKILL when the actor's worker dies
    try:
        import ctypes
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


@ray.remote(num_cpus=0, max_restarts=0)
class ProcessActor:
    """One of the swarm's processes on this actor's node."""

    def __init__(self, argv: list[str], log_path: str, cwd: str, env: dict[str, str]):
        argv = [sys.executable, *argv[1:]] if argv and argv[0].endswith(("python", "python3")) else argv
        Path(log_path).parent.mkdir(parents=True, exist_ok=True)
        with open(log_path, "ab") as log:
            self.proc = subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                         cwd=cwd, start_new_session=True, preexec_fn=_die_with_parent,
                                         env={**child_env(), **env})  # it stops when this actor is gone

    def pid(self) -> int:
        return self.proc.pid

    def poll(self) -> int | None:
        return self.proc.poll()

    def send_signal(self, sig: int) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(sig)


class RayProcess:
    """A process on a Ray node, seen by the supervisor as a Popen."""

    def __init__(self, actor):
        self.actor = actor
        self.returncode: int | None = None
        self.pid = self._call(actor.pid) or -1

    def _call(self, method, *args):
        try:
            return ray.get(method.remote(*args), timeout=CALL_TIMEOUT_S)
        except (RayActorError, GetTimeoutError):  # its node or worker is gone: so is the process
            self.returncode = -signal.SIGKILL
            return None

    def poll(self) -> int | None:
        if self.returncode is None:
            code = self._call(self.actor.poll)
            if self.returncode is None:
                self.returncode = code
        return self.returncode

    def wait(self, timeout: float | None = None) -> int:
        deadline = None if timeout is None else time.monotonic() + timeout
        while self.poll() is None:
            if deadline is not None and time.monotonic() >= deadline:
                raise subprocess.TimeoutExpired("ray actor", timeout)
            time.sleep(0.05)
        return self.returncode

    def send_signal(self, sig) -> None:
        if self.poll() is None:
            self._call(self.actor.send_signal, int(sig))

    def kill(self) -> None:
        self.send_signal(signal.SIGKILL)

    def terminate(self) -> None:
        self.send_signal(signal.SIGTERM)


def with_endpoint(argv: list[str], endpoint: str) -> list[str]:
    """``argv`` with the value of every ``-e`` (the router it connects to) replaced by ``endpoint``."""
    return [endpoint if k > 0 and argv[k - 1] == "-e" else a for k, a in enumerate(argv)]


class RayChildren(Children):
    """The supervisor's processes, each started by an actor on the node the plan gives it."""

    plan: RayPlan  # set by :func:`run_on_ray` (a subclass per run)

    def __init__(self, log_dir: Path, pid_file: Path | None = None, on_start=None):
        super().__init__(log_dir, None, on_start)  # PIDs of other nodes: `down` stops the run through the bus
        self.actors: list = []

    def _spawn(self, name: str, argv: list[str], log_path: Path):
        if name == "router" and not any(r.name in self.procs for r in self.plan.routers[1:]):
            for r in self.plan.routers[1:]:  # the other nodes' routers, linked to this one, once
                linked = [*argv[:argv.index("-l")], "-l", r.endpoint, "-e", r.connect]
                self.argv[r.name] = linked
                self.starts[r.name] = 1
                self.started_at[r.name] = time.monotonic()
                self.procs[r.name] = self._actor(r.name, r.node_id, linked, self.log_dir / f"{r.name}.log")
        if name != "router":
            argv = with_endpoint(argv, self.plan.endpoint_of(name))
        return self._actor(name, self.plan.node_of(name), argv, log_path)

    def _actor(self, name: str, node_id: str, argv: list[str], log_path: Path) -> RayProcess:
        env = {k: v for k, v in os.environ.items() if k.startswith(ENV_PREFIXES)}
        actor = ProcessActor.options(scheduling_strategy=NodeAffinitySchedulingStrategy(node_id, soft=False)) \
            .remote(argv, str(log_path.absolute()), os.getcwd(), env)
        self.actors.append(actor)
        return RayProcess(actor)

    def close_logs(self) -> None:
        super().close_logs()
        for r in self.plan.routers[1:]:  # the supervisor stops the core router; the others after it
            if r.name in self.procs:
                self.stop([r.name], timeout=5.0)
        for actor in self.actors:
            ray.kill(actor)
        self.actors = []


def cluster_nodes() -> list[RayNode]:
    """The alive nodes, the driver's first (the supervisor's session reaches the core router from there)."""
    here = ray.get_runtime_context().get_node_id()
    nodes = [RayNode(n["NodeID"], n["NodeManagerAddress"], n.get("Resources", {}).get("CPU", 0.0))
             for n in ray.nodes() if n.get("Alive")]
    return sorted(nodes, key=lambda n: (n.node_id != here, n.node_id))


def run_on_ray(cfg, opts, address: str, port: int, say=print) -> int:
    """Connect to the cluster at ``address`` ("auto": the one this machine belongs to), place the swarm,
    run it under the local supervisor; the exit code as `up`'s."""
    try:
        ray.init(address=address, log_to_driver=False, logging_level="ERROR")
    except (ConnectionError, RuntimeError, ValueError) as exc:
        raise PlanError(f"--ray {address}: cannot join the cluster ({str(exc).splitlines()[0] if str(exc) else exc})") from None
    try:
        plan = place(cluster_nodes(), cfg.scenario.n_uavs, opts.agents_per_process, port, opts.external)
        opts.listen = plan.core_endpoint
        say(f"Ray cluster {address}: {len(plan.nodes)} node(s)", flush=True)  # --quiet too: where things run
        for line in plan.lines():
            say(f"  {line}", flush=True)
        children = type("PlacedChildren", (RayChildren,), {"plan": plan})
        return supervisor.run_swarm(cfg, opts, children)
    finally:
        ray.shutdown()
