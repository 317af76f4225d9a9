"""`truav-swarm up`: start and watch a swarm of OS processes, then summarise.

The supervisor starts a Zenoh router on loopback (tcp/127.0.0.1:7447 when
free), optionally the recorder, the world process and one process per UAV
agent (all `python -m truav.cli.swarm ...`, logs under <out>/logs/), watches
the bus (liveliness, step metrics, beacons, shutdown requests) for a live
status table, and at the end (or on Ctrl-C, SIGTERM or SIGHUP) stops every
process it started, by PID, and prints a summary; it also draws
<out>/summary.png.  Killed outright, it cannot: its children then notice it is
gone and stop by themselves (:mod:`truav.lifecycle`).

Honest outcomes.  The exit code is 0 only when the world ran all its
episodes; 130 when the user stopped the run (Ctrl-C or
`truav-swarm down`; 143 for SIGTERM, 129 for SIGHUP); 2 when it could not start because of a user mistake;
1 when something went wrong: an agent or the world could not start, the
router died and could not be restarted (or died with ``--restart never``), the
recorder died, a process died more than ``--restart-limit`` times, the recorder
could not finish its file, more than ``max_missed_share`` of the actions were
missing, a lock-step run went on without a live process's message (it waited
``--lockstep-wait`` for it: the run is no longer exact, and summary.json's
``outcome.lockstep`` says how many decisions and from which tick), a shutdown came from
an unknown sender, or a process had to be killed at shutdown.  The summary's
last lines say what ended the run (and who sent its shutdown) and why it failed.

Healing (:mod:`truav.swarm.healing`): with ``--restart on-failure`` (the
default) an agent or controller that dies on its own is restarted from its
checkpoint after a backoff, and a dead router is restarted on its endpoint;
each restart is in the console, the summary, summary.json ("restarts") and
the recording (truav/<run>/fault/restart).  summary.json's "processes" lists
every process started (PID, exit code, memory).

Shutdown loses nothing.  Frozen agents are thawed first; agents get
:data:`AGENT_EXIT_GRACE_S` to leave on the world's shutdown, then SIGTERM and
:data:`AGENT_STOP_TIMEOUT_S` to write their final checkpoint and statistics;
the recorder gets :data:`RECORDER_STOP_TIMEOUT_S` to finish its file.  Only a
process still running after that is SIGKILLed, and the summary says so.
"""
from __future__ import annotations

import contextlib
import os
import signal
import sys
import time
from pathlib import Path

from agents.process.agent_options import AgentOptions
from agents.process.controller_options import ControllerOptions
from recorder.process.recorder import recorder_argv
from truav import kernel_cache
from truav.analysis.warmup import ensure_compiled
from truav.bus import transport
from truav.bus.security import SUPERVISOR, secure_setup, tls_endpoint
from truav.bus.transport import Bus, make_config
from truav.config import Config, to_toml
from truav.faults import FaultPlan, load_plan, node_faults
from truav.lifecycle import signals_handled
from truav.options import to_argv
from truav.wire import guard
from truav.swarm.children import (Children, ListenError, check_listen, default_endpoint, free_loopback_endpoint,
                                  stop_recorded_pids, wait_for_port, ROUTER_READY_LINE)
from truav.atomic import no_space
from truav.swarm.external import instructions
from truav.swarm.fault_control import FaultController
from truav.swarm.healing import Healer
from truav.swarm.monitor import Monitor
from truav.swarm.outdir import (PID_FILE, SCENARIO_FILE, OutDirError, check_record_path, check_swarm_dir,
                                hold_run_dirs, prepare_swarm_dir, write_run_file)
from truav.swarm.summary import SwarmEnd, _print_central  # noqa: F401 - _print_central: tests
from truav.swarm.swarm_options import (  # noqa: F401 - re-exported: `down`, bench and tests take them from here
    AGENT_STOP_TIMEOUT_S, DOWN_IDENTITY, RECORDER_STOP_TIMEOUT_S, ROUTER_START_TIMEOUT_S, Outcome, SwarmOptions,
    agent_groups, default_out_dir, group_name, process_of)
from truav.swarm.swarm_watch import SwarmWatch
from world.process.world_options import WorldOptions

