"""Reading an exported ROS 2 bag back with two independent decoders (rosbags, mcap-ros2-support), for the
`truav log ros2bag` tests; skips with the reason when the extras are not installed."""

from __future__ import annotations

import math
from collections import defaultdict
from pathlib import Path

import msgpack
import pytest

from recorder.reader import iter_messages

rosbags_highlevel = pytest.importorskip("rosbags.highlevel", reason="needs rosbags: pip install -e '.[ros2]'")
mcap_ros2_decoder = pytest.importorskip("mcap_ros2.decoder", reason="needs mcap-ros2-support: pip install -e '.[test]'")


def recorded_poses(recording: Path) -> dict[str, list[tuple[int, float, float]]]:
    """Per pose topic, (log time, x, y) of every observation the world sent that UAV, in file order."""
    out: dict[str, list[tuple[int, float, float]]] = defaultdict(list)
    for key, payload, log_ns, _ in iter_messages(recording):
        body = msgpack.unpackb(payload)
        if body.get("kind") == "obs" and all(map(math.isfinite, body["pos"])):
            out[f"/truav/uav_{body['uav']}/pose"].append((log_ns, float(body["pos"][0]), float(body["pos"][1])))
    return dict(out)


def poses_by_rosbags(bag: Path) -> tuple[dict[str, list[tuple[int, float, float, float]]], dict[str, str]]:
    """(per pose topic: (header stamp ns, x, y, z)), (topic -> type) of every connection, read by rosbags."""
    from rosbags.typesys import Stores, get_typestore

    poses: dict[str, list[tuple[int, float, float, float]]] = defaultdict(list)
    with rosbags_highlevel.AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        pose_conns = [c for c in reader.connections if c.topic.endswith("/pose")]
        for conn, _, raw in reader.messages(connections=pose_conns):
            m = reader.deserialize(raw, conn.msgtype)
            assert m.header.frame_id == "map"
            stamp = m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec
            p = m.pose.position
            poses[conn.topic].append((stamp, p.x, p.y, p.z))
    return dict(poses), types


def decoded_by_mcap_ros2(bag: Path) -> dict[str, list]:
    """Every message of the bag's MCAP file decoded by mcap-ros2-support's decoder, per topic."""
    from mcap.reader import make_reader

    out: dict[str, list] = defaultdict(list)
    (mcap_file,) = bag.glob("*.mcap")
    with open(mcap_file, "rb") as f:
        reader = make_reader(f, decoder_factories=[mcap_ros2_decoder.DecoderFactory()])
        for schema, channel, _, decoded in reader.iter_decoded_messages():
            assert schema.encoding == "ros2msg" and channel.message_encoding == "cdr"
            out[channel.topic].append(decoded)
    return dict(out)
