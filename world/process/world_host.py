"""The world process's run: its bus session, its node, its stop (truav.lifecycle) and its statistics.

`truav-swarm world` checks its flags, builds WorldOptions and calls :func:`host_world`.
"""

from __future__ import annotations

import logging

from truav.atomic import EXIT_NO_SPACE, no_space, no_space_line
from truav.bus.transport import Bus
from truav.config import Config
from truav.lifecycle import EXIT_ROUTER_LOST, stop_on_sigterm_or_orphaned
from truav.wire import keys
from world.process.world_process import WorldNode, WorldOptions, write_stats
from world.world_stats import missed_share

EXIT_TOO_MANY_MISSED = 1
"""Exit code of a world whose run missed more than --max-missed of its actions: 1, as `truav-swarm up`
exits on a failed run (and as a world that lost its router)."""

log = logging.getLogger("truav.swarm")  # the world process's log lines keep the swarm's logger name


def host_world(cfg: Config, opts: WorldOptions, conf, router_timeout_s: float | None) -> int:
    """Run the world on a session with Zenoh config ``conf`` until its episodes end or it is stopped
    (SIGTERM, a lost supervisor, a router lost for ``router_timeout_s``); the process's exit code."""
    with Bus(keys.SRC_WORLD, opts.run, conf) as bus:
        node = WorldNode(cfg, opts, bus)
        reasons = stop_on_sigterm_or_orphaned(node.stop, bus, router_timeout_s)
        try:
            stats = node.run()
        except KeyboardInterrupt:
            reasons.because("interrupted")
            stats = node.stats
        stats.rejected = bus.rejections.as_dict()
        stats.per_uav = node.accounts.per_uav()
        stats.silent_at_end = sorted(node.silent())
        node.close_rejections()  # what is still pending goes out before the session closes
        stats.rejections_sent = node.notices.sent
    full = None  # the disk under --stats-out was full: what the world said
    if opts.stats_out:
        try:
            write_stats(opts.stats_out, stats)
        except OSError as exc:
            if not no_space(exc):
                raise
            full = no_space_line(opts.stats_out)
            log.error("%s", full)
    log.info("world stopped after %d episode(s), %d tick(s) (%s)%s", len(stats.episodes), stats.ticks,
             reasons.first or ("finished its episodes" if len(stats.episodes) == opts.episodes
                               else "a shutdown request, see above"),
             f"; statistics in {opts.stats_out}" if opts.stats_out else "")
    if reasons.router_lost:
        return EXIT_ROUTER_LOST
    if full is not None:
        return EXIT_NO_SPACE
    share = missed_share({"ticks": stats.ticks, "episodes": stats.episodes,
                          "actions_received": stats.actions_received}, cfg.scenario.n_uavs)
    if share is not None and share > opts.max_missed_share:
        worst = sorted(stats.per_uav, key=lambda u: (-u["missed"], u["uav"]))[:5]
        log.error("%.0f%% of the actions were missing (more than --max-missed %g): exit %d; most missed: %s",
                  100 * share, opts.max_missed_share, EXIT_TOO_MANY_MISSED,
                  ", ".join(f"uav {u['uav']} {u['missed']}" for u in worst if u["missed"]))
        return EXIT_TOO_MANY_MISSED
    return 0
