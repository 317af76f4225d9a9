"""Rejections told to their sender (truav/wire/rejection_notices.py, the `rejection` kind): bounded per UAV and
period whatever the flood, the UAV only from the key, accepted by an agent only from the world, delivered by
Bus.subscribe_rare (no pump thread), counted by the project's agent. The swarm-level checks (an out-of-range
action told to its sender, plain and --secure; a flood) are in tests/swarm/test_world_accounting.py, the router's
(only uav/i reads uav/i/rejected) in tests/swarm/test_security.py."""

from __future__ import annotations

import threading
import time
from types import SimpleNamespace

from agents.process.agent_process import AgentNode
from truav.wire import guard, keys, schema
from truav.wire.rejection_notices import RejectionNotices
from truav.wire.schema_names import MAX_DETAIL_LEN
from tests.support.waits import wait_matched

RUN = "told"
KEY = keys.uav_action(RUN, 1)


def test_a_flood_is_told_once_per_period_with_every_refusal_counted() -> None:
    n = RejectionNotices(4, period_s=0.1)
    for k in range(10_000):
        n.note(1, "out_of_range" if k % 2 else "bad_type", "action", KEY, 7, f"refusal {k}")
    first = n.due(now=100.0)
    assert len(first) == 1 and first[0].uav == 1 and first[0].reason == "bad_type" and first[0].detail == "refusal 0"
    assert first[0].counts == {"bad_type": 5000, "out_of_range": 5000} and first[0].at_tick == 7
    n.note(1, "out_of_range", "action", KEY, 8, "again")
    assert n.due(now=100.05) == [] and n.pending()  # within the period: kept, counted
    n.note(1, "out_of_range", "action", KEY, 9, "and again")
    later = n.due(now=100.2)
    assert len(later) == 1 and later[0].counts == {"out_of_range": 2} and later[0].at_tick == 8
    assert not n.pending() and n.sent == 2


def test_bounded_per_call_and_outside_uavs_ignored() -> None:
    n = RejectionNotices(100, max_per_round=10)
    for uav in range(-3, 200):
        n.note(uav, "out_of_range", "action", keys.uav_action(RUN, max(uav, 0)) if uav < 1024 else "?", 1, "x")
    assert len(n.due(0.0)) == 10 and len(n.due(0.0)) == 10  # 10 UAVs a call; the ids outside [0, 100) dropped
    told = 20
    while n.pending():
        told += len(n.due(0.0))
    assert told == 100


def test_detail_is_cut_to_printable_ascii_and_the_message_validates() -> None:
    n = RejectionNotices(2)
    n.note(0, "out_of_range", "", "truav/told/uav/0/action", -1, "é\x00" + "x" * 500)
    (msg,) = n.due(0.0)
    assert len(msg.detail) == MAX_DETAIL_LEN and msg.detail.isascii() and msg.detail.isprintable()
    stamped = schema.Sequencer("world").stamp(msg)
    assert schema.decode(schema.encode(stamped), schema.KIND_REJECTION) == stamped


def test_an_agent_takes_rejections_only_from_the_world(small_cfg) -> None:
    g = guard.for_config(small_cfg.replace(scenario={"n_uavs": 3}))
    msg = schema.Rejection(uav=1, at_tick=3, reason="out_of_range", refused_kind="action", key=KEY, detail="d",
                           counts={"out_of_range": 1})
    assert g.check(keys.uav_rejected(RUN, 1), schema.Sequencer("world").stamp(msg)) is None
    assert g.check(keys.uav_rejected(RUN, 1), schema.Sequencer("uav/1").stamp(msg))[0] == guard.R_SENDER


def test_poll_subscribe_delivers_valid_rejections_without_a_thread_and_refuses_forged_ones(bus_factory,
                                                                                           small_cfg) -> None:
    world, agent, mallory = bus_factory("world"), bus_factory("uav/1"), bus_factory("supervisor")
    agent.guard = guard.for_config(small_cfg.replace(scenario={"n_uavs": 3}))
    got: list[schema.Rejection] = []
    threads_before = threading.active_count()
    drain = agent.poll_subscribe(keys.uav_rejected(RUN, 1), lambda key, msg, raw, t: got.append(msg), capacity=8)
    assert threading.active_count() == threads_before  # no thread of its own
    assert wait_matched(mallory, keys.uav_rejected(RUN, 1)) and wait_matched(world, keys.uav_rejected(RUN, 1))
    msg = schema.Rejection(uav=1, at_tick=3, reason="out_of_range", refused_kind="action", key=KEY, detail="d",
                           counts={"out_of_range": 1})
    mallory.publish(keys.uav_rejected(RUN, 1), msg)  # from the supervisor: refused (forbidden_sender)
    for _ in range(20):  # a flood: the ring keeps the newest 8
        world.publish(keys.uav_rejected(RUN, 1), msg)
    deadline = time.monotonic() + 10
    taken = 0
    while taken < 8 and time.monotonic() < deadline:
        time.sleep(0.1)
        taken += drain()
    assert 1 <= len(got) <= 8 and {(m.src, m.uav) for m in got} == {("world", 1)}
    assert drain() == 0


def test_the_project_agent_counts_what_the_world_refused(caplog) -> None:
    node = SimpleNamespace(refused_by_world={}, opts=SimpleNamespace(uav=1))
    for counts in ({"out_of_range": 3}, {"out_of_range": 2, "late_action": 1}):
        AgentNode._on_rejected(node, KEY, schema.Rejection(uav=1, at_tick=3, reason=next(iter(counts)),
                                                            refused_kind="action", key=KEY, detail="d",
                                                            counts=counts), b"", 0)
    assert node.refused_by_world == {"out_of_range": 5, "late_action": 1}
    refused_lines = [r for r in caplog.records if "the world refused" in r.getMessage()]
    assert len(refused_lines) == 2  # each reason's first only
