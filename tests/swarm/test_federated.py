"""Federated TRUAV's merge rule (agents/federated.py) and the in-process federated trainer."""

import numpy as np
import pytest

from agents.controller import TruavController
from agents.federated import (R_COUNT, R_ROUND, R_SHAPE, R_STATE, R_VALUE, Share, check_share, join_parts,
                              make_share, merge, split_share)
from truav.analysis.driver import run_episodes
from truav.analysis.trainer import run_chunk
from truav.config import Config, ConfigError
from tests.support.swarm_up import learners

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


def test_the_trainer_refuses_the_shares_a_swarm_agent_refuses():
    """The in-process round (federate) checks each share as a swarm agent does: a UAV's share holding a value
    beyond federated.q_bound (a legal setting, e.g. 0.05) moved its peers' tables in process and not on the bus,
    so a lock-step swarm, "exact", learned other tables than `truav train` with the same seed and settings."""
    from agents.federated import federate
    fc = Config().federated.__class__(every=1, q_bound=0.5)
    q = np.zeros((1, 3, S, A))
    q[0, 1, 4] = 2.0  # uav 1's row of state 4: beyond q_bound, its whole share refused
    q[0, 1, 5] = 0.25
    q[0, 2, 6] = 0.25  # uav 2's share passes
    visits = np.zeros((1, 3, S), np.int64)
    visits[0, 1, [4, 5]] = 1
    visits[0, 2, 6] = 1
    federate(q, visits, np.zeros_like(visits), 0, fc, steps_per_episode=10)
    assert not q[0, 0, [4, 5]].any() and not q[0, 2, [4, 5]].any()  # nothing of uav 1's share
    np.testing.assert_allclose(q[0, 0, 6], 0.5 * 0.25)  # uav 2's: weight 1/1 capped at max_weight
    np.testing.assert_allclose(q[0, 1, 6], 0.5 * 0.25)


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

    from tests.support.lockstep import SEED, agent_tables, run_swarm
    cfg = Config().replace(scenario={"n_vehicles": 60, "steps_per_episode": 10, "n_uavs": 3},
                           roads={"warmup_steps": 10}, learner={"episodes": 4}, federated={"every": 1})
    expected = run_chunk("truav", cfg, [SEED], cfg.learner.episodes)
    out = run_swarm(tmp_path, "fed", cfg=cfg)
    q, steps = agent_tables(out, cfg)
    assert steps == [cfg.learner.episodes * cfg.scenario.steps_per_episode] * 3
    assert q.shape == expected.q[0].shape  # every entry of every table compared, none broadcast away
    differing = [int(np.sum(q[i] != expected.q[0, i])) for i in range(3)]
    assert differing == [0, 0, 0], f"entries differing from the federated trainer, per agent: {differing}"
    unshared = run_chunk("truav", cfg.replace(federated={"every": 0}), [SEED], cfg.learner.episodes)
    assert not np.array_equal(q, unshared.q[0])  # the shares were merged
    for i in range(3):
        fed = json.loads((out / f"agent{i}.json").read_text())["federated"]
        assert fed["shares_sent"] == cfg.learner.episodes and fed["messages_sent"] == cfg.learner.episodes
        assert fed["shares_merged"] == 2 * cfg.learner.episodes and not fed["refused"] and not fed["missing"]
        assert fed["bytes_sent"] > 16 * 8 * fed["rows_sent"]  # float64 rows, and the envelope


def _qshare(uav=1, tick=5, n=2, **kw):
    from truav.wire import schema
    fields = dict(uav=uav, tick=tick, episode=0, part=0, parts=1, states=np.arange(n), counts=np.ones(n, np.int64),
                  q=np.zeros(16 * n))
    return schema.QShare(**{**fields, **kw})


def test_guard_placement_and_acl_bound_a_qshare(small_cfg):
    """A share comes only from its UAV, on its own key and part, near the current tick, with whole rows; under
    --secure uav/i may put only its own shares; a share too large to send is refused before it goes out."""
    from truav.bus import acl, placement
    from truav.wire import guard, keys, schema
    from truav.wire.schema import SchemaError
    g = guard.for_config(small_cfg)
    stamp = lambda src, m: schema.Sequencer(src).stamp(m)  # noqa: E731
    assert g.check("k", stamp("world", schema.Tick(tick=5, episode=0, sim_time=5.0, deadline_ms=100.0,
                                                   n_uavs=small_cfg.scenario.n_uavs))) is None
    assert g.check("k", stamp("uav/1", _qshare())) is None
    assert g.check("k", stamp("uav/2", _qshare()))[0] == guard.R_SENDER  # a forged sender
    assert g.check("k", stamp("uav/1", _qshare(tick=10_000)))[0] == guard.R_TICK  # stale or far ahead
    assert g.check("k", stamp("uav/1", _qshare(q=np.zeros(17))))[0] == guard.R_IMPLAUSIBLE  # not whole rows
    assert g.check("k", stamp("uav/1", _qshare(part=1, parts=1)))[0] == guard.R_IMPLAUSIBLE
    with pytest.raises(SchemaError):
        placement.check_placement(keys.uav_qshare("r", 2, 0), stamp("uav/1", _qshare()))  # another UAV's key
    with pytest.raises(SchemaError):
        placement.check_placement(keys.uav_qshare("r", 1, 3), stamp("uav/1", _qshare()))  # another part's key
    with pytest.raises(SchemaError):
        _qshare(states=np.arange(321), counts=np.ones(321, np.int64), q=np.zeros(16 * 321))  # > MAX_QSHARE_ROWS
    with pytest.raises(SchemaError):
        _qshare(q=np.array([np.nan] * 32))
    mine = next(gr for gr in acl.grants("r", 3) if gr.identity == "uav/1")
    assert keys.uav_qshares("r", 1) in mine.put and not any(keys.uav_qshares("r", 2) in gr.put for gr in [mine])
    assert acl._matches(keys.uav_qshare("r", 1, 4), keys.uav_qshares("r", 1))
    assert not any(acl._matches(keys.uav_qshare("r", 2, 0), p) for p in mine.put)


