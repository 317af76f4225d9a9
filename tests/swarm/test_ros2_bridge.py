"""`truav-swarm ros2` beside a live swarm, seen by zenoh-ros2-sdk (an rmw_zenoh client nobody here wrote,
given the message definitions rosbags ships: it would otherwise clone them from git): it lists every UAV's
pose topic with its type, finds the bridge's node in the graph, and echoes poses at the world's positions;
every sample carries rmw_zenoh's attachment."""

from __future__ import annotations

import subprocess
import sys
import threading
import time

import pytest

pytest.importorskip("rosbags", reason="the ROS 2 bridge is the optional extra 'ros2'")
pytest.importorskip("zenoh_ros2_sdk", reason="zenoh-ros2-sdk, the independent rmw_zenoh client, is in the 'test' extra")

from tests.support.ros2_msgdefs import offline_sdk_registry  # noqa: E402
from tests.support.swarm_up import up  # noqa: E402,F401
from truav.bus.transport import Bus, make_config  # noqa: E402
from truav.wire import keys  # noqa: E402

AGENTS = 3
POSE = "geometry_msgs/msg/PoseStamped"
UAV_ALTITUDE_M = 100.0  # the default scenario's scenario.uav_altitude_m


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def test_an_independent_rmw_zenoh_client_lists_the_topics_sees_the_node_and_echoes_the_worlds_poses(up, tmp_path) -> None:
    import zenoh_ros2_sdk as sdk
    from zenoh_ros2_sdk.attachment import Attachment
    from zenoh_ros2_sdk.keyexpr import topic_keyexpr
    from zenoh_ros2_sdk.utils import ros2_to_dds_type

    offline_sdk_registry(tmp_path / "msgs")  # before any SDK session: offline definitions
    u = up("ros2", "--agents", str(AGENTS), "--episodes", "1", "--steps", "400", "--max-missed", "1")
    endpoint = u.wait_ticking()
    host, port = endpoint.removeprefix("tcp/").rsplit(":", 1)
    log = open(tmp_path / "ros2.log", "wb")
    bridge = subprocess.Popen([sys.executable, "-m", "truav.cli.swarm", "ros2", "--out", str(u.out)],
                              stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    log.close()
    world: dict[int, dict[int, tuple[float, float]]] = {i: {} for i in range(AGENTS)}  # uav -> tick -> pos
    lock = threading.Lock()
    echoed: dict[int, list] = {i: [] for i in range(AGENTS)}
    attachments: list[Attachment] = []
    subscribers = []
    session = None

    def obs(_key, msg, _r, _t) -> None:
        with lock:
            world[msg.uav][msg.tick] = (float(msg.pos[0]), float(msg.pos[1]))

    try:
        with Bus("observer", u.run, make_config(connect=[endpoint], connect_timeout_ms=5000)) as bus:
            bus.subscribe(keys.all_obs(u.run), obs)
            deadline = time.monotonic() + 90.0
            topics: dict[str, list[str]] = {}
            while time.monotonic() < deadline:  # the graph: every UAV's topic with its type
                assert bridge.poll() is None, (tmp_path / "ros2.log").read_text()
                topics = dict(sdk.get_topic_names_and_types(domain_id=0, router_ip=host, router_port=int(port)))
                if all(f"/truav/uav_{i}/pose" in topics for i in range(AGENTS)):
                    break
                time.sleep(0.2)
            session = sdk.ZenohSession.get_instance(host, int(port))
            info = sdk.get_topic_info("/truav/uav_0/pose", domain_id=0, router_ip=host, router_port=int(port),
                                      verbose=True)
            nodes = [str(r.ok.key_expr) for r in session.liveliness.get("@ros2_lv/0/*/*/*/NN/**", timeout=2.0)
                     if r.ok is not None]
            for i in range(AGENTS):
                subscribers.append(sdk.ROS2Subscriber(
                    f"/truav/uav_{i}/pose", POSE, lambda m, i=i: echoed[i].append(m), domain_id=0,
                    router_ip=host, router_port=int(port)))
            key = topic_keyexpr(0, "/truav/uav_1/pose", ros2_to_dds_type(POSE), subscribers[1].type_hash)
            raw = session.session.declare_subscriber(
                key, lambda s: attachments.append(Attachment.from_bytes(s.attachment.to_bytes())))
            while time.monotonic() < deadline and not (all(len(e) >= 5 for e in echoed.values())
                                                       and len(attachments) >= 5):
                assert bridge.poll() is None, (tmp_path / "ros2.log").read_text()
                time.sleep(0.1)
            raw.undeclare()
            for s in subscribers:  # no more echoes: the ones kept are the ones checked
                s.close()
            subscribers.clear()

            def unmatched() -> int:  # echoed poses whose observation has not reached the observer (yet)
                with lock:
                    return sum(not any(abs(m.pose.position.x - x) < 1e-9 and abs(m.pose.position.y - y) < 1e-9
                                       for x, y in world[i].values()) for i in range(AGENTS) for m in echoed[i])
            settle = time.monotonic() + 20.0  # a busy host delivers the last observations to the observer late
            while unmatched() and time.monotonic() < settle:
                time.sleep(0.2)
    finally:
        for s in subscribers:
            s.close()
        if session is not None:
            session.close()
        _stop(bridge)
    out = (tmp_path / "ros2.log").read_text()
    for i in range(AGENTS):
        assert topics.get(f"/truav/uav_{i}/pose") == [POSE], (topics, out)
        assert topics.get(f"/truav/uav_{i}/velocity") == ["geometry_msgs/msg/TwistStamped"], topics
    assert topics.get("/truav/markers") == ["visualization_msgs/msg/MarkerArray"], topics
    assert topics.get("/truav/metrics") == ["diagnostic_msgs/msg/DiagnosticArray"], topics
    assert info is not None and [(p.node_namespace, p.node_name) for p in info.publishers] == [("/truav", "bridge_ros2")]
    assert any(k.endswith("/NN/%/%truav/bridge_ros2") for k in nodes), nodes
    for i in range(AGENTS):
        assert len(echoed[i]) >= 5, ({k: len(v) for k, v in echoed.items()}, out)
        for m in echoed[i]:  # each pose is the world's position of that UAV at one of its ticks
            p = m.pose.position
            assert m.header.frame_id == "map" and p.z == UAV_ALTITUDE_M
            assert any(abs(p.x - x) < 1e-9 and abs(p.y - y) < 1e-9 for x, y in world[i].values()), (i, p, world[i])
    assert len(attachments) >= 5, out
    seqs = [a.sequence_id for a in attachments]
    assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs) and len({a.gid for a in attachments}) == 1
    assert all(len(a.gid) == 16 and abs(a.timestamp_ns - time.time_ns()) < 600e9 for a in attachments)
    assert bridge.returncode == 143, out  # SIGTERM: one line, 143
    assert "truav-swarm ros2: stopped: " in out and "Traceback" not in out


