"""TRUAV recording records as ROS 2 messages: pure mapping, no I/O (:mod:`recorder.ros2_export` writes the bag).

The messages are rosbags' typestore classes (ROS 2 Jazzy's definitions), serialized to CDR by the
typestore, so neither the wire format nor the message definitions are written by hand here. Topics:

* ``/truav/uav_<i>/pose`` (``geometry_msgs/msg/PoseStamped``) for every observation the world sent UAV
  ``i`` (every tick): frame ``map``, x east and y north in metres as in the recording, z the scenario's
  UAV altitude (``scenario.uav_altitude_m``), identity orientation;
* ``/truav/uav_<i>/velocity`` (``geometry_msgs/msg/TwistStamped``) with each pose after the first of an
  episode: frame ``map``, the linear x (east) and y (north) in m/s from this position and the UAV's previous
  one in the same episode (their difference over the ticks between them x ``scenario.step_s``), z and the
  angular velocity 0. Never across an episode's reset (the UAVs jump back to their starts), nor across a
  position that was not finite;
* ``/truav/markers`` (``visualization_msgs/msg/MarkerArray``) for every positions message of the world
  (every few ticks): a DELETEALL, then the UAVs (spheres with a label), the vehicles and the RSUs (cube lists);
* ``/truav/metrics`` (``diagnostic_msgs/msg/DiagnosticArray``) for every metrics message of the world (one
  status ``truav/step`` or ``truav/episode``, its values as key/values: coverage_pct, pdr, delay_ms,
  energy_j...) and for every observation (one status ``truav/uav_<i>``: the energy the UAV spent in that
  step, energy_j, and what it covered). The scenario has no battery capacity, so a
  ``sensor_msgs/msg/BatteryState`` (charge, percentage, voltage) would be invented: it is not written.

Header stamps are the recording's log time (when the recorder received the message, ns since the epoch):
the world's sim time restarts every episode, so it cannot order a bag. The message is refused (None)
when it does not fit its kind, as the report refuses it (recorder.report_data: a UAV id disagreeing with
its key or past the schema's MAX_UAVS, a non-finite position).
"""

from __future__ import annotations

from typing import Any, NamedTuple, Optional

import numpy as np

from recorder.foxglove import Geometry, finite_xy, uav_rgb
from recorder.report_data import _numbers, _uav
from truav.wire.keys import MAX_UAVS
from truav.wire.schema_names import MAX_VEHICLE_POSITIONS

FRAME = "map"
MARKERS_TOPIC = "/truav/markers"
METRICS_TOPIC = "/truav/metrics"
POSE_TYPE = "geometry_msgs/msg/PoseStamped"
VELOCITY_TYPE = "geometry_msgs/msg/TwistStamped"
MARKERS_TYPE = "visualization_msgs/msg/MarkerArray"
METRICS_TYPE = "diagnostic_msgs/msg/DiagnosticArray"
OBS_VALUES = ("energy_j", "covered", "vehicles_in_range", "relayed", "queued_packets")
"""What an observation adds to /truav/metrics for its UAV (numbers only; the rest of it is the pose)."""


_EMPTY_BYTES = np.zeros(0, dtype=np.uint8)  # a uint8[] field (rosbags holds them as numpy arrays)


def pose_topic(uav: int) -> str:
    return f"/truav/uav_{uav}/pose"


def velocity_topic(uav: int) -> str:
    return f"/truav/uav_{uav}/velocity"


class Ros2Message(NamedTuple):
    topic: str
    msgtype: str
    message: Any  # a rosbags typestore message


