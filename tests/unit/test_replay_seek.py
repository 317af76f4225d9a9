"""Seekable replay, engine level (no network): seek to a tick or a time, forwards and backwards,
while paused and while playing; after a seek each channel's last message before that point goes out
first; step and burst by world tick; rate and steps from the keyboard's keys; commands refused in one
line; a split recording played as one, in part order; --lockstep holds each tick for the gate.

The engine (:class:`recorder.replay.Replayer`) publishes through an injected function here; the bus
side (queryable, replay-ctl, control messages, status, a live agent in lock-step) is
tests/swarm/test_replay_ctl.py."""

from __future__ import annotations

import json
import threading
from pathlib import Path

import msgpack
import pytest

from recorder.mcap_log import McapLog
from recorder.replay import KEY_BINDINGS, LockstepGate, Replayer, ReplayOptions, ReplayUsageError, recording_info
from recorder.replay_source import resolve_parts
from tests.support.ticks import MS, PER_TICK, RUN, T0, landed_on, last_before, make_ticks, of_tick, write_ticks
from tests.support.waits import wait_until as _wait_until
from truav.wire import keys, schema

WAIT_S = 10.0


class Sink:
    def __init__(self) -> None:
        self.items: list[tuple[str, bytes]] = []
        self.lock = threading.Lock()

    def __call__(self, key: str, payload: bytes) -> None:
        with self.lock:
            self.items.append((key, payload))

    def count(self) -> int:
        with self.lock:
            return len(self.items)

    def ticks(self, start: int = 0) -> list[tuple[str, int]]:
        """(last key chunk(s), tick) of everything from ``start``."""
        with self.lock:
            return [(k.split("/", 2)[2], msgpack.unpackb(p)["tick"]) for k, p in self.items[start:]]


def wait_until(pred, timeout: float = WAIT_S) -> bool:
    return _wait_until(pred, timeout, 0.005)


def started(replayer: Replayer) -> threading.Thread:
    thread = threading.Thread(target=replayer.run, daemon=True)
    thread.start()
    return thread


def restored_at(written: list[tuple[str, bytes, int]], log_time: int) -> list[tuple[str, bytes]]:
    """Each channel's last message received before ``log_time``, in recorded order (a seek to that time)."""
    last: dict[str, tuple[str, bytes, int]] = {}
    for item in written:
        if item[2] < log_time:
            last[item[0]] = item
    return [(k, p) for k, p, _ in sorted(last.values(), key=lambda w: w[2])]


def test_seek_to_a_tick_restores_each_channel_then_steps_one_tick(tmp_path: Path) -> None:
    written = make_ticks(tmp_path / "r.mcap")
    sink = Sink()
    replayer = Replayer(ReplayOptions(path=tmp_path / "r.mcap", paused=True), sink)
    thread = started(replayer)
    try:
        replayer.command("seek", tick=40)  # forwards, while paused
        assert wait_until(lambda: sink.count() == PER_TICK)
        # a late joiner's state (tick 39 on every channel), then tick 40's world tick: it is at tick 40
        assert sink.items == landed_on(written, 40)
        assert replayer.status().tick == 40 and replayer.paused
        replayer.command("step")  # the rest of tick 40, then paused again
        assert wait_until(lambda: sink.count() == 2 * PER_TICK - 1)
        assert sink.items[PER_TICK:] == of_tick(written, 40)[1:] and replayer.status().tick == 40
        replayer.command("burst", n=3)
        assert wait_until(lambda: sink.count() == 5 * PER_TICK - 1)
        assert sink.items[2 * PER_TICK - 1:] == [m for t in (41, 42, 43) for m in of_tick(written, t)]
        replayer.command("seek", tick=5)  # backwards
        assert wait_until(lambda: sink.count() == 6 * PER_TICK - 1)
        assert sink.items[5 * PER_TICK - 1:] == landed_on(written, 5) and replayer.status().tick == 5
        replayer.command("step")
        assert wait_until(lambda: sink.count() == 7 * PER_TICK - 2)
        assert sink.items[6 * PER_TICK - 1:] == of_tick(written, 5)[1:]
        assert replayer.stats.restored == 2 * PER_TICK and replayer.stats.seeks == 2
    finally:
        replayer.quit()
        thread.join(WAIT_S)


