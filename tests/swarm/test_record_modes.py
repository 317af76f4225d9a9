"""Recording in parts (by size, by duration, on command), remote pause/resume, and snapshot mode.

The writer-level tests drive recorder.parts.PartedLog and recorder.snapshot.SnapshotLog with
made-up times (no bus, no clock); the process tests start the recorder as a supervisor does
(recorder.process.recorder.spawn_recorder) on the module's loopback router and split, pause and snapshot
it over the bus and by signal. Every part and snapshot must be a finished file that the official
mcap reader and `truav log check` read, and the parts together must hold exactly what was sent.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import msgpack
import pytest
from mcap.reader import make_reader

from tests.support.waits import wait_until
from recorder.check import check
from recorder.mcap_log import McapLog, is_mirror_topic
from recorder.metadata import CONFIG_METADATA, RECORDING_METADATA, read_run_info
from recorder.parts import PartedLog, read_parts_index
from recorder.process.recorder import CONTROL_PART, spawn_recorder, stop_recorder, wait_until_recording
from recorder.reader import iter_messages, probe, read_metadata
from recorder.record_modes import (PART_FIELDS, PART_METADATA, PAUSE_METADATA, SNAPSHOT_METADATA, RecordModes,
                                   part_path, parts_index_path, snapshot_path)
from recorder.recover import recover
from recorder.snapshot import SnapshotLog
from truav.bus.transport import Bus
from truav.config import Config, to_toml
from truav.wire import keys, schema

REPO = Path(__file__).resolve().parents[2]
RUN = "modes"
S = 1_000_000_000
T0 = 1_700_000_000 * S
READY_S = 15.0
EXIT_S = 30.0
SETTLE_S = 0.3
COMMAND_S = 1.0  # a command sent: the recorder's writer has applied it (it looks between any two pulls)


def beacon(uav: int, seq: int) -> bytes:
    return msgpack.packb({"v": 1, "kind": "beacon", "src": f"uav/{uav}", "seq": seq, "t": T0 + seq, "inc": 7,
                          "uav": uav, "tick": seq, "pos": [float(seq), 1.0], "vel": [1.0, 0.0]})


def fault_start(seq: int) -> bytes:
    return msgpack.packb({"v": 1, "kind": "fault", "src": "supervisor", "seq": seq, "t": T0, "inc": 1,
                          "fault": "loss", "phase": "start", "target": "uav/1", "params": {"p": 0.5}})


def probe_finished(path: Path) -> bool:
    with open(path, "rb") as f:
        return probe(f).finished


def bus_messages(path: Path) -> list[tuple[str, bytes]]:
    """Every bus message of a finished file, read with the official reader (CRCs checked)."""
    out = []
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        assert reader.get_summary() is not None
        for _, channel, message in reader.iter_messages(log_time_order=False):
            if not is_mirror_topic(channel.topic):
                out.append((channel.topic, message.data))
    return out


def assert_valid_parts(paths: list[Path], sent: list[tuple[str, bytes]]) -> None:
    """Each part finished and clean (official reader, `truav log check`), with its part record; together,
    in order, exactly what was sent."""
    union: list[tuple[str, bytes]] = []
    sessions = set()
    for n, path in enumerate(paths, 1):
        union += bus_messages(path)
        report = check(path)
        assert report.finished and report.missing == 0 and report.corrupt_chunks == 0, (path, report.problems)
        meta = read_metadata(path)
        part = meta[PART_METADATA]
        assert set(part) == set(PART_FIELDS) and part["part"] == str(n)
        sessions.add(part["session"])
        assert meta[RECORDING_METADATA]["run"] == RUN and "toml" in meta.get(CONFIG_METADATA, {"toml": ""})
    assert len(sessions) == 1
    assert sorted(union) == sorted(sent) and len(union) == len(sent)


# --- writer level: parts -------------------------------------------------------------------------------
def make_log(path: Path) -> McapLog:
    return McapLog(path, flush_interval_s=1e9, mirrors=False)


def test_split_by_size_gives_bounded_self_contained_parts(tmp_path: Path) -> None:
    out = tmp_path / "run.mcap"
    # small chunks, as a live recorder closes one every 50 ms: a part ends once its chunks on disk hold 20 kB
    log = PartedLog(out, RecordModes(split_size_mb=0.02),
                    lambda p: McapLog(p, flush_interval_s=1e9, chunk_bytes=4000, mirrors=False),
                    repeat=(RECORDING_METADATA,))
    log.set_metadata(RECORDING_METADATA, {"run": RUN})
    sent = []
    for seq in range(600):
        for uav in range(3):
            item = (keys.uav_beacon(RUN, uav), beacon(uav, seq))
            log.write(*item, T0 + seq * S // 10)
            sent.append(item)
    log.close()
    paths = sorted(tmp_path.glob("run_*.mcap"))
    assert len(paths) >= 3 and paths == [part_path(out, n) for n in range(1, len(paths) + 1)]
    assert all(p.stat().st_size < 30_000 for p in paths)  # 20 kB + one chunk and a summary
    assert all(p.stat().st_size >= 20_000 for p in paths[:-1])
    assert_valid_parts(paths, sent)
    index = read_parts_index(out)
    assert [row["path"] for row in index["parts"]] == [p.name for p in paths]
    assert [row["reason"] for row in index["parts"]] == ["size"] * (len(paths) - 1) + ["end"]
    assert all(row["finished"] for row in index["parts"])
    # the parts' log-time ranges follow each other without overlap or hole in the messages
    ranges = [(int(read_metadata(p)[PART_METADATA]["first_log_time_ns"]),
               int(read_metadata(p)[PART_METADATA]["last_log_time_ns"])) for p in paths]
    assert all(a[1] <= b[0] for a, b in zip(ranges, ranges[1:]))


def test_split_by_duration_and_on_command(tmp_path: Path) -> None:
    now = [0.0]
    out = tmp_path / "run.mcap"
    log = PartedLog(out, RecordModes(split_duration_s=1.0), make_log, repeat=(RECORDING_METADATA,),
                    clock=lambda: now[0])
    log.set_metadata(RECORDING_METADATA, {"run": RUN})
    sent = []
    for seq in range(50):  # 5 s at 10 Hz: a part per second
        now[0] = seq / 10
        item = (keys.uav_beacon(RUN, 0), beacon(0, seq))
        log.write(*item, T0 + seq * S // 10)
        sent.append(item)
        if seq == 25:
            log.split("command")
    log.close()
    index = read_parts_index(out)
    reasons = [row["reason"] for row in index["parts"]]
    assert reasons.count("command") == 1 and reasons.count("duration") >= 4 and reasons[-1] == "end"
    assert_valid_parts(log.paths, sent)


def test_bad_mode_values_are_user_errors() -> None:
    from truav.errors import UserError
    for modes in (RecordModes(split_size_mb=0), RecordModes(split_duration_s=-1), RecordModes(snapshot="5"),
                  RecordModes(snapshot="-1:2"), RecordModes(snapshot="2:0"),
                  RecordModes(snapshot="2:2", split_size_mb=1)):
        with pytest.raises(UserError):
            modes.validate()


@pytest.mark.parametrize("argv, flag", [
    (["--split-size", "0"], "--split-size"), (["--split-duration", "-3"], "--split-duration"),
    (["--snapshot", "10"], "--snapshot"), (["--snapshot", "a:b"], "--snapshot"),
    (["--snapshot", "5:5", "--split-size", "10"], "--snapshot"),
])
def test_record_flags_bad_values_exit_2_in_one_line(tmp_path: Path, argv: list[str], flag: str) -> None:
    proc = subprocess.run([sys.executable, "-m", "truav.cli", "log", "record", "--run", RUN, "--out",
                           str(tmp_path / "x.mcap"), *argv], capture_output=True, text=True, timeout=60, cwd=REPO)
    assert proc.returncode == 2 and flag in proc.stderr and len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    assert not list(tmp_path.iterdir())


def test_parts_of_an_earlier_recording_are_not_overwritten_without_force(tmp_path: Path) -> None:
    part_path(tmp_path / "x.mcap", 1).write_bytes(b"earlier")
    proc = subprocess.run([sys.executable, "-m", "truav.cli", "log", "record", "--run", RUN, "--out",
                           str(tmp_path / "x.mcap"), "--split-size", "1"], capture_output=True, text=True, timeout=60,
                          cwd=REPO)
    assert proc.returncode == 2 and "x_0001.mcap exists; use --force" in proc.stderr, proc.stderr
    assert part_path(tmp_path / "x.mcap", 1).read_bytes() == b"earlier"


def test_up_passes_the_flags_and_checks_them() -> None:
    import argparse
    from recorder.process.recorder import recorder_argv
    from truav.cli.args import options_from
    from truav.cli.log_process import add_record_args
    modes = RecordModes(split_size_mb=5.0, split_duration_s=60.0, split_on_command=True)
    argv = recorder_argv(RUN, "r.mcap", modes=modes)
    assert options_from(RecordModes, add_record_args(argparse.ArgumentParser()).parse_args(argv[3:])) == modes
    proc = subprocess.run([sys.executable, "-m", "truav.cli.swarm", "up", "--split-size", "5"], capture_output=True,
                          text=True, timeout=60, cwd=REPO)
    assert proc.returncode == 2 and "--split-size" in proc.stderr and "--record" in proc.stderr, proc.stderr


# --- writer level: snapshots ------------------------------------------------------------------------------
def test_snapshot_on_a_fault_window_holds_before_to_after(tmp_path: Path) -> None:
    out = tmp_path / "run.mcap"
    clock = [T0]
    snap = SnapshotLog(out, before_s=2.0, after_s=1.0, max_bytes=10_000_000, make_log=make_log,
                       now_ns=lambda: clock[0])
    snap.set_metadata(RECORDING_METADATA, {"run": RUN})
    times = {}
    for seq in range(100):  # 10 s at 10 Hz; a fault starts at 5 s and again at 5.5 s (extends), another at 9.5 s
        t = T0 + seq * S // 10
        clock[0] = t
        item = (keys.uav_beacon(RUN, 0), beacon(0, seq))
        snap.write(*item, t)
        times[item[1]] = t
        if seq in (50, 55, 95):
            snap.write(keys.fault(RUN, "loss"), fault_start((50, 55, 95).index(seq)), t)
    snap.close()
    first, second = snapshot_path(out, 1), snapshot_path(out, 2)
    assert snap.paths == [first, second] and not out.exists()
    meta = read_metadata(first)[SNAPSHOT_METADATA]
    assert meta["trigger"] == "fault" and "loss fault starts on uav/1" in meta["what"]
    assert meta["trigger_time_ns"] == str(T0 + 5 * S) and meta["cut_short"] == "false"
    assert len(json.loads(meta["triggers"])) == 2
    got = [times[p] for k, p in bus_messages(first) if k == keys.uav_beacon(RUN, 0)]
    # from 2 s before the first trigger to 1 s after the second (5.5 s + 1 s)
    assert got == [T0 + seq * S // 10 for seq in range(30, 66)]
    assert check(first).finished and read_metadata(first)[RECORDING_METADATA]["run"] == RUN
    assert read_metadata(second)[SNAPSHOT_METADATA]["cut_short"] == "true"  # closed before its after-window ended


def test_snapshot_triggers_on_a_gap_and_on_missed_actions_and_the_ring_is_bounded(tmp_path: Path) -> None:
    out = tmp_path / "run.mcap"
    clock = [T0]
    snap = SnapshotLog(out, before_s=100.0, after_s=0.5, max_bytes=20_000, make_log=make_log,
                       now_ns=lambda: clock[0])
    for seq in list(range(200)) + [205]:  # 200 messages fill the 20 kB ring; then seq jumps by 5
        clock[0] = T0 + seq * S // 100
        snap.write(keys.uav_beacon(RUN, 0), beacon(0, seq), clock[0])
    assert snap.active and snap.evicted_for_bytes > 0
    clock[0] += S
    assert snap.maybe_flush()  # the after-window ended on a quiet bus: the snapshot is finished
    metrics = msgpack.packb({"v": 1, "kind": "metrics", "src": "world", "seq": 0, "t": T0, "scope": "step",
                             "tick": 9, "episode": 0, "values": {"uav.3.missed": 1.0}})
    snap.write(keys.metrics_step(RUN), metrics, clock[0])
    snap.close()
    kinds = [read_metadata(p)[SNAPSHOT_METADATA]["trigger"] for p in snap.paths]
    assert kinds == ["gap", "missed"]
    assert len(bus_messages(snap.paths[0])) < 200  # the byte cap dropped the oldest


# --- a cut file -----------------------------------------------------------------------------------------------
def test_a_part_cut_at_any_byte_recovers_every_chunk_before_the_cut(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    log = PartedLog(path, RecordModes(split_on_command=True),
                    lambda p: McapLog(p, flush_interval_s=1e9, chunk_bytes=2000, mirrors=False))
    for seq in range(300):
        log.write(keys.uav_beacon(RUN, seq % 3), beacon(seq % 3, seq), T0 + seq)
    log.close()
    part = part_path(path, 1)
    with open(part, "rb") as f:
        chunks = make_reader(f).get_summary().chunk_indexes
    assert len(chunks) > 10 and all(c.uncompressed_size <= 4_000_000 for c in chunks)
    all_msgs = [tuple(m) for m in iter_messages(part)]
    data = part.read_bytes()
    cuts = list(range(len(data) - 1, 40, -max(5, len(data) // 150)))
    for n, cut in enumerate(cuts):
        cut_path, out = tmp_path / "cut.mcap", tmp_path / "out.mcap"
        cut_path.write_bytes(data[:cut])
        if out.exists():
            out.unlink()
        whole = sum(1 for c in chunks if c.chunk_start_offset + c.chunk_length <= cut)
        if n % 50 == 0 and whole:  # the command a user runs, now and then (each is a process start)
            proc = subprocess.run([sys.executable, "-m", "truav.cli", "log", "recover", str(cut_path), str(out)],
                                  capture_output=True, text=True, timeout=60, cwd=REPO)
            assert proc.returncode == 0, proc.stderr
        else:
            recover(cut_path, out, zstd_level=3)
        got = [tuple(m) for m in iter_messages(out)]
        expected = sum(1 for m in all_msgs
                       if any(c.message_start_time <= m[2] <= c.message_end_time
                              for c in chunks if c.chunk_start_offset + c.chunk_length <= cut))
        assert got == all_msgs[:len(got)] and len(got) == expected, (cut, whole)


# --- the recorder process on a bus ------------------------------------------------------------------------
@pytest.fixture
def children():
    procs: list[subprocess.Popen] = []
    yield procs
    for proc in procs:
        if proc.poll() is None:
            proc.kill()
        proc.wait(timeout=EXIT_S)
        for stream in (proc.stdout, proc.stderr):
            if stream is not None:
                stream.close()


def start(children: list, endpoint: str, out: Path, *extra: str, modes: RecordModes | None = None,
          config: Path | None = None):
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    proc = spawn_recorder(RUN, out, [endpoint], extra=extra, env=env, stdout=subprocess.PIPE, config_toml=config,
                          stderr=subprocess.PIPE, **({} if modes is None else {"modes": modes}))
    children.append(proc)
    return proc


def ready(bus: Bus, proc: subprocess.Popen) -> None:
    if not wait_until_recording(bus, RUN, READY_S):
        proc.kill()
        raise AssertionError(f"recorder never became ready: {proc.communicate(timeout=EXIT_S)[1].decode()}")


class Counter:
    """The test's own raw subscriber: tells when the world messages published have crossed the bus."""

    def __init__(self) -> None:
        self.n = 0  # world messages received
        self.expected = 0  # world messages published

    def __call__(self, key: str, raw: bytes, recv_ns: int) -> None:
        if key in (keys.world_tick(RUN), keys.uav_obs(RUN, 0)):
            self.n += 1


