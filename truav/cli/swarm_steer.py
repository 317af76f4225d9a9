"""`truav-swarm steer`: take one UAV of a running swarm over from outside (fly it to a point), or give it back.

It sends an override on control/override/<i> (truav.wire.messages.Override) as the ``operator`` identity (under
--secure: the operator's credentials of `truav-swarm certs`), then waits for the world's confirmation on
fault/override, which names the tick it applied from. The run is found as `faults` finds it
(truav.cli.run_lookup).
"""

from __future__ import annotations

import argparse
import sys
import threading
from pathlib import Path

from truav.cli.args import int_in, non_negative_float, positive_float
from truav.cli.config import UsageError
from truav.cli.run_lookup import add_run_args, find_run, run_there
from truav.cli.swarm_common import add_transport_args, config_from_args, part_creds
from truav.swarm.steering import inside_area, send_override
from truav.wire import keys, schema

CONFIRM_WAIT_S = 5.0
LISTENER_WAIT_S = 5.0


def point(text: str) -> tuple[float, float]:
    """argparse type of --to: ``X,Y`` in metres, two finite numbers."""
    parts = text.split(",")
    if len(parts) != 2:
        raise argparse.ArgumentTypeError(f"expected X,Y in metres, e.g. 2500,1200, got {text!r}")
    try:
        x, y = (float(p) for p in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected X,Y in metres, e.g. 2500,1200, got {text!r}") from None
    if not all(abs(v) < float("inf") for v in (x, y)):
        raise argparse.ArgumentTypeError(f"X and Y must be finite, got {text!r}")
    return x, y


def _scenario(out: Path):
    from truav.config import load_config
    from truav.swarm.outdir import SCENARIO_FILE
    path = Path(out) / SCENARIO_FILE
    return load_config(path if path.is_file() else None)  # a bad file: ConfigError, one line naming it


def cmd_steer(args) -> int:
    from truav.bus.transport import Bus
    out = find_run(args)
    sc = _scenario(out).scenario
    if args.uav >= sc.n_uavs:
        raise UsageError(f"UAV {args.uav}: run {args.run!r} has UAVs 0-{sc.n_uavs - 1}")
    if args.to is not None and not inside_area(args.to, sc.area_m):
        raise UsageError(f"--to {args.to[0]:g},{args.to[1]:g}: outside run {args.run!r}'s area, "
                         f"[0, {sc.area_m:g}] m on each axis")
    part_creds(args, keys.SRC_OPERATOR)
    release = args.to is None
    confirmed: list[schema.Fault] = []
    heard = threading.Event()
    me = keys.uav_identity(args.uav)

    def on_event(_key, ev, _raw, _t) -> None:
        if ev.target == me and ev.phase == (schema.PHASE_END if release else schema.PHASE_START) \
                and ev.params.get("by") == keys.SRC_OPERATOR:
            confirmed.append(ev)
            heard.set()

    with Bus(keys.SRC_OPERATOR, args.run, config_from_args(args)) as bus:
        _, missing = run_there(bus, args, 1.0)
        if missing:  # nothing of the run alive there: no world to steer anything
            print(f"truav-swarm: error: {missing}", file=sys.stderr)
            return 1
        bus.subscribe(keys.fault(args.run, schema.FAULT_OVERRIDE), on_event)
        key = keys.control_override(args.run, args.uav)
        if not bus.await_subscribers(key, LISTENER_WAIT_S):
            print(f"truav-swarm steer: warning: nothing of run {args.run} listens for overrides (yet); sending "
                  f"anyway", file=sys.stderr)
        send_override(bus, args.run, args.uav, args.to, args.speed)
        heard.wait(args.wait)
    what = f"UAV {args.uav} of run {args.run}: " + (
        "released (its agent flies it again)" if release else
        f"steered to ({args.to[0]:g}, {args.to[1]:g}) m" + (f" at {args.speed:g} m/s" if args.speed else ""))
    if not confirmed:
        print(f"truav-swarm: error: {what}: sent, but the world did not confirm it within {args.wait:g} s"
              + (" (a UAV not overridden has nothing to release)" if release else ""), file=sys.stderr)
        return 1
    print(f"{what}, from tick {confirmed[0].params.get('tick')}")
    return 0


def add_steer_command(sub) -> None:
    st = sub.add_parser("steer", help="fly one UAV of a running swarm to a point, overriding its agent, or "
                                      "release it (--secure: the operator's credentials)")
    add_run_args(st)
    st.add_argument("uav", type=int_in(0, keys.MAX_UAVS - 1), metavar="UAV", help="the UAV's id")
    what = st.add_mutually_exclusive_group(required=True)
    what.add_argument("--to", type=point, metavar="X,Y",
                      help="the point to fly to, metres in the run's area; the UAV hovers there until released")
    what.add_argument("--release", action="store_true", help="end the override: its agent flies it again")
    st.add_argument("--speed", type=non_negative_float, default=0.0, metavar="M/S",
                    help="fly at the half or full speed of the actions nearest this (default 0: full speed)")
    st.add_argument("--wait", type=positive_float, default=CONFIRM_WAIT_S, metavar="S",
                    help=f"seconds to wait for the world's confirmation (default {CONFIRM_WAIT_S:g}); exit 1 without")
    add_transport_args(st)
    st.set_defaults(func=cmd_steer)
