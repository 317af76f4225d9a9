"""Snapshots of a lock-step run's state (world.world_state, agents.decision_state): captured at any tick and
restored, the run goes on exactly as the uninterrupted one (every message, every Q-table entry, every
generator); a state that does not fit is refused."""

from __future__ import annotations

import fnmatch

import msgpack
import numpy as np
import pytest

from recorder.resim import Resimulation, payload_fields
from truav.bus import acl, placement
from truav.config import Config
from truav.wire import keys, schema
from truav.wire.snapshot_messages import agent_snapshot, fits, state_arrays, world_snapshot

SEED = 3
CFG = Config().replace(scenario={"n_vehicles": 60, "steps_per_episode": 8, "n_uavs": 3},
                       roads={"warmup_steps": 10, "hotspot_move_prob": 0.5}, learner={"episodes": 3})
TICKS = 3 * (CFG.scenario.steps_per_episode + 1)


def fields(rounds) -> list:
    """Every message of every round, payload fields only, and the episode summaries (NaN as a string)."""
    out = []
    for r in rounds:
        out.append([payload_fields(m) for m in r.obs + r.beacons + r.actions])
        out.append(None if r.summary is None else {k: repr(v) for k, v in r.summary.items()})
    return out


@pytest.fixture(scope="module")
def uninterrupted() -> tuple[Resimulation, list]:
    run = Resimulation(CFG, SEED, 3)
    return run, [run.step() for _ in range(TICKS)]


@pytest.mark.parametrize("cut", [0, 5, 8, 9, 13, 17])  # start, mid-episode, `done` ticks, an episode's first
def test_a_restored_snapshot_goes_on_as_the_uninterrupted_run(uninterrupted, cut):
    whole, rounds = uninterrupted
    part = Resimulation(CFG, SEED, 3)
    for _ in range(cut):
        part.step()
    tick, world, agents = part.snapshot()
    assert tick == cut
    restored = Resimulation(CFG, SEED, 3)  # fresh: its tables are the run's starting ones
    restored.restore(tick, world, agents)
    # the restored state is the captured one, array by array (generators included)
    again = restored.snapshot()
    for name, a in world.items():
        assert np.array_equal(again[1][name], a), name
    for mine, theirs in zip(again[2], agents):
        for name, a in theirs.items():
            assert np.array_equal(mine[name], a), name
    assert fields(restored.step() for _ in range(TICKS - cut)) == fields(rounds[cut:])
    for a, b in zip(whole.agents, restored.agents):
        assert np.array_equal(a.learners.q, b.learners.q)
        assert a.learners.rngs[0].bit_generator.state == b.learners.rngs[0].bit_generator.state
    assert whole.world.rngs[0].bit_generator.state == restored.world.rngs[0].bit_generator.state


def test_an_agent_snapshot_holds_only_the_rows_it_updated(uninterrupted):
    whole, _ = uninterrupted
    _, _, agents = whole.snapshot()
    for agent, state in zip(whole.agents, agents):
        assert 0 < len(state["q_rows"]) < 3 * CFG.scenario.steps_per_episode
        assert state["q_values"].shape == (len(state["q_rows"]), 16)
        assert np.array_equal(state["q_values"], agent.learners.q[0, 0, state["q_rows"]])


def test_a_state_that_does_not_fit_is_refused(uninterrupted):
    whole, _ = uninterrupted
    tick, world, agents = whole.snapshot()
    fresh = Resimulation(CFG, SEED, 3)
    for broken, match in [({**world, "uav_pos": world["uav_pos"][:, :2]}, "uav_pos"),
                          ({**world, "t": np.array(99, np.int64)}, "step"),
                          ({k: v for k, v in world.items() if k != "totals"}, "totals missing"),
                          ({**world, "rng": world["episode_rng"]}, "replay")]:
        with pytest.raises(ValueError, match=match):
            fresh.restore(tick, broken, agents)
    bad_rows = {**agents[0], "q_rows": np.full_like(agents[0]["q_rows"], 10**9)}
    with pytest.raises(ValueError, match="q_rows"):
        Resimulation(CFG, SEED, 3).restore(tick, world, [bad_rows, *agents[1:]])


# --- on the wire -------------------------------------------------------------------------------------------
def stamped(msg):
    return schema.Sequencer("world" if isinstance(msg, schema.WorldSnapshot) else f"uav/{msg.uav}").stamp(msg)


