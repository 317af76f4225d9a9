"""What the `truav-swarm` subcommands share: scenario, scheme, lock-step and process flags, logging, credentials.

Light to import (no world, agents or kernels at the top): the router's command uses it, and every swarm starts
a router."""

from __future__ import annotations

import argparse
import logging
import sys

from truav.wire.schema import DEFAULT_LOCKSTEP_WAIT_S
# the transport's command-line helpers, for every truav-swarm command (one place to import them from)
from truav.analysis.agent_loader import AGENT_KIND_PREFIX
from truav.bus.transport import apply_creds, config_from_args  # noqa: F401
from truav.cli.args import add_options, positive_float, run_name, seed_int
from truav.cli.args import add_transport_args  # noqa: F401
from truav.cli.config import UsageError, parse_sets
from truav.config import Config, load_config
from truav.lifecycle import DEFAULT_ROUTER_TIMEOUT_S

log = logging.getLogger("truav.swarm")


def add_scenario_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--run", type=run_name, default="demo", help="run name: keys live under truav/<run>/ (default demo)")
    p.add_argument("--seed", type=seed_int, default=0, help="seed of the run (default 0)")
    p.add_argument("--scenario", metavar="FILE", help="scenario TOML (as `truav config show` prints)")
    p.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="override one scenario value (repeatable)")


def scenario_from(args) -> Config:
    return load_config(args.scenario, parse_sets(args.set))


GIL_SWITCH_INTERVAL_S = 0.0005
"""Bus callbacks run on Zenoh's threads and need the GIL: with Python's default
5 ms switch interval a message can wait that long behind the main thread."""


def setup_logging(verbose: bool) -> None:
    sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)
    # INFO by default: a part's log says what it did (joins, losses, checkpoints, why it stopped);
    # -v adds TRUAV's own debug lines (not the libraries').
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    if verbose:
        logging.getLogger("truav").setLevel(logging.DEBUG)


def zenoh_reason(exc: Exception) -> str:
    """The useful part of a Zenoh error ("Address already in use (os error 98)"), without source paths."""
    text = str(exc).split(" at /")[0].strip()
    return text.rsplit(": ", 1)[-1] if ": " in text else text


def part_creds(args, identity: str) -> None:
    """``--creds DIR``: this part's zenoh config from DIR (one line naming the flag if DIR is wrong)."""
    try:
        apply_creds(args, identity)
    except ValueError as exc:
        raise UsageError(str(exc)) from None


def operator_config(args):
    """The zenoh config a bridge steers with (a reposition, a ROS 2 goal): the ``operator`` identity's (under
    --creds its credentials of the same directory), whatever identity the bridge reads as. Call it before
    :func:`part_creds` for the read identity."""
    steering = argparse.Namespace(**vars(args))
    part_creds(steering, "operator")
    return config_from_args(steering)


def _origin(text: str):
    from recorder.foxglove import parse_origin
    try:
        return parse_origin(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_geo_origin_arg(p: argparse.ArgumentParser) -> None:
    from recorder.foxglove import DEFAULT_ORIGIN
    p.add_argument("--geo-origin", type=_origin, default=DEFAULT_ORIGIN, metavar="LAT,LON",
                   help="where the area's centre sits on the map (Foxglove's, a ground station's), degrees "
                        "(default %.4f,%.4f, Paris)"
                   % DEFAULT_ORIGIN)


def scheme_name(text: str) -> str:
    """argparse type of --scheme: one of SCHEMES, or agent:NAME (an agents.api class; `up --agent NAME`),
    the class checked by the command (check_agent_scheme)."""
    from truav.swarm.checks import SCHEMES
    if text in SCHEMES or (text.startswith(AGENT_KIND_PREFIX) and len(text) > len(AGENT_KIND_PREFIX)):
        return text
    raise argparse.ArgumentTypeError(f"invalid choice: {text!r} (choose from {', '.join(SCHEMES)}, or agent:NAME)")


def check_agent_scheme(args, cfg: Config) -> None:
    """--scheme agent:NAME: the class found and checked (one line, exit 2) before anything starts."""
    if args.scheme.startswith(AGENT_KIND_PREFIX):
        from truav.analysis import agent_loader
        agent_loader.load(args.scheme[len(AGENT_KIND_PREFIX):], cfg, flag="--agent")


SCHEME_CHOICES_HELP = ("truav (independent Q-learning agents, learning from scratch), central (a controller process "
                      "commands every UAV each tick), patrol (the pre-planned patrol), or agent:NAME (an agent class; "
                      "`up --agent NAME`)")


def add_scheme_arg(p: argparse.ArgumentParser, default: str | None = "truav", default_help: str | None = None) -> None:
    """--scheme; ``default`` None: resolved by the command (:func:`resolve_scheme`), ``default_help`` saying to what."""
    p.add_argument("--scheme", type=scheme_name, default=default,
                   help=f"what flies the UAVs: {SCHEME_CHOICES_HELP} (default: {default_help or default})")


def resolve_scheme(args, default: str) -> None:
    """``args.scheme`` from --scheme, --agent NAME (agent:NAME) or ``default`` when neither is given; both given is
    a mistake (one line, exit 2)."""
    if args.agent is not None:
        if args.scheme is not None:
            raise UsageError(f"--agent {args.agent} and --scheme {args.scheme} exclude each other")
        args.scheme = AGENT_KIND_PREFIX + args.agent
    elif args.scheme is None:
        args.scheme = default


def add_command_hold_arg(p: argparse.ArgumentParser) -> None:
    from agents.process.agent_options import AgentOptions
    add_options(p, AgentOptions, ["command_hold_s"])


def add_policy_args(p: argparse.ArgumentParser) -> None:
    from agents.process.controller_options import ControllerOptions
    add_options(p, ControllerOptions, ["policy", "policy_index"])


def add_lockstep_args(p: argparse.ArgumentParser, help_lockstep: str | None = None) -> None:
    p.add_argument("--lockstep", action="store_true", help=help_lockstep)
    p.add_argument("--lockstep-wait", type=positive_float, metavar="S",
                   help="lock-step: wait this long for a live agent's action or beacon (a paused process) before "
                        "going on without it; the run is then not exact and fails. The world waits so once: a live agent "
                        "that missed a round is marked silent and not waited for until it answers again (default "
                        f"{DEFAULT_LOCKSTEP_WAIT_S:g})")


def lockstep_wait(args) -> float:
    """--lockstep-wait, or its default; given without --lockstep it is a mistake (one line, exit 2)."""
    if args.lockstep_wait is not None and not args.lockstep:
        raise UsageError(f"--lockstep-wait {args.lockstep_wait:g}: only lock-step waits; add --lockstep or drop it")
    return DEFAULT_LOCKSTEP_WAIT_S if args.lockstep_wait is None else args.lockstep_wait


def add_swarm_process_args(p: argparse.ArgumentParser, who: str) -> None:
    """Flags the world and an agent process share: faults, router loss, replay, logging, transport."""
    p.add_argument("--fault-plan", metavar="FILE", help=f"apply this plan's link faults to what {who} receives")
    p.add_argument("--router-timeout", type=positive_float, default=DEFAULT_ROUTER_TIMEOUT_S, metavar="S",
                   help=f"stop this long after losing the router (default {DEFAULT_ROUTER_TIMEOUT_S:g})")
    p.add_argument("--accept-replay", action="store_true",
                   help="act on traffic a replay puts into this run (dropped and counted by default)")
    p.add_argument("-v", "--verbose", action="store_true", help="debug lines in the log")
    add_transport_args(p)


