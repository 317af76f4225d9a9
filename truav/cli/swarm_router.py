"""`truav-swarm router`: a Zenoh router for a swarm's parts (`truav-swarm up` starts one per run).

Apart from the other parts' commands so that starting it loads Zenoh and the wire's size limits only
(about 0.2 CPU-s), not the world's and the agents' kernels (0.6 CPU-s more): every swarm starts one.
"""

from __future__ import annotations

import argparse
import logging
import sys
import threading

import zenoh

from truav.bus.zenoh_config import DEFAULT_ENDPOINT
from truav.cli.args import OneLineParser, add_transport_args, check_transport, run_main
from truav.cli.swarm_common import part_creds, setup_logging, zenoh_reason
from truav.lifecycle import stop_on_sigterm_or_orphaned

log = logging.getLogger("truav.swarm")

HELP = "run a Zenoh router"


def cmd_router(args) -> int:
    from truav.bus.router import run_router
    setup_logging(args.verbose)
    stop = threading.Event()
    stop_on_sigterm_or_orphaned(stop.set)
    part_creds(args, "router")
    listen = args.listen or ([] if args.config else [DEFAULT_ENDPOINT])  # a config file keeps its own
    try:
        # "router listening" is printed once the endpoints are open: `truav-swarm up` waits for that line.
        run_router(listen, connect=args.connect, config_file=args.config, stop=stop,
                   on_ready=lambda: print(f"router listening on {', '.join(listen) or 'the endpoints of ' + args.config}",
                                          flush=True))
    except KeyboardInterrupt:
        pass
    except zenoh.ZError as exc:
        print(f"truav-swarm router: error: cannot listen on {', '.join(listen)}: {zenoh_reason(exc)}",
              file=sys.stderr, flush=True)
        return 1
    log.info("router stopped")
    return 0


def add_router_args(ro: argparse.ArgumentParser) -> None:
    add_transport_args(ro)
    ro.add_argument("-v", "--verbose", action="store_true")
    ro.set_defaults(func=cmd_router)


def main(argv: list[str]) -> int:
    """`truav-swarm router ARGS`, parsed by a parser of its own (truav.cli.swarm hands it over): the same
    flags, help and one-line mistakes as the `router` subcommand of the whole parser."""
    ap = OneLineParser(prog="truav-swarm router", description=HELP)
    add_router_args(ap)
    args = ap.parse_args(argv)

    def run() -> int:
        check_transport(args)
        return args.func(args)

    return run_main("truav-swarm", run, say_interrupted=False)
