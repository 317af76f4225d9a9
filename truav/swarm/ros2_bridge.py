"""`truav-swarm ros2`: a live run as ROS 2 topics over rmw_zenoh, for ``ros2 topic list/echo`` and RViz.

A thin wrapper: :func:`truav.swarm.view.follow` (the live views' one subscription to ``truav/<run>/**``)
feeds :class:`recorder.ros2_messages.Ros2Mapper` (the same mapping ``truav log ros2bag`` writes into a bag:
``/truav/uav_<i>/pose`` PoseStamped, ``/truav/uav_<i>/velocity`` TwistStamped, ``/truav/markers``
MarkerArray, ``/truav/metrics`` DiagnosticArray);
rosbags' typestore serializes each message to CDR, and the Bus's own Zenoh session (a client of the run's
router) puts it on rmw_zenoh's key expression with rmw_zenoh's attachment, after declaring the graph's
liveliness tokens: one node (``/truav/bridge_<run>``) and one publisher per topic
(:mod:`truav.wire.rmw_zenoh` formats all three). A ROS 2 machine sees it through an rmw_zenoh router linked
to the run's router (docs/how-to/ros2.md).

Steering: given the ``operator`` identity's config, the bridge also subscribes to ``/truav/uav_<i>/goal``
(geometry_msgs/msg/PoseStamped, frame ``map``, x east and y north in metres, as the poses), declaring each
subscription's graph token (``MS``); a goal inside the area becomes an override of that UAV
(:func:`truav.swarm.steering.send_override`, as `truav-swarm steer` and the MAVLink bridge send it), a goal
in another frame, outside the area or not a PoseStamped is counted and logged, never sent.
"""

from __future__ import annotations

import logging
import re
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Optional

from recorder.ros2_messages import (FRAME, MARKERS_TOPIC, MARKERS_TYPE, METRICS_TOPIC, METRICS_TYPE, POSE_TYPE,
                                    VELOCITY_TYPE, pose_topic, velocity_topic)
from truav.swarm.steering import inside_area, send_override
from truav.swarm.view import FedStats, feed_sample, follow
from truav.wire import keys, rmw_zenoh

log = logging.getLogger("truav.ros2")

SRC_ROS2 = "ros2"
NAMESPACE = "/truav"
GOAL_TYPE = POSE_TYPE
MAX_GOAL_BYTES = 4096  # a PoseStamped is ~100 bytes; more is not a goal (untrusted: bounded before decoding)
GOALS_QUEUED = 256  # goals waiting for the bridge's loop; beyond, the oldest are dropped
GOALS_PER_PASS = 64


def goal_topic(uav: int) -> str:
    return f"/truav/uav_{uav}/goal"


def node_name(run: str) -> str:
    """The bridge's ROS 2 node name for ``run`` (a ROS name: letters, digits and _)."""
    return "bridge_" + re.sub(r"[^A-Za-z0-9_]", "_", run)