def send(world: Bus, sent: list, counter: Counter, n: int) -> None:
    """n ticks of world messages (tick + one obs), then wait until they crossed the bus."""
    for _ in range(n):
        tick = counter.expected // 2
        for key, msg in ((keys.world_tick(RUN), schema.Tick(tick=tick, episode=0, sim_time=0.0, deadline_ms=80.0,
                                                           n_uavs=1)),
                         (keys.uav_obs(RUN, 0), schema.Obs(tick=tick, episode=0, uav=0, pos=(0.0, 0.0),
                                                          vehicles_in_range=0, queued_packets=0, relayed=0, covered=0,
                                                          energy_j=0.0, speed_max=1.0, done=False))):
            sent.append((key, schema.encode(world.publish(key, msg))))
            counter.expected += 1
    assert wait_until(lambda: counter.n >= counter.expected, 10.0)


def control(operator: Bus, command: str, sent: list) -> None:
    key = keys.control(RUN, CONTROL_PART)
    sent.append((key, schema.encode(operator.publish(key, schema.Control(command=command, args={})))))


def wait_parts(out: Path, n: int) -> None:
    assert wait_until(lambda: parts_index_path(out).exists() and len(read_parts_index(out)["parts"]) >= n, 10.0)


def test_split_on_bus_command_and_sighup_and_by_duration(tmp_path: Path, endpoint: str, bus_factory,
                                                        children) -> None:
    out, config = tmp_path / "run.mcap", tmp_path / "run.toml"
    config.write_text(to_toml(Config()))
    info = {"seed": 3, "lockstep": True}
    proc = start(children, endpoint, out, "--run-info", json.dumps(info), modes=RecordModes(split_on_command=True),
                 config=config)
    world, operator, counter = bus_factory("world"), bus_factory("supervisor"), Counter()
    bus_factory("view").subscribe_raw(keys.everything(RUN), counter)  # its own session: crossed the router
    ready(world, proc)
    sent: list[tuple[str, bytes]] = []
    send(world, sent, counter, 20)
    control(operator, "split", sent)
    wait_parts(out, 2)
    send(world, sent, counter, 20)
    proc.send_signal(signal.SIGHUP)
    wait_parts(out, 3)
    send(world, sent, counter, 20)
    time.sleep(SETTLE_S)
    assert stop_recorder(proc, EXIT_S) == 0
    stdout, stderr = proc.communicate(timeout=EXIT_S)
    assert "files: 3" in stdout.decode(), stdout.decode() + stderr.decode()
    index = read_parts_index(out)
    assert [row["reason"] for row in index["parts"]] == ["command", "signal", "end"]
    assert_valid_parts([part_path(out, n) for n in (1, 2, 3)], sent)
    assert all(read_metadata(part_path(out, n))[CONFIG_METADATA]["toml"] == config.read_text() for n in (1, 2, 3))
    assert all(read_run_info(part_path(out, n)) == info for n in (1, 2, 3))  # each part says how its run ran
    assert not out.exists()
    for n in (1, 2, 3):  # `truav log check`, as a user runs it
        proc = subprocess.run([sys.executable, "-m", "truav.cli", "log", "check", str(part_path(out, n))],
                              capture_output=True, text=True, timeout=60, cwd=REPO)
        assert proc.returncode == 0, proc.stdout + proc.stderr


