"""rmw_zenoh's key expressions, liveliness tokens and attachments (truav/wire/rmw_zenoh.py) against the
examples of rmw_zenoh's docs/design.md, and against zenoh-ros2-sdk's own formatting where it is installed."""

from __future__ import annotations

import struct

import pytest

from truav.wire import rmw_zenoh

STRING_HASH = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"  # design.md's examples


def test_keys_and_tokens_are_design_md_examples() -> None:
    assert rmw_zenoh.topic_keyexpr(0, "/chatter", "std_msgs/msg/String", STRING_HASH) == \
        f"0/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}"
    assert rmw_zenoh.topic_keyexpr(0, "/robot1/chatter", "std_msgs/msg/String", STRING_HASH) == \
        f"0/robot1/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}"
    assert rmw_zenoh.node_token(2, "aac3178e146ba6f1fc6e6a4085e77f21", 0, "", "listener") == \
        "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/0/NN/%/%/listener"
    assert rmw_zenoh.publisher_token(2, "8b20917502ee955ac4476e0266340d5c", 0, 10, "/", "talker", "/chatter",
                                     "std_msgs/msg/String", STRING_HASH, qos="::,7:,:,:,,") == \
        f"@ros2_lv/2/8b20917502ee955ac4476e0266340d5c/0/10/MP/%/%/talker/%chatter/std_msgs::msg::dds_::String_/" \
        f"{STRING_HASH}/::,7:,:,:,,"
    assert rmw_zenoh.mangle("/truav") == "%truav"


def test_a_bad_topic_name_is_refused() -> None:
    for bad in ("chatter", "/a//b", "/1a", "/a b", "/a/"):
        with pytest.raises(ValueError, match="fully qualified"):
            rmw_zenoh.topic_keyexpr(0, bad, "std_msgs/msg/String", STRING_HASH)


def test_attachment_layout_is_seq_time_gid_length_gid() -> None:
    gid = rmw_zenoh.gid("aac3178e146ba6f1fc6e6a4085e77f21", 3)
    data = rmw_zenoh.attachment(7, 1_700_000_000_123_456_789, gid)
    assert len(data) == 33 and struct.unpack_from("<qqB", data) == (7, 1_700_000_000_123_456_789, 16)
    assert data[17:] == gid and gid != rmw_zenoh.gid("aac3178e146ba6f1fc6e6a4085e77f21", 4)
    assert rmw_zenoh.parse_attachment(data) == (7, 1_700_000_000_123_456_789, gid)
    with pytest.raises(ValueError):
        rmw_zenoh.parse_attachment(data[:-1])


def test_rosbags_type_hash_is_design_md_string_hash() -> None:
    typesys = pytest.importorskip("rosbags.typesys", reason="rosbags is the optional extra 'ros2'")
    assert typesys.get_typestore(typesys.Stores.ROS2_JAZZY).hash_rihs01("std_msgs/msg/String") == STRING_HASH


def test_zenoh_ros2_sdk_reads_our_attachment_and_spells_our_keys() -> None:
    pytest.importorskip("zenoh_ros2_sdk", reason="zenoh-ros2-sdk (an independent rmw_zenoh client) is in the "
                                                 "'test' extra")
    from zenoh_ros2_sdk.attachment import Attachment
    from zenoh_ros2_sdk.keyexpr import topic_keyexpr
    from zenoh_ros2_sdk.utils import ros2_to_dds_type
    gid = rmw_zenoh.gid("s", 1)
    got = Attachment.from_bytes(rmw_zenoh.attachment(42, 99, gid))
    assert (got.sequence_id, got.timestamp_ns, got.gid) == (42, 99, gid)
    t = "geometry_msgs/msg/PoseStamped"
    assert rmw_zenoh.topic_keyexpr(5, "/truav/uav_0/pose", t, "RIHS01_x") == \
        topic_keyexpr(5, "/truav/uav_0/pose", ros2_to_dds_type(t), "RIHS01_x")


def test_a_subscription_token_is_a_publishers_under_ms() -> None:
    assert rmw_zenoh.subscription_token(0, "aac3178e146ba6f1fc6e6a4085e77f21", 0, 11, "/truav", "bridge_r",
                                        "/truav/uav_1/goal", "geometry_msgs/msg/PoseStamped", "RIHS01_x") == \
        "@ros2_lv/0/aac3178e146ba6f1fc6e6a4085e77f21/0/11/MS/%/%truav/bridge_r/%truav%uav_1%goal/" \
        "geometry_msgs::msg::dds_::PoseStamped_/RIHS01_x/::,10:,:,:,,"