@dataclass
class BridgeStats(FedStats):
    published: dict[str, int] = field(default_factory=dict)  # ROS 2 topic -> messages put
    steered: int = 0  # goals sent on as overrides
    refused: int = 0  # goals not sent: another frame, outside the area, not a PoseStamped


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
            (velocity_topic(i), VELOCITY_TYPE) for i in range(n_uavs)] + [
            (MARKERS_TOPIC, MARKERS_TYPE), (METRICS_TOPIC, METRICS_TYPE)]
        self.stats = BridgeStats()
        self._session: Any = None
        self._session_id = ""
        self._node_token: Any = None
        self._entities = 0
        self._publishers: dict[str, _Publisher] = {}
        self.n_uavs = n_uavs
        self.steer: Optional[Callable[[int, tuple[float, float]], None]] = None
        """Sends an override of a UAV to a goal (run_bridge sets it); None: no goal topics."""
        self._goals: Any = None
        self._goal_tokens: list[Any] = []

    def open(self, session: Any) -> None:
        """Declare the node and every topic known from the start (each UAV's pose, the markers, the metrics),
        and with steering each UAV's goal subscription."""
        self._session = session
        self._session_id = str(session.info.zid())
        self._node_token = session.liveliness().declare_token(
            rmw_zenoh.node_token(self.domain_id, self._session_id, 0, NAMESPACE, self.node))
        for topic, ros_type in self.topics:
            self._publisher(topic, ros_type)
        if self.steer is not None:
            self._subscribe_goals()

    def _subscribe_goals(self) -> None:
        import zenoh
        type_hash = self.typestore.hash_rihs01(GOAL_TYPE)
        for i in range(self.n_uavs):
            self._entities += 1
            self._goal_tokens.append(self._session.liveliness().declare_token(rmw_zenoh.subscription_token(
                self.domain_id, self._session_id, 0, self._entities, NAMESPACE, self.node, goal_topic(i),
                GOAL_TYPE, type_hash)))
        every = rmw_zenoh.topic_keyexpr(self.domain_id, goal_topic(0), GOAL_TYPE, type_hash).replace("/uav_0/", "/*/")
        self._goals = self._session.declare_subscriber(every, zenoh.handlers.RingChannel(GOALS_QUEUED))

    def every_pass(self) -> None:
        """The goals heard since the last pass, each sent on as an override or refused (bounded per pass)."""
        if self._goals is None:
            return
        for _ in range(GOALS_PER_PASS):
            sample = self._goals.try_recv()
            if sample is None:
                return
            self._goal(str(sample.key_expr), sample.payload.to_bytes())

    def _goal(self, key: str, data: bytes) -> None:
        parts = key.split("/")  # <domain>/truav/uav_<i>/goal/<type>/<hash>
        uav = int(parts[2][4:]) if len(parts) > 2 and parts[2].startswith("uav_") and parts[2][4:].isdigit() else -1
        why = ""
        if not 0 <= uav < self.n_uavs:
            why = f"{key}: no UAV of this run"
        elif len(data) > MAX_GOAL_BYTES:
            why = f"{goal_topic(uav)}: {len(data)} bytes, not a PoseStamped"
        else:
            try:
                msg = self.typestore.deserialize_cdr(data, GOAL_TYPE)
                frame, xy = msg.header.frame_id, (float(msg.pose.position.x), float(msg.pose.position.y))
            except Exception:  # untrusted bytes: anything rosbags cannot read is not a goal
                frame, xy, why = "", (0.0, 0.0), f"{goal_topic(uav)}: not a CDR PoseStamped"
            if not why and frame != FRAME:
                why = f"{goal_topic(uav)}: frame {frame[:40]!r}, goals are in frame {FRAME!r}"
            elif not why and not inside_area(xy, self.mapper.geometry.area_m):
                why = f"{goal_topic(uav)}: ({xy[0]:g}, {xy[1]:g}) m is outside the area [0, " \
                      f"{self.mapper.geometry.area_m:g}] m"
        if why:
            self.stats.refused += 1
            log.warning("goal refused: %s", why)
            return
        self.steer(uav, xy)
        self.stats.steered += 1
        log.info("goal on %s: UAV %d steered to (%.0f, %.0f) m", goal_topic(uav), uav, *xy)

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
        out = feed_sample(self.stats, payload, lambda kind, body: self.mapper.feed(kind, key, body, recv_ns),
                          self.on_shutdown)
        for m in out or ():
            pub = self._publisher(m.topic, m.msgtype)
            data = self.typestore.serialize_cdr(m.message, m.msgtype)
            pub.seq += 1
            pub.zenoh.put(bytes(data), attachment=rmw_zenoh.attachment(pub.seq, time.time_ns(), pub.gid))
            self.stats.published[m.topic] = self.stats.published.get(m.topic, 0) + 1


def run_bridge(run: str, zenoh_config: Any, bridge: Ros2Bridge, stop: Optional[threading.Event] = None,
               ready: Optional[Callable[[], None]] = None, steer_config: Any = None) -> BridgeStats:
    """Publish ``run`` as ROS 2 topics until ``stop`` is set (the tokens go with the session). ``steer_config``:
    the zenoh config of the ``operator`` identity (under --secure its credentials) that sends goals on as
    overrides; None: no goal topics."""
    from truav.bus.transport import Bus
    stop = stop or threading.Event()

    def serve() -> None:
        follow(run, zenoh_config, SRC_ROS2, stop, bridge.handle, every_pass=bridge.every_pass, ready=ready,
               opened=lambda bus: bridge.open(bus.session))

    if steer_config is None:
        serve()
        return bridge.stats
    with Bus(keys.SRC_OPERATOR, run, steer_config) as operator:
        bridge.steer = lambda uav, xy: send_override(operator, run, uav, xy)
        serve()
    return bridge.stats