def test_an_agent_refuses_hostile_and_stale_shares_and_bounds_the_rest(small_cfg):
    """The swarm agent's receive side (agents.process.agent_process_federated): a share with an out-of-range value or a
    count no run could make is refused whole and counted; one of an older round is stale; a good one moves the
    agent's entries at most federated.max_weight of the way, and only in its rows."""
    node = _stub_node(small_cfg.replace(scenario={"n_uavs": 4}, federated={"every": 1, "max_weight": 0.25}))
    cfg = node.cfg
    before = node.learners.q[0, 0].copy()
    node._round = 3  # this agent shared after episode 3
    T = cfg.scenario.steps_per_episode
    node._on_qshare("k", _qshare(uav=1, episode=3, q=np.full(32, 1e9)), None, 0)  # out of range
    node._on_qshare("k", _qshare(uav=2, episode=3, counts=np.array([1, 4 * T + 1])), None, 0)  # too many visits
    node._on_qshare("k", _qshare(uav=3, episode=2), None, 0)  # an older round: stale
    node._on_qshare("k", _qshare(uav=3, episode=3, counts=np.array([10 ** 0, 4 * T]), q=np.full(32, -5.0)), None, 0)
    node._merge_ready()
    st = node.fed_stats
    assert st["refused"] == {"stale_round": 1, "bad_value": 1, "bad_count": 1} and st["shares_merged"] == 1
    q = node.learners.q[0, 0]
    np.testing.assert_allclose(q[:2], before[:2] + 0.25 * (-5.0 - before[:2]))  # weight 1/1 capped at 0.25
    np.testing.assert_array_equal(q[2:], before[2:])
    assert not node._parts  # merged or refused shares are not kept


def test_shares_of_rounds_far_ahead_cannot_push_out_the_present_round(small_cfg):
    """A hostile peer's shares of rounds far ahead (a few tiny messages) used to push the round an agent was about
    to merge out of its bounded store: no share was merged all run, nothing refused. Now the nearest rounds are
    kept, and a share further ahead, of no share round, of more parts than federated.max_rows needs, or (a
    resumed agent) older than its current episode is refused and counted."""
    from types import SimpleNamespace
    node = _stub_node(small_cfg.replace(scenario={"n_uavs": 4}, federated={"every": 2, "max_rows": 640}))
    node._round = 1  # shared after episode 1 (every 2: rounds 1, 3, 5, ...)
    for ep in range(10**6 + 1, 10**6 + 12, 2):  # 6 far-ahead share rounds, as uav 1 and 3: 4 kept
        node._on_qshare("k", _qshare(uav=1, episode=ep), None, 0)
        node._on_qshare("k", _qshare(uav=3, episode=ep), None, 0)
    node._on_qshare("k", _qshare(uav=3, episode=2), None, 0)  # no share round
    node._on_qshare("k", _qshare(uav=3, episode=1, part=0, parts=3), None, 0)  # 640 rows need 2 parts
    node._on_qshare("k", _qshare(uav=2, episode=1, q=np.full(32, -5.0)), None, 0)  # the present round's share
    node._merge_ready()
    st = node.fed_stats
    assert st["shares_merged"] == 1 and st["refused"] == {"bad_round": 2 * 2 + 1, "bad_shape": 1}
    assert {r for r, _ in node._parts} == {10**6 + 1, 10**6 + 3, 10**6 + 5}  # the 3 nearest after the merged one
    resumed = _stub_node(node.cfg)
    resumed.decision = SimpleNamespace(episode=50)  # resumed at episode 50, not shared yet
    resumed._on_qshare("k", _qshare(uav=1, episode=3), None, 0)
    resumed._on_qshare("k", _qshare(uav=1, episode=49), None, 0)
    assert resumed.fed_stats["refused"] == {"stale_round": 1} and list(resumed._parts) == [(49, 1)]