def test_a_goal_published_by_an_independent_rmw_zenoh_client_steers_that_uav(up, tmp_path) -> None:
    """zenoh-ros2-sdk sees the bridge's goal subscription (`ros2 topic info`), publishes a PoseStamped goal for
    UAV 1; the bridge sends it on as the operator's override: UAV 1 gets nearer the point tick after tick and
    the summary names the override."""
    import math
    import zenoh_ros2_sdk as sdk

    goal = (2500.0, 2500.0)
    offline_sdk_registry(tmp_path / "msgs")
    u = up("ros2goal", "--agents", str(AGENTS), "--episodes", "1", "--steps", "100000", "--max-missed", "1")
    endpoint = u.wait_ticking()
    host, port = endpoint.removeprefix("tcp/").rsplit(":", 1)
    log = open(tmp_path / "ros2.log", "wb")
    bridge = subprocess.Popen([sys.executable, "-m", "truav.cli.swarm", "ros2", "--out", str(u.out)],
                              stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    log.close()
    track: list[tuple[float, float]] = []
    pub = session = info = None
    at_goal = 0
    try:
        with Bus("observer", u.run, make_config(connect=[endpoint], connect_timeout_ms=5000)) as bus:
            bus.subscribe(keys.world_positions(u.run), lambda k, m, r, t: track.append(tuple(map(float, m.uavs[1]))))
            deadline = time.monotonic() + 90.0
            while time.monotonic() < deadline:  # the bridge's goal subscription in the graph
                assert bridge.poll() is None, (tmp_path / "ros2.log").read_text()
                info = sdk.get_topic_info("/truav/uav_1/goal", domain_id=0, router_ip=host, router_port=int(port),
                                          verbose=True)
                if info is not None and info.subscribers:
                    break
                time.sleep(0.2)
            session = sdk.ZenohSession.get_instance(host, int(port))
            pub = sdk.ROS2Publisher("/truav/uav_1/goal", POSE, domain_id=0, router_ip=host, router_port=int(port))
            t = session.store.types
            time.sleep(1.0)  # the publisher's interest reaches the bridge's subscriber
            at_goal = len(track)
            pub.publish(header=t["std_msgs/msg/Header"](stamp=t["builtin_interfaces/msg/Time"](sec=0, nanosec=0),
                                                        frame_id="map"),
                        pose=t["geometry_msgs/msg/Pose"](
                            position=t["geometry_msgs/msg/Point"](x=goal[0], y=goal[1], z=UAV_ALTITUDE_M),
                            orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)))
            while time.monotonic() < deadline and len(track) < at_goal + 25:
                assert bridge.poll() is None, (tmp_path / "ros2.log").read_text()
                time.sleep(0.1)
    finally:
        if pub is not None:
            pub.close()
        if session is not None:
            session.close()
        _stop(bridge)
    out = (tmp_path / "ros2.log").read_text()
    assert info is not None and [(s.node_namespace, s.node_name, s.topic_type) for s in info.subscribers] == \
        [("/truav", "bridge_ros2goal", POSE)], (info, out)
    after = [math.dist(p, goal) for p in track[at_goal:]]
    assert len(after) >= 25 and after[-1] < after[0] - 60.0, (after, out)  # 15 m a step at full speed
    assert all(b <= a + 1e-6 or b <= 15.0 for a, b in zip(after[10:], after[11:])), after  # nearer every step
    assert "1 goal(s) sent on as overrides, 0 refused" in out and "Traceback" not in out, out
    down = subprocess.run([sys.executable, "-m", "truav.cli.swarm", "down", "--out", str(u.out)],
                          capture_output=True, text=True, timeout=120)
    assert down.returncode == 0, down.stderr
    u.wait(timeout=120)
    assert "override: UAV 1 steered by operator from tick" in u.output(), u.output()
