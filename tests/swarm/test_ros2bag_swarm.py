"""`truav log ros2bag` of a real recorded swarm (2 agents, lock-step, a few ticks): rosbags reads every UAV's pose
back equal to the world's observations in the recording, mcap-ros2-support's decoder decodes every message, and the
z of a pose is the scenario's altitude."""

from __future__ import annotations

from pathlib import Path

from tests.support.ros2bags import decoded_by_mcap_ros2, poses_by_rosbags, recorded_poses
from tests.support.runs import up_to_end
from truav.cli.main import main
from truav.config import Config

RUN = "ros2bag"
EPISODES = 1
CFG = Config().replace(scenario={"n_vehicles": 30, "steps_per_episode": 6, "n_uavs": 2, "uav_altitude_m": 120.0},
                       roads={"warmup_steps": 5}, learner={"episodes": EPISODES})


def test_a_recorded_swarm_exports_to_a_bag_with_every_pose_equal(tmp_path: Path, capsys) -> None:
    recording, bag = tmp_path / "swarm.mcap", tmp_path / "swarm_bag"
    up_to_end(tmp_path, RUN, CFG, "--lockstep", "--seed", "5", "--episodes", str(EPISODES), "--record", str(recording))
    assert main(["log", "ros2bag", str(recording), "--out", str(bag)]) == 0
    out = capsys.readouterr().out
    want = recorded_poses(recording)
    assert sorted(want) == ["/truav/uav_0/pose", "/truav/uav_1/pose"] and all(want.values()), want
    assert f"{sum(map(len, want.values()))} poses of 2 UAVs" in out, out
    got, types = poses_by_rosbags(bag)
    assert {t: [(s, x, y) for s, x, y, _ in p] for t, p in got.items()} == want
    assert {z for p in got.values() for *_, z in p} == {120.0}
    assert types["/truav/markers"] == "visualization_msgs/msg/MarkerArray"
    decoded = decoded_by_mcap_ros2(bag)
    assert {t: len(m) for t, m in decoded.items()} == _counts(bag)
    for topic, poses in want.items():
        assert [(m.pose.position.x, m.pose.position.y) for m in decoded[topic]] == [(x, y) for _, x, y in poses]
    assert decoded["/truav/markers"] and any(s.name == "truav/episode" for a in decoded["/truav/metrics"] for s in a.status)


def _counts(bag: Path) -> dict[str, int]:
    """Messages per topic as the bag's metadata.yaml states them (what `ros2 bag info` prints), read by rosbags."""
    from rosbags.rosbag2 import Reader

    with Reader(bag) as reader:
        return {topic: info.msgcount for topic, info in reader.topics.items()}