def test_split_by_duration_in_the_process(tmp_path: Path, endpoint: str, bus_factory, children) -> None:
    out = tmp_path / "run.mcap"
    proc = start(children, endpoint, out, modes=RecordModes(split_duration_s=0.5))
    world, counter = bus_factory("world"), Counter()
    bus_factory("view").subscribe_raw(keys.everything(RUN), counter)  # its own session: crossed the router
    ready(world, proc)
    sent: list[tuple[str, bytes]] = []
    deadline = time.monotonic() + 20.0
    while len(read_parts_index(out)["parts"]) < 3 and time.monotonic() < deadline:
        send(world, sent, counter, 5)
        time.sleep(0.1)
    time.sleep(SETTLE_S)
    assert stop_recorder(proc, EXIT_S) == 0
    rows = read_parts_index(out)["parts"]
    assert len(rows) >= 3 and {row["reason"] for row in rows[:-1]} == {"duration"}
    assert_valid_parts([out.with_name(row["path"]) for row in rows], sent)


def test_remote_pause_and_resume(tmp_path: Path, endpoint: str, bus_factory, children) -> None:
    out = tmp_path / "run.mcap"
    proc = start(children, endpoint, out)
    world, operator, counter = bus_factory("world"), bus_factory("supervisor"), Counter()
    bus_factory("view").subscribe_raw(keys.everything(RUN), counter)  # its own session: crossed the router
    ready(world, proc)
    nobody = subprocess.run([sys.executable, "-m", "truav.cli", "log", "record-ctl", "pause", "--run", "other",
                             "--wait", "0.5", "-e", endpoint], capture_output=True, text=True, timeout=60, cwd=REPO)
    assert nobody.returncode == 1 and "no recorder of run other" in nobody.stderr
    kept: list[tuple[str, bytes]] = []
    commands: list[tuple[str, bytes]] = []  # recorded or not, depending on which comes first in the recorder
    send(world, kept, counter, 10)
    ctl = subprocess.run([sys.executable, "-m", "truav.cli", "log", "record-ctl", "pause", "--run", RUN, "-e",
                          endpoint], capture_output=True, text=True, timeout=60, cwd=REPO)  # as a user sends it
    assert ctl.returncode == 0 and f"sent pause to the recorder of run {RUN}" in ctl.stdout, ctl.stderr
    time.sleep(COMMAND_S)  # the pause reached the writer
    dropped: list[tuple[str, bytes]] = []
    send(world, dropped, counter, 10)
    time.sleep(SETTLE_S)
    control(operator, "resume", commands)
    time.sleep(COMMAND_S)
    send(world, kept, counter, 10)
    time.sleep(SETTLE_S)
    assert stop_recorder(proc, EXIT_S) == 0
    stdout = proc.communicate(timeout=EXIT_S)[0].decode()
    assert "paused by request" in stdout
    # the pause is a pause in the summary too, not "lost before the recorder" (as `truav log check` says below)
    assert "lost before the recorder (sequence gaps): 0;" in stdout, stdout
    got = bus_messages(out)
    assert not set(got) & set(dropped)
    assert set(kept) <= set(got)
    pause = read_metadata(out)[PAUSE_METADATA]
    assert pause["paused_by"] == "supervisor" and pause["resumed_by"] == "supervisor"
    assert int(pause["messages_not_recorded"]) >= len(dropped)
    report = check(out)  # the gap the pause left is not a loss
    assert report.finished and report.missing == 0 and report.paused >= len(dropped) and not report.problems
    proc = subprocess.run([sys.executable, "-m", "truav.cli", "log", "check", str(out)], capture_output=True,
                          text=True, timeout=60, cwd=REPO)
    assert proc.returncode == 0 and "not recorded while paused" in proc.stdout, proc.stdout + proc.stderr


