"""The recorder as a process on a real Zenoh bus (loopback router, free port).

Each test starts ``python -m recorder.process`` the way a supervisor does
(:func:`recorder.process.recorder.spawn_recorder`), waits for its liveliness token,
publishes through real Buses, and stops it by signal or control message.
Every child is killed by PID and reaped in a ``finally``; every wait is
bounded.  The SIGKILL test measures the loss window: how long before the
kill the oldest message missing from the recovered file was published.
"""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import msgpack
import pytest

from tests.support.waits import free_port, wait_until
from mcap.reader import make_reader

from recorder.check import check
from recorder.mcap_log import MIRROR_PREFIX, is_mirror_topic
from recorder.metadata import CONFIG_METADATA, RECORDING_METADATA, SUMMARY_METADATA
from truav.cli.log_process import main
from recorder.process.recorder import (
    CMD_STOP,
    CONTROL_PART,
    EXIT_FAILED,
    EXIT_USAGE,
    spawn_recorder,
    stop_recorder,
    wait_until_recording,
)
from recorder.reader import iter_messages, probe
from recorder.recover import recover
from truav.bus.transport import Bus
from truav.config import Config, to_toml
from truav.wire import keys, schema

REPO = Path(__file__).resolve().parents[2]
RUN = "rec_proc"
READY_S = 15.0
EXIT_S = 15.0
SETTLE_S = 0.3  # after the test's own subscriber saw everything: let the recorder's copy land too
MS = 1_000_000
N_UAVS = 20
TICK_S = 0.1
KILL_RATE_HZ = 1000.0
KILL_AFTER_S = 1.2
LOSS_WINDOW_NS = 100 * MS


@pytest.fixture
def children() -> Iterator[list[subprocess.Popen]]:
    procs: list[subprocess.Popen] = []
    yield procs
    for proc in procs:  # by PID, reaped
        if proc.poll() is None:
            proc.kill()
        proc.wait(timeout=EXIT_S)
        for stream in (proc.stdout, proc.stderr):
            if stream is not None:
                stream.close()


