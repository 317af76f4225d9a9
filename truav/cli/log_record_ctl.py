"""``truav log record-ctl split|pause|resume|snapshot --run RUN``: command a running recorder over the bus.

Publishes a ``Control`` message with that command on ``truav/<run>/control/recorder`` as the
``supervisor`` identity (under ``--secure`` the router lets only that identity put there:
``--creds DIR`` takes its certificate).  Without -e, -c or --creds the run is found by --run NAME or
--out DIR (its swarm.json names its router), never at a default port.  Exit 0 once sent to a listening recorder; 1 when no
session opens (no router there) or no recorder of the run listens within the wait; 2 for a user
mistake.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from truav.cli import args as cli_args

__all__ = ["add_record_ctl_parser", "cmd_record_ctl", "RECORDER_COMMANDS"]

RECORDER_COMMANDS = ("split", "pause", "resume", "snapshot")  # recorder.process.recorder CMD_* (stop: `truav-swarm down`)
CONTROL_IDENTITY = "supervisor"
LISTENER_WAIT_S = 5.0
HELP = "send split, pause, resume or snapshot to a running recorder (over the bus)"


def add_record_ctl_parser(subparsers: Any) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "record-ctl", help=HELP,
        description="Send a command to the recorder of a running swarm on truav/<run>/control/recorder: split "
                    "(start the next part; recording in parts), pause (write nothing until resume; the file notes "
                    "it so the gap is not taken for a loss), resume, snapshot (snapshot mode: write the kept "
                    "seconds and those after). Sent as the supervisor identity (--creds under --secure).")
    p.add_argument("command", choices=RECORDER_COMMANDS, help="what the recorder should do")
    from truav.cli.run_lookup import add_run_args
    add_run_args(p)
    p.add_argument("--wait", type=cli_args.positive_float, default=LISTENER_WAIT_S, metavar="S",
                   help=f"how long to wait for the recorder to be listening (default {LISTENER_WAIT_S:g})")
    cli_args.add_transport_args(p)
    p.set_defaults(func=cmd_record_ctl)
    return p


def cmd_record_ctl(args: argparse.Namespace) -> int:
    from recorder.process.recorder import CONTROL_PART
    from truav.bus import transport
    from truav.wire import keys, schema

    try:
        transport.apply_creds(args, CONTROL_IDENTITY)
    except ValueError as exc:
        raise cli_args.UserError(f"--creds: {exc}") from None
    from truav.cli.run_lookup import explicit_router, find_run
    if not explicit_router(args):  # the router of the live run named (its swarm.json), never a default port
        find_run(args)
    args.run = args.run or "demo"
    try:
        bus = transport.Bus(CONTROL_IDENTITY, args.run, transport.config_from_args(args))
    except Exception as exc:  # zenoh.ZError: no router there (the endpoint's form was checked before)
        from recorder.process.recorder import short_error
        print(f"truav log record-ctl: error: cannot open a session: {short_error(exc)}", file=sys.stderr)
        return 1
    with bus:
        key = keys.control(args.run, CONTROL_PART)
        if not bus.await_subscribers(key, args.wait):
            print(f"truav log record-ctl: error: no recorder of run {args.run} listens on {key} "
                  f"(waited {args.wait:g} s)", file=sys.stderr)
            return 1
        bus.publish(key, schema.Control(command=args.command, args={}))
    print(f"sent {args.command} to the recorder of run {args.run}")
    return 0