def test_snapshot_on_a_fault_window_in_the_process(tmp_path: Path, endpoint: str, bus_factory, children) -> None:
    out = tmp_path / "run.mcap"
    proc = start(children, endpoint, out, modes=RecordModes(snapshot="1:1"))
    world, sup, counter = bus_factory("world"), bus_factory("supervisor"), Counter()
    bus_factory("view").subscribe_raw(keys.everything(RUN), counter)  # its own session: crossed the router
    ready(world, proc)
    sent: list[tuple[str, bytes]] = []
    send(world, sent, counter, 10)
    fault = schema.Fault(fault="loss", phase="start", target="uav/0", params={"p": 0.5})
    sent.append((keys.fault(RUN, "loss"), schema.encode(sup.publish(keys.fault(RUN, "loss"), fault))))
    send(world, sent, counter, 10)
    assert wait_until(lambda: snapshot_path(out, 1).exists(), 10.0)
    # the after-window ends: the recorder finishes the snapshot by itself, on a quiet bus too
    assert wait_until(lambda: probe_finished(snapshot_path(out, 1)), 10.0)
    proc.send_signal(signal.SIGUSR1)  # a second snapshot, by signal
    send(world, sent, counter, 5)
    assert wait_until(lambda: snapshot_path(out, 2).exists(), 10.0)
    time.sleep(SETTLE_S)
    assert stop_recorder(proc, EXIT_S) == 0
    meta = read_metadata(snapshot_path(out, 1))[SNAPSHOT_METADATA]
    assert meta["trigger"] == "fault" and meta["cut_short"] == "false"
    got = bus_messages(snapshot_path(out, 1))
    assert (keys.fault(RUN, "loss"), sent[20][1]) in got and set(got) <= set(sent) and len(got) >= 10
    t_fault = int(meta["trigger_time_ns"])
    for m in iter_messages(snapshot_path(out, 1)):
        assert t_fault - S <= m.log_time <= t_fault + S
    assert check(snapshot_path(out, 1)).finished
    assert read_metadata(snapshot_path(out, 2))[SNAPSHOT_METADATA]["trigger"] == "signal"
    assert not out.exists()


