"""``truav-swarm replay-ctl``: steer a running replay from another terminal, over its Zenoh queryable
(``truav/<run>/replay/ctl``, :mod:`recorder.process.replay_bus`), and print its status after the command.

    truav-swarm replay-ctl --run R status
    truav-swarm replay-ctl --run R pause | resume | toggle | quit
    truav-swarm replay-ctl --run R step [N] | burst N | next [N]
    truav-swarm replay-ctl --run R rate 2
    truav-swarm replay-ctl --run R seek --tick 40 | --time 12.5 | --by -5

Without -e, -c or --creds it finds the router of the live run named by --run or --out (its swarm.json),
never a default port. Exit code 0 with the status line; 1 with one line when no replay answers or it refuses the command
(a tick not in the recording...); 2 for a mistake on the command line.
"""

from __future__ import annotations

import argparse
import sys

from truav.cli.args import non_negative_float, non_negative_int, positive_float, positive_int
from truav.cli.run_lookup import add_run_args, explicit_router, find_run
from truav.cli.swarm_common import add_transport_args, config_from_args

DEFAULT_RUN = "demo"
CTL_IDENTITY = "supervisor"
"""Under --secure the operator's identity: the ACL lets it query a replay's ctl key (truav.bus.acl)."""


def finite(text: str) -> float:
    """argparse type: a finite number, either sign (a seek back is negative)."""
    import math
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text}")
    return value


def command_of(args: argparse.Namespace) -> tuple[str, dict]:
    """(command, args) of :meth:`recorder.replay.Replayer.command` for the parsed command line."""
    action = args.action
    if action in ("step", "burst", "next"):
        return action, {"n": args.n}
    if action == "rate":
        return action, {"rate": args.rate}
    if action == "seek":
        if args.tick is not None:
            return action, {"tick": args.tick}
        if args.time is not None:
            return action, {"s": args.time}
        return action, {"by": args.by}
    return action, {}


def cmd_replay_ctl(args: argparse.Namespace) -> int:
    """``truav-swarm replay-ctl`` (and ``truav log play-ctl``): one command, the status after it."""
    from recorder.process.replay_bus import ask_replay, status_line
    from truav.bus.transport import Bus, QueryRefused

    from truav.bus.zenoh_config import apply_replay_creds
    from truav.cli.config import UsageError

    command, cargs = command_of(args)
    try:
        apply_replay_creds(args, CTL_IDENTITY)  # under --creds: the replay's own run, <run>-replay
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if not explicit_router(args):  # the router of the live run named (its swarm.json), never a default port
        find_run(args)
    args.run = args.run or DEFAULT_RUN
    try:
        bus = Bus(CTL_IDENTITY, args.run, config_from_args(args))
    except Exception as exc:  # zenoh.ZError: no router there (the endpoint's form was checked before)
        from recorder.process.recorder import short_error
        print(f"{args.ctl_prog}: error: cannot open a session: {short_error(exc)}", file=sys.stderr)
        return 1
    with bus:
        try:
            status = ask_replay(bus, args.run, command, cargs, timeout=args.timeout)
        except QueryRefused as exc:
            print(f"{args.ctl_prog}: {command}: {exc}", file=sys.stderr)
            return 1
    print(status_line(status))
    return 0


def add_replay_ctl(subparsers, name: str = "replay-ctl", prog: str = "truav-swarm replay-ctl",
                   help: str = "alias of `truav log play-ctl`") -> argparse.ArgumentParser:
    """``replay-ctl`` of ``truav-swarm``, or ``play-ctl`` of ``truav log`` (the same parser and command)."""
    ctl = subparsers.add_parser(
        name, help=help,
        description="Send one command to the replay publishing into --run (over its queryable "
                    "truav/<run>/replay/ctl) and print its status after it. Seek takes seconds from the "
                    "recording's first message, a world tick, or seconds back (negative) or forward; after a "
                    "seek each channel's last message before that point is sent again first.")
    add_run_args(ctl, run_help="the run the replay publishes into (default demo; with --creds, <its run>-replay); "
                               "without -e, -c or --creds the live run of that name, whose router its directory "
                               "runs/swarm-NAME names (swarm.json); a replay on a router of your own: -e ENDPOINT",
                 out_help="the live run the replay publishes into, by its directory (its swarm.json gives the "
                          "run's name and router)")
    ctl.add_argument("--timeout", type=positive_float, default=5.0, metavar="S",
                     help="seconds to wait for the replay's answer (default 5)")
    add_transport_args(ctl)
    actions = ctl.add_subparsers(dest="action", required=True, metavar="ACTION")
    for name, text in (("status", "print where it stands"), ("pause", "pause"), ("resume", "resume"),
                       ("toggle", "pause or resume"), ("quit", "end the replay")):
        actions.add_parser(name, help=text)
    for name, text, default in (("step", "send the next N world ticks, then stay paused", 1),
                                ("burst", "send N world ticks as fast as possible, then stay paused", None),
                                ("next", "send the next N messages, then stay paused", 1)):
        p = actions.add_parser(name, help=text)
        if default is None:
            p.add_argument("n", type=positive_int, metavar="N")
        else:
            p.add_argument("n", type=positive_int, nargs="?", default=default, metavar="N")
    rate = actions.add_parser("rate", help="set the speed factor (2: twice as fast as recorded)")
    rate.add_argument("rate", type=positive_float, metavar="R")
    seek = actions.add_parser("seek", help="go to a time or a tick (forwards or backwards) while playing")
    where = seek.add_mutually_exclusive_group(required=True)
    where.add_argument("--tick", type=non_negative_int, metavar="K", help="the start of world tick K")
    where.add_argument("--time", type=non_negative_float, metavar="S", help="S seconds from the recording's first message")
    where.add_argument("--by", type=finite, metavar="S", help="S seconds forward (negative: back) from where it is")
    ctl.set_defaults(func=cmd_replay_ctl, ctl_prog=prog)
    return ctl
