"""Foxglove mirror of the TRUAV bus: well-known-schema messages the Foxglove app shows.

Pure conversion, no I/O: :class:`FoxgloveMirror` is fed decoded bus messages
(by the recorder, which writes what it returns into the MCAP file, and by
``truav-swarm view``, which serves it over Foxglove's WebSocket protocol) and
returns ``(topic, schema, encoded bytes)`` triples.  The messages are built
with ``foxglove-sdk``'s own schema classes (``foxglove.messages``) and encoded
with them (protobuf), so the schemas are the ones Foxglove publishes:

* ``/foxglove/scene`` (``foxglove.SceneUpdate``) every time the world publishes
  positions (every tick): UAVs with their id and coverage disc, vehicles, and
  a line from each UAV that relayed packets in the tick to its nearest RSU;
* ``/foxglove/scene/static`` (``foxglove.SceneUpdate``): road grid and RSUs,
  at the first tick and then every STATIC_EVERY_TICKS ticks (so a viewer that
  seeks, or connects late, finds it);
* ``/foxglove/tf`` (``foxglove.FrameTransforms``, a list of
  ``foxglove.FrameTransform``): ``area`` -> ``uav/<i>`` for every UAV with the
  scene, so the 3D panel can follow a UAV (one message per tick, not per UAV);
* ``/foxglove/uav/<i>/fix`` (``foxglove.LocationFix``) per observation, placed
  around a geographic origin so the Map panel shows the swarm;
* ``/foxglove/log`` (``foxglove.Log``): joins, sequence gaps, fault windows,
  episode results, shutdown.

Coordinates: the scenario's square area, metres, x east and y north, in frame
``area``; the geographic origin is the area's centre.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from typing import Any, NamedTuple, Optional

from foxglove import messages as fm

DEFAULT_ORIGIN = (48.8566, 2.3522)
"""(latitude, longitude) of the area's centre: Paris, Hôtel de Ville."""
EARTH_RADIUS_M = 6_378_137.0  # WGS-84 equatorial; an equirectangular map is exact enough for 5 km
FRAME = "area"
SCENE_TOPIC = "/foxglove/scene"
STATIC_TOPIC = "/foxglove/scene/static"
TF_TOPIC = "/foxglove/tf"
LOG_TOPIC = "/foxglove/log"
STATIC_EVERY_TICKS = 50
LOG_NAME = "truav"


def fix_topic(uav: int) -> str:
    return f"/foxglove/uav/{uav}/fix"


class FoxSchema(NamedTuple):
    """An MCAP / Foxglove schema: name, encoding and bytes (a protobuf FileDescriptorSet)."""

    name: str
    encoding: str
    data: bytes


def _schema(cls: Any) -> FoxSchema:
    s = cls.get_schema()
    return FoxSchema(s.name, s.encoding, bytes(s.data))


SCENE_SCHEMA = _schema(fm.SceneUpdate)
TF_SCHEMA = _schema(fm.FrameTransforms)
FIX_SCHEMA = _schema(fm.LocationFix)
LOG_SCHEMA = _schema(fm.Log)
MESSAGE_ENCODING = "protobuf"


class Out(NamedTuple):
    topic: str
    schema: FoxSchema
    data: bytes


@dataclass(frozen=True)
class Geometry:
    """What the mirror needs of the scenario (from the run's config TOML)."""

    area_m: float = 5000.0
    block_m: float = 250.0
    comm_range_m: float = 500.0
    uav_altitude_m: float = 100.0
    rsu_xy: tuple[tuple[float, float], ...] = ((1000.0, 1000.0), (4000.0, 1000.0), (1000.0, 4000.0), (4000.0, 4000.0))
    step_s: float = 1.0  # a tick's sim seconds (a velocity from consecutive positions)

    @classmethod
    def from_toml(cls, text: Optional[str]) -> "Geometry":
        """From the run's config TOML (None: the defaults); raises ValueError on a bad config."""
        if text is None:
            return cls()
        from truav.config import config_from_dict  # pure; the validation is the config's own

        try:
            cfg = config_from_dict(tomllib.loads(text))
        except tomllib.TOMLDecodeError as exc:
            raise ValueError(f"config is not TOML: {exc}") from None
        return cls.from_config(cfg)

    @classmethod
    def from_config(cls, cfg: Any) -> "Geometry":
        """From a :class:`truav.config.Config`."""
        sc, block = cfg.scenario, cfg.roads.block_m
        return cls(area_m=sc.area_m, block_m=block, comm_range_m=sc.comm_range_m, uav_altitude_m=sc.uav_altitude_m,
                   rsu_xy=tuple((float(i) * block, float(j) * block) for i, j in sc.rsu_intersections),
                   step_s=sc.step_s)