def test_under_secure_only_the_supervisor_may_command_the_recorder() -> None:
    """split/pause/resume/snapshot arrive on control/recorder: on a locked bus the router lets only the
    supervisor put there (the recorder trusts the router's ACL, not the envelope's src)."""
    from truav.bus import acl
    key = keys.control(RUN, CONTROL_PART)
    lines = acl.explain(acl.grants(RUN, 3), key=key)
    allowed = {line.split()[0] for line in lines if "may put" in line}
    assert allowed == {acl.SUPERVISOR}


def test_up_records_in_parts(tmp_path: Path, small_cfg) -> None:
    """`truav-swarm up --record --split-duration` hands the flag to its recorder: a tiny run in parts,
    every part clean, together every message the recorder counted."""
    from tests.support.runs import up_to_end
    record = tmp_path / "swarm.mcap"
    cfg = small_cfg.replace(scenario={"n_uavs": 2, "steps_per_episode": 10})
    out = up_to_end(tmp_path, "parts", cfg, "--episodes", "1", "--lockstep", "--record", str(record),
                    "--split-duration", "0.3")
    rows = read_parts_index(record)["parts"]
    assert len(rows) >= 2 and rows[-1]["reason"] == "end" and all(row["finished"] for row in rows)
    total = 0
    for row in rows:
        path = record.with_name(row["path"])
        report = check(path)
        assert report.finished and report.missing == 0 and report.corrupt_chunks == 0, (path, report.problems)
        total += len(bus_messages(path))
    assert total > 0 and not record.exists()
    recorder_log = (out / "logs" / "recorder.log").read_text()
    assert f"  {total} messages on" in recorder_log and f"files: {len(rows)} (" in recorder_log
    assert "parts listed in" in (tmp_path / "parts.log").read_text()


