"""`truav log cut|merge|info`: a window by time or tick with the last-before messages kept, cuts merged back
into the recording they came from, split parts joined in order, per-topic/sender/kind counts.

No network: the recording is written in process by the recorder's own writer (McapLog, mirrors on) from
the wire schema's real message classes: a 4-UAV lock-step-like run over two episodes (global ticks, as
the world numbers them), with positions every 5 ticks, a loss fault window and the run's metadata.
"""

from __future__ import annotations

import contextlib
import io
import json
import subprocess
import sys
import zlib
from pathlib import Path
from typing import NamedTuple

import pytest
from mcap.reader import make_reader

from recorder.cut import CUT_METADATA, WindowSpec, cut
from recorder.info import RUN_METADATA, info
from recorder.mcap_log import McapLog
from recorder.merge import MERGE_METADATA, PART_METADATA, merge
from recorder.metadata import CONFIG_METADATA, RECORDING_METADATA, config_metadata
from recorder.reader import iter_messages, read_metadata
from truav.cli.main import main as truav_main
from truav.config import Config, to_toml
from truav.errors import UserError
from truav.wire import keys, schema

RUN = "cut"
T0 = 1_700_000_000_000_000_000
MS = 1_000_000
N_UAVS = 4
TICKS = 40  # two episodes of 19 steps + the episode's last observation
TICK_MS = 100


class Msg(NamedTuple):
    topic: str
    log_time: int
    publish_time: int
    data: bytes


def write_run(path: Path, ticks: range = range(TICKS), *, part: dict | None = None) -> None:
    """The messages of ``ticks`` (receive times fixed by the tick), metadata as the recorder writes it."""
    now = [T0]
    clock = lambda: now[0]  # noqa: E731  (the senders' envelope time: just before each message is received)
    senders = {"world": schema.Sequencer("world", clock=clock, incarnation=1),
               "supervisor": schema.Sequencer("supervisor", clock=clock, incarnation=99),
               **{keys.uav_identity(u): schema.Sequencer(keys.uav_identity(u), clock=clock, incarnation=10 + u)
                  for u in range(N_UAVS)}}

    def stamped(tick: int) -> list[tuple[str, bytes, int]]:
        out = []
        for key, src, message, log_time in _messages(tick):
            now[0] = log_time - MS // 2
            out.append((key, schema.encode(senders[src].stamp(message)), log_time))
        return out

    for tick in range(ticks.start):  # a later part numbers on from the earlier ones, as one sender does
        stamped(tick)
    with McapLog(path) as log:
        log.set_metadata(RECORDING_METADATA, {"run": RUN, "started_ns": str(T0), "host": "test"})
        log.set_metadata(CONFIG_METADATA, config_metadata(to_toml(Config())))
        log.set_metadata(RUN_METADATA, {"seed": "7", "scheme": '"truav"', "lockstep": "true", "episodes": "2"})
        for tick in ticks:
            for key, payload, log_time in stamped(tick):
                log.write(key, payload, log_time)
        if part is not None:
            log.set_metadata(PART_METADATA, part)


def _messages(tick: int) -> list[tuple[str, str, object, int]]:
    """(key, sender, message, receive time) of one tick."""
    t = T0 + tick * TICK_MS * MS
    episode = tick // 20
    out: list[tuple[str, str, object, int]] = [
        (keys.world_tick(RUN), "world", schema.Tick(tick=tick, episode=episode, sim_time=float(tick),
                                                    deadline_ms=80.0, n_uavs=N_UAVS), t)]
    for u in range(N_UAVS):
        out.append((keys.uav_obs(RUN, u), "world", schema.Obs(
            tick=tick, episode=episode, uav=u, pos=(1000.0 + 10 * tick + u, 2000.0 + 100 * u), vehicles_in_range=3,
            queued_packets=1, relayed=1, covered=3, energy_j=10.0, speed_max=15.0, done=tick % 20 == 19),
            t + (1 + u) * MS))
    if tick % 5 == 0:
        out.append((keys.world_positions(RUN), "world", schema.Positions(
            tick=tick, uavs=tuple((1000.0 + u, 2000.0) for u in range(N_UAVS)), vehicles=((0.0, 0.0), (250.0, 0.0))),
            t + 5 * MS))
    if tick % 20 != 19:  # the episode's last observation is not acted on
        for u in range(N_UAVS):
            src = keys.uav_identity(u)
            out.append((keys.uav_beacon(RUN, u), src, schema.Beacon(uav=u, tick=tick, pos=(1000.0 + u, 2000.0),
                                                                   vel=(1.0, 0.0)), t + (10 + u) * MS))
            out.append((keys.uav_action(RUN, u), src, schema.Action(uav=u, tick=tick, action=(tick + u) % 16),
                        t + (20 + u) * MS))
        out.append((keys.metrics_step(RUN), "world", schema.Metrics(
            scope="step", tick=tick, episode=episode, values={"pdr": 0.5, "coverage_pct": float(tick)}), t + 30 * MS))
    if tick in (8, 16):
        out.append((keys.fault(RUN, "loss"), "supervisor", schema.Fault(
            fault="loss", phase="start" if tick == 8 else "end", target="uav/1", params={"p": 0.5}), t + 40 * MS))
    return out


