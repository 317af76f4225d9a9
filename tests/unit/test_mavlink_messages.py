"""The pure MAVLink conversion (truav/swarm/mavlink_messages.py) and `truav-swarm mavlink`'s one-line refusals."""

from __future__ import annotations

import math

import pytest

pytest.importorskip("pymavlink", reason="the MAVLink bridge is the optional extra 'mavlink'")

from recorder.foxglove import DEFAULT_ORIGIN, from_latlon, to_latlon  # noqa: E402
from truav.cli.swarm import main  # noqa: E402
from truav.swarm.mavlink_messages import (FleetSettings, MavlinkFleet, mav, sysid_of,  # noqa: E402
                                          uav_of)


def _fleet(**kw) -> MavlinkFleet:
    return MavlinkFleet(FleetSettings("demo", DEFAULT_ORIGIN, 5000.0, 100.0, **kw))


def _decode(packets: list[bytes]) -> list:
    parser = mav.MAVLink(None)
    return [m for p in packets for m in parser.parse_buffer(p)]


def test_system_ids_are_uavs_of_one_block_of_254() -> None:
    assert sysid_of(0) == 1 and sysid_of(253) == 254 and sysid_of(254) is None
    assert sysid_of(300, first=254) == 47 and uav_of(47, first=254) == 300
    assert uav_of(0) is None and uav_of(255) is None


def test_lat_lon_round_trip_and_the_centre_is_the_origin() -> None:
    assert to_latlon(DEFAULT_ORIGIN, 5000.0, 2500.0, 2500.0) == DEFAULT_ORIGIN
    x, y = from_latlon(DEFAULT_ORIGIN, 5000.0, *to_latlon(DEFAULT_ORIGIN, 5000.0, 120.5, 4321.0))
    assert math.isclose(x, 120.5, abs_tol=1e-6) and math.isclose(y, 4321.0, abs_tol=1e-6)


def test_position_heading_battery_and_remote_id_from_the_bus() -> None:
    f = _fleet(battery_wh=1.0, ground_alt_m=35.0)
    f.feed("positions", {"tick": 1, "uavs": [[2500.0, 2500.0], [10.0, 10.0]], "vehicles": []}, 0)
    f.feed("positions", {"tick": 2, "uavs": [[2520.0, 2500.0], [10.0, 10.0]], "vehicles": []}, 1)  # UAV 0 east
    f.feed("obs", {"uav": 0, "episode": 0, "energy_j": 1800.0}, 2)  # half of 1 Wh
    msgs = {m.get_type(): m for m in _decode(f.packets(1000, 7200.5)) if m.get_srcSystem() == 1}
    pos = msgs["GLOBAL_POSITION_INT"]
    assert from_latlon(DEFAULT_ORIGIN, 5000.0, pos.lat / 1e7, pos.lon / 1e7) == pytest.approx((2520.0, 2500.0), abs=0.02)
    assert pos.alt == 135_000 and pos.relative_alt == 100_000 and pos.hdg == 9000 and pos.vy == 2000 and pos.vx == 0
    assert msgs["ATTITUDE"].yaw == pytest.approx(math.pi / 2)
    assert msgs["HEARTBEAT"].type == mav.MAV_TYPE_QUADROTOR and msgs["HEARTBEAT"].autopilot == mav.MAV_AUTOPILOT_GENERIC
    assert msgs["BATTERY_STATUS"].battery_remaining == 50 and msgs["BATTERY_STATUS"].energy_consumed == 18
    assert msgs["SYS_STATUS"].battery_remaining == 50
    assert bytes(msgs["OPEN_DRONE_ID_BASIC_ID"].uas_id).rstrip(b"\0") == b"TRUAV0-demo"
    loc = msgs["OPEN_DRONE_ID_LOCATION"]
    assert (loc.latitude, loc.longitude, loc.direction, loc.speed_horizontal) == (pos.lat, pos.lon, 9000, 2000)
    assert loc.timestamp == pytest.approx(0.5)
    f.feed("obs", {"uav": 0, "episode": 1, "energy_j": 10.0}, 3)  # a new episode: the count starts again
    assert f.tracks[0].energy_j == 10.0


