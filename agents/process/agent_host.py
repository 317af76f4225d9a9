"""The agent host: one agent process running one UAV's agent, or several (``--id`` repeated).

Each hosted agent has its own Zenoh session, identity, credentials, checkpoint and statistics,
and runs on its own thread behind a start barrier; with ``share_beacons`` they share one beacon
subscription (:class:`SharedBeacons`). What need not be per agent is per process when it hosts several
(:class:`_SharedParts`: one peer watch, health thread, shutdown subscription, fault-plan listener and
router watchdog; about 9 threads per agent became 3, and a thousand peers' joins one Zenoh callback
each instead of one per hosted agent). SIGTERM, a lost supervisor or a failed agent stop them all;
a lost router stops the agent that lost it (several hosted agents: all of them). `truav-swarm agent` checks its flags, then calls
:func:`host_agents`.
"""

from __future__ import annotations

import logging
import signal
import sys
import threading
import time
from collections.abc import Callable

import zenoh

from agents.process.agent_process import CONTROL_SHUTDOWN
from agents.process.agent_process_reports import HEALTH_PERIOD_S
from agents.process.scheme_process import make_agent_node
from agents.process.shared_beacons import BeaconBatcher, SharedBeacons  # noqa: F401 - SharedBeacons: its old home

from truav.atomic import EXIT_NO_SPACE
from truav.bus.fault_filter import SharedPlan
from truav.bus.transport import Bus
from truav.config import Config
from truav.errors import UserError
from truav.faults import load_plan
from truav.lifecycle import EXIT_ROUTER_LOST, StopReasons, watch_router, watch_supervisor
from truav.stopping import INTERRUPTS, is_interrupt
from truav.wire import keys

log = logging.getLogger("truav.swarm")  # the agent process's log lines keep the swarm's logger name

MAX_OPENING_SESSIONS = 4
"""Hosted agents that open their Zenoh session at the same time (the others wait their turn)."""
LIVELINESS_FIFO = 1 << 16
"""Joins and leaves a process's shared peer watch queues (a thousand peers' history at start, each restart twice)."""
LOCKSTEP_SWITCH_INTERVAL_S = 0.02
"""Lock-step, several agents per process: the interpreter's thread switch interval (default 5 ms). A hundred
agent threads waiting for the GIL then wake 4x less often to ask for it (each a futex wake-up; the kernel's
time was most of such a process's); lock-step decisions do not depend on timing."""
ID_PLACEHOLDER = "{id}"
"""In --checkpoint and --stats-out of a process hosting several agents: replaced by each UAV's id."""

DUPLICATE_GRACE_S = 1.5
"""A liveliness token of this agent's UAV still alive this long after its session opened is a live agent's
(a crashed agent's token goes with its connection, within milliseconds): this one is refused."""


def refuse_duplicate(bus: Bus, run: str, uav: int) -> None:
    """One process per identity: two agents flying one UAV would both act, both checkpoint and both be counted
    (raises UserError, before this agent loads, joins or writes anything)."""
    key = keys.alive_uav(run, uav)
    deadline = time.monotonic() + DUPLICATE_GRACE_S
    while bus.alive(key, timeout=0.5):
        if time.monotonic() >= deadline:
            raise UserError(f"--id {uav}: UAV {uav} of run {run} already has a live agent (liveliness token {key}); "
                            f"stop it first, or choose another --id or --run")
        time.sleep(0.25)


def path_of(template: str | None, uav: int) -> str | None:
    """A per-UAV file name from a template with :data:`ID_PLACEHOLDER` (None stays None)."""
    return template.replace(ID_PLACEHOLDER, str(uav)) if template else None