def all_messages(path: Path, mirrors: bool = True) -> list[Msg]:
    """Every message as the official reader gives it, in log-time order."""
    with open(path, "rb") as f:
        return [Msg(c.topic, m.log_time, m.publish_time, bytes(m.data))
                for _, c, m in make_reader(f).iter_messages(log_time_order=True)
                if mirrors or not c.topic.startswith("/")]


def tick_times(path: Path) -> dict[int, int]:
    return {schema.decode(m.data).tick: m.log_time for m in all_messages(path) if m.topic == keys.world_tick(RUN)}


@pytest.fixture
def recording(tmp_path: Path) -> Path:
    path = tmp_path / "run.mcap"
    write_run(path)
    return path


class Done(NamedTuple):
    returncode: int
    stdout: str
    stderr: str


def truav(*args: object) -> Done:
    """``truav log ARGS`` in process (the same main as the console script), its output captured."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = truav_main(["log", *map(str, args)])
        except SystemExit as exc:  # argparse's usage errors
            code = exc.code
    return Done(code, out.getvalue(), err.getvalue())


# --- cut ------------------------------------------------------------------------------------------------
def test_cut_by_tick_holds_the_tick_window_and_the_state_before_it(recording: Path, tmp_path: Path) -> None:
    out = tmp_path / "ticks.mcap"
    report = cut(recording, out, WindowSpec(from_tick=10, to_tick=14))
    times = tick_times(recording)
    start, end = times[10], times[15]
    original = all_messages(recording)
    inside = [m for m in original if start <= m.log_time < end]
    before: dict[str, Msg] = {}
    for m in original:
        if m.log_time < start:
            before[m.topic] = m
    got = all_messages(out)
    kept, window = got[:len(before)], got[len(before):]
    assert window == inside  # exactly the window, in order
    assert {m.topic for m in window if m.topic == keys.world_tick(RUN)} and \
        sorted(schema.decode(m.data).tick for m in window if m.topic == keys.world_tick(RUN)) == [10, 11, 12, 13, 14]
    # the last message of every channel before the window, stamped at its start, each listed in truav.cut
    assert report.kept == len(before) == len(kept)
    assert all(m.log_time == start for m in kept)
    assert {(m.topic, m.publish_time, m.data) for m in kept} == {(m.topic, m.publish_time, m.data)
                                                                 for m in before.values()}
    meta = read_metadata(out)
    listed = json.loads(meta[CUT_METADATA]["kept"])
    assert sorted((t, lt, pub, crc) for t, lt, pub, crc in listed) == sorted(
        (m.topic, m.log_time, m.publish_time, zlib.crc32(m.data)) for m in before.values())
    assert meta[CUT_METADATA]["from_tick"] == "10" and meta[CUT_METADATA]["to_tick"] == "14"
    assert meta[CUT_METADATA]["source"] == recording.name
    for name in (RECORDING_METADATA, CONFIG_METADATA, RUN_METADATA):  # the run's metadata travels with the cut
        assert meta[name] == read_metadata(recording)[name]


def test_cut_by_time_and_topics(recording: Path, tmp_path: Path) -> None:
    """--start/--end seconds, --topics and --exclude; a JSON mirror goes with the key it mirrors."""
    out = tmp_path / "uav1.mcap"
    cut(recording, out, WindowSpec(start_s=1.0, end_s=2.5), include=["truav/*/uav/1/*", "truav/*/metrics/*"],
        exclude=["*/action"])
    first = all_messages(recording)[0].log_time
    start, end = first + 1_000_000_000, first + 2_500_000_000
    topics = {keys.uav_obs(RUN, 1), keys.uav_beacon(RUN, 1), keys.metrics_step(RUN),
              "/json/" + keys.metrics_step(RUN)}
    got = all_messages(out)
    assert {m.topic for m in got} == topics
    assert [m.log_time for m in got[:len(topics)]] == [start] * len(topics)  # one kept per channel
    assert got[len(topics):] == [m for m in all_messages(recording) if m.topic in topics and start <= m.log_time < end]
    # the command line's spelling, !PATTERN excluding as replay's --topics does
    again = tmp_path / "again.mcap"
    done = truav("cut", recording, again, "--start", "1", "--end", "2.5", "--topics", "truav/*/uav/1/*",
                 "truav/*/metrics/*", "!*/action")
    assert done.returncode == 0 and "last-before messages kept" in done.stdout, done.stderr
    assert all_messages(again) == got


def test_cut_then_merge_gives_back_every_message(recording: Path, tmp_path: Path) -> None:
    """Three cuts (by tick, by time, by tick to the end) merged: the original's messages, each once."""
    times = tick_times(recording)
    first = all_messages(recording)[0].log_time
    pieces = [tmp_path / n for n in ("a.mcap", "b.mcap", "c.mcap")]
    cut(recording, pieces[0], WindowSpec(to_tick=11))
    cut(recording, pieces[1], WindowSpec(start_ns=times[12], end_s=(times[27] - first) / 1e9))
    cut(recording, pieces[2], WindowSpec(from_tick=27))
    out = tmp_path / "merged.mcap"
    report = merge(out, [pieces[2], pieces[0], pieces[1]])  # any order: log time decides
    assert all_messages(out) == all_messages(recording)
    assert report.duplicates == report.restored > 0  # the kept messages, restored, duplicate the earlier cut's
    assert json.loads(read_metadata(out)[MERGE_METADATA]["duplicates_dropped"]) == report.duplicates
    assert truav("check", out).returncode == 0  # no gaps, no duplicates by seq


