"""The swarm as MAVLink systems: bus messages in, MAVLink packets out. Pure: no socket, no Zenoh.

:class:`MavlinkFleet` is fed the run's decoded bus messages (the world's ``positions`` for where each UAV
is, the agents' ``beacon`` for its velocity, each ``obs`` for the energy it spent in the step) and, when
asked, builds per UAV a HEARTBEAT, GLOBAL_POSITION_INT, ATTITUDE, SYS_STATUS, BATTERY_STATUS,
OPEN_DRONE_ID_BASIC_ID and OPEN_DRONE_ID_LOCATION, each packed by pymavlink (MAVLink 2) with the UAV's
own system id. ``truav-swarm mavlink`` (truav/swarm/mavlink_bridge.py) sends them over UDP.

System ids: UAV ``first + k`` is system ``k + 1`` (1..254; 0 is broadcast and 255 is the ground station's
by convention), so one bridge carries at most 254 UAVs. A larger swarm runs one bridge per block of 254
(``--first-uav 0``, ``254``, ``508``, ...), each to its own ground-station port: a ground station keys
vehicles by system id, and MAVLink's component ids name parts of one vehicle, not vehicles.

Coordinates: the area's (x east, y north) in metres around a geographic origin at its centre
(:func:`recorder.foxglove.to_latlon`, as Foxglove's map); altitude is the scenario's UAV altitude above
``ground_alt_m`` (the ground's altitude above mean sea level). Heading and yaw follow the velocity
(0 north, clockwise). Energy: the world models the power each UAV draws, not a battery; the bridge
reports the energy spent since the episode started (``energy_consumed``), and a charge remaining only
against a capacity the user gives (``battery_wh``), else "unknown" (-1) as MAVLink allows.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Any, Optional

os.environ.setdefault("MAVLINK20", "1")  # before pymavlink picks its wire version
from pymavlink.dialects.v20 import common as mav  # noqa: E402

from recorder.foxglove import finite_xy, from_latlon, to_latlon  # noqa: E402
from truav.swarm.steering import inside_area  # noqa: E402

SYSIDS_PER_BRIDGE = 254
"""System ids 1..254 (0: broadcast, 255: the ground station by convention)."""
COMPONENT = mav.MAV_COMP_ID_AUTOPILOT1
UAS_ID_LEN = 20
UINT16_UNKNOWN = 65535
INT16_UNKNOWN = 32767
DIRECTION_UNKNOWN = 361  # OpenDroneID: degrees, 361 = unknown
STILL_MPS = 0.05
"""Below this speed a UAV has no heading of its own: it keeps its last one."""


def sysid_of(uav: int, first: int = 0) -> Optional[int]:
    """The system id of UAV ``uav`` on a bridge whose first UAV is ``first``; None if not on it."""
    k = uav - first
    return k + 1 if 0 <= k < SYSIDS_PER_BRIDGE else None


def uav_of(sysid: int, first: int = 0) -> Optional[int]:
    """The UAV a system id stands for on a bridge whose first UAV is ``first``; None for 0 or 255."""
    return first + sysid - 1 if 1 <= sysid <= SYSIDS_PER_BRIDGE else None


def uas_id(run: str, uav: int) -> bytes:
    """The Remote ID serial of a UAV: ``TRUAV`` + the UAV id, and as much of the run's name as fits (20 bytes)."""
    text = f"TRUAV{uav}-{run}".encode("ascii", "replace")[:UAS_ID_LEN]
    return text.ljust(UAS_ID_LEN, b"\0")


@dataclass
class UavTrack:
    """What the bridge knows of one UAV."""

    xy: Optional[tuple[float, float]] = None  # None: no finite position (yet, or it vanished)
    vel: tuple[float, float] = (0.0, 0.0)
    vel_ns: Optional[int] = None  # when a beacon last gave the velocity
    tick: Optional[int] = None  # of the last position
    yaw: float = 0.0  # radians, 0 north, clockwise
    episode: Optional[int] = None
    energy_j: float = 0.0  # spent since the episode began
    step_energy_j: float = 0.0


@dataclass(frozen=True)
class FleetSettings:
    run: str
    origin: tuple[float, float]
    area_m: float
    uav_altitude_m: float
    ground_alt_m: float = 0.0
    first_uav: int = 0
    battery_wh: Optional[float] = None
    step_s: float = 1.0