def start(children: list, endpoint: str, out: Path, *extra: str, config: Path | None = None,
          run: str = RUN) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    proc = spawn_recorder(run, out, [endpoint], config_toml=config, extra=extra, env=env,
                          stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    children.append(proc)
    return proc


def ready(bus: Bus, proc: subprocess.Popen, run: str = RUN) -> None:
    if not wait_until_recording(bus, run, READY_S):
        proc.kill()
        _, err = proc.communicate(timeout=EXIT_S)
        raise AssertionError(f"recorder never became ready: {err.decode()}")


class Sink:
    """The test's own raw subscriber: tells when everything published has crossed the bus."""

    def __init__(self) -> None:
        self.items: list[tuple[str, bytes]] = []
        self.lock = threading.Lock()

    def __call__(self, key: str, raw: bytes, recv_ns: int) -> None:
        with self.lock:
            self.items.append((key, raw))

    def count(self) -> int:
        with self.lock:
            return len(self.items)


def swarm_tick(seqs: dict[str, schema.Sequencer], tick: int) -> list[tuple[str, bytes]]:
    """One tick of a 20-agent swarm: tick, 20 x (obs, beacon, action), positions, step metrics."""
    def stamp(src: str, msg: schema.Message) -> bytes:
        seq = seqs.get(src) or seqs.setdefault(src, schema.Sequencer(src))
        return schema.encode(seq.stamp(msg))

    out = [(keys.world_tick(RUN), stamp("world", schema.Tick(tick=tick, episode=0, sim_time=float(tick),
                                                             deadline_ms=80.0, n_uavs=N_UAVS)))]
    for i in range(N_UAVS):
        out.append((keys.uav_obs(RUN, i), stamp("world", schema.Obs(
            tick=tick, episode=0, uav=i, pos=(10.0 * i, float(tick)), vehicles_in_range=3, queued_packets=1,
            relayed=2, covered=4, energy_j=5.0, speed_max=15.0, done=False))))
        out.append((keys.uav_beacon(RUN, i), stamp(f"uav/{i}", schema.Beacon(
            uav=i, tick=tick, pos=(10.0 * i, float(tick)), vel=(1.0, 0.0)))))
        out.append((keys.uav_action(RUN, i), stamp(f"uav/{i}", schema.Action(uav=i, tick=tick, action=tick % 16))))
    out.append((keys.world_positions(RUN), stamp("world", schema.Positions(
        tick=tick, uavs=[(10.0 * i, float(tick)) for i in range(N_UAVS)], vehicles=[(1.0, 2.0)] * 50))))
    out.append((keys.metrics_step(RUN), stamp("world", schema.Metrics(
        scope="step", tick=tick, episode=0, values={"coverage_pct": 50.0 + tick, "delivered": 3.0}))))
    return out


def test_records_a_swarm_and_finishes_the_file_on_sigterm(tmp_path: Path, endpoint: str, bus_factory,
                                                           children) -> None:
    out, summary_json, cfg_file = tmp_path / "run.mcap", tmp_path / "summary.json", tmp_path / "run.toml"
    cfg_text = to_toml(Config())
    cfg_file.write_text(cfg_text)
    proc = start(children, endpoint, out, "--summary-json", str(summary_json), config=cfg_file)
    world, sink = bus_factory("world"), Sink()
    world.subscribe_raw(keys.everything(RUN), sink)
    ready(world, proc)
    # a 20-agent swarm at 10 Hz for 1 s (630 msgs/s), in real time, all from one raw publisher
    seqs: dict[str, schema.Sequencer] = {}
    sent: list[tuple[str, bytes]] = []
    t0 = time.monotonic()
    for tick in range(10):
        batch = swarm_tick(seqs, tick)
        for k, payload in batch:
            world.publish_raw(k, payload)
        sent += batch
        time.sleep(max(t0 + (tick + 1) * TICK_S - time.monotonic(), 0.0))
    # typed publishers too, a fault, and a payload that is not msgpack (recorded raw)
    agent = bus_factory("uav/3")
    sent.append((keys.uav_beacon(RUN, 3), schema.encode(agent.publish(
        keys.uav_beacon(RUN, 3), schema.Beacon(uav=3, tick=99, pos=(1.0, 2.0), vel=(0.0, 0.0))))))
    fault = schema.Fault(fault="loss", phase="start", target="uav/3", params={"p": 0.5})
    sent.append((keys.fault(RUN, "loss"), schema.encode(world.publish(keys.fault(RUN, "loss"), fault))))
    world.publish_raw(keys.uav_obs(RUN, 0), b"\xc1 not msgpack")
    sent.append((keys.uav_obs(RUN, 0), b"\xc1 not msgpack"))
    assert wait_until(lambda: sink.count() >= len(sent), 10.0)
    time.sleep(SETTLE_S)
    assert stop_recorder(proc, EXIT_S) == 0
    stdout, stderr = proc.communicate(timeout=EXIT_S)
    # nothing but the line a recorder started alone prints as it starts (what it records, where)
    assert [line for line in stderr.decode().splitlines() if not line.startswith("recorder: recording run ")] == [], \
        stderr.decode()
    text = stdout.decode()
    assert text.startswith(f"recorder: run {RUN} -> {out} (SIGTERM)") and "lost in the recorder: 0" in text
    assert f"{len(sent)} messages on {len(set(k for k, _ in sent))} channels" in text

    # the official reader reads the finished file; one channel per key, same order per channel
    with open(out, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        got: dict[str, list[bytes]] = {}
        for _, channel, message in reader.iter_messages():
            if not is_mirror_topic(channel.topic):
                got.setdefault(channel.topic, []).append(message.data)
                if message.data != b"\xc1 not msgpack":
                    t = msgpack.unpackb(message.data)["t"]
                    assert message.publish_time == t <= message.log_time  # publish = sender, log = receive
        metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
    expected: dict[str, list[bytes]] = {}
    for k, payload in sent:
        expected.setdefault(k, []).append(payload)
    assert got == expected
    topics = {c.topic for c in summary.channels.values()}
    assert "/foxglove/log" in topics and MIRROR_PREFIX + keys.metrics_step(RUN) in topics
    assert metadata[CONFIG_METADATA]["toml"] == cfg_text
    assert metadata[CONFIG_METADATA]["scenario.n_uavs"] == "5"
    assert metadata[RECORDING_METADATA]["run"] == RUN
    assert metadata[SUMMARY_METADATA]["messages"] == str(len(sent))
    # nothing lost anywhere: no sequence gaps, and the JSON summary agrees
    report = check(out)
    assert report.finished and report.missing == 0 and report.messages == len(sent) and report.undecodable == 1
    data = json.loads(summary_json.read_text())
    assert data["messages"] == len(sent) and data["recorder_dropped"] == 0 and data["missing_by_seq"] == 0


def test_stops_on_control_message_and_on_sigint(tmp_path: Path, endpoint: str, bus_factory, children) -> None:
    first = start(children, endpoint, tmp_path / "a.mcap")
    second = start(children, endpoint, tmp_path / "b.mcap", run="other_run")
    operator = bus_factory("operator")
    ready(operator, first)
    ready(bus_factory("operator", "other_run"), second, run="other_run")
    operator.publish(keys.control(RUN, CONTROL_PART), schema.Control(command=CMD_STOP, args={}))
    assert first.wait(EXIT_S) == 0
    second.send_signal(signal.SIGINT)
    assert second.wait(EXIT_S) == 0
    out_a, out_b = first.communicate(timeout=EXIT_S)[0].decode(), second.communicate(timeout=EXIT_S)[0].decode()
    assert "(stop command from operator)" in out_a and "(SIGINT)" in out_b
    for name in ("a.mcap", "b.mcap"):
        with open(tmp_path / name, "rb") as f:
            assert probe(f).finished
    # the stop command itself was recorded; the other run's recorder saw nothing of this run
    assert [m.key for m in iter_messages(tmp_path / "a.mcap")] == [keys.control(RUN, CONTROL_PART)]
    assert list(iter_messages(tmp_path / "b.mcap")) == []


def test_sigkill_loses_at_most_100ms_and_recovers(tmp_path: Path, endpoint: str, bus_factory, children) -> None:
    """Publish at 1 kHz, SIGKILL the recorder, recover: everything published more than
    100 ms before the kill is in the file, in order, without gaps."""
    out = tmp_path / "killed.mcap"
    proc = start(children, endpoint, out)
    world = bus_factory("world")
    ready(world, proc)
    sent_ns: list[int] = []  # wall time of each put, index = seq
    stop = threading.Event()
    seq = schema.Sequencer("world")
    key = keys.uav_obs(RUN, 0)

    def publish() -> None:
        period, begin = 1.0 / KILL_RATE_HZ, time.monotonic()
        while not stop.is_set():
            msg = seq.stamp(schema.Obs(tick=len(sent_ns), episode=0, uav=0, pos=(0.0, 0.0), vehicles_in_range=0,
                                       queued_packets=0, relayed=0, covered=0, energy_j=0.0, speed_max=1.0,
                                       done=False))
            world.publish_raw(key, schema.encode(msg))
            sent_ns.append(msg.t)
            time.sleep(max(begin + len(sent_ns) * period - time.monotonic(), 0.0))

    thread = threading.Thread(target=publish, daemon=True)
    thread.start()
    try:
        time.sleep(KILL_AFTER_S + random.uniform(0.0, 0.06))  # land anywhere in the 50 ms flush cycle
        kill_ns = time.time_ns()
        os.kill(proc.pid, signal.SIGKILL)  # this child only
        assert proc.wait(EXIT_S) == -signal.SIGKILL
    finally:
        stop.set()
        thread.join(5.0)
    with open(out, "rb") as f:
        assert not probe(f).finished
    rep = recover(out, tmp_path / "recovered.mcap")
    assert rep.truncated and rep.clean
    seqs = [msgpack.unpackb(m.payload)["seq"] for m in iter_messages(tmp_path / "recovered.mcap")]
    assert seqs == list(range(len(seqs))) and len(seqs) > 0.5 * KILL_AFTER_S * KILL_RATE_HZ
    before_kill = sum(1 for t in sent_ns if t <= kill_ns)
    lost = before_kill - len(seqs)
    window_ns = kill_ns - sent_ns[len(seqs)] if lost > 0 else 0
    print(f"\nrecorder SIGKILL: {before_kill} published before the kill, {len(seqs)} recovered, {lost} lost; "
          f"oldest lost was published {window_ns / MS:.1f} ms before the kill")
    assert window_ns <= LOSS_WINDOW_NS


def test_user_mistakes_are_one_line_errors(tmp_path: Path, capsys) -> None:
    existing = tmp_path / "exists.mcap"
    existing.write_bytes(b"old")
    bad_toml = tmp_path / "bad.toml"
    bad_toml.write_text("scenario = [")
    cases = [
        (["--run", RUN, "--out", str(existing)], "exists; use --force"),
        (["--run", "bad/run", "--out", str(tmp_path / "x.mcap")], "run name"),
        (["--run", RUN, "--out", str(tmp_path / "nodir" / "x.mcap")], "does not exist"),
        (["--run", RUN, "--out", str(tmp_path / "x.mcap"), "--config-toml", str(tmp_path / "no.toml")],
         "config file not found"),
        (["--run", RUN, "--out", str(tmp_path / "x.mcap"), "--config-toml", str(bad_toml)], "not valid TOML"),
    ]
    for argv, message in cases:
        assert main(argv) == EXIT_USAGE
        err = capsys.readouterr().err
        assert message in err and err.count("\n") == 1 and "Traceback" not in err, err
    assert existing.read_bytes() == b"old" and not (tmp_path / "x.mcap").exists()


def test_unreachable_router_fails_cleanly(tmp_path: Path, capsys) -> None:
    out = tmp_path / "x.mcap"
    code = main(["--run", RUN, "--out", str(out), "-e", f"tcp/127.0.0.1:{free_port()}", "--router-wait", "0.2"])
    err = capsys.readouterr().err
    assert code == EXIT_FAILED and "could not record run" in err and "Traceback" not in err
    assert not out.exists()  # nothing half-made left behind