def _stub_node(cfg):
    """An agent node's federated part alone (agents.process.agent_process_federated), on no bus."""
    import threading
    from types import SimpleNamespace

    from agents.process.agent_process_federated import FederatedShares
    from agents.qlearning import QLearners
    from agents.state import StateEncoder
    node = FederatedShares()
    node.cfg, node.opts = cfg, SimpleNamespace(uav=0, run="r", train=True, lockstep=False)
    node.encoder = StateEncoder(cfg)
    node.learners = QLearners(cfg.learner, node.encoder.n_states, [np.random.default_rng(0)], 1, 1)
    node._lock, node._gone = threading.Lock(), set()
    node._init_federated()
    return node


def test_a_share_split_over_parts_is_merged_whole_or_not_at_all(small_cfg):
    """A share of more rows than one message holds crosses the bus in parts: merged once every part came, as
    the unsplit share would be; with a part missing, not at all."""
    from truav.wire import schema
    cfg = small_cfg.replace(scenario={"n_uavs": 3}, learner={"grid_cells": 20}, federated={"every": 1})
    rng = np.random.default_rng(1)
    n = schema.MAX_QSHARE_ROWS + 80
    states = rng.choice(cfg_states := _stub_node(cfg).encoder.n_states, n, replace=False)
    share = Share(1, 0, states, rng.integers(1, 10, n), rng.normal(size=(n, A)))
    parts = split_share(share, schema.MAX_QSHARE_ROWS)
    assert len(parts) == 2 and cfg_states > n
    msgs = [_qshare(uav=1, tick=9, episode=0, part=k, parts=2, states=p.states, counts=p.counts, q=p.q.ravel())
            for k, p in enumerate(parts)]
    node = _stub_node(cfg)
    node._round = 0
    node._on_qshare("k", msgs[1], None, 0)
    node._merge_ready()
    assert node.fed_stats["shares_merged"] == 0  # one part of two: nothing merged yet
    node._on_qshare("k", msgs[0], None, 0)
    expected = node.learners.q[0, 0].copy()
    merge(expected, node.visits, [share], cfg.federated.max_weight)
    node._merge_ready()
    assert node.fed_stats["shares_merged"] == 1
    np.testing.assert_array_equal(node.learners.q[0, 0], expected)


def _fed_swarm(tmp, name, cfg, plan_toml, *extra):
    import sys

    from tests.support.runs import run_to_end
    from tests.support.lockstep import SEED
    from truav.config import to_toml
    (tmp / f"{name}.toml").write_text(to_toml(cfg))
    (tmp / f"{name}-plan.toml").write_text(plan_toml)
    out = tmp / name
    cmd = [sys.executable, "-m", "truav.cli.swarm", "up", *learners(extra), "--lockstep", "--seed", str(SEED), "--run", name,
           "--episodes", str(cfg.learner.episodes), "--scenario", str(tmp / f"{name}.toml"), "--out", str(out),
           "--fault-plan", str(tmp / f"{name}-plan.toml"), "--quiet", "--no-plot", *extra]
    return run_to_end(cmd, tmp / f"{name}.log", 180.0, term_wait_s=30), out


FED_CFG = Config().replace(scenario={"n_vehicles": 60, "steps_per_episode": 10, "n_uavs": 3},
                           roads={"warmup_steps": 10}, learner={"episodes": 3}, federated={"every": 1})


def test_link_faults_reach_the_shares_delayed_ones_are_waited_for_lost_ones_counted(tmp_path):
    """A fault plan's latency and loss apply to `qshare` as to any message: in lock-step a delayed share is
    waited for (the tables still equal the federated trainer's), a lost one is waited out (--lockstep-wait),
    counted, and the run says it is no longer exact."""
    import json

    from tests.support.lockstep import SEED, agent_tables
    expected = run_chunk("truav", FED_CFG, [SEED], FED_CFG.learner.episodes).q[0]
    latency = '[[fault]]\nkind = "latency"\nstart = 0.0\nfixed_ms = 300.0\nkeys = "uav/*/qshare/*"\n'
    rc, out = _fed_swarm(tmp_path, "late", FED_CFG, latency)
    assert rc == 0, (tmp_path / "late.log").read_text(errors="replace")
    assert np.array_equal(agent_tables(out, FED_CFG)[0], expected)
    loss = '[[fault]]\nkind = "loss"\nstart = 0.0\nprobability = 1.0\nkeys = "uav/*/qshare/*"\ndst = "uav/0"\n'
    rc, out = _fed_swarm(tmp_path, "lost", FED_CFG, loss, "--lockstep-wait", "1")
    summary = json.loads((out / "summary.json").read_text())
    assert rc == 1 and summary["outcome"]["lockstep"]["exact"] is False
    fed0 = json.loads((out / "agent0.json").read_text())["federated"]
    # Every share to uav 0 lost: none merged; each round's wait counted, but the last if the run ended meanwhile
    # (the world waits --lockstep-wait for uav 0's answer too, and may finish first).
    assert fed0["shares_merged"] == 0 and fed0["missing"] >= 2
    fed1 = json.loads((out / "agent1.json").read_text())["federated"]
    assert fed1["shares_merged"] == 2 * FED_CFG.learner.episodes and fed1["missing"] == 0
