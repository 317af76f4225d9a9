"""rmw_zenoh's wire conventions, as strings and bytes: pure, no Zenoh, no I/O.

ROS 2's Zenoh middleware (rmw_zenoh_cpp) names, stamps and announces what it publishes as its design
document (``docs/design.md`` of ros2/rmw_zenoh) specifies; :mod:`truav.swarm.ros2_bridge` publishes the
swarm the same way, so a ROS 2 machine using rmw_zenoh lists and echoes it:

* a topic's data key expression: ``<domain_id>/<fully_qualified_name>/<type_name>/<type_hash>``, the name
  without its leading slash, the type as DDS spells it (``geometry_msgs::msg::dds_::PoseStamped_``), the
  type hash REP-2016's ``RIHS01_<sha256>`` (computed by the caller: rosbags' ``typestore.hash_rihs01``);
* the graph's liveliness tokens, a node's
  ``@ros2_lv/<domain_id>/<session_id>/<node_id>/<node_id>/NN/<enclave>/<namespace>/<node_name>`` and a
  publisher's ``@ros2_lv/<domain_id>/<session_id>/<node_id>/<entity_id>/MP/<enclave>/<namespace>/<node_name>/
  <qualified_name>/<type_name>/<type_hash>/<qos>`` (a subscription's the same under ``MS``), names mangled (each ``/`` as ``%``; ``%`` when empty);
* every sample's attachment: the sequence number (int64 little-endian), the source timestamp (int64 ns since
  the UNIX epoch, little-endian), one byte the GID's length (16) and the publisher's 16-byte GID.
"""

from __future__ import annotations

import hashlib
import re
import struct
from typing import NamedTuple

ADMIN_SPACE = "@ros2_lv"
NODE = "NN"
PUBLISHER = "MP"
SUBSCRIPTION = "MS"
GID_LEN = 16
MAX_DOMAIN_ID = 232  # ROS 2's range for ROS_DOMAIN_ID (0-232 on every RMW)
DEFAULT_PUBLISHER_QOS = "::,10:,:,:,,"
"""A publisher's (and the bridge's subscriptions') QoS in rmw_zenoh's compact form (``qos_to_keyexpr``): reliability, durability, history and
liveliness at the defaults (empty: reliable, volatile, keep last, automatic), depth 10, no deadline, no lifespan."""

_ATTACHMENT = struct.Struct("<qqB")
_NAME_PART = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


class Attachment(NamedTuple):
    sequence_number: int
    timestamp_ns: int
    gid: bytes


def check_name(name: str, what: str = "name") -> str:
    """A ROS 2 fully qualified name (``/a/b_1``): ValueError otherwise."""
    parts = name.split("/")
    if not name.startswith("/") or not all(_NAME_PART.fullmatch(p) for p in parts[1:]):
        raise ValueError(f"{what} {name!r} is not a fully qualified ROS 2 name (/word/word..., each word "
                         f"letters, digits and _, not starting with a digit)")
    return name


def dds_type_name(ros_type: str) -> str:
    """``geometry_msgs/msg/PoseStamped`` -> ``geometry_msgs::msg::dds_::PoseStamped_``."""
    package, kind, name = ros_type.split("/")
    return f"{package}::{kind}::dds_::{name}_"


def mangle(name: str) -> str:
    """Each ``/`` as ``%``; ``%`` alone for an empty (or root) name."""
    return name.replace("/", "%") if name not in ("", "/") else "%"


def topic_keyexpr(domain_id: int, topic: str, ros_type: str, type_hash: str) -> str:
    return f"{domain_id}/{check_name(topic, 'topic').strip('/')}/{dds_type_name(ros_type)}/{type_hash}"


def node_token(domain_id: int, session_id: str, node_id: int, namespace: str, node_name: str,
               enclave: str = "") -> str:
    return "/".join((ADMIN_SPACE, str(domain_id), session_id, str(node_id), str(node_id), NODE, mangle(enclave),
                     mangle(namespace), node_name))


def publisher_token(domain_id: int, session_id: str, node_id: int, entity_id: int, namespace: str,
                    node_name: str, topic: str, ros_type: str, type_hash: str, qos: str = DEFAULT_PUBLISHER_QOS,
                    enclave: str = "", kind: str = PUBLISHER) -> str:
    """A publisher's token (``kind`` MP), or a subscription's (MS: :func:`subscription_token`)."""
    return "/".join((ADMIN_SPACE, str(domain_id), session_id, str(node_id), str(entity_id), kind,
                     mangle(enclave), mangle(namespace), node_name, mangle(check_name(topic, "topic")),
                     dds_type_name(ros_type), type_hash, qos))


def subscription_token(domain_id: int, session_id: str, node_id: int, entity_id: int, namespace: str,
                       node_name: str, topic: str, ros_type: str, type_hash: str, qos: str = DEFAULT_PUBLISHER_QOS,
                       enclave: str = "") -> str:
    """A subscription's token: a publisher's fields under MS (so ``ros2 topic info`` counts it)."""
    return publisher_token(domain_id, session_id, node_id, entity_id, namespace, node_name, topic, ros_type,
                           type_hash, qos, enclave, kind=SUBSCRIPTION)


def gid(session_id: str, entity_id: int) -> bytes:
    """A publisher's 16-byte GID, unique per (session, entity) as rmw_zenoh's is (a hash of both)."""
    return hashlib.blake2b(f"{session_id}/{entity_id}".encode(), digest_size=GID_LEN).digest()


def attachment(sequence_number: int, timestamp_ns: int, publisher_gid: bytes) -> bytes:
    if len(publisher_gid) != GID_LEN:
        raise ValueError(f"a GID is {GID_LEN} bytes, got {len(publisher_gid)}")
    return _ATTACHMENT.pack(sequence_number, timestamp_ns, GID_LEN) + publisher_gid


def parse_attachment(data: bytes) -> Attachment:
    """The attachment's three fields; ValueError when it is not one (wrong length, GID length not 16)."""
    if len(data) != _ATTACHMENT.size + GID_LEN:
        raise ValueError(f"an rmw_zenoh attachment is {_ATTACHMENT.size + GID_LEN} bytes, got {len(data)}")
    seq, ts, n = _ATTACHMENT.unpack_from(data)
    if n != GID_LEN:
        raise ValueError(f"GID length byte {n}, expected {GID_LEN}")
    return Attachment(seq, ts, bytes(data[_ATTACHMENT.size:]))