class Ros2Mapper:
    """Decoded bus messages in, ROS 2 messages out (rosbags ``typestore`` classes)."""

    def __init__(self, typestore: Any, geometry: Geometry = Geometry()) -> None:
        self.geometry = geometry
        self._t = typestore.types
        self._last: dict[int, tuple[int, int, float, float]] = {}  # uav -> (episode, tick, x, y) of its last pose

    def feed(self, kind: Any, key: str, body: dict, log_ns: int) -> list[Ros2Message]:
        """The ROS 2 messages of one decoded bus message ([] for kinds not exported or a body that does not fit)."""
        if kind == "obs":
            return self._obs(key, body, log_ns)
        if kind == "positions":
            return self._positions(body, log_ns)
        if kind == "metrics" and isinstance(body.get("values"), dict):
            status = self._status(f"truav/{body.get('scope')!s:.40}", _numbers(body["values"]),
                                  f"tick {body.get('tick')!s:.20} episode {body.get('episode')!s:.20}")
            return [Ros2Message(METRICS_TOPIC, METRICS_TYPE, self._diagnostics(log_ns, [status]))]
        return []

    # --- the messages ------------------------------------------------------------------------
    def _header(self, log_ns: int) -> Any:
        t = self._t
        return t["std_msgs/msg/Header"](stamp=t["builtin_interfaces/msg/Time"](
            sec=log_ns // 1_000_000_000, nanosec=log_ns % 1_000_000_000), frame_id=FRAME)

    def _pose(self, x: float, y: float, z: float) -> Any:
        t = self._t
        return t["geometry_msgs/msg/Pose"](position=t["geometry_msgs/msg/Point"](x=x, y=y, z=z),
                                           orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0))

    def _obs(self, key: str, body: dict, log_ns: int) -> list[Ros2Message]:
        uav, xy = _uav(body, key), finite_xy(body.get("pos"))
        if uav is not None and xy is None:
            self._last.pop(uav, None)  # no velocity across a position that is not one
        if uav is None or xy is None:
            return []
        pose = self._t[POSE_TYPE](header=self._header(log_ns), pose=self._pose(xy[0], xy[1], self.geometry.uav_altitude_m))
        values = _numbers({k: body[k] for k in OBS_VALUES if k in body})
        status = self._status(f"truav/uav_{uav}", values, f"tick {body.get('tick')!s:.20}")
        out = [Ros2Message(pose_topic(uav), POSE_TYPE, pose)]
        velocity = self._velocity(uav, body.get("episode"), body.get("tick"), xy)
        if velocity is not None:
            t = self._t
            vector = t["geometry_msgs/msg/Vector3"]
            twist = t["geometry_msgs/msg/Twist"](linear=vector(x=velocity[0], y=velocity[1], z=0.0),
                                                 angular=vector(x=0.0, y=0.0, z=0.0))
            out.append(Ros2Message(velocity_topic(uav), VELOCITY_TYPE,
                                   t[VELOCITY_TYPE](header=self._header(log_ns), twist=twist)))
        return out + [Ros2Message(METRICS_TOPIC, METRICS_TYPE, self._diagnostics(log_ns, [status]))]

    def _velocity(self, uav: int, episode: Any, tick: Any, xy: tuple[float, float]) -> Optional[tuple[float, float]]:
        """(vx, vy) m/s from the UAV's previous position in this episode to ``xy``; None for the first of an
        episode, or a tick not after the last one seen (a repeat: the last one is kept)."""
        if not all(isinstance(v, int) and not isinstance(v, bool) for v in (episode, tick)):
            self._last.pop(uav, None)
            return None
        last = self._last.get(uav)
        if last is not None and (episode, tick) <= last[:2]:
            return None
        self._last[uav] = (episode, tick, xy[0], xy[1])
        if last is None or last[0] != episode:
            return None
        dt = (tick - last[1]) * self.geometry.step_s
        return (xy[0] - last[2]) / dt, (xy[1] - last[3]) / dt

    def _status(self, name: str, values: dict[str, float], message: str) -> Any:
        t = self._t
        cls = t["diagnostic_msgs/msg/DiagnosticStatus"]
        return cls(level=cls.OK, name=name, message=message, hardware_id="truav",
                   values=[t["diagnostic_msgs/msg/KeyValue"](key=k, value=repr(v)) for k, v in values.items()])

    def _diagnostics(self, log_ns: int, statuses: list) -> Any:
        return self._t[METRICS_TYPE](header=self._header(log_ns), status=statuses)

    def _marker(self, log_ns: int, ns: str, id_: int, type_: int, action: int, pose: Any = None,
                scale: tuple[float, float, float] = (1.0, 1.0, 1.0), rgba: tuple[float, ...] = (0.0, 0.0, 0.0, 1.0),
                points: Optional[list] = None, text: str = "") -> Any:
        t = self._t
        return t["visualization_msgs/msg/Marker"](
            header=self._header(log_ns), ns=ns, id=id_, type=type_, action=action,
            pose=pose if pose is not None else self._pose(0.0, 0.0, 0.0),
            scale=t["geometry_msgs/msg/Vector3"](x=scale[0], y=scale[1], z=scale[2]),
            color=t["std_msgs/msg/ColorRGBA"](r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3]),
            lifetime=t["builtin_interfaces/msg/Duration"](sec=0, nanosec=0), frame_locked=False,
            points=points or [], colors=[], texture_resource="",
            texture=t["sensor_msgs/msg/CompressedImage"](header=self._header(log_ns), format="", data=_EMPTY_BYTES),
            uv_coordinates=[], text=text, mesh_resource="", mesh_file=t["visualization_msgs/msg/MeshFile"](
                filename="", data=_EMPTY_BYTES), mesh_use_embedded_materials=False)

    def _positions(self, body: dict, log_ns: int) -> list[Ros2Message]:
        uavs, vehicles = body.get("uavs"), body.get("vehicles")
        if not isinstance(uavs, list) or not isinstance(vehicles, list):
            return []
        g, m = self.geometry, self._t["visualization_msgs/msg/Marker"]
        point = self._t["geometry_msgs/msg/Point"]
        markers = [self._marker(log_ns, "", 0, m.CUBE, m.DELETEALL)]  # UAVs gone since (NaN) do not linger
        for i, p in enumerate(uavs[:MAX_UAVS]):
            xy = finite_xy(p)
            if xy is None:
                continue
            rgba = (*uav_rgb(i), 1.0)
            markers.append(self._marker(log_ns, "uavs", i, m.SPHERE, m.ADD, self._pose(xy[0], xy[1], g.uav_altitude_m),
                                        (80.0, 80.0, 80.0), rgba))
            markers.append(self._marker(log_ns, "uav_labels", i, m.TEXT_VIEW_FACING, m.ADD,
                                        self._pose(xy[0], xy[1], g.uav_altitude_m + 80.0), (0.0, 0.0, 60.0), rgba,
                                        text=f"UAV {i}"))
        cars = [point(x=xy[0], y=xy[1], z=5.0) for xy in map(finite_xy, vehicles[:MAX_VEHICLE_POSITIONS])
                if xy is not None]
        markers.append(self._marker(log_ns, "vehicles", 0, m.CUBE_LIST, m.ADD, scale=(40.0, 40.0, 10.0),
                                    rgba=(0.15, 0.15, 0.15, 1.0), points=cars))
        markers.append(self._marker(log_ns, "rsus", 0, m.CUBE_LIST, m.ADD, scale=(60.0, 60.0, 30.0),
                                    rgba=(0.1, 0.1, 0.1, 1.0), points=[point(x=x, y=y, z=15.0) for x, y in g.rsu_xy]))
        return [Ros2Message(MARKERS_TOPIC, MARKERS_TYPE, self._t[MARKERS_TYPE](markers=markers))]