def test_overlapping_cuts_merge_without_duplicates(recording: Path, tmp_path: Path) -> None:
    a, b = tmp_path / "a.mcap", tmp_path / "b.mcap"
    cut(recording, a, WindowSpec(end_s=2.0))
    cut(recording, b, WindowSpec(start_s=1.0))
    merge(tmp_path / "m.mcap", [a, b])
    assert all_messages(tmp_path / "m.mcap") == all_messages(recording)


def test_split_parts_are_joined_in_part_order(tmp_path: Path) -> None:
    """Parts of one split recording (truav.part records, named as the recorder names them) merge into the run."""
    whole = tmp_path / "whole.mcap"
    write_run(whole)
    bounds = [(0, 13), (13, 26), (26, TICKS)]
    parts = []
    for n, (lo, hi) in enumerate(bounds, 1):
        path = tmp_path / f"rec_{n:04d}.mcap"
        write_run(path, range(lo, hi), part={"session": "abc", "part": str(n), "reason": "size",
                                             "first_log_time_ns": "", "last_log_time_ns": ""})
        parts.append(path)
    index = tmp_path / "rec.parts.json"
    index.write_text(json.dumps({"version": 1, "session": "abc",
                                 "parts": [{"part": n, "path": p.name} for n, p in enumerate(parts, 1)]}))
    for given in ([parts[2], parts[0], parts[1]], [index]):
        out = tmp_path / "joined.mcap"
        report = merge(out, given)
        assert [i.part_number for i in report.inputs] == [1, 2, 3]
        # bus messages: each part's writer logs its own "joined" lines to the Foxglove mirror
        assert all_messages(out, mirrors=False) == all_messages(whole, mirrors=False)
        assert PART_METADATA not in read_metadata(out)  # folded into truav.merge
        assert json.loads(read_metadata(out)[MERGE_METADATA]["sessions"]) == {"abc": [1, 2, 3]}
        out.unlink()
    report = merge(tmp_path / "holes.mcap", [parts[0], parts[2]])
    assert report.missing_parts == {"abc": [2]}


# --- info -----------------------------------------------------------------------------------------------
def test_info_counts_equal_the_readers(recording: Path) -> None:
    result = info(recording)
    per_topic: dict[str, int] = {}
    per_sender: dict[str, int] = {}
    per_kind: dict[str, int] = {}
    for key, payload, _, _ in iter_messages(recording):
        per_topic[key] = per_topic.get(key, 0) + 1
        env = schema.decode(payload)
        per_sender[env.src] = per_sender.get(env.src, 0) + 1
        per_kind[env.KIND] = per_kind.get(env.KIND, 0) + 1
    assert {k: t.count for k, t in result.topics.items()} == per_topic
    assert {k: t.count for k, t in result.senders.items()} == per_sender
    assert {k: t.count for k, t in result.kinds.items()} == per_kind
    assert result.messages == sum(per_topic.values())
    assert result.mirror_messages == sum(1 for _ in iter_messages(recording, include_mirrors=True)) - result.messages
    assert sum(s.missing for s in result.streams) == 0
    assert result.ticks == (0, TICKS - 1) and result.episodes == (0, 1)
    assert [(f["fault"], f["target"]) for f in result.faults] == [("loss", "uav/1")]
    assert result.faults[0]["end_s"] - result.faults[0]["start_s"] == pytest.approx(0.8)
    assert result.run_facts()["seed"] == 7 and result.run_facts()["scheme"] == "truav"
    assert result.topics[keys.world_tick(RUN)].rate_hz == pytest.approx(1e3 / TICK_MS)
    as_json = json.loads(json.dumps(result.as_json()))
    assert as_json["topics"][keys.world_tick(RUN)]["messages"] == TICKS


