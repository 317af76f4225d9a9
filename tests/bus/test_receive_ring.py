"""Receive rings (Bus.receive_ring): a flood costs a real-time process bounded work; FIFO loses nothing."""

from __future__ import annotations

import threading
import time

import zenoh

from tests.support.waits import wait_matched, wait_until
from truav.bus import transport
from truav.wire import keys, schema

RUN = "ring"


def _action(tick: int) -> schema.Action:
    return schema.Action(uav=0, tick=tick, action=3)


def _flood_while_stalled(bus_factory, endpoint: str, ring: int | None, junk: int) -> tuple[transport.Bus, list[int]]:
    """A reader that is stuck in its first callback while ``junk`` garbage puts and one valid action
    arrive; then released. Returns the reader's bus and the ticks it was delivered."""
    reader = bus_factory("world")
    reader.receive_ring = ring
    stalled, delivered = threading.Event(), []

    def on_action(key, msg, raw, recv_ns) -> None:
        delivered.append(msg.tick)
        if len(delivered) == 1:
            stalled.wait(10)

    reader.subscribe(keys.uav_action(RUN, 0), on_action)
    agent = bus_factory("uav/0")
    agent.prepare(keys.uav_action(RUN, 0))
    assert wait_matched(agent, keys.uav_action(RUN, 0))  # the subscription reached the router
    agent.publish(keys.uav_action(RUN, 0), _action(1))
    assert wait_until(lambda: delivered == [1], 10)
    attacker = zenoh.open(transport.make_config("client", connect=[endpoint]))
    # The attacker's puts and the agent's come over different links: only once a marker put after the junk
    # (same link and priority, so in order behind it) has reached the reader's session has all the junk too.
    flushed = threading.Event()
    marker = reader._session.declare_subscriber(f"{keys.prefix(RUN)}/test/marker", lambda _s: flushed.set())
    try:
        time.sleep(0.3)  # the marker's subscription reached the router
        for n in range(junk):  # DROP: the attacker must not stall on a reader that pushes back
            attacker.put(keys.uav_action(RUN, 0), b"\xc1" * (1 + n % 7), congestion_control=zenoh.CongestionControl.DROP)
        attacker.put(f"{keys.prefix(RUN)}/test/marker", b"", congestion_control=zenoh.CongestionControl.BLOCK)
        assert flushed.wait(10), "the marker behind the junk never arrived"
        agent.publish(keys.uav_action(RUN, 0), _action(2))  # the valid one comes last: the newest
        time.sleep(0.5)
        stalled.set()
        assert wait_until(lambda: 2 in delivered, 60), delivered  # behind the junk's refusals on a busy host
    finally:
        marker.undeclare()
        attacker.close()
    return reader, delivered


def test_a_flood_on_a_ring_key_costs_at_most_the_ring(bus_factory, endpoint) -> None:
    reader, delivered = _flood_while_stalled(bus_factory, endpoint, ring=64, junk=5000)
    st = reader.stats()
    # What the stalled reader ever saw: the first action, the ring's 64 newest samples and what came in
    # while it drained them; the rest was dropped inside Zenoh and cost this process no Python at all.
    assert st.received <= 1 + 64 + 8, st
    assert delivered == [1, 2] and sum(st.malformed.values()) == st.received - 2


def test_a_fifo_key_loses_nothing(bus_factory, endpoint) -> None:
    reader, delivered = _flood_while_stalled(bus_factory, endpoint, ring=None, junk=500)
    st = reader.stats()
    assert delivered == [1, 2] and sum(st.malformed.values()) >= 1  # nothing valid lost behind the junk


def test_a_full_realtime_inbox_evicts_without_decoding(bus_factory, endpoint) -> None:
    reader = bus_factory("uav/1")
    reader.receive_ring = transport.REALTIME_RECEIVE_RING
    box = reader.inbox(keys.all_beacons(RUN), capacity=8, compact=False)
    time.sleep(0.3)
    attacker = zenoh.open(transport.make_config("client", connect=[endpoint]))
    try:
        for _ in range(200):
            attacker.put(keys.uav_beacon(RUN, 0), b"\xc1")
        assert wait_until(lambda: reader.stats().overflow >= 150, 10), reader.stats()
        assert reader.stats().malformed == {}  # evicting decoded none of them
        assert len(box.drain()) == 0 and sum(reader.stats().malformed.values()) <= 8  # the drain decodes <= capacity
    finally:
        attacker.close()