def test_snapshot_messages_round_trip_every_array_bit_for_bit(uninterrupted):
    whole, _ = uninterrupted
    tick, world, agents = whole.snapshot()
    msgs = [world_snapshot(tick, whole.episode, world), *(agent_snapshot(i, tick, a) for i, a in enumerate(agents))]
    for msg, state in zip(msgs, [world, *agents]):
        back = state_arrays(schema.decode(schema.encode(stamped(msg)), msg.KIND).arrays)
        assert set(back) == set(state)
        for name, a in state.items():
            assert back[name].dtype == a.dtype and back[name].shape == a.shape
            assert back[name].tobytes() == a.tobytes(), name


def test_snapshots_are_bounded_in_size():
    """The paper's city fits one message; a table of every state updated does not and is not published (the
    agent says so once); nothing larger than the limit is ever encoded."""
    cfg = Config()
    run = Resimulation(cfg, SEED, 1)
    _, world, agents = run.snapshot()
    assert fits(world) and len(schema.encode(stamped(world_snapshot(0, 0, world)))) < 64 << 10
    n_states = run.agents[0].learners.n_states
    full = {**agents[0], "q_rows": np.arange(n_states, dtype=np.int64),
            "q_values": np.zeros((n_states, 16))}  # 14,400 rows: 1.8 MB
    assert not fits(full)
    with pytest.raises(schema.SchemaError) as info:
        schema.encode(stamped(agent_snapshot(0, 0, full)))
    assert info.value.reason == schema.R_TOO_LARGE
    some = {**full, "q_rows": full["q_rows"][:5000], "q_values": full["q_values"][:5000]}
    assert fits(some) and len(schema.encode(stamped(agent_snapshot(0, 0, some)))) <= schema.MAX_SNAPSHOT_BYTES


@pytest.mark.parametrize("arrays, reason", [
    ({"t": ["<f4", [1], bytes(4)]}, schema.R_OUT_OF_RANGE),  # a dtype not allowed
    ({"t": ["O", [1], bytes(8)]}, schema.R_OUT_OF_RANGE),  # objects: never
    ({"t": ["<f8", [2], bytes(8)]}, schema.R_OUT_OF_RANGE),  # fewer bytes than its shape says
    ({"t": ["<f8", [1 << 40, 1 << 40], bytes(8)]}, schema.R_OUT_OF_RANGE),  # a shape claiming terabytes
    ({"t": ["<f8", [1, 1, 1, 1], bytes(8)]}, schema.R_TOO_LARGE),  # too many dimensions: msgpack's limit
    ({"t": ["<f8", [-1], bytes(8)]}, schema.R_OUT_OF_RANGE),  # a negative length
    ({"t": ["<f8", [1], "text"]}, schema.R_BAD_TYPE),  # data not bytes
    ({"../x": ["<f8", [1], bytes(8)]}, schema.R_OUT_OF_RANGE),  # a name no state has
    ({f"a{i}": ["<f8", [1], bytes(8)] for i in range(schema.MAX_SNAPSHOT_ARRAYS + 1)}, schema.R_TOO_LARGE),
    ([["<f8", [1], bytes(8)]], schema.R_BAD_TYPE),  # not a map
])
def test_a_hostile_snapshot_payload_is_refused_by_the_schema(arrays, reason):
    wire = {"v": schema.SCHEMA_VERSION, "kind": schema.KIND_WORLD_SNAPSHOT, "src": "world", "seq": 0, "t": 1,
            "inc": 1, "tick": 0, "episode": 0, "arrays": arrays}
    with pytest.raises(schema.SchemaError) as info:
        schema.decode(msgpack.packb(wire, use_bin_type=True), schema.KIND_WORLD_SNAPSHOT)
    assert info.value.reason == reason


def test_an_agent_may_put_only_its_own_snapshot():
    grant = next(g for g in acl.grants("r", 3) if g.identity == "uav/1")
    assert keys.uav_snapshot("r", 1) in grant.put and keys.uav_snapshot("r", 2) not in grant.put
    world = next(g for g in acl.grants("r", 3) if g.identity == acl.WORLD)
    assert any(fnmatch.fnmatch(keys.world_snapshot("r"), k.replace("**", "*")) for k in world.put)
    msg = stamped(agent_snapshot(2, 0, {"t": np.array(0, np.int64)}))
    with pytest.raises(schema.SchemaError):
        placement.check_placement(keys.uav_snapshot("r", 1), msg)  # uav/2's snapshot on uav/1's key
