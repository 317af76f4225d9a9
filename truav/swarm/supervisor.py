"""`truav-swarm up`: start and watch a swarm of OS processes, then summarise.

The supervisor starts a Zenoh router on loopback (tcp/127.0.0.1:7447 when
free), optionally the recorder, the world process and one process per UAV
agent (all `python -m truav.swarm.cli ...`, logs under <out>/logs/), watches
the bus (liveliness, step metrics, beacons, shutdown requests) for a live
status table, and at the end (or on Ctrl-C, SIGTERM or SIGHUP) stops every
process it started, by PID, and prints a summary; it also draws
<out>/summary.png.  Killed outright, it cannot: its children then notice it is
gone and stop by themselves (:mod:`truav.lifecycle`).

Honest outcomes.  The exit code is 0 only when the world ran all its
episodes; 130 when the user stopped the run (Ctrl-C, SIGTERM, SIGHUP,
`truav-swarm down`); 2 when it could not start because of a user mistake;
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
import json
import os
import signal
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from agents.agent_process import AgentOptions
from agents.central_process import ControllerOptions
from truav.bus import guard, keys, transport
from truav.bus.security import SUPERVISOR, secure_setup, tls_endpoint
from truav.bus.transport import Bus, make_config
from truav.config import Config, to_toml
from truav.lograte import Every
from truav.options import to_argv
from truav.faults import load_plan
from truav.swarm.children import (Children, ListenError, check_listen, default_endpoint, exit_text,
                                  free_loopback_endpoint, stop_recorded_pids, wait_for_port, ROUTER_READY_LINE)
from truav.swarm.fault_control import FaultController
from truav.swarm.healing import (DEFAULT_RESTART_LIMIT, DEFAULT_RESTART_POLICY, RESTART_RECORD,
                                 RESTART_BACKOFF_MAX_S, ROUTER_BACKOFF_MAX_S, Healer, Restart)
from truav.bus.schema import DEFAULT_LOCKSTEP_WAIT_S
from truav.lifecycle import DEFAULT_ROUTER_TIMEOUT_S, signals_handled
from truav.swarm.monitor import Monitor
from world.world_process import WorldOptions
from truav.swarm.outdir import (PID_FILE, SCENARIO_FILE, SUMMARY_FILE, OutDirError, check_record_path,
                                prepare_swarm_dir, write_run_file)

__all__ = ["SwarmOptions", "run_swarm", "free_loopback_endpoint", "wait_for_port", "stop_recorded_pids",
           "DOWN_IDENTITY", "PID_FILE", "SCENARIO_FILE"]

DOWN_IDENTITY = "supervisor"
"""The sender of `truav-swarm down`'s shutdown request."""
SHUTDOWN_SENDERS = {keys.SRC_WORLD: "the world, after its last episode", DOWN_IDENTITY: "`truav-swarm down`"}
"""Senders whose shutdown is expected; one from anyone else fails the run (and names the sender)."""

STATUS_PERIOD_S = 1.0
ROUTER_START_TIMEOUT_S = 15.0
RECORDER_START_TIMEOUT_S = 30.0
AGENT_EXIT_GRACE_S = 5.0
"""Normal end: agents leave by themselves on the world's shutdown; SIGTERM after this long."""
AGENT_STOP_TIMEOUT_S = 30.0
"""After SIGTERM an agent writes its final checkpoint and statistics (an fsync each); SIGKILL after this long."""
WORLD_STOP_TIMEOUT_S = 15.0
RECORDER_STOP_TIMEOUT_S = 90.0
"""The recorder writes its backlog and footer (its writer alone may take 60 s), then rewrites the
file into big chunks (seconds per 10 MB); SIGKILL after this long."""
ROUTER_STOP_TIMEOUT_S = 5.0
ROUTER_RECONNECT_WAIT_S = 10.0
"""After restarting the router: how long the supervisor waits for its own session to reconnect."""
RSS_PERIOD_S = 5.0
"""How often the supervisor samples its children's memory (summary.json "processes")."""
CENTRAL_STATE_VALUES = 50
"""The paper's centralized baseline: each UAV uploads a 50-value state at 10 Hz."""
CENTRAL_VALUE_BYTES = 4


