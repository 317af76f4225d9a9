"""MAVSDK (the `mavsdk` package: MAVSDK's own C++ library, run in this process, nobody here wrote it) against
`truav-swarm mavlink` beside a live swarm, on loopback: it discovers UAV 0 as system 1 and reads its position
(at the world's, within a few metres), its battery (the bridge's remaining charge of the world's spent energy)
and its heading (the world's direction of flight); a goto_location sent from MAVSDK (a reposition) steers
UAV 0: its world position gets nearer the point tick after tick."""

from __future__ import annotations

import asyncio
import math
import socket
import subprocess
import sys
import threading
import time

import pytest

pytest.importorskip("pymavlink", reason="the MAVLink bridge is the optional extra 'mavlink'")
pytest.importorskip("mavsdk", reason="MAVSDK (the mavsdk package) is in the 'test' extra")

from recorder.foxglove import DEFAULT_ORIGIN, from_latlon  # noqa: E402
from tests.support.swarm_up import up  # noqa: E402,F401
from truav.bus.transport import Bus, make_config  # noqa: E402
from truav.wire import keys  # noqa: E402

AGENTS = 3
AREA_M = 5000.0  # the default scenario's
ALTITUDE_M = 100.0  # its uav_altitude_m (the bridge's --ground-alt 0: above mean sea level too)
BATTERY_WH = 100.0
STEP_M = 15.0  # a full-speed step


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


async def _ground_station(port: int, goal_latlon: tuple[float, float], moved: threading.Event, got: dict) -> None:
    """MAVSDK as a ground station on udp ``port``: system 1's position, battery and heading into ``got``, then
    a goto to ``goal_latlon``; waits for ``moved`` (the test's thread watches the world) before it lets go."""
    from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
    from mavsdk.asyncio.plugins.action import ActionAsync
    from mavsdk.asyncio.plugins.telemetry import TelemetryAsync
    async with Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION)) as mavsdk:
        await asyncio.wait_for(mavsdk.add_any_connection(f"udpin://127.0.0.1:{port}"), 10.0)
        system = None
        deadline = time.monotonic() + 60.0
        while system is None and time.monotonic() < deadline:
            for s in await asyncio.wait_for(mavsdk.get_systems(), 10.0):
                if await asyncio.wait_for(s.get_system_id(), 5.0) == 1:
                    system = s
            await asyncio.sleep(0.2)
        assert system is not None, "MAVSDK discovered no system 1"
        got["systems"] = sorted([await asyncio.wait_for(s.get_system_id(), 5.0)
                                 for s in await asyncio.wait_for(mavsdk.get_systems(), 10.0)])
        telemetry = TelemetryAsync(system)

        async def first(gen):
            async for item in gen:
                return item

        got["positions"] = [await asyncio.wait_for(first(telemetry.subscribe_position()), 20.0) for _ in range(3)]
        got["battery"] = await asyncio.wait_for(first(telemetry.subscribe_battery()), 20.0)
        got["heading"] = await asyncio.wait_for(first(telemetry.subscribe_heading()), 20.0)
        await asyncio.wait_for(ActionAsync(system).goto_location(goal_latlon[0], goal_latlon[1], ALTITUDE_M,
                                                                 math.nan), 20.0)
        got["goto_done"] = True
        await asyncio.wait_for(asyncio.get_running_loop().run_in_executor(None, moved.wait, 60.0), 70.0)


def test_mavsdk_reads_position_battery_heading_and_a_goto_steers_the_uav(up) -> None:
    u = up("mavsdk", "--agents", str(AGENTS), "--episodes", "1", "--steps", "100000", "--max-missed", "1")
    endpoint = u.wait_ticking()
    port = _free_udp_port()
    log_path = u.out.parent / "mavlink.log"
    log = open(log_path, "wb")
    bridge = subprocess.Popen([sys.executable, "-m", "truav.cli.swarm", "mavlink", "--out", str(u.out),
                               "--udp-out", f"127.0.0.1:{port}", "--rate", "5", "--battery-wh", str(BATTERY_WH)],
                              stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    log.close()
    track: list[tuple[float, float]] = []  # UAV 0's world positions
    energy: list[float] = []  # UAV 0's spent energy (its observations)
    centre = (AREA_M / 2, AREA_M / 2)  # DEFAULT_ORIGIN
    moved = threading.Event()
    result: dict = {}

    def ground_station() -> None:
        try:
            asyncio.run(_ground_station(port, DEFAULT_ORIGIN, moved, result))
        except BaseException as exc:  # reported by the test's thread
            result["error"] = repr(exc)

    def obs(_k, m, _r, _t) -> None:
        if m.uav == 0:
            energy.append(float(m.energy_j))

    gcs = threading.Thread(target=ground_station, daemon=True)
    try:
        with Bus("observer", u.run, make_config(connect=[endpoint], connect_timeout_ms=5000)) as bus:
            bus.subscribe(keys.world_positions(u.run), lambda k, m, r, t: track.append(tuple(map(float, m.uavs[0]))))
            bus.subscribe(keys.all_obs(u.run), obs)
            gcs.start()
            deadline = time.monotonic() + 150.0
            at_goto = None
            while time.monotonic() < deadline and gcs.is_alive():
                assert bridge.poll() is None, log_path.read_text()
                if at_goto is None and result.get("goto_done"):
                    at_goto = len(track)
                if at_goto is not None and len(track) >= at_goto + 20:
                    moved.set()
                time.sleep(0.1)
            moved.set()
            gcs.join(timeout=80.0)
    finally:
        moved.set()
        if bridge.poll() is None:
            bridge.terminate()
            try:
                bridge.wait(timeout=10)
            except subprocess.TimeoutExpired:
                bridge.kill()
                bridge.wait()
    out = log_path.read_text()
    assert "error" not in result and not gcs.is_alive() and at_goto is not None, (result, out)
    assert result["systems"] == list(range(1, AGENTS + 1)), result["systems"]
    for p in result["positions"]:  # at one of the world's positions of UAV 0, within a few metres
        x, y = from_latlon(DEFAULT_ORIGIN, AREA_M, p.latitude_deg, p.longitude_deg)
        assert min(math.dist((x, y), w) for w in track) < 3.0, ((x, y), track[-5:])
        assert abs(p.absolute_altitude_m - ALTITUDE_M) < 1.0 and abs(p.relative_altitude_m - ALTITUDE_M) < 1.0, p
    spent = [100.0 * (1.0 - e / (BATTERY_WH * 3600.0)) for e in energy]
    remaining = result["battery"].remaining_percent
    assert min(abs(remaining - s) for s in spent) <= 1.0, (remaining, spent[:3], spent[-3:])
    headings = {0.0} | {math.degrees(math.atan2(b[0] - a[0], b[1] - a[1])) % 360.0
                        for a, b in zip(track, track[1:]) if math.dist(a, b) > 0.1}  # 0: not moved yet
    h = result["heading"].heading_deg % 360.0
    assert min(min(abs(h - d), 360.0 - abs(h - d)) for d in headings) < 1.0, (h, sorted(headings))
    after = [math.dist(p, centre) for p in track[at_goto:]]

    assert len(after) >= 20 and after[-1] < after[0] - 4 * STEP_M, after
    assert all(b <= a + 1e-6 or b <= STEP_M for a, b in zip(after[5:], after[6:])), (after, out)  # nearer every step
    assert "1 reposition(s) sent on as overrides" in out, out
