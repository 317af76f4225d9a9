"""The agent host: one agent process running one UAV's agent, or several (``--id`` repeated).

Each hosted agent has its own Zenoh session, identity, credentials, checkpoint and statistics,
and runs on its own thread behind a start barrier; with ``share_beacons`` they share one beacon
subscription (:class:`SharedBeacons`). SIGTERM, a lost supervisor or a failed agent stop them all;
a lost router stops the agent that lost it. `truav-swarm agent` checks its flags, then calls
:func:`host_agents`.
"""

from __future__ import annotations

import logging
import signal
import threading
from collections.abc import Callable

from agents.scheme_process import make_agent_node
from agents.shared_beacons import BeaconBatcher, SharedBeacons  # noqa: F401 - SharedBeacons: its old home
from truav.bus import keys
from truav.bus.transport import Bus
from truav.config import Config
from truav.lifecycle import EXIT_ROUTER_LOST, StopReasons, watch_router, watch_supervisor

log = logging.getLogger("truav.swarm")  # the agent process's log lines keep the swarm's logger name

MAX_OPENING_SESSIONS = 4
"""Hosted agents that open their Zenoh session at the same time (the others wait their turn)."""
ID_PLACEHOLDER = "{id}"
"""In --checkpoint and --stats-out of a process hosting several agents: replaced by each UAV's id."""


def path_of(template: str | None, uav: int) -> str | None:
    """A per-UAV file name from a template with :data:`ID_PLACEHOLDER` (None stays None)."""
    return template.replace(ID_PLACEHOLDER, str(uav)) if template else None


def host_agents(cfg: Config, run: str, ids: list[int], configs: dict, options_for: Callable[[int], object],
                router_timeout_s: float | None, share_beacons: bool, batch_beacons: bool = False) -> int:
    """Run the agents of ``ids`` (``options_for(uav)``: each one's AgentOptions, ``configs[uav]``: its
    Zenoh config) until they stop; the exit code of the process (EXIT_ROUTER_LOST if one lost its router)."""
    results: dict[int, tuple[object, StopReasons]] = {}
    stops: list = []
    failed: list[BaseException] = []
    started = threading.Barrier(len(ids) + 1) if len(ids) > 1 else None
    several = len(ids) > 1
    # With batches every process subscribes to them through a shared feed, a process of one agent too.
    shared = SharedBeacons(run, batched=batch_beacons) if (share_beacons and several) or batch_beacons else None
    batcher = BeaconBatcher(run, ids) if batch_beacons and several else None

    opening = threading.Semaphore(MAX_OPENING_SESSIONS)

    def open_bus(uav: int) -> Bus:
        with opening:  # a hundred hosted agents connecting at once time out on a busy router
            return Bus(keys.uav_identity(uav), run, configs[uav])

    def host(uav: int) -> None:
        opts = options_for(uav)
        with open_bus(uav) as bus:
            if batcher is not None:
                batcher.attach(uav, bus)
            node = make_agent_node(cfg, opts, bus, beacon_inbox=shared)
            if batcher is not None:
                node._publish_beacon = batcher.sender(uav)
            reasons = StopReasons(node.stop)
            if router_timeout_s is not None:
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
            except KeyboardInterrupt:
                reasons.because("interrupted")
                node.checkpoint()
            finally:
                if batcher is not None:
                    batcher.stopped(uav)
            node.write_stats()
        log.info("uav %d stopped after %d step(s) (%s); final checkpoint %s, statistics %s", uav, node.steps,
                 reasons.first or "shutdown", opts.checkpoint or "(none: no --checkpoint)", opts.stats_out or "(none)")

    stopping: list[str] = []

    def stop_all(reason: str) -> None:
        stopping.append(reason)
        for because in list(stops):
            because(reason)

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
                log.exception("uav %d failed", uav)
                if started.n_waiting:
                    started.abort()
                stop_all(f"uav {uav} failed")
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
    return EXIT_ROUTER_LOST if any(r.router_lost for _, r in results.values()) else 0
