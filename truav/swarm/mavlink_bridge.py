"""`truav-swarm mavlink`: a live run's UAVs as MAVLink systems for a ground-control station.

A thin wrapper: :func:`truav.swarm.view.follow` (the live views' one subscription to ``truav/<run>/**``)
feeds :class:`truav.swarm.mavlink_messages.MavlinkFleet`, whose packets go out over one UDP socket to the
ground station (``127.0.0.1:14550`` by default, where QGroundControl listens) every ``period_s``. What the
ground station sends back comes in on the same socket: a reposition of a UAV (MAV_CMD_DO_REPOSITION in
COMMAND_LONG or COMMAND_INT, SET_POSITION_TARGET_GLOBAL_INT) becomes an override of that UAV
(control/override/<i>, sent as the ``operator`` identity: the world flies it to the point), acked
MAV_RESULT_ACCEPTED (MAV_RESULT_DENIED for a point outside the area or not given); any other command is
answered MAV_RESULT_UNSUPPORTED (docs/how-to/ground-control.md).
"""

from __future__ import annotations

import logging
import socket
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Optional

from truav.swarm.mavlink_messages import MavlinkFleet, commands_to_refuse, mav
from truav.swarm.view import FedStats, feed_sample, follow
from truav.swarm.steering import send_override
from truav.wire import keys

log = logging.getLogger("truav.mavlink")

SRC_MAVLINK = "mavlink"
DEFAULT_GCS = ("127.0.0.1", 14550)  # the UDP port ground stations listen on (QGroundControl, MAVProxy)
DEFAULT_RATE_HZ = 2.0
MAX_DATAGRAM = 2048  # a MAVLink 2 frame is at most 280 bytes; more is not MAVLink


@dataclass
class BridgeStats(FedStats):
    sent: int = 0  # datagrams
    refused: dict[int, int] = field(default_factory=dict)  # command -> times acked UNSUPPORTED
    steered: int = 0  # repositions sent on as overrides (acked ACCEPTED)
    denied: int = 0  # repositions to a point outside the area or none (acked DENIED)


class Bridge:
    """The fleet, a UDP socket and the clock that paces the telemetry."""

    def __init__(self, fleet: MavlinkFleet, gcs: tuple[str, int], rate_hz: float = DEFAULT_RATE_HZ,
                 on_shutdown: Optional[Callable[[], None]] = None) -> None:
        self.fleet = fleet
        self.on_shutdown = on_shutdown  # the run's shutdown was heard
        self.gcs = gcs
        self.period_ns = int(1e9 / rate_hz)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1" if gcs[0].startswith("127.") else "0.0.0.0", 0))
        self.sock.setblocking(False)
        self.start_ns = time.monotonic_ns()
        self._next_ns = self.start_ns
        self._parser = mav.MAVLink(None)
        self._parser.robust_parsing = True
        self.stats = BridgeStats()
        self.steer: Optional[Callable[[int, tuple[float, float], float], None]] = None
        """Sends an override of a UAV to a goal (run_bridge sets it); None: repositions are unsupported."""

    def handle(self, key: str, payload: bytes, recv_ns: int) -> None:
        feed_sample(self.stats, payload, lambda kind, body: self.fleet.feed(kind, body, recv_ns), self.on_shutdown)

    def every_pass(self) -> None:
        now = time.monotonic_ns()
        if now >= self._next_ns:
            self._next_ns = max(self._next_ns + self.period_ns, now)
            for packet in self.fleet.packets((now - self.start_ns) // 1_000_000, time.time()):
                self._send(packet, self.gcs)
        self._answer()

    def _send(self, packet: bytes, to: tuple[str, int]) -> None:
        try:
            self.sock.sendto(packet, to)
            self.stats.sent += 1
        except OSError:  # nobody listening (ICMP port unreachable) or a full buffer: telemetry is lossy
            pass

    def _answer(self) -> None:
        for _ in range(64):  # bounded per pass
            try:
                data, sender = self.sock.recvfrom(MAX_DATAGRAM)
            except (BlockingIOError, ConnectionRefusedError, OSError):
                return
            try:
                msgs = self._parser.parse_buffer(data) or []
            except Exception:  # not MAVLink
                continue
            for msg in msgs:
                if self.steer is not None and self._reposition(msg, sender):
                    continue
                ask = commands_to_refuse(msg)
                if ask is None:
                    continue
                target, command = ask
                ack = self.fleet.unsupported_ack(target, command, msg.get_srcSystem(), msg.get_srcComponent())
                if ack is not None:
                    self.stats.refused[command] = self.stats.refused.get(command, 0) + 1
                    if self.stats.refused[command] == 1:  # once per command: ground stations retry and poll
                        log.warning("command %d to system %d refused (MAV_RESULT_UNSUPPORTED): the bridge takes "
                                    "repositions only", command, target)
                    self._send(ack, sender)

    def _reposition(self, msg: Any, sender: tuple[str, int]) -> bool:
        """A reposition of a UAV of this bridge: sent on as an override and acked; False for anything else."""
        try:
            goal = self.fleet.reposition_goal(msg)
        except (AttributeError, TypeError, ValueError):
            return False
        if goal is None:
            return False
        uav, xy, speed = goal
        command = int(getattr(msg, "command", mav.MAV_CMD_DO_REPOSITION))
        result = mav.MAV_RESULT_DENIED
        if xy is not None:
            self.steer(uav, xy, speed)
            self.stats.steered += 1
            result = mav.MAV_RESULT_ACCEPTED
            log.info("reposition of system %d: UAV %d steered to (%.0f, %.0f) m", msg.target_system, uav, *xy)
        else:
            self.stats.denied += 1
            log.warning("reposition of system %d denied: no point inside the area", msg.target_system)
        ack = self.fleet.command_ack(msg.target_system, command, result, msg.get_srcSystem(), msg.get_srcComponent())
        if ack is not None:
            self._send(ack, sender)
        return True

    def close(self) -> None:
        self.sock.close()


def run_bridge(run: str, zenoh_config: Any, bridge: Bridge, stop: Optional[threading.Event] = None,
               ready: Optional[Callable[[], None]] = None, steer_config: Any = None) -> BridgeStats:
    """Serve ``run``'s UAVs to the ground station until ``stop`` is set. ``steer_config``: the zenoh config of
    the ``operator`` identity (under --secure its credentials) that sends repositions on as overrides; None:
    repositions are acked unsupported."""
    from truav.bus.transport import Bus
    stop = stop or threading.Event()
    try:
        if steer_config is None:
            follow(run, zenoh_config, SRC_MAVLINK, stop, bridge.handle, every_pass=bridge.every_pass, ready=ready)
            return bridge.stats
        with Bus(keys.SRC_OPERATOR, run, steer_config) as bus:
            bridge.steer = lambda uav, xy, speed: send_override(bus, run, uav, xy, speed)
            follow(run, zenoh_config, SRC_MAVLINK, stop, bridge.handle, every_pass=bridge.every_pass, ready=ready)
    finally:
        bridge.close()
    return bridge.stats
