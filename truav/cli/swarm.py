"""`truav-swarm`: the decentralized TRUAV swarm as separate processes on Zenoh.

    truav-swarm up                          # short demo: own router on loopback, world, 5 agents, summary + picture
    truav-swarm up --agents 8 --episodes 5 --record runs/demo.mcap
    truav-swarm up --lockstep --qtable runs/train-15mps
    truav-swarm status                      # run demo's processes: its router from runs/swarm-demo/swarm.json
    truav-swarm down --run demo             # the same lookup (--out DIR: a run with another --out)

and the parts, for other hosts or terminals (zenoh-example style flags):

    truav-swarm router -l tcp/0.0.0.0:7447
    truav-swarm world --run demo -e tcp/HOST:7447
    truav-swarm agent --id 3 --run demo -e tcp/HOST:7447
    truav-swarm controller --run demo -e tcp/HOST:7447 --policy RUN   # --scheme central's controller

and the wire protocol, for an agent of your own (docs/reference/protocol.md, examples/outside_agent.py):

    truav-swarm schema --out schemas        # the JSON Schemas of every message kind
"""

from __future__ import annotations

import argparse
import sys

from truav.cli.args import OneLineParser, UserError, run_main

PARTS = ("world", "agent", "controller")
"""The swarm's processes: started several times per run, each parses a parser of its own part alone (not
every command's, nor the other parts': their imports cost a part CPU at every start). The router has a parser of
its own."""


def build_parser(parts_only: bool = False, part: str | None = None) -> argparse.ArgumentParser:
    """The whole command line; with ``parts_only`` the process parts' subcommands alone (PARTS), with ``part``
    too that part's alone."""
    from truav.cli.swarm_processes import add_process_commands
    ap = OneLineParser(prog="truav-swarm", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="command", required=True, metavar="COMMAND")
    if parts_only:
        add_process_commands(sub, only=part)
        return ap
    from truav.cli.swarm_mavlink import add_mavlink_command
    from truav.cli.swarm_ops import add_ops_commands
    from truav.cli.swarm_replay import add_replay_ctl
    from truav.cli.swarm_ros2 import add_ros2_command
    from truav.cli.swarm_schema import add_schema_commands
    from truav.cli.swarm_secure import add_security_commands
    from truav.cli.swarm_up import add_up_commands
    add_up_commands(sub)
    add_ops_commands(sub)
    add_process_commands(sub)
    add_security_commands(sub)
    add_schema_commands(sub)
    add_replay_ctl(sub)
    add_mavlink_command(sub)
    add_ros2_command(sub)

    try:
        from truav.cli.log import add_swarm_commands
    except ImportError:  # recorder commands not installed
        pass
    else:
        add_swarm_commands(sub)
    return ap


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv[:1] == ["router"]:
        from truav.cli.swarm_router import main as router_main
        return router_main(argv[1:])
    part = argv[0] if argv and argv[0] in PARTS else None
    args = build_parser(parts_only=part is not None, part=part).parse_args(argv)

    def run() -> int:
        import zenoh

        from truav.cli.args import check_transport
        if args.command != "up" and args.command != "chaos":  # their -l is the supervisor's (checked there)
            check_transport(args)
        try:
            return args.func(args)
        except zenoh.ZError as exc:  # almost always: no router where --connect points
            if not (getattr(args, "creds", None) or getattr(args, "config", None)):
                for ep in getattr(args, "connect", None) or []:
                    from truav.bus.security import answers_tls
                    if isinstance(ep, str) and answers_tls(ep):  # a --secure swarm's router, asked in plain TCP
                        raise UserError(f"-e/--connect {ep}: the router there speaks TLS (a --secure swarm) and "
                                        f"admits only clients with its credentials: pass --creds DIR (the run's "
                                        f"<out>/creds)") from None
            print(f"truav-swarm: error: Zenoh could not open a session ({str(exc).split(' at ')[0].strip()}); is a "
                  f"router running there? Start one with `truav-swarm router`, or pass -e/--connect ENDPOINT",
                  file=sys.stderr)
            return 1

    return run_main("truav-swarm", run, say_interrupted=False)


def entry() -> None:
    """The `truav-swarm` console script and `python -m truav.cli.swarm`: a swarm's part ends without the
    interpreter's finalization once its files are written (truav.lifecycle.exit_after_work)."""
    argv = sys.argv[1:]
    code = main(argv)
    if argv[:1] and argv[0] in (*PARTS, "router"):
        from truav.lifecycle import exit_after_work
        exit_after_work(code)
    sys.exit(code)


if __name__ == "__main__":
    entry()
