"""`truav log ros2bag`: a recording's poses, markers and metrics as a ROS 2 bag (rosbag2, MCAP storage), read back
by rosbags and by mcap-ros2-support's decoder (independent implementations), every pose equal to the recording's;
user mistakes and damaged inputs get one line and the log tools' exit codes."""

from __future__ import annotations

import builtins
from pathlib import Path

import pytest

from tests.support.recordings import N_UAVS, TICKS, make_swarm_recording
from tests.support.ros2bags import decoded_by_mcap_ros2, poses_by_rosbags, recorded_poses, rosbags_highlevel
from truav.cli.main import main
from truav.config import Config

ALTITUDE = Config().scenario.uav_altitude_m


@pytest.fixture(scope="module")
def exported(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    tmp = tmp_path_factory.mktemp("ros2bag")
    recording, bag = tmp / "rec.mcap", tmp / "bag"
    make_swarm_recording(recording)
    assert main(["log", "ros2bag", str(recording), "--out", str(bag)]) == 0
    return recording, bag


def test_rosbags_reads_every_pose_equal_to_the_recordings(exported) -> None:
    recording, bag = exported
    want = recorded_poses(recording)
    got, types = poses_by_rosbags(bag)
    assert sorted(want) == [f"/truav/uav_{u}/pose" for u in range(N_UAVS)] and all(len(v) == TICKS for v in want.values())
    assert {t: [(s, x, y) for s, x, y, _ in p] for t, p in got.items()} == want
    assert {z for p in got.values() for *_, z in p} == {ALTITUDE}
    assert types == {**{t: "geometry_msgs/msg/PoseStamped" for t in want},
                     **{f"/truav/uav_{u}/velocity": "geometry_msgs/msg/TwistStamped" for u in range(N_UAVS)},
                     "/truav/markers": "visualization_msgs/msg/MarkerArray",
                     "/truav/metrics": "diagnostic_msgs/msg/DiagnosticArray"}


def test_mcap_ros2_support_decodes_every_message(exported) -> None:
    recording, bag = exported
    decoded = decoded_by_mcap_ros2(bag)
    want = recorded_poses(recording)
    for topic, poses in want.items():
        assert [(m.header.stamp.sec * 10**9 + m.header.stamp.nanosec, m.pose.position.x, m.pose.position.y)
                for m in decoded[topic]] == poses
    markers = decoded["/truav/markers"]
    assert len(markers) == TICKS // 10  # the synthetic world sends positions every 10 ticks
    by_ns = {m.ns: m for m in markers[0].markers}
    assert markers[0].markers[0].action == 3 and len(by_ns["vehicles"].points) == 71 and len(by_ns["rsus"].points) == 4
    steps = [s for a in decoded["/truav/metrics"] for s in a.status if s.name == "truav/step"]
    assert len(steps) == TICKS and {kv.key for kv in steps[0].values} == {"coverage_pct", "delivered", "pdr"}
    energy = [kv.value for a in decoded["/truav/metrics"] for s in a.status if s.name == "truav/uav_0"
              for kv in s.values if kv.key == "energy_j"]
    assert energy == ["10.0"] * TICKS


def test_velocity_is_each_step_of_a_uav_within_an_episode_never_across_a_reset(exported) -> None:
    """rosbags reads each UAV's TwistStamped: one with every pose but the first of an episode, stamped as that
    pose, its linear x, y the position's change since the UAV's previous one over the scenario's step."""
    import msgpack
    from rosbags.typesys import Stores, get_typestore

    from recorder.reader import iter_messages
    recording, bag = exported
    step_s = Config().scenario.step_s
    obs: dict[int, list[tuple[int, int, int, float, float]]] = {}  # uav -> (log ns, episode, tick, x, y)
    for _key, payload, log_ns, _ in iter_messages(recording):
        b = msgpack.unpackb(payload)
        if b.get("kind") == "obs":
            obs.setdefault(b["uav"], []).append((log_ns, b["episode"], b["tick"], *map(float, b["pos"])))
    got: dict[str, list[tuple[int, float, float, float]]] = {}
    with rosbags_highlevel.AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        conns = [c for c in reader.connections if c.topic.endswith("/velocity")]
        for conn, _, raw in reader.messages(connections=conns):
            m = reader.deserialize(raw, conn.msgtype)
            assert m.header.frame_id == "map" and m.twist.angular.z == 0.0
            got.setdefault(conn.topic, []).append((m.header.stamp.sec * 10**9 + m.header.stamp.nanosec,
                                                   m.twist.linear.x, m.twist.linear.y, m.twist.linear.z))
    for uav, seen in obs.items():
        want = [(t, (x - px) / ((k - pk) * step_s), (y - py) / ((k - pk) * step_s), 0.0)
                for (_, pe, pk, px, py), (t, e, k, x, y) in zip(seen, seen[1:]) if e == pe]
        assert len(want) == TICKS - TICKS // 60 and len(want) < len(seen)  # none at an episode's first tick
        assert [(t, round(vx, 9), round(vy, 9), vz) for t, vx, vy, vz in got[f"/truav/uav_{uav}/velocity"]] == \
            [(t, round(vx, 9), round(vy, 9), vz) for t, vx, vy, vz in want]
        assert max(abs(vx) for _, vx, _, _ in want) > 1.0  # the UAVs move: not a trivial zero


def test_mapper_velocity_skips_resets_repeats_and_non_finite_positions() -> None:
    from rosbags.typesys import Stores, get_typestore

    from recorder.foxglove import Geometry
    from recorder.ros2_messages import Ros2Mapper
    mapper = Ros2Mapper(get_typestore(Stores.ROS2_JAZZY), Geometry(step_s=0.5))

    def vel(episode, tick, x, y):
        out = mapper.feed("obs", "truav/r/uav/3/obs", {"uav": 3, "episode": episode, "tick": tick, "pos": [x, y]}, 1)
        twists = [m.message.twist.linear for m in out if m.topic == "/truav/uav_3/velocity"]
        return (twists[0].x, twists[0].y) if twists else None

    assert vel(0, 0, 100.0, 100.0) is None  # the first: nothing to differ from
    assert vel(0, 1, 110.0, 95.0) == (20.0, -10.0)  # 10 m east, 5 m south in 0.5 s
    assert vel(0, 1, 500.0, 500.0) is None  # a repeated tick: not a step
    assert vel(0, 3, 120.0, 95.0) == (10.0, 0.0)  # a lost tick between: over the two steps
    assert vel(1, 0, 4000.0, 4000.0) is None  # an episode's reset: never a jump across it
    assert vel(1, 1, 4000.0, 4010.0) == (0.0, 20.0)
    assert vel(1, 2, float("nan"), 1.0) is None and vel(1, 3, 4000.0, 4020.0) is None  # not across a NaN


def test_mistakes_are_one_line_and_exit_2(exported, tmp_path: Path, capsys) -> None:
    recording, bag = exported
    cases = [([str(tmp_path / "none.mcap"), "--out", str(tmp_path / "b")], "none.mcap"),
             ([str(recording), "--out", str(bag)], "exists; use --force"),
             ([str(Path(__file__)), "--out", str(tmp_path / "b")], "MCAP")]
    for args, words in cases:
        capsys.readouterr()
        assert main(["log", "ros2bag", *args]) == 2, args
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and words in err and "Traceback" not in err, (args, err)
    assert not (tmp_path / "b").exists()


def test_force_replaces_an_existing_bag(exported, tmp_path: Path) -> None:
    recording, _ = exported
    out = tmp_path / "bag"
    assert main(["log", "ros2bag", str(recording), "--out", str(out)]) == 0
    assert main(["log", "ros2bag", str(recording), "--out", str(out), "--force"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["bag.mcap", "metadata.yaml"]
    assert not (tmp_path / "bag.part").exists()


def test_a_damaged_recording_is_one_line_exit_1_and_no_bag(exported, tmp_path: Path, capsys) -> None:
    recording, _ = exported
    data = bytearray(recording.read_bytes())
    data[len(data) // 3] ^= 0x10  # inside a chunk's compressed data
    damaged = tmp_path / "damaged.mcap"
    damaged.write_bytes(bytes(data))
    assert main(["log", "ros2bag", str(damaged), "--out", str(tmp_path / "b")]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "damaged recording" in err, err
    assert not (tmp_path / "b").exists() and not (tmp_path / "b.part").exists()


def test_without_rosbags_it_names_the_extra(exported, tmp_path: Path, capsys, monkeypatch) -> None:
    recording, _ = exported
    real_import = builtins.__import__

    def no_rosbags(name, *args, **kwargs):
        if name.startswith("rosbags"):
            raise ImportError(name)
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_rosbags)
    assert main(["log", "ros2bag", str(recording), "--out", str(tmp_path / "b")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "pip install -e '.[ros2]'" in err, err
    assert not (tmp_path / "b").exists() and not (tmp_path / "b.part").exists()
