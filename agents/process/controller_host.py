"""The central scheme's controller process's run: its bus session, its node, its stop (truav.lifecycle).

`truav-swarm controller` checks its flags, builds ControllerOptions and calls :func:`host_controller`.
"""

from __future__ import annotations

import logging

from agents.process.central_process import ControllerNode, ControllerOptions
from truav.bus.transport import Bus
from truav.config import Config
from truav.lifecycle import EXIT_ROUTER_LOST, stop_on_sigterm_or_orphaned
from truav.wire import keys

log = logging.getLogger("truav.swarm")  # the controller process's log lines keep the swarm's logger name


def host_controller(cfg: Config, opts: ControllerOptions, conf, router_timeout_s: float | None) -> int:
    """Run the controller on a session with Zenoh config ``conf`` until it is stopped (a shutdown,
    SIGTERM, a lost supervisor, a router lost for ``router_timeout_s``); the process's exit code."""
    with Bus(keys.SRC_CONTROLLER, opts.run, conf) as bus:
        node = ControllerNode(cfg, opts, bus)
        reasons = stop_on_sigterm_or_orphaned(node.stop, bus, router_timeout_s)
        log.info("controller joined run %s (%s)", opts.run, f"policy {opts.policy}" if opts.policy else "learning online")
        try:
            node.run()
        except KeyboardInterrupt:
            reasons.because("interrupted")
        node.write_stats()
    log.info("controller stopped after %d tick(s), %d command(s) (%s)", node.stats["ticks"], node.stats["commands"],
             reasons.first or "shutdown")
    return EXIT_ROUTER_LOST if reasons.router_lost else 0
