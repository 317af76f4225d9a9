"""Snapshots of a lock-step run's state (world.world_state, agents.decision_state): captured at any tick and
restored, the run goes on exactly as the uninterrupted one (every message, every Q-table entry, every
generator); a state that does not fit is refused."""

from __future__ import annotations

import numpy as np
import pytest

from recorder.resim import Resimulation, payload_fields
from truav.config import Config

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