def test_without_a_capacity_the_charge_is_unknown_and_a_vanished_uav_only_beats() -> None:
    f = _fleet()
    f.feed("positions", {"tick": 1, "uavs": [[1.0, 1.0], [math.nan, math.nan]], "vehicles": []}, 0)
    msgs = _decode(f.packets(0, 0.0))
    assert {m.get_type() for m in msgs if m.get_srcSystem() == 2} == {"HEARTBEAT"}
    assert [m.battery_remaining for m in msgs if m.get_type() == "BATTERY_STATUS"] == [-1]


def test_a_reposition_is_acked_unsupported_only_for_a_uav_of_the_bridge() -> None:
    f = _fleet()
    f.feed("positions", {"tick": 1, "uavs": [[1.0, 1.0]], "vehicles": []}, 0)
    (ack,) = _decode([f.unsupported_ack(1, mav.MAV_CMD_DO_REPOSITION, 255, 190)])
    assert (ack.get_srcSystem(), ack.command, ack.result, ack.target_system) == \
        (1, mav.MAV_CMD_DO_REPOSITION, mav.MAV_RESULT_UNSUPPORTED, 255)
    assert f.unsupported_ack(2, mav.MAV_CMD_DO_REPOSITION, 255, 190) is None


def test_a_reposition_names_its_uav_point_and_speed() -> None:
    f = _fleet(first_uav=10)
    f.feed("positions", {"tick": 1, "uavs": [[1.0, 1.0]] * 12, "vehicles": []}, 0)
    lat, lon = to_latlon(DEFAULT_ORIGIN, 5000.0, 1200.0, 3400.0)
    long_ = mav.MAVLink_command_long_message(2, 1, mav.MAV_CMD_DO_REPOSITION, 0, -1, 0, 0, math.nan, lat, lon, 100)
    uav, (x, y), speed = f.reposition_goal(long_)
    assert uav == 11 and math.isclose(x, 1200.0, abs_tol=0.1) and math.isclose(y, 3400.0, abs_tol=0.1) and speed == 0
    int_ = mav.MAVLink_command_int_message(1, 1, 0, mav.MAV_CMD_DO_REPOSITION, 0, 0, 7.5, 0, 0, math.nan,
                                           round(lat * 1e7), round(lon * 1e7), 100)
    uav, (x, y), speed = f.reposition_goal(int_)
    assert uav == 10 and math.isclose(x, 1200.0, abs_tol=0.1) and speed == 7.5
    target = mav.MAVLink_set_position_target_global_int_message(0, 2, 1, 6, 0b110111111000, round(lat * 1e7),
                                                                round(lon * 1e7), 100, 0, 0, 0, 0, 0, 0, 0, 0)
    assert f.reposition_goal(target)[0] == 11 and math.isclose(f.reposition_goal(target)[1][1], 3400.0, abs_tol=0.1)
    far = mav.MAVLink_command_long_message(2, 1, mav.MAV_CMD_DO_REPOSITION, 0, -1, 0, 0, 0, lat + 1.0, lon, 100)
    nan = mav.MAVLink_command_long_message(2, 1, mav.MAV_CMD_DO_REPOSITION, 0, -1, 0, 0, 0, math.nan, math.nan, 100)
    assert f.reposition_goal(far) == (11, None, 0.0) and f.reposition_goal(nan) == (11, None, 0.0)
    other = mav.MAVLink_command_long_message(2, 1, mav.MAV_CMD_NAV_LAND, 0, 0, 0, 0, 0, 0, 0, 0)
    stranger = mav.MAVLink_command_long_message(99, 1, mav.MAV_CMD_DO_REPOSITION, 0, -1, 0, 0, 0, lat, lon, 100)
    assert f.reposition_goal(other) is None and f.reposition_goal(stranger) is None


@pytest.mark.parametrize("argv, flag", [(["--udp-out", "localhost"], "--udp-out"), (["--udp-out", "127.0.0.1:0"], "--udp-out"),
                                        (["--geo-origin", "48.8,2.3,35"], "--geo-origin"), (["--rate", "0"], "--rate"),
                                        (["--ground-alt", "nan"], "--ground-alt"), (["--run", "nosuch"], "--run nosuch")])
def test_a_user_mistake_is_one_line_and_exit_2(argv, flag, capsys, tmp_path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exc:
        code = main(["mavlink", *argv])
        raise SystemExit(code)
    err = capsys.readouterr().err
    assert exc.value.code == 2 and len(err.strip().splitlines()) == 1 and flag in err, err
