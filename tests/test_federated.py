"""Federated TRUAV's merge rule (agents/federated.py) and the in-process federated trainer."""

import numpy as np
import pytest

from agents.controller import TruavController
from agents.federated import (R_COUNT, R_ROUND, R_SHAPE, R_STATE, R_VALUE, Share, check_share, join_parts,
                              make_share, merge, split_share)
from truav.config import ConfigError, Config
from truav.driver import run_episodes
from truav.trainer import run_chunk

S, A = 50, 16


def _share(uav, states, counts, rows, episode=9):
    return Share(uav, episode, np.array(states, np.int64), np.array(counts, np.int64), np.array(rows, np.float64))


def test_merge_is_the_visit_weighted_average_capped_per_peer():
    q = np.zeros((S, A))
    visits = np.zeros(S, np.int64)
    visits[3] = 2  # own: 2 visits of state 3, value 0
    peer1 = _share(1, [3], [1], np.ones((1, A)))  # 1 visit, value 1
    peer2 = _share(2, [3, 7], [1, 4], np.full((2, A), 4.0))  # state 7: only peer 2 knows it
    changed = merge(q, visits, [peer1, peer2], max_weight=0.5)
    assert changed == 2
    np.testing.assert_allclose(q[3], (2 * 0 + 1 * 1 + 1 * 4) / 4)  # (n_i Q_i + sum n_j Q_j) / (n_i + sum n_j)
    np.testing.assert_allclose(q[7], 0.5 * 4.0)  # the weight 4/4 capped at max_weight
    untouched = np.ones(S, bool)
    untouched[[3, 7]] = False
    assert not q[untouched].any()  # only rows a peer shared


def test_a_peer_claiming_huge_counts_moves_an_entry_at_most_max_weight_of_the_way():
    q = np.full((S, A), 1.0)
    visits = np.full(S, 1000, np.int64)
    hostile = _share(1, [0], [10**9], np.full((1, A), -50.0))
    merge(q, visits, [hostile], max_weight=0.1)
    np.testing.assert_allclose(q[0], 1.0 + 0.1 * (-50.0 - 1.0))


@pytest.mark.parametrize("share, reason", [
    (_share(1, [0], [1], [[np.nan] * A]), R_VALUE),
    (_share(1, [0], [1], [[np.inf] * A]), R_VALUE),
    (_share(1, [0], [1], [[1e9] * A]), R_VALUE),
    (_share(1, [S], [1], [[0.0] * A]), R_STATE),
    (_share(1, [-1], [1], [[0.0] * A]), R_STATE),
    (_share(1, [2, 2], [1, 1], [[0.0] * A] * 2), R_STATE),
    (_share(1, [0], [0], [[0.0] * A]), R_COUNT),
    (_share(1, [0], [1001], [[0.0] * A]), R_COUNT),  # more visits than 10 episodes x 100 steps allow
    (_share(1, [0], [1], [[0.0] * 3]), R_SHAPE),
    (_share(1, [0], [1], [[0.0] * A], episode=8), R_ROUND),  # a stale round's share
])
def test_hostile_or_stale_shares_are_refused(share, reason):
    why = check_share(share, S, A, episode=9, most=1000, q_bound=1e4)
    assert why is not None and why.startswith(reason)


def test_a_good_share_passes_and_splits_and_joins_back_exactly():
    rng = np.random.default_rng(0)
    q, visits, since = rng.random((S, A)), rng.integers(0, 5, S), np.zeros(S, np.int64)
    sh = make_share(0, 9, q, visits, since, max_rows=S)
    assert check_share(sh, S, A, 9, 1000, 1e4) is None
    assert set(sh.states) == set(np.flatnonzero(visits))
    assert list(sh.counts) == sorted(sh.counts, reverse=True)  # most visited first
    parts = split_share(sh, 7)
    assert all(len(p.states) <= 7 for p in parts)
    back = join_parts(parts)
    for a, b in zip(back, sh):
        np.testing.assert_array_equal(a, b)
    capped = make_share(0, 9, q, visits, since, max_rows=3)
    np.testing.assert_array_equal(capped.states, sh.states[:3])


def test_federated_config_is_checked():
    with pytest.raises(ConfigError, match="federated.max_weight"):
        Config().replace(federated={"max_weight": 1.5})
    with pytest.raises(ConfigError, match="federated"):
        Config().replace(federated={"every_k": 1})


def _run(cfg, seeds, fused, episodes):
    ctrl = TruavController(cfg, seeds)
    ctrl.fused = fused
    return run_episodes(cfg, seeds, ctrl, episodes), ctrl


def test_federated_trainer_fused_equals_the_step_path_and_is_reproducible(small_cfg):
    cfg = small_cfg.replace(scenario={"n_uavs": 3}, federated={"every": 1, "max_rows": 5})
    ref, c_ref = _run(cfg, [0, 4], fused=False, episodes=3)
    got, c_got = _run(cfg, [0, 4], fused=True, episodes=3)
    np.testing.assert_array_equal(c_got.learners.q, c_ref.learners.q)
    np.testing.assert_array_equal(c_got.visits, c_ref.visits)
    for k in ref:
        np.testing.assert_array_equal(got[k], ref[k], err_msg=k)
    assert c_got.visits.sum() == 2 * 3 * 3 * cfg.scenario.steps_per_episode
    again = run_chunk("truav", cfg, [0, 4], 3)
    np.testing.assert_array_equal(again.q, c_got.learners.q)  # same seed, same tables
    plain = run_chunk("truav", cfg.replace(federated={"every": 0}), [0, 4], 3)
    assert not np.array_equal(plain.q, again.q)  # sharing changed the tables


def test_lockstep_federated_swarm_learns_the_federated_trainers_tables(tmp_path):
    """3 agent processes sharing every episode over the bus, in lock-step: the in-process federated trainer's
    Q-tables entry for entry, and each agent's stats say what it sent (bytes of its Q shares)."""
    import json

    from test_lockstep import SEED, agent_tables, run_swarm
    cfg = Config().replace(scenario={"n_vehicles": 60, "steps_per_episode": 10, "n_uavs": 3},
                           roads={"warmup_steps": 10}, learner={"episodes": 4}, federated={"every": 1})
    expected = run_chunk("truav", cfg, [SEED], cfg.learner.episodes)
    out = run_swarm(tmp_path, "fed", cfg=cfg)
    q, steps = agent_tables(out, cfg)
    assert steps == [cfg.learner.episodes * cfg.scenario.steps_per_episode] * 3
    differing = [int(np.sum(q[i] != expected.q[0, i])) for i in range(3)]
    assert differing == [0, 0, 0], f"entries differing from the federated trainer, per agent: {differing}"
    unshared = run_chunk("truav", cfg.replace(federated={"every": 0}), [SEED], cfg.learner.episodes)
    assert not np.array_equal(q, unshared.q[0])  # the shares were merged
    for i in range(3):
        fed = json.loads((out / f"agent{i}.json").read_text())["federated"]
        assert fed["shares_sent"] == cfg.learner.episodes and fed["messages_sent"] == cfg.learner.episodes
        assert fed["shares_merged"] == 2 * cfg.learner.episodes and not fed["refused"] and not fed["missing"]
        assert fed["bytes_sent"] > 16 * 8 * fed["rows_sent"]  # float64 rows, and the envelope
