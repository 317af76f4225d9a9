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

Under --secure the supervisor makes the CA and every certificate in memory (a router-per-host deployment of
the plan's nodes, truav.bus.certs.site_bundles) and hands each node's :class:`CredentialsActor` only that
node's bundle through Ray; the actor writes it into a private directory of its node's own (mode 0700) that
the node's processes get as --creds, and removes it when the run ends. No shared file system sees a key.
"""

from __future__ import annotations

import atexit
import os
import shutil
import signal
import stat
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import ray
from ray.exceptions import ActorUnschedulableError, GetTimeoutError, RayActorError
from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

from truav.bus.acl import SUPERVISOR, file_stem
from truav.bus.certs import site_bundles
from truav.bus.secure_configs import tls_endpoint
from truav.bus.zenoh_config import make_config
from truav.faults import node_faults
from truav.lifecycle import child_env
from truav.swarm import supervisor
from truav.swarm.children import Children
from truav.swarm.ray_plan import PlanError, RayNode, RayPlan, place  # noqa: F401 - PlanError: `up` catches it
from truav.swarm.ray_recovery import NodeRecovery

CALL_TIMEOUT_S = 30.0
"""A call to a process's actor that takes longer counts its node as lost."""
START_TIMEOUT_S = 180.0
"""The first call, which waits for the actor's worker process to start: a busy node takes long (Ray's own
worker start-up allows 60 s per attempt, and retries)."""
ENV_PREFIXES = ("TRUAV_",)
"""The supervisor's environment variables handed to every process on the nodes."""


def _die_with_parent() -> None:  # in the child, before exec: SIGKILL when the actor's worker dies
    # A Ray worker blocks and ignores SIGINT (and ignores SIGQUIT): a child would inherit both through exec,
    # and the recorder, which finishes its file on SIGINT, would never see it. Signals as a shell gives them.
    signal.pthread_sigmask(signal.SIG_SETMASK, [])
    for sig in (signal.SIGINT, signal.SIGQUIT):
        signal.signal(sig, signal.SIG_DFL)
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


@ray.remote(num_cpus=0, max_restarts=0)
class CredentialsActor:
    """One node's credentials (--secure): its bundle's files in a new private directory on this node."""

    def __init__(self, files: dict[str, bytes]):
        self.directory = tempfile.mkdtemp(prefix="truav-creds-")  # mode 0700, on this node's own disk
        os.chmod(self.directory, 0o700)
        atexit.register(self.remove)
        for name, data in files.items():
            fd = os.open(os.path.join(self.directory, os.path.basename(name)), os.O_WRONLY | os.O_CREAT | os.O_EXCL,
                         0o600)  # keys and configs holding them: owner only
            with os.fdopen(fd, "wb") as f:
                f.write(data)

    def path(self) -> str:
        return self.directory

    def listing(self) -> tuple[int, list[str]]:
        """The directory's mode and file names (what a test checks)."""
        return stat.S_IMODE(os.stat(self.directory).st_mode), sorted(os.listdir(self.directory))

    def remove(self) -> None:
        shutil.rmtree(self.directory, ignore_errors=True)


class RayProcess:
    """A process on a Ray node, seen by the supervisor as a Popen."""

    def __init__(self, actor):
        self.actor = actor
        self.returncode: int | None = None
        self.ended_wall_ns: int | None = None  # when it was first seen gone (truav.swarm.ray_recovery)
        self.pid = self._call(actor.pid, timeout=START_TIMEOUT_S) or -1

    def _call(self, method, *args, timeout: float = CALL_TIMEOUT_S):
        try:
            return ray.get(method.remote(*args), timeout=timeout)
        except (RayActorError, ActorUnschedulableError, GetTimeoutError):  # its node or worker is gone: so is the process
            self.returncode = -signal.SIGKILL
            self.ended_wall_ns = self.ended_wall_ns or time.time_ns()
            return None

    def poll(self) -> int | None:
        if self.returncode is None:
            code = self._call(self.actor.poll)
            if self.returncode is None:
                self.returncode = code
                self.ended_wall_ns = None if code is None else time.time_ns()
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


def with_endpoint(argv: list[str], endpoint: str, flag: str = "-e") -> list[str]:
    """``argv`` with the value of every ``flag`` (``-e``: the router it connects to) replaced by ``endpoint``."""
    return [endpoint if k > 0 and argv[k - 1] == flag else a for k, a in enumerate(argv)]


class RayChildren(Children):
    """The supervisor's processes, each started by an actor on the node the plan gives it."""

    plan: RayPlan  # set by :func:`run_on_ray` (a subclass per run)

    def __init__(self, log_dir: Path, pid_file: Path | None = None, on_start=None):
        super().__init__(log_dir, None, on_start)  # PIDs of other nodes: `down` stops the run through the bus
        self.actors: list = []
        self.creds_actors: list = []
        self.creds_dirs: dict[str, str] = {}  # --secure: each node's credentials directory, on that node
        self.recovery = NodeRecovery(lambda: {n.node_id for n in cluster_nodes()})  # a lost node's agents elsewhere
        self.node_losses = self.recovery.losses  # the summary's (truav.swarm.summary)
        self.placed = self.plan  # the placement as started (a fault plan's node index is into its nodes)

    def secure_setup(self, out: Path, opts, n_uavs: int, endpoint: str, share_every_ticks: int = 0):
        """--secure (the supervisor's hook, as truav.bus.security.secure_setup): the CA and certificates made
        here in memory, each node's bundle handed to its :class:`CredentialsActor`; the router's and the
        processes' arguments (the core node's directory: :meth:`_spawn` puts each node's own) and the
        supervisor's zenoh config (this driver runs on the core node)."""
        self.recovery.secure = True
        sites = self.plan.sites()
        bundles = site_bundles(opts.run, n_uavs, sites)
        for router, site in zip(self.plan.routers, sites):
            actor = CredentialsActor.options(scheduling_strategy=NodeAffinitySchedulingStrategy(
                router.node_id, soft=False)).remote(bundles.pop(site.name))
            self.creds_actors.append(actor)
            self.creds_dirs[router.node_id] = ray.get(actor.path.remote(), timeout=CALL_TIMEOUT_S)
        core = self.creds_dirs[self.plan.core_node]
        sup = make_config(None, [tls_endpoint(self.plan.core_endpoint)], connect_timeout_ms=5000,
                          config_file=str(Path(core) / f"{file_stem(SUPERVISOR)}.json5"))
        return ["--creds", core], ["--creds", core], sup

    def _spawn(self, name: str, argv: list[str], log_path: Path):
        if name == "router" and not any(r.name in self.procs for r in self.plan.routers[1:]):
            for r in self.plan.routers[1:]:  # the other nodes' routers, linked to this one, once
                linked = (with_endpoint(argv, self.creds_dirs[r.node_id], "--creds") if self.creds_dirs
                          else [*argv[:argv.index("-l")], "-l", r.endpoint, "-e", r.connect])  # --creds: its config's
                self.argv[r.name] = linked
                self.starts[r.name] = 1
                self.started_at[r.name] = time.monotonic()
                self.procs[r.name] = self._actor(r.name, r.node_id, linked, self.log_dir / f"{r.name}.log")
        if name != "router":
            self.recovery.plan_for(self, name)  # its node lost: self.plan without it
            endpoint = self.plan.endpoint_of(name)
            argv = with_endpoint(argv, tls_endpoint(endpoint) if self.creds_dirs else endpoint)
        if self.creds_dirs:
            argv = with_endpoint(argv, self.creds_dirs[self.plan.node_of(name)], "--creds")
        return self._actor(name, self.plan.node_of(name), argv, log_path)

    def _actor(self, name: str, node_id: str, argv: list[str], log_path: Path) -> RayProcess:
        env = {k: v for k, v in os.environ.items() if k.startswith(ENV_PREFIXES)}
        actor = ProcessActor.options(scheduling_strategy=NodeAffinitySchedulingStrategy(node_id, soft=False)) \
            .remote(argv, str(log_path.absolute()), os.getcwd(), env)
        self.actors.append(actor)
        proc = RayProcess(actor)
        proc.node_id = node_id
        return proc

    def kill_node(self, k: int) -> None:
        """The nemesis (a fault plan's crash of node ``k``, truav.faults): every process of that node killed
        with its Ray worker, as when the node's workers are killed; the node is then lost (its router gone) and
        its agents' restarts place them on the nodes left (truav.swarm.ray_recovery)."""
        node = self.placed.nodes[k].node_id
        for proc in list(self.procs.values()):
            if getattr(proc, "node_id", None) == node and proc.poll() is None:
                ray.kill(proc.actor)  # its worker dies, and the process with it (PR_SET_PDEATHSIG)

    def close_logs(self) -> None:
        super().close_logs()
        for r in self.plan.routers[1:]:  # the supervisor stops the core router; the others after it
            if r.name in self.procs:
                self.stop([r.name], timeout=5.0)
        for actor in self.actors:
            ray.kill(actor)
        self.actors = []
        for actor in self.creds_actors:  # the keys go with the run
            try:
                ray.get(actor.remove.remote(), timeout=CALL_TIMEOUT_S)
            except (RayActorError, GetTimeoutError):
                pass  # its node is gone, and its directory with the node's temp dir or at its worker's exit
            ray.kill(actor)
        self.creds_actors = []


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
        for n, k in node_faults(opts.plan) if opts.plan is not None else ():
            if k >= len(plan.nodes):
                raise PlanError(f"fault plan {opts.fault_plan}: fault #{n + 1} (crash) names node {k}, but the cluster "
                                f"has {len(plan.nodes)} node(s) (0-{len(plan.nodes) - 1})")
        opts.listen = plan.core_endpoint
        say(f"Ray cluster {address}: {len(plan.nodes)} node(s)", flush=True)  # --quiet too: where things run
        for line in plan.lines(secure=opts.secure):
            say(f"  {line}", flush=True)
        children = type("PlacedChildren", (RayChildren,), {"plan": plan})
        return supervisor.run_swarm(cfg, opts, children)
    finally:
        ray.shutdown()