class _SharedParts:
    """What a process hosting several agents runs once for them all instead of once per agent: ONE
    liveliness watch of alive/uav/* fanned out to every hosted node, ONE health thread publishing each
    node's report on that node's own bus, ONE control/shutdown subscription, ONE fault-plan listener
    (each bus keeps its own link filter: truav.bus.fault_filter.SharedPlan) and ONE router watchdog (the
    router lost stops them all). With a hundred agents per process that is ~4 threads per agent fewer,
    and a thousand peers' joins cost one Zenoh callback each instead of one per hosted agent.

    They live on the first bus opened, which closes after every other hosted agent is done."""

    def __init__(self, run: str, ids: list[int], options_for, router_timeout_s: float | None) -> None:
        self.run, self.ids = run, ids
        opts = options_for(ids[0])
        self.plan = SharedPlan(run, load_plan(opts.fault_plan) if opts.fault_plan else None, opts.tick_period_s)
        self.router_timeout_s = router_timeout_s
        self.nodes: list = []
        self.reasons: list[StopReasons] = []
        self._lock = threading.Lock()
        self._bus = None
        self._exited = threading.Condition()
        self._n_exited = 0
        self._stop = threading.Event()
        self._handles: list = []  # what it declared on the Zenoh session itself (the peer watch)

    def node_switches(self) -> dict:
        return {"watch_peers": False, "health_thread": False, "listen_shutdown": False, "shared_plan": self.plan}

    def first_bus(self, bus: Bus) -> None:
        """The first hosted bus opened holds the shared parts; the fault listener and the router watchdog
        start on it at once (the world's first tick may come before the last hosted agent is ready)."""
        with self._lock:
            if self._bus is not None:
                return
            self._bus = bus
        self.plan.listen(bus)
        if self.router_timeout_s is not None:
            watch_router(bus.session, self.router_timeout_s, self._router_lost)

    def add(self, node, reasons: StopReasons) -> None:
        with self._lock:
            self.nodes.append(node)
            self.reasons.append(reasons)

    def _router_lost(self, seconds: float) -> None:
        log.error("uavs %d-%d: no router for %.1f s (it stopped, or the network to it is down)",
                  min(self.ids), max(self.ids), seconds)
        with self._lock:
            reasons = list(self.reasons)
        for r in reasons:
            r.router_lost = True
            r.because(f"router lost for {seconds:.1f} s")

    def start(self) -> None:
        """Every hosted node exists (its token declared): the watch, the shutdown and the health thread."""
        bus = self._bus
        bus.subscribe(keys.control(self.run, CONTROL_SHUTDOWN), self._on_control)
        # The joins and leaves come through a channel read by a thread of this process, not as a Python callback
        # on Zenoh's receive thread: that thread, one for all of the process's sessions, then never waits for
        # the GIL (behind a hundred agents' threads) while their leases need renewing.
        watch = bus.session.liveliness().declare_subscriber(
            keys.all_alive_uavs(self.run), zenoh.handlers.FifoChannel(LIVELINESS_FIFO), history=True)
        self._handles.append(watch)
        threading.Thread(target=self._watch_loop, args=(watch.handler,), name="peers", daemon=True).start()
        threading.Thread(target=self._health_loop, name="health", daemon=True).start()

    def _watch_loop(self, handler) -> None:
        while True:
            try:
                sample = handler.recv()
            except zenoh.ZError:  # undeclared, or the session closed
                return
            key = str(sample.key_expr)
            try:
                (self._on_join if sample.kind == zenoh.SampleKind.PUT else self._on_leave)(key)
            except Exception:  # noqa: BLE001 - a last resort: the watch goes on
                log.exception("peer watch failed on %s", key)

    def _on_control(self, key, msg, raw, recv_ns) -> None:
        for node in list(self.nodes):
            node._on_control(key, msg, raw, recv_ns)

    def _on_join(self, key: str) -> None:
        uav = keys.parse_uav_id(key)
        if sum(node._peer_joined(uav) for node in list(self.nodes)):
            log.info("uavs %d-%d: peer uav %d joined", min(self.ids), max(self.ids), uav)

    def _on_leave(self, key: str) -> None:
        uav = keys.parse_uav_id(key)
        if sum(node._peer_left(uav) for node in list(self.nodes)):
            log.info("uavs %d-%d: peer uav %d lost", min(self.ids), max(self.ids), uav)

    def _health_loop(self) -> None:
        """About once a second (and at once, so `truav-swarm status` sees fresh agents): each running
        node's health report on its own bus, spread over the period."""
        nodes = list(self.nodes)
        while True:
            t0 = time.monotonic()
            if not sum([node.publish_health() for node in nodes]):
                return
            if self._stop.wait(max(HEALTH_PERIOD_S - (time.monotonic() - t0), 0.0)):
                return

    def exited(self) -> None:
        """A hosted agent's thread has ended (finished or failed)."""
        with self._exited:
            self._n_exited += 1
            self._exited.notify_all()

    def done(self, bus: Bus) -> None:
        """A hosted agent has finished; the one holding the shared parts waits for all the others first."""
        if bus is not self._bus:
            return
        with self._exited:
            while self._n_exited < len(self.ids) - 1:
                self._exited.wait()
        self._stop.set()
        for handle in self._handles:
            try:
                handle.undeclare()
            except zenoh.ZError:
                pass