class MavlinkFleet:
    """The UAVs of one bridge (at most 254) as MAVLink systems."""

    BEACON_FRESH_NS = 3_000_000_000  # a beacon's velocity older than this gives way to the positions' deltas

    def __init__(self, settings: FleetSettings) -> None:
        self.s = settings
        self.tracks: dict[int, UavTrack] = {}
        self._links: dict[int, mav.MAVLink] = {}  # sysid -> its packer (its own sequence numbers)

    # --- bus messages in ---------------------------------------------------------------------------
    def feed(self, kind: str, body: dict, recv_ns: int) -> None:
        """One decoded bus message; kinds other than positions, beacon and obs are ignored.
        Raises (KeyError, TypeError, ValueError) on a body that does not fit its kind."""
        if kind == "positions":
            tick = int(body["tick"])
            for i, p in enumerate(body["uavs"]):
                if sysid_of(i, self.s.first_uav) is not None:
                    self._position(i, finite_xy(p), tick, recv_ns)
        elif kind == "beacon":
            uav, vel = int(body["uav"]), finite_xy(body["vel"])
            if sysid_of(uav, self.s.first_uav) is not None and vel is not None:
                t = self.tracks.setdefault(uav, UavTrack())
                t.vel, t.vel_ns = vel, recv_ns
                self._turn(t)
        elif kind == "obs":
            uav = int(body["uav"])
            if sysid_of(uav, self.s.first_uav) is None:
                return
            t = self.tracks.setdefault(uav, UavTrack())
            episode, energy = int(body["episode"]), float(body["energy_j"])
            if t.episode != episode:
                t.episode, t.energy_j = episode, 0.0
            if math.isfinite(energy) and energy >= 0.0:
                t.energy_j += energy
                t.step_energy_j = energy

    def _position(self, uav: int, xy: Optional[tuple[float, float]], tick: int, recv_ns: int) -> None:
        t = self.tracks.setdefault(uav, UavTrack())
        beacon_fresh = t.vel_ns is not None and recv_ns - t.vel_ns < self.BEACON_FRESH_NS
        if xy is not None and t.xy is not None and t.tick is not None and not beacon_fresh and tick > t.tick:
            dt = (tick - t.tick) * self.s.step_s  # the world's seconds: velocities in its metres per second
            t.vel = ((xy[0] - t.xy[0]) / dt, (xy[1] - t.xy[1]) / dt)
            self._turn(t)
        t.xy, t.tick = xy, tick

    @staticmethod
    def _turn(t: UavTrack) -> None:
        if math.hypot(*t.vel) >= STILL_MPS:
            t.yaw = math.atan2(t.vel[0], t.vel[1])  # x east, y north: 0 north, clockwise

    # --- MAVLink out --------------------------------------------------------------------------------
    def link(self, sysid: int) -> mav.MAVLink:
        ln = self._links.get(sysid)
        if ln is None:
            ln = self._links[sysid] = mav.MAVLink(None, srcSystem=sysid, srcComponent=COMPONENT)
        return ln

    def messages(self, uav: int, boot_ms: int, unix_s: float) -> list[Any]:
        """The MAVLink messages of one UAV now (``boot_ms``: the bridge's uptime; ``unix_s``: wall time
        for Remote ID's time stamp). A UAV without a finite position sends its heartbeat alone."""
        t = self.tracks.get(uav)
        if t is None:
            return []
        s = self.s
        if t.xy is None:
            return [mav.MAVLink_heartbeat_message(mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_GENERIC, 0, 0,
                                                  mav.MAV_STATE_FLIGHT_TERMINATION, 3)]
        lat, lon = to_latlon(s.origin, s.area_m, *t.xy)
        lat_e7, lon_e7 = int(round(lat * 1e7)), int(round(lon * 1e7))
        alt_m = s.ground_alt_m + s.uav_altitude_m
        vx, vy = t.vel
        speed = math.hypot(vx, vy)
        hdg_deg = math.degrees(t.yaw) % 360.0
        hb = mav.MAVLink_heartbeat_message(
            mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_GENERIC,
            mav.MAV_MODE_FLAG_SAFETY_ARMED | mav.MAV_MODE_FLAG_AUTO_ENABLED, 0, mav.MAV_STATE_ACTIVE, 3)
        pos = mav.MAVLink_global_position_int_message(
            boot_ms, lat_e7, lon_e7, int(round(alt_m * 1000)), int(round(s.uav_altitude_m * 1000)),
            _i16(vy * 100), _i16(vx * 100), 0, int(round(hdg_deg * 100)) % 36000)
        att = mav.MAVLink_attitude_message(boot_ms, 0.0, 0.0, math.atan2(math.sin(t.yaw), math.cos(t.yaw)),
                                           0.0, 0.0, 0.0)
        remaining = -1
        if s.battery_wh:
            remaining = max(0, min(100, int(round(100.0 * (1.0 - t.energy_j / (s.battery_wh * 3600.0))))))
        sys_status = mav.MAVLink_sys_status_message(0, 0, 0, 0, UINT16_UNKNOWN, -1, remaining, 0, 0, 0, 0, 0, 0)
        battery = mav.MAVLink_battery_status_message(
            0, mav.MAV_BATTERY_FUNCTION_ALL, mav.MAV_BATTERY_TYPE_UNKNOWN, INT16_UNKNOWN,
            [UINT16_UNKNOWN] * 10, -1, -1, min(int(t.energy_j / 100.0), 2**31 - 1), remaining)
        basic = mav.MAVLink_open_drone_id_basic_id_message(
            0, 0, [0] * 20, mav.MAV_ODID_ID_TYPE_SERIAL_NUMBER, mav.MAV_ODID_UA_TYPE_HELICOPTER_OR_MULTIROTOR,
            list(uas_id(s.run, uav)))
        location = mav.MAVLink_open_drone_id_location_message(
            0, 0, [0] * 20, mav.MAV_ODID_STATUS_AIRBORNE,
            int(round(hdg_deg * 100)) % 36000 if speed >= STILL_MPS else DIRECTION_UNKNOWN * 100,
            min(int(round(speed * 100)), 25425), 0, lat_e7, lon_e7, -1000.0, float(alt_m),
            mav.MAV_ODID_HEIGHT_REF_OVER_TAKEOFF, float(s.uav_altitude_m),
            mav.MAV_ODID_HOR_ACC_1_METER, mav.MAV_ODID_VER_ACC_1_METER, mav.MAV_ODID_VER_ACC_UNKNOWN,
            mav.MAV_ODID_SPEED_ACC_0_3_METERS_PER_SECOND, float(unix_s % 3600.0), mav.MAV_ODID_TIME_ACC_0_1_SECOND)
        return [hb, pos, att, sys_status, battery, basic, location]

    def packets(self, boot_ms: int, unix_s: float) -> list[bytes]:
        """Every UAV's messages, packed with its own system id (MAVLink 2)."""
        out = []
        for uav in sorted(self.tracks):
            ln = self.link(sysid_of(uav, self.s.first_uav))
            out.extend(m.pack(ln) for m in self.messages(uav, boot_ms, unix_s))
        return out

    def command_ack(self, sysid: int, command: int, result: int, to_system: int, to_component: int) -> Optional[bytes]:
        """A COMMAND_ACK of ``result`` (MAV_RESULT_*) from ``sysid`` to the sender of ``command``; None when
        ``sysid`` is no UAV of this bridge."""
        uav = uav_of(sysid, self.s.first_uav)
        if uav is None or uav not in self.tracks:
            return None
        msg = mav.MAVLink_command_ack_message(command, result, 0, 0, to_system, to_component)
        return msg.pack(self.link(sysid))

    def unsupported_ack(self, sysid: int, command: int, to_system: int, to_component: int) -> Optional[bytes]:
        """:meth:`command_ack` MAV_RESULT_UNSUPPORTED: a command the bridge does not carry out."""
        return self.command_ack(sysid, command, mav.MAV_RESULT_UNSUPPORTED, to_system, to_component)

    def reposition_goal(self, msg: Any) -> Optional[tuple[int, Optional[tuple[float, float]], float]]:
        """(UAV, goal (x, y) in m or None, speed m/s (0: full)) of a ground station's reposition (MAV_CMD_DO_REPOSITION
        in COMMAND_LONG or COMMAND_INT, or SET_POSITION_TARGET_GLOBAL_INT) to a UAV of this bridge; goal None
        when the point is not given (NaN, or the position ignored by the type mask), unreadable or outside the
        area. None for any other message, or a system that is no UAV of this bridge."""
        name = msg.get_type()
        uav = uav_of(int(getattr(msg, "target_system", 0)), self.s.first_uav)
        if uav is None or uav not in self.tracks:
            return None
        speed = 0.0
        if name == "COMMAND_LONG" and msg.command == mav.MAV_CMD_DO_REPOSITION:
            lat, lon, speed = float(msg.param5), float(msg.param6), float(msg.param1)
        elif name == "COMMAND_INT" and msg.command == mav.MAV_CMD_DO_REPOSITION:
            lat, lon, speed = msg.x / 1e7, msg.y / 1e7, float(msg.param1)
        elif name == "SET_POSITION_TARGET_GLOBAL_INT":
            ignore = mav.POSITION_TARGET_TYPEMASK_X_IGNORE | mav.POSITION_TARGET_TYPEMASK_Y_IGNORE
            lat, lon = (math.nan, math.nan) if msg.type_mask & ignore else (msg.lat_int / 1e7, msg.lon_int / 1e7)
        else:
            return None
        speed = speed if math.isfinite(speed) and speed > 0 else 0.0  # -1 (MAVLink's "default"): full speed
        if not (math.isfinite(lat) and math.isfinite(lon) and -90 <= lat <= 90 and -180 <= lon <= 180):
            return uav, None, speed
        x, y = from_latlon(self.s.origin, self.s.area_m, lat, lon)
        return uav, ((x, y) if inside_area((x, y), self.s.area_m) else None), speed


def _i16(v: float) -> int:
    return max(-32768, min(32767, int(round(v))))


def commands_to_refuse(msg: Any) -> Optional[tuple[int, int]]:
    """(target system, command) of a ground station's message that asks a vehicle to act: COMMAND_LONG,
    COMMAND_INT (any command; MAV_CMD_DO_REPOSITION among them) and SET_POSITION_TARGET_GLOBAL_INT (acked
    as MAV_CMD_DO_REPOSITION); None for anything else (heartbeats, requests the bridge ignores)."""
    name = msg.get_type()
    if name in ("COMMAND_LONG", "COMMAND_INT"):
        return int(msg.target_system), int(msg.command)
    if name == "SET_POSITION_TARGET_GLOBAL_INT":
        return int(msg.target_system), mav.MAV_CMD_DO_REPOSITION
    return None
