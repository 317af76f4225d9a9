"""Tests for truav.bus.inbox over real Zenoh sessions (loopback, bounded waits)."""

from __future__ import annotations

import threading
import time

import pytest

from truav.wire import keys, schema
from truav.wire.schema import Action, Beacon

RUN = "test_inbox"
WAIT_S = 3.0
DELAY_S = 0.2


def beacon(uav: int, tick: int) -> Beacon:
    return Beacon(uav=uav, tick=tick, pos=(float(uav), float(tick)), vel=(0.0, 0.0))


def drain_until(box, pred, timeout: float = WAIT_S) -> list:
    """Drain ``box`` (waiting on it) until ``pred(everything drained so far)``; returns everything."""
    got: list = []
    deadline = time.monotonic() + timeout
    while not pred(got) and time.monotonic() < deadline:
        box.wait(0.05)
        got += box.drain()
    return got


def ready(sender, box, key: str, msg) -> list:
    """Publish until the inbox hears it: subscriptions take a moment to propagate."""
    deadline = time.monotonic() + WAIT_S
    while time.monotonic() < deadline:
        sender.publish(key, msg)
        got = drain_until(box, bool, 0.05)
        if got:
            time.sleep(0.1)  # resends still in flight land now, not in the test's own window
            return got + box.drain()
    raise AssertionError("inbox never received")


class KeyFilter:
    """Drops or delays one key suffix; remembers on which threads it ran."""

    def __init__(self, drop: str | None = None, delay: str | None = None) -> None:
        self.drop, self.delay = drop, delay
        self.threads: set[str] = set()

    def decide(self, key, src, dst, now_ns):
        self.threads.add(threading.current_thread().name)
        if self.drop and key.endswith(self.drop):
            return False, 0.0
        if self.delay and key.endswith(self.delay):
            return True, DELAY_S
        return True, 0.0


def test_drain_gives_valid_messages_in_arrival_order_with_their_arrival_time(bus_factory) -> None:
    sender, reader = bus_factory("uav/1"), bus_factory("uav/0")
    box = reader.inbox(keys.all_beacons(RUN))
    ready(sender, box, keys.uav_beacon(RUN, 1), beacon(1, 0))
    before = reader.stats().received

    sent = [sender.publish(keys.uav_beacon(RUN, 1), beacon(1, tick)) for tick in range(1, 21)]
    got = drain_until(box, lambda g: len(g) >= 20)
    assert [r.msg for r in got] == sent  # decoded, validated, in order, nothing lost on loopback
    assert all(r.key == keys.uav_beacon(RUN, 1) and schema.decode(r.raw) == r.msg for r in got)
    assert all(r.recv_ns >= r.msg.t for r in got)
    assert [r.recv_ns for r in got] == sorted(r.recv_ns for r in got)
    assert box.drain() == [] and len(box) == 0
    stats = reader.stats()
    assert stats.received - before == 20 and stats.delivered - before == 20


def test_malformed_messages_are_dropped_and_counted_when_drained(bus_factory) -> None:
    sender, reader = bus_factory("world"), bus_factory("uav/0")
    box = reader.inbox(keys.all_beacons(RUN))
    ready(sender, box, keys.uav_beacon(RUN, 2), beacon(2, 0))
    sender.publish_raw(keys.uav_beacon(RUN, 2), b"\xc1 not msgpack")
    stray = schema.Sequencer("uav/3").stamp(beacon(3, 1))  # a valid beacon on another UAV's key
    sender.publish_raw(keys.uav_beacon(RUN, 2), schema.encode(stray))
    sender.publish_raw(keys.uav_beacon(RUN, 2), b"\x00" * (schema.MAX_SMALL_PAYLOAD_BYTES + 1))  # passes the router
    last = sender.publish(keys.uav_beacon(RUN, 2), beacon(2, 99))
    got = drain_until(box, lambda g: any(r.msg == last for r in g))
    assert [r.msg for r in got] == [last]
    assert reader.dropped_malformed == {schema.R_NOT_MSGPACK: 1, "key_mismatch": 1, schema.R_TOO_LARGE: 1}


