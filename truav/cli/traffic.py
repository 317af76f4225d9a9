"""`truav traffic build`: the SUMO trace of a scenario, built and cached (truav/analysis/sumo_traffic.py)."""

from __future__ import annotations

import argparse
import time

from truav.checks import check_out_dir
from truav.cli.config import add_config_args, config_from


def cmd_traffic_build(args) -> int:
    from truav.analysis import sumo_traffic
    cfg = config_from(args)
    sumo_traffic.sumo_home()  # one line naming what to install, before anything starts
    root = check_out_dir("--cache", args.cache) if args.cache is not None else None
    t0 = time.perf_counter()
    path, trace, built = sumo_traffic.checked_trace(cfg, root, args.force, say=lambda line: print(line, flush=True))
    rows, n = trace.positions.shape[:2]
    print(f"{'built' if built else 'cached'}: {path}")
    print(f"  {n} vehicles x {rows} rows of {trace.step_s:g} s ({trace.windows} episodes of "
          f"{trace.steps_per_episode} steps), {100.0 * (1.0 - trace.active.mean()):.2f}% of slot-steps off the road"
          + (f", built in {time.perf_counter() - t0:.1f} s" if built else ""))
    print("  train on it: truav train --mobility sumo (same --preset/--config/--set)")
    return 0


def add_traffic_parser(sub) -> None:
    """Register `truav traffic ...` on the main parser's subcommands."""
    tr = sub.add_parser("traffic", help="SUMO traffic for scenario.mobility = sumo (needs the sumo extra)")
    tr_sub = tr.add_subparsers(dest="traffic_command", required=True, metavar="ACTION")
    b = tr_sub.add_parser("build", help="build (or find cached) the scenario's SUMO trace: netgenerate grid, "
                                        "randomTrips.py towards the major intersections, SUMO's positions per step",
                          formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    add_config_args(b)
    b.add_argument("--force", action="store_true", help="build it again even if cached")
    b.add_argument("--cache", metavar="DIR", default=None,
                   help="cache directory (default $TRUAV_TRACE_CACHE, else ~/.cache/truav/sumo)")
    b.set_defaults(func=cmd_traffic_build)