def test_seek_by_time_forwards_and_backwards(tmp_path: Path) -> None:
    written = make_ticks(tmp_path / "r.mcap", ticks=60, gap_ms=100.0)  # 100 ms per tick, 1 us between its messages
    sink = Sink()
    replayer = Replayer(ReplayOptions(path=tmp_path / "r.mcap", paused=True), sink)
    thread = started(replayer)
    sent = 0

    def expect(items: list[tuple[str, bytes]]) -> None:
        nonlocal sent
        assert wait_until(lambda: sink.count() == sent + len(items))
        assert sink.items[sent:] == items
        sent += len(items)

    try:
        replayer.command("seek", s=2.0)  # tick 20 starts at 2.0 s
        expect(last_before(written, 20))
        replayer.command("step")
        expect(of_tick(written, 20))
        last_sent = T0 + 2_000 * MS + 4_000  # tick 20's last message
        replayer.command("seek", by=-1.0)  # back 1 s from there: into tick 10, before its last message
        expect(restored_at(written, last_sent - 1_000 * MS))
        assert replayer.status().tick == 10
        replayer.command("step")  # the rest of tick 10: its last message
        expect([of_tick(written, 10)[-1]])
        replayer.command("step")
        expect(of_tick(written, 11))
        replayer.command("seek", by=2.5)  # forward, from tick 11's last message
        expect(restored_at(written, T0 + 1_100 * MS + 4_000 + 2_500 * MS))
        assert replayer.status().tick == 36
        with pytest.raises(ValueError, match="outside the recording"):
            replayer.command("seek", s=60.0)
    finally:
        replayer.quit()
        thread.join(WAIT_S)


def test_seek_while_playing_restores_then_plays_on_from_there(tmp_path: Path) -> None:
    written = make_ticks(tmp_path / "r.mcap", ticks=400, gap_ms=10.0)  # 4 s at rate 1
    sink = Sink()
    replayer = Replayer(ReplayOptions(path=tmp_path / "r.mcap"), sink)
    thread = started(replayer)
    try:
        assert wait_until(lambda: sink.count() > 3 * PER_TICK)
        replayer.command("seek", tick=300)
        assert wait_until(lambda: replayer.stats.seeks == 1)
        replayer.command("seek", tick=100)  # and back
        thread.join(WAIT_S * 3)
        assert not thread.is_alive()
    finally:
        replayer.quit()
        thread.join(WAIT_S)
    items = sink.items
    restored_300, restored_100 = landed_on(written, 300), landed_on(written, 100)
    at_300 = next(i for i in range(len(items)) if items[i:i + PER_TICK] == restored_300)
    at_100 = next(i for i in range(at_300, len(items)) if items[i:i + PER_TICK] == restored_100)
    played_300 = [msgpack.unpackb(p)["tick"] for _, p in items[at_300 + PER_TICK:at_100]]
    assert played_300 == sorted(played_300) and (not played_300 or played_300[0] == 300)
    rest = items[at_100 + PER_TICK:]  # after tick 100's world tick to the end, every message in recorded order
    assert rest == [(k, p) for k, p, _ in written if msgpack.unpackb(p)["tick"] >= 100][1:]


def test_keys_set_the_rate_step_a_tick_and_seek(tmp_path: Path) -> None:
    """The keyboard's keys fed to the engine (the terminal itself: tests/swarm/test_replay.py's pty test)."""
    written = make_ticks(tmp_path / "r.mcap", ticks=100, gap_ms=100.0)  # 9.9 s
    sink = Sink()
    replayer = Replayer(ReplayOptions(path=tmp_path / "r.mcap", paused=True), sink)
    thread = started(replayer)
    try:
        assert replayer.key("+") and replayer.rate == 2.0
        assert replayer.key("+") and replayer.key("-") and replayer.rate == 2.0
        assert replayer.key("s")
        assert wait_until(lambda: sink.count() == PER_TICK)
        assert sink.items == of_tick(written, 0)
        assert replayer.key("b")  # burst: the next ten ticks
        assert wait_until(lambda: sink.count() == 11 * PER_TICK)
        assert {t for _, t in sink.ticks(PER_TICK)} == set(range(1, 11))
        assert replayer.key(".")  # forward 5 s from tick 10's last message: into tick 60
        assert wait_until(lambda: sink.count() == 12 * PER_TICK)
        assert sink.items[11 * PER_TICK:] == restored_at(written, T0 + 6_000 * MS + 4_000)
        assert replayer.key(",")  # back 5 s
        assert wait_until(lambda: sink.count() == 13 * PER_TICK)
        assert replayer.paused and not replayer.key("x")
        assert replayer.status().rate == 2.0 and replayer.status().paused
        for char in "g42\r":  # go to tick 42
            assert replayer.key(char)
        assert wait_until(lambda: sink.count() == 14 * PER_TICK)
        assert sink.items[13 * PER_TICK:] == landed_on(written, 42) and replayer.status().tick == 42
        for char in "t2.05\x7f\r":  # go to 2.0 s (typed 2.05, one deleted): tick 20
            assert replayer.key(char)
        assert wait_until(lambda: sink.count() == 15 * PER_TICK)
        assert sink.items[14 * PER_TICK:] == last_before(written, 20)
        for char in "g7\x1b":  # Esc: no seek
            assert replayer.key(char)
        with pytest.raises(ValueError, match="tick 999 is not in the replayed window"):
            for char in "g999\n":
                replayer.key(char)
        replayer.key("s")
        assert wait_until(lambda: sink.count() == 16 * PER_TICK)
        assert sink.items[15 * PER_TICK:] == of_tick(written, 20)  # still where the last seek went
    finally:
        replayer.quit()
        thread.join(WAIT_S)
    assert set(KEY_BINDINGS) >= {" ", "s", "b", "n", "+", "-", ",", ".", "0", "q"}


