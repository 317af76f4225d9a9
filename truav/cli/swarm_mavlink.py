"""`truav-swarm mavlink`: a running swarm's UAVs as MAVLink systems for a ground-control station
(QGroundControl, MAVSDK, pymavlink) over UDP; truav/swarm/mavlink_bridge.py does the work."""

from __future__ import annotations

import argparse
import ipaddress
import threading

from truav.cli.args import UserError, int_in, positive_float
from truav.cli.run_lookup import add_run_args
from truav.cli.swarm_bridges import open_bridge_run, serve_bridge
from truav.cli.swarm_common import add_geo_origin_arg, add_transport_args

MAX_RATE_HZ = 50.0
GCS_HELP = "the ground station's UDP endpoint HOST:PORT, an IPv4 address (default 127.0.0.1:14550, QGroundControl's)"


def udp_endpoint(text: str) -> tuple[str, int]:
    """argparse type: an IPv4 HOST:PORT with a port in [1, 65535]."""
    host, _, port = text.rpartition(":")
    try:
        ipaddress.IPv4Address(host)
        number = int(port)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected IPV4:PORT, e.g. 127.0.0.1:14550, got {text!r}") from None
    if not 1 <= number <= 65535:
        raise argparse.ArgumentTypeError(f"port must be in [1, 65535], got {text!r}")
    return host, number


def _altitude(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not -500.0 <= value <= 9000.0:
        raise argparse.ArgumentTypeError(f"must be a ground altitude in [-500, 9000] m, got {text}")
    return value


def _rate(text: str) -> float:
    value = positive_float(text)
    if value > MAX_RATE_HZ:
        raise argparse.ArgumentTypeError(f"must be at most {MAX_RATE_HZ:g} Hz, got {text}")
    return value


def cmd_mavlink(args) -> int:
    try:
        from truav.swarm import mavlink_bridge
        from truav.swarm.mavlink_messages import SYSIDS_PER_BRIDGE, FleetSettings, MavlinkFleet
    except ImportError as exc:
        if "pymavlink" not in str(exc):
            raise
        raise UserError("truav-swarm mavlink needs pymavlink: pip install -e '.[mavlink]' -c constraints.txt") from None
    from recorder.foxglove import Geometry

    run = open_bridge_run(args)  # repositions go out as the operator (its credentials)
    cfg = run.cfg
    geometry = Geometry.from_config(cfg)
    fleet = MavlinkFleet(FleetSettings(
        run=args.run, origin=args.geo_origin, area_m=geometry.area_m, uav_altitude_m=geometry.uav_altitude_m,
        ground_alt_m=args.ground_alt, first_uav=args.first_uav, battery_wh=args.battery_wh,
        step_s=cfg.scenario.step_s))
    stop = threading.Event()
    bridge = mavlink_bridge.Bridge(fleet, args.udp_out, rate_hz=args.rate, on_shutdown=stop.set)
    last = min(args.first_uav + SYSIDS_PER_BRIDGE - 1, cfg.scenario.n_uavs - 1)

    def ready_line() -> str:
        return (f"MAVLink: run {args.run}'s UAVs {args.first_uav}-{last} as systems 1-{last - args.first_uav + 1}, "
                f"to udp {args.udp_out[0]}:{args.udp_out[1]}")

    def summary() -> str:
        st = bridge.stats
        return (f"{st.sent} datagram(s) sent to {args.udp_out[0]}:{args.udp_out[1]}, {st.steered} reposition(s) "
                f"sent on as overrides, {st.denied} denied (no point inside the area), "
                f"{sum(st.refused.values())} command(s) refused as unsupported")

    return serve_bridge("mavlink", args, run, mavlink_bridge.run_bridge, bridge, stop, ready_line, summary)


def add_mavlink_command(sub) -> None:
    from truav.wire.keys import MAX_UAVS
    mv = sub.add_parser("mavlink", help="a running swarm's UAVs as MAVLink systems for a ground station (UDP; "
                                        "needs the mavlink extra)")
    add_run_args(mv)
    mv.add_argument("--udp-out", type=udp_endpoint, default=("127.0.0.1", 14550), metavar="HOST:PORT", help=GCS_HELP)
    add_geo_origin_arg(mv)
    mv.add_argument("--ground-alt", type=_altitude, default=0.0, metavar="M",
                    help="altitude of the area's ground above mean sea level, metres (default 0); the UAVs fly "
                         "the scenario's uav_altitude_m above it")
    mv.add_argument("--first-uav", type=int_in(0, MAX_UAVS - 1), default=0, metavar="N",
                    help="the UAV sent as system id 1; this bridge carries UAVs N to N+253 (a swarm of more than "
                         "254 UAVs: one bridge per block, each to its own --udp-out port; default 0)")
    mv.add_argument("--battery-wh", type=positive_float, default=None, metavar="WH",
                    help="a battery capacity to report the charge remaining against (the world models the energy "
                         "spent, not a battery; default: remaining unknown)")
    mv.add_argument("--rate", type=_rate, default=2.0, metavar="HZ",
                    help=f"telemetry messages per UAV per second (default 2, at most {MAX_RATE_HZ:g})")
    mv.add_argument("-v", "--verbose", action="store_true")
    add_transport_args(mv)
    mv.set_defaults(func=cmd_mavlink)