def parse_origin(text: str) -> tuple[float, float]:
    """``"LAT,LON"`` in degrees -> (lat, lon); ValueError with a one-line reason."""
    parts = text.split(",")
    if len(parts) != 2:
        raise ValueError(f"expected LAT,LON in degrees, got {text!r}")
    try:
        lat, lon = float(parts[0]), float(parts[1])
    except ValueError:
        raise ValueError(f"expected LAT,LON in degrees, got {text!r}") from None
    if not (-85.0 <= lat <= 85.0 and -180.0 <= lon <= 180.0):
        raise ValueError(f"latitude must be in [-85, 85] and longitude in [-180, 180], got {text!r}")
    return lat, lon


def to_latlon(origin: tuple[float, float], area_m: float, x: float, y: float) -> tuple[float, float]:
    """The area's (x east, y north) in metres -> (latitude, longitude) in degrees, the area's centre at
    ``origin`` (equirectangular: exact enough for a few km). Every geographic view uses it (Foxglove's
    map, the MAVLink bridge)."""
    half = area_m / 2.0
    m_per_deg_lat = EARTH_RADIUS_M * math.pi / 180.0
    return (origin[0] + (y - half) / m_per_deg_lat,
            origin[1] + (x - half) / (m_per_deg_lat * math.cos(math.radians(origin[0]))))


def from_latlon(origin: tuple[float, float], area_m: float, lat: float, lon: float) -> tuple[float, float]:
    """The inverse of :func:`to_latlon`: (latitude, longitude) -> the area's (x, y) in metres."""
    half = area_m / 2.0
    m_per_deg_lat = EARTH_RADIUS_M * math.pi / 180.0
    return (half + (lon - origin[1]) * m_per_deg_lat * math.cos(math.radians(origin[0])),
            half + (lat - origin[0]) * m_per_deg_lat)


# --- colours ---------------------------------------------------------------------------
_TAB10 = ((0.12, 0.47, 0.71), (1.0, 0.5, 0.05), (0.17, 0.63, 0.17), (0.84, 0.15, 0.16), (0.58, 0.4, 0.74),
          (0.55, 0.34, 0.29), (0.89, 0.47, 0.76), (0.5, 0.5, 0.5), (0.74, 0.74, 0.13), (0.09, 0.75, 0.81))


def uav_rgb(uav: int) -> tuple[float, float, float]:
    """The colour of a UAV, as in the matplotlib pictures (tab10)."""
    return _TAB10[uav % len(_TAB10)]


def _color(rgb: tuple[float, float, float], a: float = 1.0) -> fm.Color:
    return fm.Color(r=rgb[0], g=rgb[1], b=rgb[2], a=a)


_IDENTITY = fm.Quaternion(w=1.0)
_VEHICLE_COLOR = fm.Color(r=0.15, g=0.15, b=0.15, a=1.0)
_VEHICLE_SIZE = fm.Vector3(x=40.0, y=40.0, z=10.0)
_ROAD_COLOR = fm.Color(r=0.7, g=0.7, b=0.7, a=1.0)
_RSU_COLOR = fm.Color(r=0.1, g=0.1, b=0.1, a=1.0)
_LINK_COLOR = fm.Color(r=0.0, g=0.6, b=0.0, a=0.9)
_LOG_LEVELS = {"debug": fm.LogLevel.Debug, "info": fm.LogLevel.Info, "warning": fm.LogLevel.Warning,
               "error": fm.LogLevel.Error}
VEHICLE_GRID_M = 1.0  # vehicles are drawn on this grid (m), as the world publishes them: compresses well