def test_bad_commands_are_one_line_errors(tmp_path: Path) -> None:
    make_ticks(tmp_path / "r.mcap", ticks=10)
    replayer = Replayer(ReplayOptions(path=tmp_path / "r.mcap", paused=True), Sink())
    for name, args, match in (("seek", {"tick": 99}, "tick 99 is not in the replayed window"),
                              ("seek", {}, "seek takes one of"), ("seek", {"s": 1.0, "tick": 2}, "seek takes one of"),
                              ("rate", {"rate": 0}, "rate takes"), ("rate", {}, "rate takes"),
                              ("step", {"n": 0}, "n must be"), ("burst", {"n": True}, "n must be"),
                              ("rewind", {}, "unknown replay command")):
        with pytest.raises(ValueError, match=match) as info:
            replayer.command(name, **args)
        assert "\n" not in str(info.value)


def test_a_split_recording_plays_as_one_in_part_order(tmp_path: Path) -> None:
    """Parts as the recorder writes them: <stem>_0001.mcap ... each with a truav.part record, and
    <stem>.parts.json; the index, any part, or the parts in any order play the whole run in order."""
    written: list[tuple[str, bytes, int]] = []
    parts = []
    for n, ticks in enumerate((range(0, 10), range(10, 25), range(25, 30)), start=1):
        part = tmp_path / f"run_{n:04d}.mcap"
        with McapLog(part) as log:
            rows = write_ticks(log, RUN, ticks, 10.0)
            written += rows
            log.set_metadata("truav.part", {"session": "abc", "part": str(n), "reason": "size",
                                            "first_log_time_ns": str(rows[0][2]), "last_log_time_ns": str(rows[-1][2])})
        parts.append(part)
    (tmp_path / "run.parts.json").write_text(json.dumps(
        {"version": 1, "session": "abc", "parts": [{"part": n, "path": p.name, "finished": True}
                                                   for n, p in enumerate(parts, start=1)]}))
    for given in ([tmp_path / "run.parts.json"], [parts[1]], [tmp_path / "run.mcap"], [parts[2], parts[0], parts[1]]):
        assert resolve_parts(given if len(given) > 1 else given[0]) == tuple(parts), given
        sink = Sink()
        stats = Replayer(ReplayOptions(path=tuple(given), rate=50.0), sink).run()
        assert sink.items == [(k, p) for k, p, _ in written] and stats.published == len(written)
    info = recording_info(tmp_path / "run.parts.json")
    assert info.paths == tuple(parts) and info.first_ns == written[0][2] and info.last_ns == written[-1][2]
    sink = Sink()
    replayer = Replayer(ReplayOptions(path=tmp_path / "run.parts.json", paused=True), sink)
    thread = started(replayer)
    try:
        replayer.command("seek", tick=26)  # in the third part: the state restored from the second
        assert wait_until(lambda: sink.count() == PER_TICK)
        assert sink.items == landed_on(written, 26)
    finally:
        replayer.quit()
        thread.join(WAIT_S)
    other = tmp_path / "other_0002.mcap"
    with McapLog(other) as log:
        write_ticks(log, RUN, range(40, 41), 10.0)
        log.set_metadata("truav.part", {"session": "zzz", "part": "2", "reason": "end",
                                        "first_log_time_ns": "", "last_log_time_ns": ""})
    with pytest.raises(ReplayUsageError, match="different recordings"):
        recording_info([parts[0], other])
    (tmp_path / "run.parts.json").write_text(json.dumps({"parts": [{"part": 1, "path": "gone.mcap"}]}))
    with pytest.raises(ReplayUsageError, match="missing"):
        recording_info(tmp_path / "run.parts.json")


class RecordingGate(LockstepGate):
    """A gate that notes what the engine tells it and lets every tick through."""

    def __init__(self) -> None:
        self.events: list[str] = []

    def published(self, key: str, payload: bytes) -> None:
        self.events.append(key.rsplit("/", 1)[1])

    def wait_answers(self, interrupted) -> None:
        self.events.append("wait")


def test_lockstep_asks_the_gate_before_every_tick_and_skips_recorded_actions(tmp_path: Path) -> None:
    path = tmp_path / "r.mcap"
    with McapLog(path) as log:
        write_ticks(log, RUN, range(5), 1000.0)  # 1 s apart: lock-step does not keep the recorded pace
        log.write(keys.uav_action(RUN, 0), schema.encode(schema.Sequencer("uav/0").stamp(
            schema.Action(uav=0, tick=4, action=3))), T0 + 4_500 * MS)
    gate, sink = RecordingGate(), Sink()
    stats = Replayer(ReplayOptions(path=path, lockstep=True), sink, gate=gate).run()
    assert stats.published == 5 * PER_TICK and not any(k.endswith("/action") for k, _ in sink.items)
    assert gate.events == [e for _ in range(5) for e in ("wait", "tick", "obs", "obs", "beacon", "step")]
