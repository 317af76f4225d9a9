"""The ROS 2 bridge's goals (truav/swarm/ros2_bridge.py) without a bus: a PoseStamped in frame map inside the
area steers its UAV; another frame, a point outside the area, bytes that are no PoseStamped, an oversized
sample or a UAV the run does not have are refused and counted, never sent on."""

from __future__ import annotations

import pytest

pytest.importorskip("rosbags", reason="the ROS 2 bridge is the optional extra 'ros2'")

from recorder.foxglove import Geometry  # noqa: E402
from recorder.ros2_messages import Ros2Mapper  # noqa: E402
from truav.swarm.ros2_bridge import GOAL_TYPE, MAX_GOAL_BYTES, Ros2Bridge  # noqa: E402


def _pose(store, x: float, y: float, frame: str = "map") -> bytes:
    t = store.types
    header = t["std_msgs/msg/Header"](stamp=t["builtin_interfaces/msg/Time"](sec=1, nanosec=0), frame_id=frame)
    pose = t["geometry_msgs/msg/Pose"](position=t["geometry_msgs/msg/Point"](x=x, y=y, z=100.0),
                                       orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0))
    msg = t[GOAL_TYPE](header=header, pose=pose)
    return bytes(store.serialize_cdr(msg, GOAL_TYPE))


def test_goals_in_frame_map_inside_the_area_steer_and_the_rest_are_refused() -> None:
    from rosbags.typesys import Stores, get_typestore
    store = get_typestore(Stores.ROS2_JAZZY)
    bridge = Ros2Bridge(Ros2Mapper(store, Geometry()), store, "r", n_uavs=3)
    sent: list[tuple[int, tuple[float, float]]] = []
    bridge.steer = lambda uav, xy: sent.append((uav, xy))
    key = "0/truav/uav_{}/goal/geometry_msgs::msg::dds_::PoseStamped_/RIHS01_x"
    area = bridge.mapper.geometry.area_m
    bridge._goal(key.format(1), _pose(store, 2500.0, 1200.0))
    for k, data in [(key.format(1), _pose(store, 2500.0, 1200.0, frame="odom")),
                    (key.format(1), _pose(store, area + 1.0, 10.0)),
                    (key.format(1), _pose(store, float("nan"), 10.0)),
                    (key.format(1), b"\x00\x01garbage"),
                    (key.format(1), b"\x00" * (MAX_GOAL_BYTES + 1)),
                    (key.format(3), _pose(store, 10.0, 10.0)),
                    (key.format("x"), _pose(store, 10.0, 10.0))]:
        bridge._goal(k, data)
    assert sent == [(1, (2500.0, 1200.0))]
    assert (bridge.stats.steered, bridge.stats.refused) == (1, 7)
