"""`truav-swarm ros2`: a running swarm as ROS 2 topics over rmw_zenoh (``ros2 topic list/echo``, RViz), steered
by goals from ROS 2 (as the ``operator`` identity);
truav/swarm/ros2_bridge.py does the work, truav/wire/rmw_zenoh.py formats rmw_zenoh's keys."""

from __future__ import annotations

import sys
import threading
from pathlib import Path

from truav.cli.args import UserError, int_in
from truav.cli.run_lookup import add_run_args, find_run
from truav.cli.swarm_common import add_transport_args, config_from_args, operator_config, part_creds, setup_logging


def cmd_ros2(args) -> int:
    try:
        from rosbags.typesys import Stores, get_typestore
    except ImportError:
        raise UserError("truav-swarm ros2 needs rosbags: pip install -e '.[ros2]' -c constraints.txt") from None
    from recorder.foxglove import Geometry
    from recorder.ros2_messages import Ros2Mapper
    from truav.config import load_config
    from truav.swarm import ros2_bridge
    from truav.swarm.outdir import SCENARIO_FILE

    out = find_run(args)
    scenario = Path(out) / SCENARIO_FILE
    cfg = load_config(scenario if scenario.is_file() else None)  # a bad file: ConfigError, one line naming it
    steer_config = operator_config(args)  # goals go out as the operator (its credentials)
    part_creds(args, "view")
    setup_logging(args.verbose)
    typestore = get_typestore(Stores.ROS2_JAZZY)
    stop = threading.Event()
    bridge = ros2_bridge.Ros2Bridge(Ros2Mapper(typestore, Geometry.from_config(cfg)), typestore, args.run,
                                    cfg.scenario.n_uavs, domain_id=args.domain_id, on_shutdown=stop.set)

    def ready() -> None:
        print(f"ROS 2: run {args.run} as node {ros2_bridge.NAMESPACE}/{bridge.node} on ROS_DOMAIN_ID "
              f"{args.domain_id}, {len(bridge.topics)} topics (/truav/uav_<i>/pose and velocity, /truav/markers, "
              f"/truav/metrics) and {cfg.scenario.n_uavs} goal subscriptions (/truav/uav_<i>/goal) through the "
              f"router at {', '.join(args.connect or ['(the zenoh config)'])}"
              + ("" if scenario.is_file() else f" (no {scenario}: the default scenario's geometry)"), flush=True)

    why = "stopped"
    try:
        ros2_bridge.run_bridge(args.run, config_from_args(args), bridge, stop=stop, ready=ready,
                               steer_config=steer_config)
        why = "the run shut down"
    finally:  # Ctrl-C and SIGTERM too (exit 130 / 143): one line of what was done
        st = bridge.stats
        print(f"truav-swarm ros2: {why}: {sum(st.published.values())} ROS 2 message(s) published on "
              f"{len(st.published)} topic(s), {st.steered} goal(s) sent on as overrides, {st.refused} refused "
              f"(another frame than map, outside the area, or not a PoseStamped)"
              + (f", {st.odd} bus message(s) that did not fit their kind" if st.odd else ""), file=sys.stderr)
    return 0


def add_ros2_command(sub) -> None:
    from truav.wire.rmw_zenoh import MAX_DOMAIN_ID
    p = sub.add_parser("ros2", help="a running swarm as ROS 2 topics over rmw_zenoh: each UAV's pose, markers "
                                    "for RViz, the metrics; a PoseStamped on /truav/uav_N/goal steers UAV N "
                                    "(sent as the operator; needs the ros2 extra)")
    add_run_args(p)
    p.add_argument("--domain-id", type=int_in(0, MAX_DOMAIN_ID), default=0, metavar="N",
                   help="the ROS_DOMAIN_ID the ROS 2 side uses (default 0)")
    p.add_argument("-v", "--verbose", action="store_true")
    add_transport_args(p)
    p.set_defaults(func=cmd_ros2)
