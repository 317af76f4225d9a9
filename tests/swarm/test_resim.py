"""`truav log resim`: a recorded lock-step run, re-simulated in process, is reproduced bit for bit; a recording
changed in one action is caught at that tick and key; a what-if branched at a tick under the recorded policy
equals the run from there on, under another policy it reports the difference.

One lock-step swarm of 5 agents (2 short episodes) is recorded once for the module (`truav-swarm up
--lockstep --record`, tests/support/runs.py up_to_end); altered copies are written with mcap's own reader and writer.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Callable

import msgpack
import pytest
from mcap.reader import make_reader
from mcap.writer import Writer

from tests.support.runs import up_to_end
from recorder.metadata import RUN_METADATA
from recorder.resim import Resimulation, load_run, payload_fields
from recorder.resim_branch import run_branch
from truav.cli.main import main as truav_main
from truav.config import Config
from truav.wire import keys

RUN = "resim"
SEED = 3
EPISODES = 2
CFG = Config().replace(scenario={"n_vehicles": 60, "steps_per_episode": 8, "n_uavs": 5},
                       roads={"warmup_steps": 10}, learner={"episodes": EPISODES})
TICKS = EPISODES * (CFG.scenario.steps_per_episode + 1)
ALTERED_TICK, ALTERED_UAV = 5, 2
BRANCH_TICK = 11  # in episode 1 (ticks 9-17)
SNAPSHOT_EVERY = 4  # snapshots at ticks 0, 4, 8, 12, 16: a branch at 11 restores the one of tick 8


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    tmp = tmp_path_factory.mktemp("resim")
    path = tmp / "lockstep.mcap"
    up_to_end(tmp, RUN, CFG, "--lockstep", "--seed", str(SEED), "--episodes", str(EPISODES), "--record", str(path),
              "--snapshot-every", str(SNAPSHOT_EVERY))
    return path


def rewrite(src: Path, dst: Path, payload: Callable[[str, bytes], bytes | None] = lambda _k, d: d,
            metadata: Callable[[str, dict], dict | None] = lambda _n, m: m) -> Path:
    """A copy of ``src`` with every message's payload through ``payload(topic, data)`` and every metadata record
    through ``metadata(name, map)`` (None drops either)."""
    with open(src, "rb") as f, open(dst, "wb") as g:
        reader = make_reader(f)
        writer = Writer(g)
        writer.start()
        for record in reader.iter_metadata():
            kept = metadata(record.name, dict(record.metadata))
            if kept is not None:
                writer.add_metadata(record.name, kept)
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            if schema is not None and schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in channels:
                channels[channel.id] = writer.register_channel(channel.topic, channel.message_encoding,
                                                               schemas.get(channel.schema_id, 0), channel.metadata)
            data = payload(channel.topic, message.data)
            if data is not None:  # None: the message is left out
                writer.add_message(channels[channel.id], message.log_time, data, message.publish_time,
                                   message.sequence)
        writer.finish()
    return dst


def resim(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = truav_main(["log", "resim", *map(str, argv), "--quiet"])
    out, err = capsys.readouterr()
    return code, out, err


def fresh(path: Path) -> tuple:
    rec = load_run(path)
    return rec, Resimulation(rec.cfg, rec.seed, rec.episodes)


def test_a_recorded_lockstep_run_is_reproduced_bit_for_bit(recording: Path, capsys) -> None:
    code, out, err = resim(capsys, recording)
    assert code == 0, out + err
    total = TICKS * CFG.scenario.n_uavs
    assert f"{TICKS} ticks re-simulated: {3 * total} of {3 * total} messages reproduced bit for bit" in out
    assert f"{total}/{total} obs, {total}/{total} beacon, {total}/{total} action" in out
    assert "result: reproduced" in out
    snapshots = len(range(0, TICKS, SNAPSHOT_EVERY))
    assert f"{snapshots} of {snapshots} recorded state snapshot(s) equal the re-simulated state" in out


def test_one_altered_action_is_reported_at_its_tick_and_key(recording: Path, tmp_path: Path, capsys) -> None:
    action_key = keys.uav_action(RUN, ALTERED_UAV)
    was: list[int] = []

    def alter(topic: str, data: bytes) -> bytes:
        if topic != action_key:
            return data
        body = msgpack.unpackb(data, raw=False)
        if body.get("tick") == ALTERED_TICK:
            was.append(body["action"])
            body["action"] = (body["action"] + 1) % 16
            return msgpack.packb(body, use_bin_type=True)
        return data

    altered = rewrite(recording, tmp_path / "altered.mcap", alter)
    assert len(was) == 1
    code, out, err = resim(capsys, altered)
    assert code == 1, out + err
    first = next(line for line in out.splitlines() if line.startswith("first divergence:"))
    assert first == (f"first divergence: tick {ALTERED_TICK}, {action_key}, action: recorded {(was[0] + 1) % 16}, "
                     f"re-simulated {was[0]}")
    # the re-simulation follows its own decisions, which are the run's: only the altered message differs
    assert "result: NOT reproduced (1 divergent message(s))" in out


def test_a_branch_under_the_recorded_policy_equals_the_run_from_its_tick_on(recording: Path, tmp_path: Path,
                                                                           capsys) -> None:
    rec, sim = fresh(recording)
    result = run_branch(recording, rec.run, rec, sim, BRANCH_TICK)
    assert result.snapshot_tick == 8 and result.restored.ticks == BRANCH_TICK - 8
    assert result.restored.divergent_messages == 0
    assert result.from_episode == 1 and result.changes == []
    assert result.after.ticks == TICKS - BRANCH_TICK and result.after.exact and result.departed is None
    for episode in range(EPISODES):  # the world's recorded episode metrics, value for value
        recorded = result.recorded[episode]
        assert recorded and all(result.branch[episode][k] == v for k, v in recorded.items()), episode
    code, out, err = resim(capsys, recording, "--from", BRANCH_TICK, "--out", tmp_path / "same")
    assert code == 0, out + err
    assert f"the branch equals the recorded run from tick {BRANCH_TICK} on" in out
    assert "branch: nothing changed (the recorded policy)" in out
    assert f"restored at tick {BRANCH_TICK} (episode 1) from the recording's snapshot of tick 8, re-simulating " \
           f"ticks 8-{BRANCH_TICK - 1}" in out


def branch_rounds(recording: Path, snapshots: bool) -> tuple:
    """A greedy branch at BRANCH_TICK: its result and every round it ran from its tick on (payload fields)."""
    rec, sim = fresh(recording)
    rounds: list = []

    def keep(rnd, _divergent: int) -> None:
        if rnd.tick >= BRANCH_TICK:
            rounds.append(([payload_fields(m) for m in rnd.obs + rnd.beacons + rnd.actions],
                           None if rnd.summary is None else {k: repr(v) for k, v in rnd.summary.items()}))
    result = run_branch(recording, rec.run, rec, sim, BRANCH_TICK, greedy=True, on_round=keep, snapshots=snapshots)
    return result, rounds, sim


def test_a_branch_from_a_snapshot_equals_the_branch_from_tick_0(recording: Path) -> None:
    snap, snap_rounds, snap_sim = branch_rounds(recording, snapshots=True)
    full, full_rounds, full_sim = branch_rounds(recording, snapshots=False)
    assert snap.snapshot_tick == 8 and full.snapshot_tick is None and full.restored.ticks == BRANCH_TICK
    assert len(snap_rounds) == TICKS - BRANCH_TICK and snap_rounds == full_rounds  # every message, every metric
    assert snap.after.divergent_messages == full.after.divergent_messages > 0  # greedy departs from the run
    assert snap.branch[1] == full.branch[1]
    for a, b in zip(snap_sim.agents, full_sim.agents):
        assert (a.learners.q == b.learners.q).all()


def test_a_recording_without_snapshots_branches_from_tick_0_and_says_so(recording: Path, tmp_path: Path,
                                                                         capsys) -> None:
    bare = rewrite(recording, tmp_path / "bare.mcap",
                   lambda topic, data: None if topic.endswith("/" + keys.SNAPSHOT) else data)
    code, out, err = resim(capsys, bare, "--from", BRANCH_TICK, "--out", tmp_path / "bare")
    assert code == 0, out + err
    assert (f"from tick 0 (the recording holds no snapshot at or before tick {BRANCH_TICK}), re-simulating ticks "
            f"0-{BRANCH_TICK - 1}") in out
    assert f"the branch equals the recorded run from tick {BRANCH_TICK} on" in out


def test_a_branch_under_another_policy_reports_how_the_outcome_differs(recording: Path, tmp_path: Path,
                                                                      capsys) -> None:
    out_dir = tmp_path / "greedy"
    code, out, err = resim(capsys, recording, "--from", BRANCH_TICK, "--greedy", "--set", "learner.w_overlap=0.5",
                           "--out", out_dir)
    assert code == 0, out + err
    assert "branch: learner.w_overlap=0.5, greedy, not learning" in out
    assert f"the branch departs from the recorded run at tick {BRANCH_TICK}, " in out
    with open(out_dir / "whatif.csv") as f:
        rows = list(csv.DictReader(f))
    assert [int(r["episode"]) for r in rows] == list(range(EPISODES))
    before, after = rows[0], rows[1]
    assert before["branched"] == "0" and after["branched"] == "1"
    assert all(before[f"{k}_recorded"] == before[f"{k}_branch"] for k in ("coverage_pct", "pdr", "energy_j"))
    assert after["energy_j_recorded"] != after["energy_j_branch"]  # the UAVs flew otherwise
    assert (out_dir / "whatif.png").stat().st_size > 0


def test_recordings_and_flags_it_cannot_use_are_one_line_errors(recording: Path, tmp_path: Path, capsys) -> None:
    def with_run_info(name: str, change: Callable[[dict], dict | None]) -> Path:
        def meta(record: str, values: dict) -> dict | None:
            if record != RUN_METADATA:
                return values
            info = change({k: json.loads(v) for k, v in values.items()})
            return None if info is None else {k: json.dumps(v) for k, v in info.items()}
        return rewrite(recording, tmp_path / name, metadata=meta)

    cases = [
        ((with_run_info("old.mcap", lambda info: None),), "not a lock-step TRUAV run recording"),
        ((with_run_info("realtime.mcap", lambda info: {**info, "lockstep": False}),), "a real-time run"),
        ((recording, "--greedy"), "--greedy changes a what-if branch: give --from TICK"),
        ((recording, "--from", TICKS), f"--from {TICKS}: the run has ticks 0-{TICKS - 1}"),
        ((recording, "--from", 3, "--set", "scenario.n_uavs=3"), "--set scenario.n_uavs: a branch restores"),
        ((recording, "--from", 3, "--qtable", tmp_path / "none"), "none"),
        ((tmp_path / "missing.mcap",), "no such file"),
    ]
    for argv, expected in cases:
        code, out, err = resim(capsys, *argv)
        assert code == 2, (argv, out, err)
        lines = err.strip().splitlines()
        assert len(lines) == 1 and expected in lines[0] and "Traceback" not in err, (argv, err)


def test_a_cut_from_mid_run_is_refused_a_check_from_tick_0_and_branches(recording: Path, tmp_path: Path,
                                                                       capsys) -> None:
    """A cut lacks the ticks before its window: checked from tick 0, every one of them would be reported as a
    divergence (recorded 'not recorded'); it is refused in one line, and a branch restores from its snapshots."""
    cut = tmp_path / "cut.mcap"
    assert truav_main(["log", "cut", str(recording), str(cut), "--from-tick", "12"]) == 0
    capsys.readouterr()
    code, out, err = resim(capsys, cut)
    assert code == 2 and len(err.strip().splitlines()) == 1 and "holds nothing of ticks 0-" in err, out + err
    code, out, err = resim(capsys, cut, "--from", 13, "--out", tmp_path / "whatif")
    assert code == 0, out + err
    assert "the branch equals the recorded run from tick 13 on" in out


def test_a_run_stopped_amid_a_tick_is_checked_up_to_its_end(recording: Path, tmp_path: Path, capsys) -> None:
    """A lock-step run stopped early (`truav-swarm down`) leaves a recording that ends amid a tick: what it
    holds is checked, what it lacks of that tick is not a divergence, and the summary says where it ends."""
    cut_tick = 7
    obs_of_cut = keys.uav_obs(RUN, 3)

    def cut(topic: str, data: bytes) -> bytes | None:
        if not topic.startswith(f"{keys.prefix(RUN)}/uav/"):  # the bus keys (not the mirrors for Foxglove)
            return data
        tick = msgpack.unpackb(data, raw=False).get("tick", 0)
        return None if tick > cut_tick or (tick == cut_tick and topic >= obs_of_cut) else data

    stopped = rewrite(recording, tmp_path / "stopped.mcap", cut)
    code, out, err = resim(capsys, stopped)
    assert code == 0, out + err
    assert f"the recording ends after tick {cut_tick}" in out
    assert "of the last recorded tick not recorded" in out


def test_a_recorded_snapshot_is_checked_against_the_re_simulated_state(recording: Path, tmp_path: Path,
                                                                      capsys) -> None:
    """Verify compares every recorded snapshot with the state it re-simulated; a branch refuses a snapshot that
    is not its run's (one line) and one that does not reproduce the recording (exit 1)."""
    world_key = keys.world_snapshot(RUN)

    def change_uav_pos(shape_of: Callable[[list], list], data_of: Callable[[bytes], bytes]):
        def change(topic: str, data: bytes) -> bytes:
            if topic != world_key:
                return data
            body = msgpack.unpackb(data, raw=False)
            if body["tick"] == 8:
                dtype, shape, raw = body["arrays"]["uav_pos"]
                body["arrays"]["uav_pos"] = [dtype, shape_of(shape), data_of(raw)]
            return msgpack.packb(body, use_bin_type=True)
        return change

    moved = rewrite(recording, tmp_path / "moved.mcap",
                    change_uav_pos(lambda s: s, lambda raw: bytes([raw[0] ^ 1]) + raw[1:]))
    code, out, err = resim(capsys, moved)
    assert code == 1, out + err
    assert f"first divergence: tick 8, {world_key}, state array uav_pos: recorded 'recorded'" in out
    assert "result: NOT reproduced (0 divergent message(s), 1 recorded state snapshot(s) differ)" in out
    code, out, err = resim(capsys, moved, "--from", BRANCH_TICK, "--out", tmp_path / "moved")
    assert code == 1 and f"cannot branch at tick {BRANCH_TICK}" in err, out + err

    shrunk = rewrite(recording, tmp_path / "shrunk.mcap",
                     change_uav_pos(lambda s: [s[0], s[1] - 1, s[2]], lambda raw: raw[:-16]))
    code, out, err = resim(capsys, shrunk, "--from", BRANCH_TICK, "--out", tmp_path / "shrunk")
    assert code == 2 and len(err.strip().splitlines()) == 1, out + err
    assert "its snapshot of tick 8 does not fit its run (state array uav_pos" in err