def test_wait_wakes_on_arrival_and_times_out_when_idle(bus_factory) -> None:
    sender, reader = bus_factory("uav/1"), bus_factory("uav/0")
    box = reader.inbox(keys.all_beacons(RUN))
    ready(sender, box, keys.uav_beacon(RUN, 1), beacon(1, 0))

    t0 = time.monotonic()
    assert box.wait(0.15) is False
    assert time.monotonic() - t0 >= 0.14

    timer = threading.Timer(0.1, lambda: sender.publish(keys.uav_beacon(RUN, 1), beacon(1, 5)))
    timer.start()
    try:
        t0 = time.monotonic()
        assert box.wait(WAIT_S) is True
        assert time.monotonic() - t0 < WAIT_S / 2  # woken by the arrival, not by the timeout
        assert [r.msg.tick for r in box.drain()] == [5]
    finally:
        timer.cancel()


def test_link_filter_applies_at_arrival(bus_factory) -> None:
    flt = KeyFilter()
    sender, reader = bus_factory("uav/4"), bus_factory("world", link_filter=flt)
    box = reader.inbox(keys.uav_prefix(RUN, 4) + "/*")
    ready(sender, box, keys.uav_beacon(RUN, 4), beacon(4, 0))

    flt.drop = "/beacon"
    for tick in range(1, 6):
        sender.publish(keys.uav_beacon(RUN, 4), beacon(4, tick))
    sender.publish(keys.uav_action(RUN, 4), Action(uav=4, tick=6, action=1))
    got = drain_until(box, lambda g: any(r.msg.tick == 6 for r in g))
    assert [r.msg.tick for r in got] == [6]  # dropped at arrival, never queued
    assert reader.stats().filtered == 5

    flt.drop, flt.delay = None, "/action"
    sent_at = time.monotonic()
    sent = sender.publish(keys.uav_action(RUN, 4), Action(uav=4, tick=7, action=2))
    sender.publish(keys.uav_beacon(RUN, 4), beacon(4, 8))
    got = drain_until(box, lambda g: any(r.msg.tick == 8 for r in g))
    assert [r.msg.tick for r in got] == [8]  # the delayed action is not visible yet
    got = drain_until(box, lambda g: any(r.msg.tick == 7 for r in g))
    assert time.monotonic() - sent_at >= DELAY_S
    assert [r.msg for r in got] == [sent]
    assert got[0].recv_ns - sent.t >= DELAY_S * 1e9  # its receive time is when its delay ended
    assert reader.stats().delayed == 1
    assert not any(name.startswith("truav-bus[") for name in flt.threads)  # no hand-off to the scheduler


@pytest.mark.parametrize("link_filter", [None, KeyFilter()], ids=["unfiltered", "filtered"])
def test_a_full_inbox_keeps_the_newest_and_counts_the_rest(bus_factory, link_filter) -> None:
    sender = bus_factory("uav/1")
    reader = bus_factory("uav/0") if link_filter is None else bus_factory("uav/0", link_filter=link_filter)
    box = reader.inbox(keys.all_beacons(RUN), capacity=4)
    ready(sender, box, keys.uav_beacon(RUN, 1), beacon(1, 0))
    received = reader.stats().received
    for tick in range(1, 11):
        sender.publish(keys.uav_beacon(RUN, 1), beacon(1, tick))
    deadline = time.monotonic() + WAIT_S
    while reader.stats().overflow < 6 and time.monotonic() < deadline:
        time.sleep(0.01)
    assert [r.msg.tick for r in box.drain()] == [7, 8, 9, 10]
    assert reader.stats().overflow == 6
    assert reader.stats().received == received + 10  # each message counted once, evicted or drained


def test_prepare_declares_publishers_within_the_agents_permissions(bus_factory) -> None:
    agent = bus_factory("uav/1")
    agent.prepare(keys.uav_beacon(RUN, 1), keys.uav_action(RUN, 1))
    with pytest.raises(PermissionError):
        agent.prepare(keys.uav_beacon(RUN, 2))  # another UAV's key: refused as publish would be
