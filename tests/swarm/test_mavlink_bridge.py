"""`truav-swarm mavlink` beside a live swarm: a pymavlink listener on loopback hears every UAV as its own
MAVLink system, at the world's positions, with its Remote ID; a reposition steers that UAV (an override):
acked accepted, its world position gets closer to the point over the next ticks."""

from __future__ import annotations

import math
import os
import subprocess
import sys
import time

import pytest

pytest.importorskip("pymavlink", reason="the MAVLink bridge is the optional extra 'mavlink'")
os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil  # noqa: E402

from recorder.foxglove import DEFAULT_ORIGIN, from_latlon  # noqa: E402
from tests.support.swarm_up import up  # noqa: E402,F401
from truav.bus.transport import Bus, make_config  # noqa: E402
from truav.wire import keys  # noqa: E402

AGENTS = 3
AREA_M = 5000.0  # the default scenario's


def test_bridge_sends_each_uav_as_a_system_at_the_worlds_positions_and_a_reposition_steers_it(up) -> None:
    u = up("mav", "--agents", str(AGENTS), "--episodes", "1", "--steps", "400", "--max-missed", "1")
    endpoint = u.wait_ticking()
    gcs = mavutil.mavlink_connection("udpin:127.0.0.1:0", source_system=255)
    port = gcs.port.getsockname()[1]
    log = open(u.out.parent / "mavlink.log", "wb")
    bridge = subprocess.Popen([sys.executable, "-m", "truav.cli.swarm", "mavlink", "--out", str(u.out),
                               "--udp-out", f"127.0.0.1:{port}", "--rate", "5", "--battery-wh", "100"],
                              stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    log.close()
    world: dict[int, list[tuple[float, float]]] = {i: [] for i in range(AGENTS)}

    def positions(_key, msg, _r, _t) -> None:
        for i, p in enumerate(msg.uavs[:AGENTS]):
            world[i].append((float(p[0]), float(p[1])))

    heartbeats: set[int] = set()
    fixes: dict[int, list[tuple[float, float]]] = {}
    basic: dict[int, bytes] = {}
    located: set[int] = set()
    batteries: dict[int, int] = {}
    ack = None
    at_ack = 0  # UAV 1's world positions heard when the ack came
    try:
        with Bus("observer", u.run, make_config(connect=[endpoint], connect_timeout_ms=5000)) as bus:
            bus.subscribe(keys.world_positions(u.run), positions)
            deadline = time.monotonic() + 90.0
            asked = False
            while time.monotonic() < deadline and (ack is None or len(world[1]) < at_ack + 15):
                assert bridge.poll() is None, (u.out.parent / "mavlink.log").read_text()
                msg = gcs.recv_match(blocking=True, timeout=0.5)
                if msg is None:
                    continue
                sysid, kind = msg.get_srcSystem(), msg.get_type()
                if kind == "HEARTBEAT":
                    heartbeats.add(sysid)
                elif kind == "GLOBAL_POSITION_INT":
                    fixes.setdefault(sysid, []).append(from_latlon(DEFAULT_ORIGIN, AREA_M, msg.lat / 1e7, msg.lon / 1e7))
                elif kind == "OPEN_DRONE_ID_BASIC_ID":
                    basic[sysid] = bytes(msg.uas_id).rstrip(b"\0")
                elif kind == "OPEN_DRONE_ID_LOCATION":
                    located.add(sysid)
                elif kind == "BATTERY_STATUS":
                    batteries[sysid] = msg.energy_consumed
                elif kind == "COMMAND_ACK" and ack is None:
                    ack, at_ack = msg, len(world[1])
                done = all(len(fixes.get(s, [])) >= 3 for s in range(1, AGENTS + 1)) and \
                    heartbeats >= set(range(1, AGENTS + 1)) and len(basic) == AGENTS and len(located) == AGENTS
                if done and not asked:  # steer UAV 1 (system 2) to the area's centre
                    gcs.mav.command_long_send(2, 1, mavutil.mavlink.MAV_CMD_DO_REPOSITION, 0, -1, 0, 0, math.nan,
                                              DEFAULT_ORIGIN[0], DEFAULT_ORIGIN[1], 100.0)
                    asked = True
    finally:
        if bridge.poll() is None:
            bridge.terminate()
            try:
                bridge.wait(timeout=10)
            except subprocess.TimeoutExpired:
                bridge.kill()
                bridge.wait()
        gcs.close()
    out = (u.out.parent / "mavlink.log").read_text()
    assert heartbeats == set(range(1, AGENTS + 1)), (heartbeats, out)
    for sysid in range(1, AGENTS + 1):
        uav = sysid - 1
        assert basic[sysid].startswith(f"TRUAV{uav}-".encode()), basic
        assert sysid in located and sysid in batteries
        for x, y in fixes[sysid]:  # each fix is one of the world's positions of that UAV (1e-7 degree: ~1 cm)
            nearest = min(math.hypot(x - wx, y - wy) for wx, wy in world[uav])
            assert nearest < 1.0, (sysid, (x, y), nearest)
    assert ack is not None, out
    assert ack.get_srcSystem() == 2 and ack.command == mavutil.mavlink.MAV_CMD_DO_REPOSITION
    assert ack.result == mavutil.mavlink.MAV_RESULT_ACCEPTED
    centre = (AREA_M / 2, AREA_M / 2)  # DEFAULT_ORIGIN, where the reposition pointed
    after = [math.dist(p, centre) for p in world[1][at_ack:]]
    assert len(after) >= 15 and after[-1] < after[0] - 60.0, after  # 15 m a step at full speed, a few steps late
    assert all(b <= a + 1e-6 or b <= 15.0 for a, b in zip(after[5:], after[6:])), after  # nearer every step
    assert bridge.returncode == 143, out  # SIGTERM: one line, 143
    assert "truav-swarm mavlink: stopped: " in out and "1 reposition(s) sent on as overrides" in out, out
    assert "Traceback" not in out