def test_info_cli_of_a_cut_and_its_json(recording: Path, tmp_path: Path) -> None:
    out = tmp_path / "c.mcap"
    assert truav("cut", recording, out, "--from-tick", "5", "--to-tick", "9").returncode == 0
    text = truav("info", out)
    assert text.returncode == 0, text.stderr
    assert "cut from run.mcap" in text.stdout and "ticks 5..9" in text.stdout and "seed 7" in text.stdout
    assert "loss" in text.stdout  # the fault window starting at tick 8
    done = subprocess.run([sys.executable, "-m", "truav.cli", "log", "info", "--json", str(recording), str(out)],
                          capture_output=True, text=True, timeout=120)  # the command as a user runs it
    rows = json.loads(done.stdout)
    assert [Path(r["path"]).name for r in rows] == ["run.mcap", "c.mcap"]
    assert rows[1]["cut"]["from_tick"] == "5" and rows[1]["kept"] == rows[1]["cut"]["kept_before"] > 0
    assert sum(t["kept"] for t in [*rows[1]["topics"].values(), *rows[1]["mirrors"].values()]) == rows[1]["kept"]
    # the kept messages are not sequence gaps
    assert all(s["missing"] == 0 for s in rows[1]["streams"])


# --- mistakes ---------------------------------------------------------------------------------------------
def test_bad_inputs_are_one_line_exit_2(recording: Path, tmp_path: Path) -> None:
    text = tmp_path / "notes.txt"
    text.write_text("not a recording\n")
    unfinished = tmp_path / "unfinished.mcap"
    log = McapLog(unfinished)
    log.write(keys.world_tick(RUN), schema.encode(schema.Sequencer("world").stamp(schema.Tick(
        tick=0, episode=0, sim_time=0.0, deadline_ms=80.0, n_uavs=1))), T0)
    log.flush()  # a recorder that died: no summary
    exists = tmp_path / "exists.mcap"
    exists.write_bytes(b"")
    out = tmp_path / "out.mcap"
    cases = [
        (("cut", text, out, "--end", "1"), "not an MCAP file"),
        (("cut", tmp_path / "missing.mcap", out), "no such file"),
        (("cut", unfinished, out), "unfinished"),
        (("cut", recording, exists, "--end", "1"), "exists; use --force"),
        (("cut", recording, out, "--start", "100"), "holds no message"),
        (("cut", recording, out, "--start", "2", "--end", "1"), "must end after it starts"),
        (("cut", recording, out, "--from-tick", "500"), "no world tick"),
        (("cut", recording, out, "--from-tick", "3", "--end", "1"), "by tick or by time"),
        (("cut", recording, out, "--topics", "truav/*/nothing"), "matches no recorded key"),
        (("cut", recording, out, "--start", "-1"), "--start"),
        (("merge", out, recording, text), "not an MCAP file"),
        (("merge", exists, recording), "exists; use --force"),
        (("merge", recording, recording, "--force"), "also an input"),
        (("merge", out, unfinished), "unfinished"),
        (("info", recording, text), "not an MCAP file"),
    ]
    for args, words in cases:
        done = truav(*args)
        lines = done.stderr.strip().splitlines()
        assert done.returncode == 2 and len(lines) == 1 and words in lines[0], (args, done.stderr)
        assert not out.exists() and not Path(str(out) + ".part").exists()
    assert exists.read_bytes() == b""
    done = truav("info", unfinished)  # info reads what an unfinished file holds, and says so
    assert done.returncode == 0 and "UNFINISHED" in done.stdout and "1 bus messages" in done.stdout


def test_api_errors_are_user_errors(recording: Path, tmp_path: Path) -> None:
    with pytest.raises(UserError, match="holds no message"):
        cut(recording, tmp_path / "x.mcap", WindowSpec(start_s=1e6))
    assert not (tmp_path / "x.mcap").exists()
