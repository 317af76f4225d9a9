"""`truav-swarm ros2`: a running swarm as ROS 2 topics over rmw_zenoh (``ros2 topic list/echo``, RViz), steered
by goals from ROS 2 (as the ``operator`` identity);
truav/swarm/ros2_bridge.py does the work, truav/wire/rmw_zenoh.py formats rmw_zenoh's keys."""

from __future__ import annotations

import threading

from truav.cli.args import UserError, int_in
from truav.cli.run_lookup import add_run_args
from truav.cli.swarm_bridges import open_bridge_run, serve_bridge
from truav.cli.swarm_common import add_transport_args


def cmd_ros2(args) -> int:
    try:
        from rosbags.typesys import Stores, get_typestore
    except ImportError:
        raise UserError("truav-swarm ros2 needs rosbags: pip install -e '.[ros2]' -c constraints.txt") from None
    from recorder.foxglove import Geometry
    from recorder.ros2_messages import Ros2Mapper
    from truav.swarm import ros2_bridge

    run = open_bridge_run(args)  # goals go out as the operator (its credentials)
    cfg = run.cfg
    typestore = get_typestore(Stores.ROS2_JAZZY)
    stop = threading.Event()
    bridge = ros2_bridge.Ros2Bridge(Ros2Mapper(typestore, Geometry.from_config(cfg)), typestore, args.run,
                                    cfg.scenario.n_uavs, domain_id=args.domain_id, on_shutdown=stop.set)

    def ready_line() -> str:
        return (f"ROS 2: run {args.run} as node {ros2_bridge.NAMESPACE}/{bridge.node} on ROS_DOMAIN_ID "
                f"{args.domain_id}, {len(bridge.topics)} topics (/truav/uav_<i>/pose and velocity, /truav/markers, "
                f"/truav/metrics) and {cfg.scenario.n_uavs} goal subscriptions (/truav/uav_<i>/goal) through the "
                f"router at {', '.join(args.connect or ['(the zenoh config)'])}")

    def summary() -> str:
        st = bridge.stats
        return (f"{sum(st.published.values())} ROS 2 message(s) published on {len(st.published)} topic(s), "
                f"{st.steered} goal(s) sent on as overrides, {st.refused} refused "
                f"(another frame than map, outside the area, or not a PoseStamped)")

    return serve_bridge("ros2", args, run, ros2_bridge.run_bridge, bridge, stop, ready_line, summary)


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