@dataclass
class SwarmOptions:
    run: str = "demo"
    seed: int = 0
    episodes: int = 2
    lockstep: bool = False
    lockstep_wait_s: float = DEFAULT_LOCKSTEP_WAIT_S
    """Lock-step: how long world and agents wait for a live process before the run gives up exactness."""
    rate_hz: float = 10.0
    record: str | None = None
    qtable: str | None = None
    greedy: bool = False
    out: str | None = None
    listen: str | None = None
    plot: bool = True
    quiet: bool = False
    wait_agents_s: float = 60.0
    checkpoint_every: int = 50
    """Agents checkpoint their Q-table every this many steps."""
    verbose: bool = False
    """Children log at DEBUG level too; each process's start is printed."""
    fault_plan: str | None = None
    """Fault plan TOML (truav.faults): link faults applied by every process,
    crashes and freezes sent by this supervisor."""
    resume: bool = False
    """Continue the run already in ``out`` (agents resume from its checkpoints); else ``out`` must be empty."""
    force: bool = False
    """Delete an earlier run's files in ``out`` first, and overwrite ``record``."""
    max_missed_share: float = 0.5
    """The run fails when more than this share of the actions the world waited for did not come."""
    router_timeout_s: float = DEFAULT_ROUTER_TIMEOUT_S
    """World and agents stop by themselves this long after losing their router."""
    foxglove_port: int | None = None
    """Serve the run to the Foxglove app on ws://127.0.0.1:<port> (`truav-swarm view`)."""
    geo_origin: tuple[float, float] | None = None
    """(lat, lon) of the area's centre on Foxglove's map (recorder and view); None: Paris."""
    secure: bool = False
    """Mutual TLS and the router's access control, with fresh credentials in <out>/creds (truav.bus.security)."""
    scheme: str = "truav"
    """truav (Q-learning agents) | central (a controller process commands every UAV) | patrol (the plan)."""
    policy: str | None = None
    """Scheme central: the trained controller to fly (`truav train --scheme central` run); None: learn online."""
    policy_index: int = 0
    command_hold_s: float = 1.0
    """Scheme central: how long a UAV keeps its last command once commands stop, then hovers."""
    beacon_every: int = 1
    """Real time: agents beacon every this many ticks (10 at 10 Hz: 1 Hz, the Remote ID rate)."""
    beacon_cell_m: float | None = None
    """Real time: range-limited beacons under map cells of this side (agents/beacon_cells.py); None: all-to-all."""
    agents_per_process: int = 1
    """Agents hosted by one OS process, each with its own session, identity and files (fewer processes:
    less memory and start-up for a large swarm). Fault plans that kill or freeze agents need 1."""
    share_beacons: bool = False
    """With agents_per_process > 1: one beacon subscription per process, fanned out to its agents' inboxes."""
    restart: str = DEFAULT_RESTART_POLICY
    """on-failure: restart an agent, the controller or the router that dies on its own (truav.swarm.healing); never."""
    restart_limit: int = DEFAULT_RESTART_LIMIT
    """Restarts of one process before it is left down and the run fails."""


def agent_groups(n: int, per_process: int) -> list[list[int]]:
    """UAV ids 0..n-1 in consecutive groups of ``per_process``, one process each."""
    return [list(range(a, min(a + per_process, n))) for a in range(0, n, per_process)]


def group_name(ids: list[int]) -> str:
    """The process name (log file, pids.json) of a group: ``agent3`` alone, ``agents0-9`` for several."""
    return f"agent{ids[0]}" if len(ids) == 1 else f"agents{ids[0]}-{ids[-1]}"


@dataclass
class Outcome:
    """How a run ended: what ended it, what went wrong, what the user should know."""

    ended_by: str = ""
    interrupted_by: str | None = None  # Ctrl-C, SIGTERM, SIGHUP or `truav-swarm down`
    failures: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    shutdowns: list[tuple[float, str]] = field(default_factory=list)  # (s since start, sender)
    ticked: bool = False
    exactness: dict | None = None  # lock-step only: see lockstep_exactness
    restarts: list[dict] = field(default_factory=list)  # truav.swarm.healing.Restart.as_dict(), in order

    def fail(self, reason: str) -> None:
        if reason not in self.failures:
            self.failures.append(reason)
        self.ended_by = self.ended_by or reason

    @property
    def result(self) -> str:
        return "failed" if self.failures else "interrupted" if self.interrupted_by else "ok"

    def exit_code(self) -> int:
        return 1 if self.failures else 130 if self.interrupted_by else 0


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


def _python_module(*args: str) -> list[str]:
    return [sys.executable, "-m", *args]


def run_swarm(cfg: Config, opts: SwarmOptions) -> int:
    """Run a swarm to its end (or Ctrl-C, SIGTERM, SIGHUP), stop every process it started, summarise.

    Returns the exit code (see the module docstring)."""
    out = Path(opts.out or f"runs/swarm-{opts.run}")
    try:  # every check that needs no process, before anything starts or any file is touched
        if opts.record:
            check_record_path(opts.record, opts.force)
        if opts.listen:
            check_listen(opts.listen)
        plan = load_plan(opts.fault_plan) if opts.fault_plan else None
        prepare_swarm_dir(out, to_toml(cfg), resume=opts.resume, force=opts.force)
        if opts.record:
            Path(opts.record).absolute().parent.mkdir(parents=True, exist_ok=True)
    except (OutDirError, ListenError, OSError) as exc:
        print(f"truav-swarm: error: {exc}", file=sys.stderr)
        return 2
    interrupts = _Interrupts()
    with signals_handled((signal.SIGINT, signal.SIGTERM, signal.SIGHUP), interrupts):
        return _Swarm(cfg, opts, out, plan, interrupts).run()