def test_split_by_size_in_the_process(tmp_path: Path, endpoint: str, bus_factory, children) -> None:
    out = tmp_path / "run.mcap"
    proc = start(children, endpoint, out, modes=RecordModes(split_size_mb=0.002))
    world, counter = bus_factory("world"), Counter()
    bus_factory("view").subscribe_raw(keys.everything(RUN), counter)  # its own session: crossed the router
    ready(world, proc)
    sent: list[tuple[str, bytes]] = []
    for _ in range(8):  # a burst every 0.1 s: chunks close every 50 ms, so parts fill up chunk by chunk
        send(world, sent, counter, 5)
        time.sleep(0.1)
    time.sleep(SETTLE_S)
    assert stop_recorder(proc, EXIT_S) == 0
    rows = read_parts_index(out)["parts"]
    assert len(rows) >= 3 and {row["reason"] for row in rows[:-1]} == {"size"}
    assert_valid_parts([out.with_name(row["path"]) for row in rows], sent)


def test_a_storm_of_triggers_does_not_make_one_endless_snapshot(tmp_path: Path) -> None:
    from recorder.snapshot import MIN_MAX_SPAN_S
    out = tmp_path / "run.mcap"
    clock = [T0]
    snap = SnapshotLog(out, before_s=0.5, after_s=0.5, max_bytes=10_000_000, make_log=make_log,
                       now_ns=lambda: clock[0])
    for n in range(600):  # a fault starting every 0.25 s for 150 s
        clock[0] = T0 + n * S // 4
        snap.write(keys.fault(RUN, "loss"), fault_start(n), clock[0])
    snap.close()
    assert len(snap.paths) == 3
    first = read_metadata(snap.paths[0])[SNAPSHOT_METADATA]
    assert first["at_span_limit"] == "true"
    assert int(first["window_end_ns"]) - int(first["window_start_ns"]) == int(MIN_MAX_SPAN_S * S)