__all__ = ["SwarmOptions", "run_swarm", "free_loopback_endpoint", "wait_for_port", "stop_recorded_pids",
           "DOWN_IDENTITY", "PID_FILE", "SCENARIO_FILE"]


class _Interrupts:
    """SIGINT, SIGTERM and SIGHUP stop the swarm (KeyboardInterrupt in the main thread), once: a signal
    during the shutdown does not cut it short (the children would lose their final writes)."""

    def __init__(self) -> None:
        self.by: str | None = None
        self.stopping = False

    def __call__(self, signum: int, _frame: object) -> None:
        name = {signal.SIGINT: "Ctrl-C"}.get(signum, signal.Signals(signum).name)
        if self.stopping:
            print(f"\n{name}: already stopping; waiting for every process to write its files "
                  f"(at most {AGENT_STOP_TIMEOUT_S + RECORDER_STOP_TIMEOUT_S:.0f} s)", flush=True)
            return
        self.by = name
        self.stopping = True
        raise KeyboardInterrupt


def run_info(opts: SwarmOptions) -> dict:
    """How this run is started beyond its config, for the recording (recorder.metadata.RUN_METADATA): what the
    re-simulation of a lock-step recording needs to re-run it (`truav log resim`)."""
    return {"seed": opts.seed, "lockstep": opts.lockstep, "scheme": opts.scheme, "episodes": opts.episodes,
            "qtable": str(Path(opts.qtable).resolve()) if opts.qtable else None, "qtable_index": 0,
            "greedy": opts.greedy, "resume": opts.resume, "external": list(opts.external),
            "fault_plan": str(Path(opts.fault_plan).resolve()) if opts.fault_plan else None}


def _python_module(*args: str) -> list[str]:
    return [sys.executable, "-m", *args]


def run_swarm(cfg: Config, opts: SwarmOptions, children=Children) -> int:
    """Run a swarm to its end (or Ctrl-C, SIGTERM, SIGHUP), stop every process it started, summarise.

    ``children(log_dir, pid_file, on_start)`` starts the processes (truav.swarm.ray_swarm: on Ray nodes).
    Returns the exit code (see the module docstring)."""
    out = opts.out_dir
    with contextlib.ExitStack() as held:
        try:  # every check that needs no process, before anything starts or any file is touched
            if opts.record:
                check_record_path(opts.record, opts.force)
            if opts.listen:
                check_listen(opts.listen)
            plan = opts.plan if opts.plan is not None else load_plan(opts.fault_plan) if opts.fault_plan else None
            if plan is not None and node_faults(plan) and not hasattr(children, "kill_node"):
                where = f"fault plan {opts.fault_plan}: " if opts.fault_plan else ""
                print(f"truav-swarm: error: {where}fault #{node_faults(plan)[0][0] + 1} (crash) kills a Ray node: "
                      f"only with --ray", file=sys.stderr)
                return 2
            check_swarm_dir(out, resume=opts.resume, force=opts.force)
            # Held until the summary is written: no other run replaces or continues this one meanwhile.
            held.enter_context(hold_run_dirs([out], run=opts.run, command="truav-swarm up"))
            prepare_swarm_dir(out, to_toml(cfg), resume=opts.resume, force=opts.force)
            if opts.record:
                Path(opts.record).absolute().parent.mkdir(parents=True, exist_ok=True)
        except (OutDirError, ListenError, OSError) as exc:
            if no_space(exc):  # not a mistake of the user's command: exit 1
                print(f"truav-swarm: error: no space left on {out.absolute()}: {exc.filename or ''}", file=sys.stderr)
                return 1
            print(f"truav-swarm: error: {exc}", file=sys.stderr)
            return 2
        return _run_held(cfg, opts, out, plan, children)


def _run_held(cfg: Config, opts: SwarmOptions, out: Path, plan, children) -> int:
    interrupts = _Interrupts()
    with signals_handled((signal.SIGINT, signal.SIGTERM, signal.SIGHUP), interrupts):
        try:  # before any process starts: else the world and every agent compile the same kernels side by side
            ensure_compiled(lambda line: print(line, flush=True))
        except KeyboardInterrupt:
            print(f"interrupted ({interrupts.by or 'Ctrl-C'}) while compiling; nothing was started", flush=True)
            return Outcome(interrupted_by=interrupts.by or "Ctrl-C").exit_code()
        return _Swarm(cfg, opts, out, plan, interrupts, children).run()