def host_agents(cfg: Config, run: str, ids: list[int], configs: dict, options_for: Callable[[int], object],
                router_timeout_s: float | None, share_beacons: bool, batch_beacons: bool = False) -> int:
    """Run the agents of ``ids`` (``options_for(uav)``: each one's AgentOptions, ``configs[uav]``: its
    Zenoh config) until they stop; the exit code of the process (EXIT_ROUTER_LOST if one lost its router)."""
    results: dict[int, tuple[object, StopReasons]] = {}
    stops: list = []
    failed: list[BaseException] = []
    several = len(ids) > 1
    # The last agent to arrive starts the shared parts, before any agent runs.
    started = threading.Barrier(len(ids) + 1, action=lambda: parts.start()) if several else None
    # With batches every process subscribes to them through a shared feed, a process of one agent too.
    shared = SharedBeacons(run, batched=batch_beacons) if (share_beacons and several) or batch_beacons else None
    batcher = BeaconBatcher(run, ids) if batch_beacons and several else None

    opening = threading.Semaphore(MAX_OPENING_SESSIONS)
    # Several agents: what need not be per agent is per process (_SharedParts), on the first bus opened.
    parts = _SharedParts(run, ids, options_for, router_timeout_s) if several else None

    def open_bus(uav: int) -> Bus:
        with opening:  # a hundred hosted agents connecting at once time out on a busy router
            return Bus(keys.uav_identity(uav), run, configs[uav])

    def host(uav: int) -> None:
        opts = options_for(uav)
        with open_bus(uav) as bus:
            refuse_duplicate(bus, run, uav)
            if batcher is not None:
                batcher.attach(uav, bus)
            if parts is not None:
                parts.first_bus(bus)
            node = make_agent_node(cfg, opts, bus, beacon_inbox=shared,
                                   **({} if parts is None else parts.node_switches()))
            if batcher is not None:
                node._publish_beacon = batcher.sender(uav)
            reasons = StopReasons(node.stop)
            if parts is not None:
                parts.add(node, reasons)
            elif router_timeout_s is not None:
                def router_lost(seconds: float, reasons=reasons) -> None:
                    reasons.router_lost = True
                    log.error("uav %d: no router for %.1f s (it stopped, or the network to it is down)", uav, seconds)
                    reasons.because(f"router lost for {seconds:.1f} s")
                watch_router(bus.session, router_timeout_s, router_lost)
            results[uav] = (node, reasons)
            stops.append(reasons.because)
            if stopping:  # SIGTERM (or a lost supervisor) while this agent was starting
                reasons.because(stopping[0])
            if started is not None:
                started.wait()
            log.info("uav %d joined run %s (%s)", uav, run, opts.scheme if opts.scheme != "truav"
                     else "greedy" if not opts.train else "learning")
            try:
                node.run()
            except INTERRUPTS as exc:
                if not is_interrupt(exc):
                    raise
                reasons.because("interrupted")
                node.checkpoint()
            finally:
                if batcher is not None:
                    batcher.stopped(uav)
            node.write_stats()
            if parts is not None:
                parts.done(bus)  # the bus holding the shared parts closes last
        log.info("uav %d stopped after %d step(s) (%s); final checkpoint %s, statistics %s%s", uav, node.steps,
                 reasons.first or "shutdown", opts.checkpoint or "(none: no --checkpoint)", opts.stats_out or "(none)",
                 " (a write found the disk full: the last complete copies, see above)" if node.no_space else "")

    stopping: list[str] = []

    def stop_all(reason: str) -> None:
        stopping.append(reason)
        for because in list(stops):
            because(reason)

    if several and options_for(ids[0]).lockstep:
        sys.setswitchinterval(LOCKSTEP_SWITCH_INTERVAL_S)
    signal.signal(signal.SIGTERM, lambda *_: stop_all("SIGTERM"))
    watch_supervisor(lambda: stop_all("the truav-swarm up that started this process is gone"))
    if started is None:  # one agent: on the main thread, as always
        host(ids[0])
    else:
        def hosted(uav: int) -> None:
            try:
                host(uav)
            except BaseException as exc:  # noqa: BLE001 - reported below, the others stop
                failed.append(exc)
                if isinstance(exc, UserError):
                    log.error("%s", exc)
                else:
                    log.exception("uav %d failed", uav)
                if started.n_waiting:
                    started.abort()
                stop_all(f"uav {uav} failed")
            finally:
                parts.exited()
        threads = [threading.Thread(target=hosted, args=(uav,), name=f"uav{uav}") for uav in ids]
        for t in threads:
            t.start()
        try:
            started.wait()
        except threading.BrokenBarrierError:
            pass
        try:
            while any(t.is_alive() for t in threads):
                for t in threads:
                    t.join(0.2)
        except KeyboardInterrupt:
            stop_all("interrupted")
            for t in threads:
                t.join()
        if failed:
            raise failed[0]
    if any(r.router_lost for _, r in results.values()):
        return EXIT_ROUTER_LOST
    return EXIT_NO_SPACE if any(getattr(node, "no_space", None) for node, _ in results.values()) else 0