def _stamp(ns: int) -> fm.Timestamp:
    return fm.Timestamp(sec=ns // 1_000_000_000, nsec=ns % 1_000_000_000)


def _pose(x: float, y: float, z: float) -> fm.Pose:
    return fm.Pose(position=fm.Vector3(x=x, y=y, z=z), orientation=_IDENTITY)


def finite_xy(p: Any) -> Optional[tuple[float, float]]:
    """A message's (x, y) as floats, or None unless it is a pair of finite numbers (the bridges and exports read
    untrusted bodies through it)."""
    try:
        x, y = float(p[0]), float(p[1])
    except (TypeError, ValueError, IndexError, KeyError):
        return None
    return (x, y) if math.isfinite(x) and math.isfinite(y) else None


class FoxgloveMirror:
    """Bus messages in, Foxglove messages out; keeps what it needs between messages
    (last observation per UAV for the links, who has been seen)."""

    KINDS = frozenset(("obs", "positions", "fault", "metrics", "control"))
    """Kinds :meth:`feed` converts (everything else returns nothing, cheaply)."""

    def __init__(self, geometry: Geometry = Geometry(), origin: tuple[float, float] = DEFAULT_ORIGIN) -> None:
        self.geometry = geometry
        self.origin = origin
        self._relayed: dict[int, int] = {}  # uav -> packets relayed in its last observation
        self._last_static_tick: Optional[int] = None

    # --- entry points ---------------------------------------------------------------------
    def feed(self, kind: str, body: dict, log_time_ns: int) -> list[Out]:
        """Foxglove messages for one decoded bus message; [] for kinds not mirrored.
        Raises (KeyError, TypeError, ValueError...) on a body that does not fit its kind."""
        if kind == "obs":
            return self._obs(body, log_time_ns)
        if kind == "positions":
            return self._positions(body, log_time_ns)
        if kind == "fault":
            return self._fault(body, log_time_ns)
        if kind == "metrics":
            return self._episode(body, log_time_ns)
        if kind == "control":
            return [self.log(log_time_ns, "info", f"control: {body.get('command')!s} from {body.get('src')!s}")]
        return []

    def log(self, log_time_ns: int, level: str, message: str, name: str = LOG_NAME) -> Out:
        """A ``foxglove.Log`` line (level: debug, info, warning, error)."""
        msg = fm.Log(timestamp=_stamp(log_time_ns), level=_LOG_LEVELS[level], message=message, name=name)
        return Out(LOG_TOPIC, LOG_SCHEMA, msg.encode())

    def joined(self, src: str, log_time_ns: int) -> Out:
        return self.log(log_time_ns, "info", f"{src} joined (first message)", name=src)

    def lost(self, src: str, kind: str, missing: int, log_time_ns: int) -> Out:
        return self.log(log_time_ns, "warning", f"{missing} {kind} message(s) from {src} lost (sequence gap)",
                        name=src)

    # --- converters ----------------------------------------------------------------------------
    def latlon(self, x: float, y: float) -> tuple[float, float]:
        return to_latlon(self.origin, self.geometry.area_m, x, y)

    def _obs(self, b: dict, t: int) -> list[Out]:
        uav = int(b["uav"])
        self._relayed[uav] = int(b.get("relayed", 0))
        xy = finite_xy(b["pos"])
        if xy is None:
            return []
        alt = self.geometry.uav_altitude_m
        lat, lon = self.latlon(*xy)
        frame = f"uav/{uav}"
        fix = fm.LocationFix(timestamp=_stamp(t), frame_id=frame, latitude=lat, longitude=lon, altitude=alt,
                             color=_color(uav_rgb(uav)))
        return [Out(fix_topic(uav), FIX_SCHEMA, fix.encode())]

    def _positions(self, b: dict, t: int) -> list[Out]:
        tick = int(b["tick"])
        out = []
        if self._last_static_tick is None or tick < self._last_static_tick \
                or tick - self._last_static_tick >= STATIC_EVERY_TICKS:
            self._last_static_tick = tick
            out.append(Out(STATIC_TOPIC, SCENE_SCHEMA, self.static_scene(t).encode()))
        g = self.geometry
        stamp = _stamp(t)
        entities = []
        uavs = [finite_xy(p) for p in b["uavs"]]
        for i, xy in enumerate(uavs):
            if xy is None:
                continue
            rgb = uav_rgb(i)
            texts = [fm.TextPrimitive(pose=_pose(xy[0], xy[1], g.uav_altitude_m + 80.0), billboard=True,
                                      font_size=14.0, scale_invariant=True, color=_color(rgb), text=f"UAV {i}")]
            lines = []
            rsu = self._nearest_rsu(xy)
            if self._relayed.get(i, 0) > 0 and rsu is not None:
                lines.append(fm.LinePrimitive(type=fm.LinePrimitiveLineType.LineStrip, thickness=3.0,
                                              scale_invariant=True, color=_LINK_COLOR,
                                              points=[fm.Point3(x=xy[0], y=xy[1], z=g.uav_altitude_m),
                                                      fm.Point3(x=rsu[0], y=rsu[1], z=30.0)]))
            entities.append(fm.SceneEntity(
                timestamp=stamp, frame_id=FRAME, id=f"uav/{i}",
                spheres=[fm.SpherePrimitive(pose=_pose(xy[0], xy[1], g.uav_altitude_m),
                                            size=fm.Vector3(x=80.0, y=80.0, z=80.0), color=_color(rgb))],
                cylinders=[fm.CylinderPrimitive(pose=_pose(xy[0], xy[1], 1.0),
                                                size=fm.Vector3(x=2 * g.comm_range_m, y=2 * g.comm_range_m, z=2.0),
                                                bottom_scale=1.0, top_scale=1.0, color=_color(rgb, 0.18))],
                texts=texts, lines=lines))
        q = VEHICLE_GRID_M
        vehicles = []
        for p in b["vehicles"]:
            xy = finite_xy(p)
            if xy is not None:
                vehicles.append(fm.CubePrimitive(pose=_pose(round(xy[0] / q) * q, round(xy[1] / q) * q, 5.0),
                                                 size=_VEHICLE_SIZE, color=_VEHICLE_COLOR))
        entities.append(fm.SceneEntity(timestamp=stamp, frame_id=FRAME, id="vehicles", cubes=vehicles))
        tf = fm.FrameTransforms(transforms=[
            fm.FrameTransform(timestamp=stamp, parent_frame_id=FRAME, child_frame_id=f"uav/{i}",
                              translation=fm.Vector3(x=xy[0], y=xy[1], z=g.uav_altitude_m), rotation=_IDENTITY)
            for i, xy in enumerate(uavs) if xy is not None])
        out.append(Out(TF_TOPIC, TF_SCHEMA, tf.encode()))
        # entities of UAVs that vanished (NaN position) must not linger: replace all each tick
        update = fm.SceneUpdate(deletions=[fm.SceneEntityDeletion(timestamp=stamp, type=fm.SceneEntityDeletionType.All)],
                                entities=entities)
        out.append(Out(SCENE_TOPIC, SCENE_SCHEMA, update.encode()))
        return out

    def static_scene(self, t: int) -> fm.SceneUpdate:
        """Road grid (one line list) and RSUs (cubes with a label)."""
        g = self.geometry
        n = int(math.floor(g.area_m / g.block_m + 1e-9)) + 1
        pts = []
        for k in range(n):
            c = k * g.block_m
            pts += [fm.Point3(x=c, y=0.0), fm.Point3(x=c, y=g.area_m), fm.Point3(x=0.0, y=c), fm.Point3(x=g.area_m, y=c)]
        stamp = _stamp(t)
        roads = fm.SceneEntity(timestamp=stamp, frame_id=FRAME, id="roads", lines=[fm.LinePrimitive(
            type=fm.LinePrimitiveLineType.LineList, pose=_pose(0.0, 0.0, 0.0), thickness=2.0, scale_invariant=True,
            points=pts, color=_ROAD_COLOR)])
        rsus = fm.SceneEntity(
            timestamp=stamp, frame_id=FRAME, id="rsus",
            cubes=[fm.CubePrimitive(pose=_pose(x, y, 15.0), size=fm.Vector3(x=60.0, y=60.0, z=30.0), color=_RSU_COLOR)
                   for x, y in g.rsu_xy],
            texts=[fm.TextPrimitive(pose=_pose(x, y, 60.0), billboard=True, font_size=12.0, scale_invariant=True,
                                    color=_RSU_COLOR, text=f"RSU {k}") for k, (x, y) in enumerate(g.rsu_xy)])
        return fm.SceneUpdate(entities=[roads, rsus])

    def _nearest_rsu(self, xy: tuple[float, float]) -> Optional[tuple[float, float]]:
        """The RSU a UAV's direct route goes to: the air-to-ground rate falls with
        distance, so the fastest direct hop is the nearest RSU (multi-hop relays
        through other UAVs are not drawn)."""
        if not self.geometry.rsu_xy:
            return None
        return min(self.geometry.rsu_xy, key=lambda r: (r[0] - xy[0]) ** 2 + (r[1] - xy[1]) ** 2)

    def _fault(self, b: dict, t: int) -> list[Out]:
        params = b.get("params") or {}
        detail = ", ".join(f"{k}={v}" for k, v in sorted(params.items(), key=lambda kv: str(kv[0])))
        text = f"fault {b['fault']} {b['phase']} on {b.get('target', '')}" + (f" ({detail})" if detail else "")
        return [self.log(t, "warning" if b["phase"] == "start" else "info", text, name="fault")]

    def _episode(self, b: dict, t: int) -> list[Out]:
        if b.get("scope") != "episode":
            return []
        values = b.get("values") or {}
        shown = ", ".join(f"{k} {float(v):.4g}" for k, v in values.items())
        return [self.log(t, "info", f"episode {b.get('episode')} finished: {shown}", name="world")]
