"""`truav-swarm ros2`: a live run as ROS 2 topics over rmw_zenoh, for ``ros2 topic list/echo`` and RViz.

A thin wrapper: :func:`truav.swarm.view.follow` (the live views' one subscription to ``truav/<run>/**``)
feeds :class:`recorder.ros2_messages.Ros2Mapper` (the same mapping ``truav log ros2bag`` writes into a bag:
``/truav/uav_<i>/pose`` PoseStamped, ``/truav/markers`` MarkerArray, ``/truav/metrics`` DiagnosticArray);
rosbags' typestore serializes each message to CDR, and the Bus's own Zenoh session (a client of the run's
router) puts it on rmw_zenoh's key expression with rmw_zenoh's attachment, after declaring the graph's
liveliness tokens: one node (``/truav/bridge_<run>``) and one publisher per topic
(:mod:`truav.wire.rmw_zenoh` formats all three). A ROS 2 machine sees it through an rmw_zenoh router linked
to the run's router (docs/how-to/ros2.md).
"""

from __future__ import annotations

import logging
import re
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Optional

from recorder.ros2_messages import MARKERS_TOPIC, MARKERS_TYPE, METRICS_TOPIC, METRICS_TYPE, POSE_TYPE, pose_topic
from recorder.schemas import envelope_fields
from truav.swarm.view import follow
from truav.wire import rmw_zenoh

log = logging.getLogger("truav.ros2")

SRC_ROS2 = "ros2"
NAMESPACE = "/truav"


def node_name(run: str) -> str:
    """The bridge's ROS 2 node name for ``run`` (a ROS name: letters, digits and _)."""
    return "bridge_" + re.sub(r"[^A-Za-z0-9_]", "_", run)


@dataclass
class BridgeStats:
    samples: int = 0
    odd: int = 0  # bus bodies that did not fit their kind
    published: dict[str, int] = field(default_factory=dict)  # ROS 2 topic -> messages put


class _Publisher:
    def __init__(self, session: Any, key: str, token: Any, gid: bytes) -> None:
        self.zenoh = session.declare_publisher(key)
        self.token = token
        self.gid = gid
        self.seq = 0


class Ros2Bridge:
    """ROS 2 messages of the run's bus messages, put with rmw_zenoh's keys, attachments and graph tokens."""

    def __init__(self, mapper: Any, typestore: Any, run: str, n_uavs: int, domain_id: int = 0,
                 on_shutdown: Optional[Callable[[], None]] = None) -> None:
        self.mapper = mapper
        self.typestore = typestore
        self.domain_id = domain_id
        self.node = node_name(run)
        self.on_shutdown = on_shutdown
        self.topics = [(pose_topic(i), POSE_TYPE) for i in range(n_uavs)] + [
            (MARKERS_TOPIC, MARKERS_TYPE), (METRICS_TOPIC, METRICS_TYPE)]
        self.stats = BridgeStats()
        self._session: Any = None
        self._session_id = ""
        self._node_token: Any = None
        self._entities = 0
        self._publishers: dict[str, _Publisher] = {}

    def open(self, session: Any) -> None:
        """Declare the node and every topic known from the start (each UAV's pose, the markers, the metrics)."""
        self._session = session
        self._session_id = str(session.info.zid())
        self._node_token = session.liveliness().declare_token(
            rmw_zenoh.node_token(self.domain_id, self._session_id, 0, NAMESPACE, self.node))
        for topic, ros_type in self.topics:
            self._publisher(topic, ros_type)

    def _publisher(self, topic: str, ros_type: str) -> _Publisher:
        pub = self._publishers.get(topic)
        if pub is None:
            self._entities += 1
            type_hash = self.typestore.hash_rihs01(ros_type)
            token = self._session.liveliness().declare_token(rmw_zenoh.publisher_token(
                self.domain_id, self._session_id, 0, self._entities, NAMESPACE, self.node, topic, ros_type, type_hash))
            pub = self._publishers[topic] = _Publisher(
                self._session, rmw_zenoh.topic_keyexpr(self.domain_id, topic, ros_type, type_hash), token,
                rmw_zenoh.gid(self._session_id, self._entities))
        return pub

    def handle(self, key: str, payload: bytes, recv_ns: int) -> None:
        self.stats.samples += 1
        env = envelope_fields(payload)
        if env is None:
            return
        if env[0] == "control" and env[4].get("command") == "shutdown" and self.on_shutdown is not None:
            self.on_shutdown()
        try:
            out = self.mapper.feed(env[0], key, env[4], recv_ns)
        except Exception:  # an odd body: count it, keep serving
            self.stats.odd += 1
            return
        for m in out:
            pub = self._publisher(m.topic, m.msgtype)
            data = self.typestore.serialize_cdr(m.message, m.msgtype)
            pub.seq += 1
            pub.zenoh.put(bytes(data), attachment=rmw_zenoh.attachment(pub.seq, time.time_ns(), pub.gid))
            self.stats.published[m.topic] = self.stats.published.get(m.topic, 0) + 1


def run_bridge(run: str, zenoh_config: Any, bridge: Ros2Bridge, stop: Optional[threading.Event] = None,
               ready: Optional[Callable[[], None]] = None) -> BridgeStats:
    """Publish ``run`` as ROS 2 topics until ``stop`` is set (the tokens go with the session)."""
    follow(run, zenoh_config, SRC_ROS2, stop or threading.Event(), bridge.handle, ready=ready, opened=lambda bus:
           bridge.open(bus.session))
    return bridge.stats
