"""Agents sharing a process (issue 28): one beacon subscription decoded once per process, batched
beacons (``--batch-beacons``), and what each hosted agent still does alone (its link filter per UAV link,
its guard, its counts). Correctness only; the cost is measured by bench/bench_swarm.py.

Network tests use a router on loopback (scouting off); every swarm is one `truav-swarm up` process that
starts and reaps its own children, stopped by the test only if it overruns.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest

from agents.process.shared_beacons import SharedBeacons, split_batch
from tests.support.waits import wait_matched
from tests.support.runs import up_to_end
from truav.analysis.trainer import run_chunk
from truav.bus import acl
from truav.bus.fault_filter import PlanFilter
from truav.bus.placement import R_KEY_MISMATCH, check_placement
from truav.config import Config
from truav.faults import plan_from_dict
from truav.swarm.swarm_options import agent_groups
from truav.wire import guard, keys, schema

RUN = "sharedb"
SWARM_TIMEOUT_S = 300.0


def _cfg(n: int) -> Config:
    return Config().replace(scenario={"n_uavs": n})


def _beacon(uav: int, tick: int = 3) -> schema.Beacon:
    return schema.Beacon(uav=uav, tick=tick, pos=(100.0 + uav, 200.0), vel=(1.0, 0.0))


def _drain_until(view, want: int, timeout_s: float = 8.0) -> list:
    got, deadline = [], time.monotonic() + timeout_s
    while time.monotonic() < deadline and len(got) < want:
        view.wait(0.05)
        got += view.drain()
    time.sleep(0.2)  # and nothing more comes
    return got + view.drain()


def _batch_raw(src: str, entries) -> bytes:
    return schema.encode(schema.Sequencer(src).stamp(schema.Beacons(entries=tuple(entries))))


# -- the schema and placement of a batch ----------------------------------------------------------
def test_a_batch_belongs_only_on_its_group_key_and_names_only_its_uavs():
    key = keys.group_beacons(RUN, 0, 9)
    assert keys.parse_group(key) == (0, 9) and keys.parse_group(keys.uav_beacon(RUN, 3)) is None
    ok = schema.decode(_batch_raw("uav/0", [(0, 5, (1.0, 2.0), (0.0, 0.0)), (9, 5, (3.0, 4.0), (0.0, 0.0))]))
    check_placement(key, ok)
    for src, entries, fragment in (
            ("uav/0", [(12, 5, (1.0, 2.0), (0.0, 0.0))], "beacons of uav [12]"),
            ("uav/3", [(3, 5, (1.0, 2.0), (0.0, 0.0))], "sender uav/3 may not appear"),
            ("uav/0", [(1, 5, (1.0, 2.0), (0.0, 0.0))] * 2, "twice")):
        with pytest.raises(schema.SchemaError) as err:
            check_placement(key, schema.decode(_batch_raw(src, entries)))
        assert err.value.reason == R_KEY_MISMATCH and fragment in str(err.value)
    with pytest.raises(schema.SchemaError):  # an empty batch is no batch
        schema.Beacons(entries=())
    parts = split_batch(key, ok, RUN)
    assert [(k, b.src, b.uav, b.pos) for k, b in parts] == [
        (keys.uav_beacon(RUN, 0), "uav/0", 0, (1.0, 2.0)), (keys.uav_beacon(RUN, 9), "uav/9", 9, (3.0, 4.0))]


def test_the_grant_table_lets_only_a_groups_first_uav_put_its_batch():
    n, k = 7, 3
    assert acl.batch_groups(n, k) == [(g[0], g[-1]) for g in agent_groups(n, k) if len(g) > 1] == [(0, 2), (3, 5)]
    table = {g.identity: g for g in acl.grants(RUN, n, batch_group_size=k)}
    for first, last in acl.batch_groups(n, k):
        key = keys.group_beacons(RUN, first, last)
        putters = [i for i, g in table.items() if any(acl._matches(key, e) for e in g.put)]
        assert putters == [keys.uav_identity(first)]
        assert all(any(acl._matches(key, e) for e in table[keys.uav_identity(u)].subscribe) for u in range(n))
    rules = acl.acl_config(tuple(table.values()))["rules"]
    put_rules = [r for r in rules if r["id"].endswith("-put") and keys.group_beacons(RUN, 3, 5) in r["key_exprs"]]
    assert [r["id"] for r in put_rules] == ["uav-3-put"]
    # No batches (the default): nobody may put on any group key.
    plain = acl.grants(RUN, n)
    assert not any("/group/" in e for g in plain for e in g.put)


# -- one subscription, decoded once, each agent its own filter, guard and counts ----------------
def test_a_batch_is_split_filtered_per_link_and_a_foreign_uav_refused(bus_factory):
    """uav/0 sends the batch of group 0-1; a plan drops every beacon from uav 1 to uav 2: uav 2 hears
    uav 0 only, uav 3 hears both; a batch carrying uav 12 is refused and counted by each receiver."""
    cfg = _cfg(16)
    rx2, rx3 = bus_factory(keys.uav_identity(2)), bus_factory(keys.uav_identity(3))
    sender = bus_factory(keys.uav_identity(0))
    plan = plan_from_dict({"fault": [{"kind": "loss", "start": 0.0, "probability": 1.0, "src": "uav/1",
                                      "dst": "uav/2", "keys": "uav/*/beacon"}]})
    rx2.link_filter = PlanFilter(plan, RUN, t0_ns=1)
    feed = SharedBeacons(RUN, batched=True)
    views = {}
    for bus in (rx2, rx3):
        bus.guard = guard.for_config(cfg)
        views[bus.identity] = feed(bus)
    key = keys.group_beacons(RUN, 0, 1)
    assert wait_matched(sender, key)  # the subscriptions reach the router
    sender.publish(key, schema.Beacons(entries=((0, 3, (10.0, 20.0), (0.0, 0.0)), (1, 3, (30.0, 40.0), (0.0, 0.0)))))
    got2, got3 = _drain_until(views["uav/2"], 1), _drain_until(views["uav/3"], 2)
    assert [(r.msg.uav, r.msg.pos, r.key) for r in got3] == [(0, (10.0, 20.0), keys.uav_beacon(RUN, 0)),
                                                               (1, (30.0, 40.0), keys.uav_beacon(RUN, 1))]
    assert [r.msg.uav for r in got2] == [0]  # the link 1 -> 2 is down, 0 -> 2 is not
    s2, s3 = rx2.stats(), rx3.stats()
    assert (s2.received, s2.delivered, s2.filtered) == (2, 1, 1)
    assert (s3.received, s3.delivered, s3.filtered) == (2, 2, 0)
    # A batch carrying a UAV its key does not name: refused by every receiver, counted on its own bus.
    sender.publish_raw(key, _batch_raw("uav/0", [(0, 4, (1.0, 2.0), (0.0, 0.0)), (12, 4, (1.0, 2.0), (0.0, 0.0))]))
    # One from a sender that is not the group's first UAV (without --secure, src can be forged).
    sender.publish_raw(key, _batch_raw("world", [(0, 4, (1.0, 2.0), (0.0, 0.0))]))
    for bus in (rx2, rx3):
        view = views[bus.identity]
        deadline = time.monotonic() + 8
        while time.monotonic() < deadline and sum(bus.dropped_malformed.values()) < 2:
            view.wait(0.05)
            assert view.drain() == []
        assert bus.dropped_malformed == {R_KEY_MISMATCH: 1, guard.R_SENDER: 1}
        assert set(bus.rejections.as_dict()) == {R_KEY_MISMATCH, guard.R_SENDER}


def test_shared_decoding_refuses_what_each_agents_own_inbox_refused_with_the_same_reasons(bus_factory):
    """Hostile beacons through an agent's own inbox and through a shared feed: the same counts by reason
    and sender on the receiving bus, and the same valid beacons delivered."""
    cfg = _cfg(4)
    own, shared = bus_factory(keys.uav_identity(1)), bus_factory(keys.uav_identity(2))
    for bus in (own, shared):
        bus.guard = guard.for_config(cfg)
    box = own.inbox(keys.all_beacons(RUN))
    view = SharedBeacons(RUN)(shared)
    senders = {u: bus_factory(keys.uav_identity(u)) for u in (0, 3)}
    time.sleep(0.5)
    seq = schema.Sequencer("uav/0")
    payloads = [
        (0, schema.encode(seq.stamp(_beacon(0)))),  # valid
        (0, b"\xc1 not msgpack"),
        (0, schema.encode(schema.Sequencer("uav/3").stamp(_beacon(3)))),  # uav 3's beacon on uav 0's key
        (3, schema.encode(seq.stamp(_beacon(0)))),  # sender uav/0 on uav 3's key
        (0, schema.encode(seq.stamp(schema.Beacon(uav=0, tick=3, pos=(1e7, 0.0), vel=(0.0, 0.0))))),  # outside
        (0, schema.encode(seq.stamp(_beacon(0, tick=10_000)))),  # far from the current tick
        (0, bytes(20_000)),  # too large (the test router may drop it first)
        (3, schema.encode(schema.Sequencer("uav/3").stamp(_beacon(3)))),  # valid
    ]
    for bus in (own, shared):
        bus.guard._advance(5)  # the current tick: 5
    for uav, raw in payloads:
        senders[uav].publish_raw(keys.uav_beacon(RUN, uav), raw)
    got_own, got_shared = _drain_until(box, 2), _drain_until(view, 2)
    assert sorted(r.msg.uav for r in got_own) == sorted(r.msg.uav for r in got_shared) == [0, 3]
    a, b = own.stats(), shared.stats()
    assert (a.received, a.delivered, a.malformed) == (b.received, b.delivered, b.malformed)
    assert a.rejected == b.rejected and len(a.malformed) >= 4


# -- whole swarms -------------------------------------------------------------------------------
def _up(tmp: Path, name: str, cfg: Config, *args: str) -> Path:
    return up_to_end(tmp, name, cfg, *args, timeout_s=SWARM_TIMEOUT_S)


@pytest.mark.parametrize("batch", [False, True], ids=["shared", "batched-secure"])
def test_hosted_agents_with_shared_or_batched_beacons_learn_what_the_trainer_learns(tmp_path, batch):
    """Lock-step, 5 agents in processes of 3 and 2 with one beacon subscription decoded once per process
    (and, batched, each process's beacons of a tick as one message under --secure, the router enforcing
    who may put a group's batch): every Q-table equals the trainer's, every agent heard every peer."""
    seed, episodes, n = 3, 4, 5
    cfg = Config().replace(scenario={"n_vehicles": 60, "steps_per_episode": 10, "n_uavs": n},
                           roads={"warmup_steps": 10}, learner={"episodes": episodes})
    expected = run_chunk("truav", cfg, [seed], episodes).q[0]
    extra = ["--batch-beacons", "--secure"] if batch else []
    out = _up(tmp_path, "batched" if batch else "shared", cfg, "--lockstep", "--seed", str(seed), "--episodes",
              str(episodes), "--agents-per-process", "3", "--share-beacons", *extra)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["outcome"]["result"] == "ok"
    assert summary["control_plane"]["beacons"] > 0  # the supervisor counts a batch's beacons
    for i in range(n):
        with np.load(out / f"agent{i}.npz") as ck:
            assert int(ck["steps"]) == episodes * 10
            np.testing.assert_array_equal(ck["q"], expected[i])
        stats = json.loads((out / f"agent{i}.json").read_text())
        assert stats["bus"]["rejected"] == {} and stats["lockstep"]["decisions_without_peer"] == 0
        assert {s for s, _ in stats["beacon_latency_from"]} == set(range(n)) - {i}