class _Swarm(SwarmWatch, SwarmEnd):
    """One run: its start-up here, its watch in SwarmWatch, its end and summary in SwarmEnd."""

    def __init__(self, cfg: Config, opts: SwarmOptions, out: Path, plan, interrupts: _Interrupts, children=Children):
        self.cfg, self.opts, self.out, self.plan, self.interrupts = cfg, opts, out, plan, interrupts
        self.n = cfg.scenario.n_uavs
        self.groups = agent_groups(self.n, opts.agents_per_process, opts.external)  # external UAVs: no process
        self.agents = [group_name(g) for g in self.groups]  # the agent processes' names
        self.central = opts.scheme == "central"
        self.fleet = self.agents + (["controller"] if self.central else [])
        """The processes a fault plan may kill or freeze; a frozen one is thawed before it is stopped."""
        self.children = children(out / "logs", out / PID_FILE, on_start=self._started if opts.verbose else None)
        self.monitor = Monitor(self.n, period_s=1.0 / opts.rate_hz)
        self.outcome = Outcome()
        self.controller: FaultController | None = None
        self.planned_exits: set[int] = set()  # PIDs the fault plan killed
        self.healer = Healer(opts.restart, opts.restart_limit)
        self.deaths: list[tuple[str, float]] = []  # (process, monotonic) of each kill or death seen (restart_cost)
        self.bus: Bus | None = None  # the supervisor's session, once open (restarts are published on it)
        self.router_down_ns: int | None = None  # wall clock of the router's death, until it is back
        self.router_outages: list[tuple[int, int]] = []  # (died, listening again), wall-clock ns
        self.endpoint = opts.listen
        self.external_since: float | None = None  # monotonic time the external UAVs' commands were printed
        self.external_joined: dict[int, float] = {}  # external UAV -> s since start its token was first seen
        self.external_left: dict[int, float] = {}  # external UAV -> s since start its token went, mid-run
        self.external_progress = 0.0  # s waited for them at the last progress line
        self.t0 = time.monotonic()
        self.t0_wall_ns = time.time_ns()  # the same instant on the wall clock (recordings' log times)

    def _started(self, name: str, proc) -> None:
        print(f"started {name} (pid {proc.pid}, log {self.children.log_dir / name}.log)", flush=True)

    def _since(self) -> float:
        return time.monotonic() - self.t0

    # -- the run --
    def run(self) -> int:
        normal_end = False
        try:
            if self._start_router() and self._start_rest():
                normal_end = True
        except KeyboardInterrupt:
            self.outcome.interrupted_by = self.interrupts.by or "Ctrl-C"
            self.outcome.ended_by = f"interrupted ({self.outcome.interrupted_by})"
            print(f"\n{self.outcome.ended_by}: stopping every process of the swarm", flush=True)
        finally:
            self.interrupts.stopping = True
            self._shutdown(normal_end and not self.outcome.failures)
        self._judge()
        self._summary(time.monotonic() - self.t0)
        return self.outcome.exit_code()

    def _start_router(self) -> bool:
        default = self.opts.listen is None
        self.endpoint = self.opts.listen or default_endpoint()
        ok, error = self._router_ready(ROUTER_START_TIMEOUT_S)
        if not ok and default and "in use" in error:  # lost a race for 7447 to another process: any port will do
            lost = self.children.pids().get("router")
            if lost is not None:  # its exit 1 is this retry's cause, not a fault of the run (truav.swarm.invariants)
                self.outcome.superseded.append({"process": "router", "pid": lost,
                                                "cause": f"{self.endpoint} in use; started again on a free port"})
            self.endpoint = free_loopback_endpoint()
            ok, error = self._router_ready(ROUTER_START_TIMEOUT_S)
        if not ok:
            self.outcome.fail(f"the router could not listen on {self.endpoint}: {error}")
        return ok

    def _router_ready(self, timeout: float) -> tuple[bool, str]:
        router_args = ["-l", self.endpoint]
        self.creds_args: list[str] = []
        self.bus_config = make_config(connect=[self.endpoint], connect_timeout_ms=5000)
        if self.opts.secure:  # fresh credentials for this endpoint; every process gets its own certificate
            setup = getattr(self.children, "secure_setup", secure_setup)  # on Ray: each node's own (ray_swarm)
            router_args, self.creds_args, self.bus_config = setup(
                self.out, self.opts, self.n, self.endpoint,
                self.cfg.federated.every * self.cfg.scenario.steps_per_episode)
            self.endpoint = tls_endpoint(self.endpoint)
        proc = self.children.start("router", _python_module("truav.cli.swarm", "router", *router_args))
        return self._wait_router(proc, timeout)

    def _wait_router(self, proc, timeout: float) -> tuple[bool, str]:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if ROUTER_READY_LINE in self.children.log_text("router"):
                return True, ""
            if proc.poll() is not None:
                return False, self.children.last_line("router")
            time.sleep(0.02)
        return False, f"not listening after {timeout:.0f} s (see {self.children.log_dir}/router.log)"

    def _start_rest(self) -> bool:
        opts, out, ep = self.opts, self.out, self.endpoint
        # Asked before any child starts to fill the cache: a cold one costs the first start most of a minute.
        self.cold_note = kernel_cache.cold_start_note(kernel_cache.SWARM_KERNELS
                                                      + (["agents/sac_kernels.py", "agents/central.py"] if self.central else []))
        write_run_file(out, {"run": opts.run, "endpoint": ep, "supervisor_pid": os.getpid(), "agents": self.n,
                             **({"external": list(opts.external)} if opts.external else {})})
        if opts.external:  # first, so the user can start them while the rest comes up
            for line in instructions(opts.external, opts.run, ep, out, lockstep=opts.lockstep, secure=opts.secure,
                                     wait_s=opts.external_wait_s):
                print(line, flush=True)
            self.external_since = time.monotonic()
        scenario = out / SCENARIO_FILE
        scenario_args = ["--run", opts.run, "--seed", str(opts.seed), "--scenario", str(scenario), "-e", ep,
                         *self.creds_args]
        common = [*scenario_args, "--router-timeout", str(opts.router_timeout_s)]
        timing = (["--lockstep", "--lockstep-wait", repr(opts.lockstep_wait_s)] if opts.lockstep else []) \
            + (["-v"] if opts.verbose else [])
        faults_args = ["--fault-plan", str(Path(opts.fault_plan).resolve())] if self.plan else []
        origin = ["--geo-origin", "%r,%r" % opts.geo_origin] if opts.geo_origin else []
        if opts.record:
            self.children.start("recorder", recorder_argv(
                opts.run, opts.record, [ep], config_toml=scenario, force=opts.force, geo_origin=opts.geo_origin,
                modes=opts.record_modes,
                extra=[*self.creds_args, *(["-v"] if opts.verbose else [])], run_info=run_info(opts)))
        if opts.foxglove_port is not None:
            self.children.start("view", _python_module("truav.cli.swarm", "view", *scenario_args, *origin,
                                                        "--port", str(opts.foxglove_port)))
        with Bus(SUPERVISOR, opts.run, self.bus_config) as bus:
            self.bus = bus
            bus.guard = guard.for_config(self.cfg)  # what the world and agents refuse, the monitor refuses too
            bus.rejections.quiet_reasons = frozenset({guard.R_TICK})  # a monitor behind a fast lock-step run: its lag
            # Real time: a flood costs the monitor a bounded amount of work, as it does the world and agents.
            bus.receive_ring = None if opts.lockstep else transport.REALTIME_RECEIVE_RING
            self.monitor.attach(bus, opts.run, central=self.central, tracks_from_world=opts.scheme != "truav")
            if opts.record and not self._recorder_ready(bus):
                return False
            # With or without a plan: a plan sent to the live run (`truav-swarm faults`) is scheduled and told too.
            hooks = {"kill": self._plan_kill, "restart": self._plan_restart,
                     "freeze": lambda u: self.children.send(process_of(u), signal.SIGSTOP),
                     "thaw": lambda u: self.children.send(process_of(u), signal.SIGCONT),
                     "kill_node": getattr(self.children, "kill_node", None)}  # --ray: truav.swarm.ray_swarm
            self.controller = FaultController(bus, opts.run, self.plan or FaultPlan(), hooks)
            scheme = ["--scheme", opts.scheme]
            if self.central:  # before the world, which waits for it (and the agents) before tick 0
                controller = ControllerOptions(policy=str(Path(opts.policy).resolve()) if opts.policy else None,
                                               policy_index=opts.policy_index, stats_out=str(out / "controller.json"))
                self.children.start("controller", _python_module(
                    "truav.cli.swarm", "controller", *common, *timing, *faults_args, "--rate", str(opts.rate_hz),
                    *to_argv(controller, (["policy", "policy_index"] if opts.policy else []) + ["stats_out"])))
            # Snapshots only where a recording keeps them and a re-simulation can use them.
            snapshot_every = opts.snapshot_every if opts.record and opts.lockstep and opts.scheme == "truav" else 0
            # The supervisor's bounded wait for external UAVs decides (with its progress lines); the world's is longer.
            world = WorldOptions(episodes=opts.episodes, rate_hz=opts.rate_hz, stats_out=str(out / "world.json"),
                                 wait_agents_s=opts.wait_agents_s + (opts.external_wait_s if opts.external else 0.0),
                                 max_missed_share=1.0,  # up judges the missed share itself (summary, chaos)
                                 snapshot_every=snapshot_every)
            self.children.start("world", _python_module(
                "truav.cli.swarm", "world", *common, *timing, *faults_args, *scheme,
                *to_argv(world, ["episodes", "rate_hz", "stats_out", "wait_agents_s", "max_missed_share",
                                 "snapshot_every"])))
            for ids in self.groups:
                name = "{id}" if len(ids) > 1 else str(ids[0])  # the agent process fills in each UAV's id
                agent = AgentOptions(checkpoint=str(out / f"agent{name}.npz"), stats_out=str(out / f"agent{name}.json"),
                                     checkpoint_every=opts.checkpoint_every, qtable=opts.qtable or None,
                                     command_hold_s=opts.command_hold_s, beacon_every=opts.beacon_every,
                                     beacon_cell_m=opts.beacon_cell_m, beacon_slots=opts.beacon_slots,
                                     snapshot_every=snapshot_every)
                extra = [*to_argv(agent, ["checkpoint", "stats_out", "checkpoint_every", "snapshot_every"]), *scheme,
                         *to_argv(agent, ["qtable"])]
                extra += ["--greedy"] if opts.greedy else []
                extra += to_argv(agent, ["command_hold_s"]) if self.central else []
                extra += to_argv(agent, ["beacon_every"]) if opts.beacon_every != 1 else []
                extra += to_argv(agent, ["beacon_cell_m"])
                extra += to_argv(agent, ["beacon_slots"]) if opts.beacon_slots != AgentOptions.beacon_slots else []
                extra += ["--share-beacons"] if opts.share_beacons and len(ids) > 1 else []
                extra += ["--batch-beacons"] if opts.batch_beacons else []
                self.children.start(group_name(ids), _python_module(
                    "truav.cli.swarm", "agent", *[a for i in ids for a in ("--id", str(i))], *common, *timing,
                    *faults_args, "--rate", str(opts.rate_hz), *extra))
            self._announce()
            ok = self._watch()
            self.monitor.poll()
            if self.controller is not None:
                self.controller.stop()
            return ok

    def _announce(self) -> None:
        opts, ep = self.opts, self.endpoint
        default_out = default_out_dir(opts.run)
        where = "" if self.out == default_out else f" --out {self.out}"
        external = ", ".join(f"uav/{i}" for i in opts.external)
        print(f"swarm '{opts.run}' ({opts.scheme}): router {ep}, world + {self.n - len(opts.external)} agents"
              f"{' + external ' + external + ' (yours)' if external else ''}"
              f"{' + controller (' + (opts.policy or 'learning online') + ')' if self.central else ''}"
              f"{' + recorder -> ' + opts.record if opts.record else ''}; "
              f"{'lock-step' if opts.lockstep else f'{opts.rate_hz:g} Hz'}; logs in {self.out}/logs\n"
              f"  watch it: truav-swarm status --run {opts.run}{where}    stop it: truav-swarm down --run {opts.run}{where}", flush=True)
        if opts.foxglove_port is not None:
            print(f"Foxglove: open ws://127.0.0.1:{opts.foxglove_port} (layout deploy/foxglove-layout.json)", flush=True)
        if self.cold_note:  # else tick 0 waits for the compiler without a word
            print(f"{self.cold_note}; tick 0 comes once the world and the agents have them", flush=True)