class _Swarm:
    def __init__(self, cfg: Config, opts: SwarmOptions, out: Path, plan, interrupts: _Interrupts):
        self.cfg, self.opts, self.out, self.plan, self.interrupts = cfg, opts, out, plan, interrupts
        self.n = cfg.scenario.n_uavs
        self.groups = agent_groups(self.n, opts.agents_per_process)
        self.agents = [group_name(g) for g in self.groups]  # the agent processes' names
        self.central = opts.scheme == "central"
        self.fleet = self.agents + (["controller"] if self.central else [])
        """The processes a fault plan may kill or freeze; a frozen one is thawed before it is stopped."""
        self.children = Children(out / "logs", out / PID_FILE, on_start=self._started if opts.verbose else None)
        self.monitor = Monitor(self.n, period_s=1.0 / opts.rate_hz)
        self.outcome = Outcome()
        self.controller: FaultController | None = None
        self.planned_exits: set[int] = set()  # PIDs the fault plan killed
        self.healer = Healer(opts.restart, opts.restart_limit)
        self.bus: Bus | None = None  # the supervisor's session, once open (restarts are published on it)
        self.router_down_ns: int | None = None  # wall clock of the router's death, until it is back
        self.router_outages: list[tuple[int, int]] = []  # (died, listening again), wall-clock ns
        self.endpoint = opts.listen
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
            router_args, self.creds_args, self.bus_config = secure_setup(self.out, self.opts, self.n, self.endpoint)
            self.endpoint = tls_endpoint(self.endpoint)
        proc = self.children.start("router", _python_module("truav.swarm.cli", "router", *router_args))
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
        from truav import kernel_cache  # here: it imports numba
        self.cold_note = kernel_cache.cold_start_note(kernel_cache.SWARM_KERNELS
                                                      + (["agents/sac_kernels.py"] if self.central else []))
        write_run_file(out, {"run": opts.run, "endpoint": ep, "supervisor_pid": os.getpid(), "agents": self.n})
        scenario = out / SCENARIO_FILE
        scenario_args = ["--run", opts.run, "--seed", str(opts.seed), "--scenario", str(scenario), "-e", ep,
                         *self.creds_args]
        common = [*scenario_args, "--router-timeout", str(opts.router_timeout_s)]
        timing = (["--lockstep", "--lockstep-wait", repr(opts.lockstep_wait_s)] if opts.lockstep else []) \
            + (["-v"] if opts.verbose else [])
        faults_args = ["--fault-plan", str(Path(opts.fault_plan).resolve())] if self.plan else []
        origin = ["--geo-origin", "%r,%r" % opts.geo_origin] if opts.geo_origin else []
        if opts.record:
            self.children.start("recorder", _python_module(
                "recorder.process", "--run", opts.run, "--out", opts.record, "--connect", ep,
                "--config-toml", str(scenario), *origin, *(["--force"] if opts.force else []), *self.creds_args,
                *(["-v"] if opts.verbose else [])))
        if opts.foxglove_port is not None:
            self.children.start("view", _python_module("truav.swarm.cli", "view", *scenario_args, *origin,
                                                        "--port", str(opts.foxglove_port)))
        with Bus(SUPERVISOR, opts.run, self.bus_config) as bus:
            self.bus = bus
            bus.guard = guard.for_config(self.cfg)  # what the world and agents refuse, the monitor refuses too
            # Real time: a flood costs the monitor a bounded amount of work, as it does the world and agents.
            bus.receive_ring = None if opts.lockstep else transport.REALTIME_RECEIVE_RING
            self.monitor.attach(bus, opts.run, central=self.central, tracks_from_world=opts.scheme != "truav")
            if opts.record and not self._recorder_ready(bus):
                return False
            if self.plan:
                hooks = {"kill": self._plan_kill, "restart": self._plan_restart,
                         "freeze": lambda u: self.children.send(_process(u), signal.SIGSTOP),
                         "thaw": lambda u: self.children.send(_process(u), signal.SIGCONT)}
                self.controller = FaultController(bus, opts.run, self.plan, hooks)
            scheme = ["--scheme", opts.scheme]
            if self.central:  # before the world, which waits for it (and the agents) before tick 0
                controller = ControllerOptions(policy=str(Path(opts.policy).resolve()) if opts.policy else None,
                                               policy_index=opts.policy_index, stats_out=str(out / "controller.json"))
                self.children.start("controller", _python_module(
                    "truav.swarm.cli", "controller", *common, *timing, *faults_args, "--rate", str(opts.rate_hz),
                    *to_argv(controller, (["policy", "policy_index"] if opts.policy else []) + ["stats_out"])))
            world = WorldOptions(episodes=opts.episodes, rate_hz=opts.rate_hz, stats_out=str(out / "world.json"),
                                 wait_agents_s=opts.wait_agents_s)
            self.children.start("world", _python_module(
                "truav.swarm.cli", "world", *common, *timing, *faults_args, *scheme,
                *to_argv(world, ["episodes", "rate_hz", "stats_out", "wait_agents_s"])))
            for ids in self.groups:
                name = "{id}" if len(ids) > 1 else str(ids[0])  # the agent process fills in each UAV's id
                agent = AgentOptions(checkpoint=str(out / f"agent{name}.npz"), stats_out=str(out / f"agent{name}.json"),
                                     checkpoint_every=opts.checkpoint_every, qtable=opts.qtable or None,
                                     command_hold_s=opts.command_hold_s, beacon_every=opts.beacon_every,
                                     beacon_cell_m=opts.beacon_cell_m)
                extra = [*to_argv(agent, ["checkpoint", "stats_out", "checkpoint_every"]), *scheme,
                         *to_argv(agent, ["qtable"])]
                extra += ["--greedy"] if opts.greedy else []
                extra += to_argv(agent, ["command_hold_s"]) if self.central else []
                extra += to_argv(agent, ["beacon_every"]) if opts.beacon_every != 1 else []
                extra += to_argv(agent, ["beacon_cell_m"])
                extra += ["--share-beacons"] if opts.share_beacons and len(ids) > 1 else []
                self.children.start(group_name(ids), _python_module(
                    "truav.swarm.cli", "agent", *[a for i in ids for a in ("--id", str(i))], *common, *timing,
                    *faults_args, "--rate", str(opts.rate_hz), *extra))
            self._announce()
            ok = self._watch()
            self.monitor.poll()
            if self.controller is not None:
                self.controller.stop()
            return ok

    def _announce(self) -> None:
        opts, ep = self.opts, self.endpoint
        default_out = Path(f"runs/swarm-{opts.run}")
        where = "" if self.out == default_out else f" --out {self.out}"
        print(f"swarm '{opts.run}' ({opts.scheme}): router {ep}, world + {self.n} agents"
              f"{' + controller (' + (opts.policy or 'learning online') + ')' if self.central else ''}"
              f"{' + recorder -> ' + opts.record if opts.record else ''}; "
              f"{'lock-step' if opts.lockstep else f'{opts.rate_hz:g} Hz'}; logs in {self.out}/logs\n"
              f"  watch it: truav-swarm status -e {ep}    stop it: truav-swarm down --run {opts.run}{where}", flush=True)
        if opts.foxglove_port is not None:
            print(f"Foxglove: open ws://127.0.0.1:{opts.foxglove_port} (layout deploy/foxglove-layout.json)", flush=True)
        if self.cold_note:  # else tick 0 waits for the compiler without a word
            print(f"{self.cold_note}; tick 0 comes once the world and the agents have them", flush=True)

    def _plan_kill(self, who) -> None:
        name = _process(who)
        p = self.children.procs.get(name)
        if p is not None:
            self.planned_exits.add(p.pid)
        if name == "router":
            self.router_down_ns = time.time_ns()
        self.children.send(name, signal.SIGKILL)

    def _plan_restart(self, who) -> None:
        name = _process(who)
        if name == "router":
            ok, error = self._restart_router()
            if not ok:
                self.outcome.fail(f"the router could not be restarted on {self.endpoint} after the plan's crash: {error}")
        else:
            self.children.restart(name)

    def _restart_router(self) -> tuple[bool, str]:
        """The router again, with its own command line, on the same endpoint; its clients reconnect by themselves."""
        proc = self.children.start("router", self.children.argv["router"])
        ok, error = self._wait_router(proc, ROUTER_START_TIMEOUT_S)
        if ok:  # messages sent in between were lost on the wire: the soak's checker needs to know when
            self.router_outages.append((self.router_down_ns or time.time_ns(), time.time_ns()))
            self.router_down_ns = None
        return ok, error

    def _died(self, name: str, p) -> bool:
        """A process died on its own mid-run: say how, restart it if the policy allows; False if it stays down."""
        cause = exit_text(p.returncode)
        if name == "router":
            self.router_down_ns = time.time_ns()
        r = self.healer.died(name, p.pid, cause, self._since(), time.monotonic(),
                             cap=ROUTER_BACKOFF_MAX_S if name == "router" else RESTART_BACKOFF_MAX_S)
        last = self.children.last_line(name)
        what = "the router" if name == "router" else name
        if r is None:
            if self.opts.restart == "never" or name == "router":  # the router's failure is the caller's
                return False
            self.outcome.fail(f"{what} died {self.opts.restart_limit + 1} times ({cause} the last time; its last log "
                              f"line: {last}); not restarted again (--restart-limit {self.opts.restart_limit})")
            return False
        note = f"{what} died mid-run ({cause}) at {r.died_s:.1f} s; its last log line: {last}"
        self.outcome.warnings.append(note)
        due = self.healer.pending[name][0] - time.monotonic()
        print(f"{note}\n  restarting it in {max(due, 0):.1f} s (restart {r.number} of at most {self.opts.restart_limit})",
              flush=True)
        self._publish_restart(r, schema_phase="start")
        return True

    def _heal_due(self) -> None:
        with self.monitor.lock:
            ending = bool(self.monitor.shutdowns)
        for r in self.healer.due(time.monotonic()):
            if ending and r.process != "router":  # the run is ending: nothing to rejoin (the router still serves it)
                continue
            if r.process == "router":
                ok, error = self._restart_router()
                if not ok:
                    self.outcome.fail(f"the router died mid-run ({r.cause}) at {r.died_s:.1f} s and could not be "
                                      f"restarted on {self.endpoint}: {error}")
                    continue
            else:
                self.children.start(r.process, self.children.argv[r.process])
            self.healer.done(r, self.children.procs[r.process].pid, self._since())
            self.outcome.restarts.append(r.as_dict())
            print(f"restarted {r.process} (pid {r.new_pid}) at {r.restarted_s:.1f} s"
                  + (f" on {self.endpoint}" if r.process == "router" else " from its checkpoint"
                     if r.process != "controller" else ""), flush=True)
            if r.process == "router":  # its start was lost with the router: both phases once it is back
                self._await_router(ROUTER_RECONNECT_WAIT_S)
                self._publish_restart(r, schema_phase="start")
            self._publish_restart(r, schema_phase="end")

    def _await_router(self, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        while self.bus is not None and time.monotonic() < deadline:
            with contextlib.suppress(Exception):
                if list(self.bus.session.info.routers_zid()):
                    return
            time.sleep(0.05)

    def _publish_restart(self, r: Restart, schema_phase: str) -> None:
        """In the recording (and `truav report`'s fault spans): a restart span from death to restart."""
        if self.bus is None:
            return
        from truav.bus import schema
        target = keys.uav_identity(int(r.process[5:])) if r.process.startswith("agent") and r.process[5:].isdigit() \
            else r.process
        params = {"cause": r.cause, "restart": r.number, "old_pid": r.old_pid}
        if r.new_pid is not None:
            params["new_pid"] = r.new_pid
        with contextlib.suppress(Exception):  # a router going down under the put must not stop the watch
            self.bus.publish(keys.fault(self.opts.run, RESTART_RECORD),
                             schema.Fault(fault=RESTART_RECORD, phase=schema_phase, target=target, params=params))

    def _recorder_ready(self, bus: Bus) -> bool:
        proc = self.children.procs["recorder"]
        deadline = time.monotonic() + RECORDER_START_TIMEOUT_S
        while time.monotonic() < deadline:
            if proc.poll() is not None:
                self.outcome.fail(f"the recorder could not start: {self.children.last_line('recorder')}")
                return False
            if bus.alive(keys.alive_recorder(self.opts.run), timeout=0.3):
                return True
        self.outcome.fail(f"the recorder did not start within {RECORDER_START_TIMEOUT_S:.0f} s "
                          f"(see {self.children.log_dir}/recorder.log)")
        return False

    def _watch(self) -> bool:
        """Until the world exits; False (with the failure noted) if the run must end early."""
        opts, monitor, children = self.opts, self.monitor, self.children
        tty = sys.stdout.isatty() and not opts.quiet
        drawn, last_print = 0, 0.0
        world = children.procs["world"]
        reported: set[int] = set()
        debug_every = Every(None, STATUS_PERIOD_S) if opts.verbose else None
        last_rss = 0.0
        while world.poll() is None:
            faults_pending = self.controller is not None and not self.outcome.ticked
            time.sleep(0.05 if faults_pending or not self.outcome.ticked else 0.2)
            monitor.poll()
            if debug_every is not None and debug_every.due():  # -v: what the bus showed, once a second
                print(f"debug: supervisor at {self._since():.1f} s: {monitor.debug_line()}", flush=True)
            if not self.outcome.ticked and monitor.t0 is not None:
                self.outcome.ticked = True
                if self.controller is not None:
                    self.controller.start(monitor.t0)
            for name in ("router", "recorder"):
                p = children.procs.get(name)
                if p is None or p.poll() is None or p.pid in reported:
                    continue
                reported.add(p.pid)
                if name == "router" and (p.pid in self.planned_exits or self._died(name, p)):
                    continue  # the plan or the healer restarts it
                what = "the router" if name == "router" else "the recorder"
                self.outcome.fail(f"{what} exited mid-run ({exit_text(p.returncode)}) at {self._since():.1f} s"
                                  + ("; the recording is incomplete" if name == "recorder" else "")
                                  + (f"; not restarted again (--restart-limit {self.opts.restart_limit})"
                                     if name in self.healer.given_up else ""))
                return False
            for name in self.fleet:
                p = children.procs.get(name)
                if p is None or p.poll() is None or p.pid in reported:
                    continue
                reported.add(p.pid)
                if not self.outcome.ticked:  # before the first tick: it could not start
                    self.outcome.fail(f"{name} could not start ({exit_text(p.returncode)}): "
                                      f"{children.last_line(name)}")
                    return False
                with monitor.lock:
                    shut_down = bool(monitor.shutdowns)
                if p.returncode == 0 and shut_down:  # left on a shutdown request: not news
                    continue
                if p.pid in self.planned_exits:
                    if opts.verbose or name == "controller":
                        print(f"{name} killed by the fault plan at {self._since():.1f} s"
                              + ("; the UAVs fly on without commands" if name == "controller" else ""), flush=True)
                    continue
                if p.returncode != 0 and not shut_down and self._died(name, p):
                    continue
                note = f"{name} exited mid-run ({exit_text(p.returncode)}); its last log line: " \
                    f"{children.last_line(name)}" + ("; the UAVs fly on without commands" if name == "controller" else "")
                self.outcome.warnings.append(note)
                print(note, flush=True)
            self._heal_due()
            if time.monotonic() - last_rss >= RSS_PERIOD_S:
                children.sample_rss()
                last_rss = time.monotonic()
            now = time.monotonic()
            if opts.quiet or now - last_print < (STATUS_PERIOD_S if tty else 5.0):
                continue
            last_print = now
            lines = monitor.status_lines()
            if tty:
                if drawn:
                    sys.stdout.write(f"\x1b[{drawn}F")
                sys.stdout.write("".join(f"\x1b[2K{line}\n" for line in lines))
                sys.stdout.flush()
                drawn = len(lines)
            else:
                print(" | ".join(lines[:2]), flush=True)
        if world.returncode:
            self.outcome.fail(f"the world exited with {exit_text(world.returncode)}: {children.last_line('world')}")
            return False
        return True

    # -- the end --
    def _shutdown(self, normal_end: bool) -> None:
        """Stop every process started, in an order that loses nothing (see the module docstring)."""
        children = self.children
        if self.controller is not None:
            self.controller.stop()
        pausable = [*self.fleet, "world", "recorder"]  # what a fault plan may freeze
        children.thaw(pausable)  # a frozen process must run to stop; SIGTERM alone would wait for ever
        if normal_end:
            children.wait_exit(self.fleet, AGENT_EXIT_GRACE_S)
        killed = children.stop(["world"], timeout=WORLD_STOP_TIMEOUT_S)
        children.thaw(pausable)  # the plan's last thaw may have been cancelled
        killed += children.stop(self.fleet, timeout=AGENT_STOP_TIMEOUT_S)
        for name in killed:
            self.outcome.fail(f"{name} did not stop within {AGENT_STOP_TIMEOUT_S:.0f} s of SIGTERM and was killed: "
                              f"its final checkpoint and statistics may be missing")
        if "recorder" in children.procs:
            if children.stop(["recorder"], sig=signal.SIGINT, timeout=RECORDER_STOP_TIMEOUT_S):
                self.outcome.fail(f"the recorder did not finish {self.opts.record} within "
                                  f"{RECORDER_STOP_TIMEOUT_S:.0f} s and was killed (try `truav log recover`)")
            elif children.procs["recorder"].returncode and not any("recorder" in f for f in self.outcome.failures):
                self.outcome.fail(f"the recorder failed to finish {self.opts.record} "
                                  f"({exit_text(children.procs['recorder'].returncode)}): "
                                  f"{children.last_line('recorder')}")
        others = [n for n in children.procs if n not in ("world", "recorder", "router", *self.fleet)]  # the viewer
        children.stop(others, timeout=WORLD_STOP_TIMEOUT_S)
        if "router" in children.procs:
            children.stop(["router"], timeout=ROUTER_STOP_TIMEOUT_S)
        children.close_logs()

    def _judge(self) -> None:
        """What ended the run, from what was seen; failures the watch could not see on its own."""
        o, opts = self.outcome, self.opts
        with self.monitor.lock:
            o.shutdowns = [(round(t - self.t0, 2), src) for t, src in self.monitor.shutdowns]
        foreign = [src for _, src in o.shutdowns if src != keys.SRC_WORLD]
        for src in dict.fromkeys(foreign):
            if src not in SHUTDOWN_SENDERS:
                o.fail(f"a shutdown came from an unknown sender {src!r}")
        world = _read_json(self.out / "world.json")
        done = len((world or {}).get("episodes") or [])
        if not o.ended_by:
            if foreign:
                first = foreign[0]
                o.ended_by = f"a shutdown from {first!r} ({SHUTDOWN_SENDERS.get(first, 'unknown sender')})"
                if first == DOWN_IDENTITY and done < opts.episodes:
                    o.interrupted_by = SHUTDOWN_SENDERS[first]
            elif done == opts.episodes:
                o.ended_by = f"the world finished its {done} episode(s) (shutdown from 'world')"
            else:
                o.fail(f"the world stopped after {done} of {opts.episodes} episode(s)")
        if world and o.ticked:
            acting = world.get("ticks", 0) - done
            expected = acting * self.n
            if expected > 0:
                missed = 1.0 - world.get("actions_received", 0) / expected
                if missed > opts.max_missed_share:
                    o.fail(f"{100 * missed:.0f}% of the actions were missing (more than --max-missed "
                           f"{opts.max_missed_share:g})")
        killed_for_good = {_process(f.params.get("target", f.params.get("uav")))
                           for f in (self.plan.faults if self.plan else ())
                           if f.kind == "crash" and "restart_after" not in f.params}
        logs = {f"agent{i}": name for ids, name in zip(self.groups, self.agents) for i in ids}  # uav -> its process
        for name in [*logs, *(["controller"] if self.central else [])]:
            if o.ticked and not (self.out / f"{name}.json").is_file() and name not in killed_for_good:
                o.warnings.append(f"{name} wrote no statistics (see {self.children.log_dir}/{logs.get(name, name)}.log)")
        if opts.lockstep and o.ticked:
            o.exactness = lockstep_exactness(world, [_read_json(self.out / f"{name}.json") for name in logs],
                                             _read_json(self.out / "controller.json") if self.central else None)
            if not o.exactness["exact"]:
                o.fail(inexact_text(o.exactness, opts.lockstep_wait_s))
        if opts.lockstep and o.restarts:
            o.warnings.append(f"{len(o.restarts)} restart(s) in a lock-step run: a restarted process resumed from its "
                              f"checkpoint while the world went on without it, so this run is not exactly a clean "
                              f"run of seed {opts.seed}")
        lost = ((world or {}).get("controller_losses") or []) if self.central else []
        if lost:
            o.warnings.append(f"the controller was lost at {', '.join(f'{t:g}' for t in lost)} s after tick 0; the "
                              f"UAVs held their last command for {opts.command_hold_s:g} s, then hovered "
                              f"(the world ran on)")

    def _summary(self, elapsed: float) -> None:
        cfg, opts, out, monitor, o = self.cfg, self.opts, self.out, self.monitor, self.outcome
        world = _read_json(out / "world.json")
        agents = [_read_json(out / f"agent{i}.json") for i in range(self.n)]
        controller = _read_json(out / "controller.json") if self.central else None
        cp = monitor.control_plane()
        events = self.controller.events if self.controller is not None else []
        with monitor.lock:
            timeline = {"coverage": list(monitor.coverage), "hovering": list(monitor.hovering)}
        outcome = {"result": o.result, "ended_by": o.ended_by, "interrupted_by": o.interrupted_by,
                   "lockstep": o.exactness, "restarts": o.restarts,
                   "failures": o.failures, "warnings": o.warnings, "shutdowns": o.shutdowns, "exit_code": o.exit_code()}
        (out / SUMMARY_FILE).write_text(json.dumps({
            "scheme": opts.scheme, "world": world, "agents": agents, "controller": controller,
            "control_plane": cp, "elapsed_s": elapsed,
            "interrupted": o.interrupted_by is not None, "outcome": outcome, "endpoint": self.endpoint,
            "fault_events": events, "timeline": timeline,
            "controller_incarnations": self.children.starts.get("controller", 0) if self.central else None,
            "processes": self.children.incarnation_stats(self.t0), "t0_wall_ns": self.t0_wall_ns,
            "router_outages_wall_ns": self.router_outages}, indent=1))
        if o.ticked:
            _print_results(cfg, opts, world, agents, cp, events, elapsed, o)
            if self.central:
                _print_central(cfg, opts, world, agents, controller, cp, self.children.starts.get("controller", 1))
            if opts.plot and monitor.tracks:
                from truav.swarm.plots import swarm_figure
                picture = swarm_figure(cfg, monitor, out / "summary.png", title=f"swarm {opts.run!r}", plan=self.plan,
                                       episodes_done=len((world or {}).get("episodes") or []) if world else None)
                print(f"picture: {picture}")
            if opts.record:
                print(f"recording: {opts.record}")
        for r in o.restarts:
            print(f"restarted {r['process']} at {r['restarted_s']:.1f} s (it died at {r['died_s']:.1f} s, "
                  f"{r['cause']}; restart {r['number']})")
        for note in o.warnings:
            print(f"warning: {note}")
        print(f"ended by: {o.ended_by}")
        if o.failures:
            print(f"result: FAILED ({'; '.join(o.failures)})", flush=True)
            print(f"truav-swarm: error: {o.failures[0]}", file=sys.stderr, flush=True)
        else:
            print(f"result: {o.result}", flush=True)


def _print_results(cfg, opts, world, agents, cp, events, elapsed, o: Outcome) -> None:
    print(f"\n== swarm '{opts.run}' summary ({elapsed:.1f} s{', ' + o.result if o.result != 'ok' else ''}) ==")
    for e, m in enumerate((world or {}).get("episodes") or []):
        print(f"episode {e}: coverage {m.get('coverage_pct', float('nan')):5.1f}%  PDR {m.get('pdr', float('nan')):.3f}  "
              f"delay {m.get('delay_ms', float('nan')):6.1f} ms  energy/UAV {m.get('energy_j', float('nan')) / 1e3:6.2f} kJ")
    if world:
        lat = world.get("tick_lateness_ms")
        if lat:
            print(f"tick lateness p50 {lat['p50']:.2f} ms, p99 {lat['p99']:.2f} ms over {lat['n']} ticks")
        late, stale = world.get("late_actions", 0), world.get("stale_actions", 0)
        print(f"ticks {world['ticks']}, actions received {world['actions_received']}, "
              f"missed (hovered) {world['deadline_misses']}"
              + (f" (answers that came late {late}, out of order {stale})" if late or stale else "")
              + f", agent losses seen {len(world['losses'])}")
    ex = o.exactness
    if ex is not None:
        print("lock-step: exact (every live process was waited for)" if ex["exact"] else
              f"lock-step: NOT exact from tick {ex['inexact_from_tick']}: {ex['decisions_without_peer']} decision(s) "
              f"without a live peer's message, {ex['world_went_on_without']} answer(s) the world went on without")
    rejected = rejection_summary(world, agents)
    if rejected:
        print(rejected)
    lat = [a["beacon_latency_ms"] for a in agents if a and a.get("beacon_latency_ms", {}).get("n")]
    if lat:
        print(f"beacon one-way latency: p50 {np.median([x['p50'] for x in lat]):.2f} ms, "
              f"p99 {np.max([x['p99'] for x in lat]):.2f} ms (worst agent)")
    if cp["beacons"]:
        n = cfg.scenario.n_uavs
        central = n * CENTRAL_STATE_VALUES * opts.rate_hz
        print(f"control plane: {cp['bytes_per_beacon']:.0f} B/beacon, {cp['beacons_per_s_per_uav']:.1f} beacons/s per UAV, "
              f"{cp['beacon_bytes_per_s_total'] / 1e3:.1f} kB/s in total; a centralized critic would upload "
              f"{n} x {CENTRAL_STATE_VALUES} values x {opts.rate_hz:g} Hz = {central:,.0f} values/s "
              f"({central * CENTRAL_VALUE_BYTES / 1e3:.1f} kB/s of float32) to one controller")
    for t, kind, phase in events:
        print(f"fault {kind} {phase} at {t:.1f} s")


def lockstep_exactness(world, agents, controller) -> dict:
    """Lock-step: whether every process waited for every live peer (the run is then exact), else how many
    decisions were taken without a live process's message, and from which tick (the earliest)."""
    world_missed = int((world or {}).get("lockstep_missed", 0))
    ticks = [(world or {}).get("lockstep_missed_from_tick")]
    per_agent: dict[str, int] = {}
    for stats in agents:
        ls = (stats or {}).get("lockstep") or {}
        if ls.get("decisions_without_peer"):
            per_agent[f"agent{stats.get('uav')}"] = int(ls["decisions_without_peer"])
            ticks.append(ls.get("inexact_from_tick"))
    ctl = ((controller or {}).get("lockstep") or {})
    ctl_missed = int(ctl.get("decisions_without_peer", 0))
    ticks.append(ctl.get("inexact_from_tick"))
    ticks = [t for t in ticks if t is not None]
    decisions = sum(per_agent.values()) + ctl_missed
    return {"exact": not (world_missed or decisions), "decisions_without_peer": decisions,
            "by_agent": per_agent, "controller_decisions_without_peer": ctl_missed,
            "world_went_on_without": world_missed, "inexact_from_tick": min(ticks) if ticks else None}


def inexact_text(ex: dict, wait_s: float) -> str:
    parts = []
    if ex["decisions_without_peer"]:
        who = [f"{a} {n}" for a, n in ex["by_agent"].items()]
        who += [f"controller {ex['controller_decisions_without_peer']}"] if ex["controller_decisions_without_peer"] else []
        parts.append(f"{ex['decisions_without_peer']} decision(s) taken without a live peer's message ({', '.join(who)})")
    if ex["world_went_on_without"]:
        parts.append(f"the world went on without {ex['world_went_on_without']} live agent answer(s)")
    return (f"lock-step is no longer exact from tick {ex['inexact_from_tick']} (a live process did not answer within "
            f"--lockstep-wait {wait_s:g} s; a longer one waits out longer pauses): {'; '.join(parts)}")


def _process(who) -> str:
    """The supervisor's name of a fault plan's process: agent<i> for a UAV id, else the target's name."""
    return who if isinstance(who, str) else f"agent{who}"


def central_model_bytes_per_s(cfg: Config, rate_hz: float) -> float:
    """What the in-process control-plane model sends per second of real time: every UAV's upload and
    command each round (agents.central.ControlPlaneModel.messages), rate_hz / update_period rounds."""
    c = cfg.central
    up_m, up_b, down_m, down_b = cfg.scenario.n_uavs, cfg.scenario.n_uavs * c.upload_bytes, \
        cfg.scenario.n_uavs, cfg.scenario.n_uavs * c.download_bytes
    return (up_b + down_b) * rate_hz / c.update_period_steps


def _print_central(cfg, opts, world, agents, controller, cp, incarnations: int = 1) -> None:
    c = cfg.central
    model = central_model_bytes_per_s(cfg, opts.rate_hz)
    ctl = controller or {}
    policy = ctl.get('policy', opts.policy or 'learning online')
    own = (f"{ctl.get('ticks', 0)} tick(s) decided, {ctl.get('commands', 0)} command(s) sent, "
           f"{ctl.get('stale_states', 0)} missing upload(s) filled from the last one"
           + (f", decision p99 {ctl['decide_ms']['p99']:.1f} ms" if ctl.get("decide_ms") else ""))
    if incarnations > 1:  # a crashed incarnation writes no statistics: the bus counts every one's commands
        print(f"controller ({policy}), {incarnations} incarnations: commands for {cp.get('command_ticks', 0)} tick(s), "
              f"{cp.get('commands', 0)} command(s) heard on the bus; the last incarnation: {own}")
    else:
        print(f"controller ({policy}): {own}")
    counts = {"fresh": 0, "held": 0, "hovered": 0}
    for a in agents:
        for k, v in ((a or {}).get("commands") or {}).items():
            counts[k] = counts.get(k, 0) + v
    print(f"UAVs flew a fresh command {counts['fresh']} time(s), held the last one {counts['held']}, hovered without "
          f"one {counts['hovered']} (hold {opts.command_hold_s:g} s)")
    if cp.get("states") or cp.get("commands"):
        if opts.lockstep:
            rate = "lock-step: per second of wall time, not of the world's"
        else:
            rate = f"model at {opts.rate_hz:g} Hz: {model / 1e3:.1f} kB/s"
        print(f"control plane measured on the bus: {cp['states']} uploads x {cp['bytes_per_state']:.0f} B + "
              f"{cp['commands']} commands x {cp['bytes_per_command']:.0f} B = "
              f"{cp['central_bytes_per_s'] / 1e3:.1f} kB/s; the in-process model: {cfg.scenario.n_uavs} x "
              f"({c.upload_bytes} + {c.download_bytes}) B per round = "
              f"{cfg.scenario.n_uavs * (c.upload_bytes + c.download_bytes):,} B ({rate})")
    eps = (world or {}).get("episodes") or []
    if eps and "ctrl_delay_ms" in eps[0]:
        print(f"modelled radio effects applied by the world: action delay {np.mean([e['ctrl_delay_ms'] for e in eps]):.1f}"
              f" ms, control airtime {np.mean([e['ctrl_airtime_s'] for e in eps]):.2f} s/UAV/episode "
              f"({np.mean([e['ctrl_energy_j'] for e in eps]):.1f} J)")




def rejection_summary(world, agents) -> str:
    """One line: how many messages the world and the agents refused, by reason (truav.bus.guard)."""
    by_reason: dict[str, int] = {}
    for stats in [(world or {}).get("rejected") or {}] + [((a or {}).get("bus") or {}).get("rejected") or {}
                                                          for a in agents]:
        for reason, senders in stats.items():
            by_reason[reason] = by_reason.get(reason, 0) + sum(senders.values())
    if not by_reason:
        return ""
    return (f"rejected messages (world + agents): {sum(by_reason.values())} ("
            + ", ".join(f"{r} {n}" for r, n in sorted(by_reason.items())) + "); see world.json / agent<i>.json")


def _read_json(path: Path):
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None
