"""Tests for truav.bus.transport over real Zenoh sessions, loopback only.

One in-process router per module on a free tcp/127.0.0.1 port; every Bus is a
client of it.  Multicast scouting is off, every wait is bounded.
"""

from __future__ import annotations

import argparse
import json
import logging
import threading
import time
from collections.abc import Callable

import msgpack
import pytest

from tests.support.waits import free_port, wait_matched
import zenoh

from truav.cli import args as cli_args
from tests.support.waits import wait_until as _wait_until
from truav.bus import transport
from truav.wire import keys, schema
from truav.wire.schema import Action, Beacon, Obs, SchemaError

RUN = "test_run"
WAIT_S = 3.0
POLL_S = 0.005
RESEND_S = 0.02
DELAY_S = 0.2
LEAVE_BUDGET_S = 1.0


def wait_until(pred: Callable[[], bool], timeout: float = WAIT_S) -> bool:
    return _wait_until(pred, timeout, POLL_S)


def obs(uav: int = 0, tick: int = 0) -> Obs:
    return Obs(tick=tick, episode=0, uav=uav, pos=(1.0, 2.0), vehicles_in_range=3, queued_packets=4, relayed=1,
               covered=2, energy_j=0.5, speed_max=20.0, done=False)


def beacon(uav: int, tick: int = 0) -> Beacon:
    return Beacon(uav=uav, tick=tick, pos=(float(uav), 0.0), vel=(0.0, 0.0))


class Inbox:
    """Collects Bus deliveries for assertions."""

    def __init__(self) -> None:
        self.items: list[tuple[str, schema.Message, bytes, int, float, str]] = []
        self.lock = threading.Lock()

    def __call__(self, key: str, msg: schema.Message, raw: bytes, recv_ns: int) -> None:
        with self.lock:
            self.items.append((key, msg, raw, recv_ns, time.monotonic(), threading.current_thread().name))

    def msgs(self) -> list[schema.Message]:
        with self.lock:
            return [item[1] for item in self.items]


def sync(publish: Callable[[], object], received: Callable[[], bool]) -> None:
    """Publish until the subscriber sees something: subscription declarations take a moment to propagate."""
    deadline = time.monotonic() + WAIT_S
    while time.monotonic() < deadline:
        publish()
        if wait_until(received, RESEND_S):
            return
    raise AssertionError("subscription never became ready")


# --- config -------------------------------------------------------------------------
def test_make_config_turns_multicast_off_and_sets_endpoints() -> None:
    conf = transport.make_config("peer", connect=["tcp/127.0.0.1:1"], listen=["tcp/127.0.0.1:0"])
    assert json.loads(conf.get_json("scouting/multicast/enabled")) is False
    assert json.loads(conf.get_json("mode")) == "peer"
    assert json.loads(conf.get_json("connect/endpoints")) == ["tcp/127.0.0.1:1"]
    client = transport.make_config()
    assert json.loads(client.get_json("connect/endpoints")) == [transport.DEFAULT_ENDPOINT]
    router = transport.make_config("router")
    assert json.loads(router.get_json("listen/endpoints")) == [transport.DEFAULT_ENDPOINT]
    with pytest.raises(ValueError):
        transport.make_config("broker")


def test_config_from_args(tmp_path) -> None:
    parser = cli_args.add_transport_args(argparse.ArgumentParser())
    args = parser.parse_args(["-m", "peer", "-e", "tcp/127.0.0.1:7000", "-e", "tcp/127.0.0.1:7001",
                              "-l", "tcp/127.0.0.1:0"])
    conf = transport.config_from_args(args)
    assert json.loads(conf.get_json("connect/endpoints")) == ["tcp/127.0.0.1:7000", "tcp/127.0.0.1:7001"]
    assert json.loads(conf.get_json("mode")) == "peer"
    cfg_file = tmp_path / "z.json5"
    cfg_file.write_text('{ mode: "router", scouting: { multicast: { enabled: true } } }')
    conf = transport.config_from_args(parser.parse_args(["--config", str(cfg_file)]))
    assert json.loads(conf.get_json("mode")) == "router"  # the file's mode is kept
    assert json.loads(conf.get_json("scouting/multicast/enabled")) is False  # but multicast is always off
    assert json.loads(transport.config_from_args(parser.parse_args([])).get_json("mode")) == "client"


# --- pub/sub ------------------------------------------------------------------------
def test_pubsub_roundtrip_through_router(bus_factory) -> None:
    world, agent = bus_factory("world"), bus_factory("uav/0")
    inbox = Inbox()
    agent.subscribe(keys.uav_obs(RUN, 0), inbox)
    sync(lambda: world.publish(keys.uav_obs(RUN, 0), obs(tick=0)), lambda: bool(inbox.msgs()))
    sent = world.publish(keys.uav_obs(RUN, 0), obs(tick=42))
    assert wait_until(lambda: any(m.tick == 42 for m in inbox.msgs()))
    key, msg, raw, recv_ns, _, thread = next(item for item in inbox.items if item[1].tick == 42)
    assert key == keys.uav_obs(RUN, 0)
    assert msg == sent and msg.src == "world" and msg.KIND == schema.KIND_OBS
    assert schema.decode(raw) == sent
    assert recv_ns >= sent.t
    assert not thread.startswith("truav-bus[")  # undelayed messages are delivered in place, no hand-off
    seqs = [m.seq for m in inbox.msgs()]
    assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs)

    # the agent answers from inside its callback: callbacks may publish
    actions = Inbox()
    world.subscribe(keys.all_actions(RUN), actions)
    agent.subscribe(keys.uav_obs(RUN, 0), lambda k, m, r, t: agent.publish(
        keys.uav_action(RUN, 0), Action(uav=0, tick=m.tick, action=m.tick % schema.N_ACTIONS)))
    sync(lambda: world.publish(keys.uav_obs(RUN, 0), obs(tick=7)), lambda: bool(actions.msgs()))
    assert actions.msgs()[0].src == "uav/0" and actions.msgs()[0].action == 7


def test_one_bus_never_runs_two_callbacks_at_once(bus_factory) -> None:
    """Subscribers deliver on their own threads, but a Bus serializes its user callbacks."""
    world, agent = bus_factory("world"), bus_factory("uav/0")
    running, overlaps, seen = [0], [0], []
    guard = threading.Lock()

    def slow(key: str, msg: schema.Message, raw: bytes, recv_ns: int) -> None:
        with guard:
            running[0] += 1
            overlaps[0] = max(overlaps[0], running[0])
        time.sleep(0.002)  # long enough for the other subscriber's thread to try to enter
        with guard:
            running[0] -= 1
            seen.append(key)

    agent.subscribe(keys.uav_obs(RUN, 0), slow)
    agent.subscribe(keys.control(RUN, "test"), slow)
    sync(lambda: world.publish(keys.uav_obs(RUN, 0), obs(tick=0)), lambda: bool(seen))
    for tick in range(1, 41):
        world.publish(keys.uav_obs(RUN, 0), obs(tick=tick))
        world.publish(keys.control(RUN, "test"), schema.Control(command="pause", args={}))
    assert wait_until(lambda: sum(k == keys.control(RUN, "test") for k in seen) == 40)
    assert overlaps[0] == 1


def test_malformed_messages_are_dropped_counted_and_logged_once(bus_factory, caplog) -> None:
    world, agent, recorder = bus_factory("world"), bus_factory("uav/1"), bus_factory("recorder")
    inbox, raw_seen = Inbox(), []
    key = keys.uav_obs(RUN, 1)
    agent.subscribe(key, inbox)
    recorder.subscribe_raw(keys.everything(RUN), lambda k, raw, t: raw_seen.append(raw))
    sync(lambda: world.publish(key, obs(uav=1, tick=0)), lambda: bool(inbox.msgs()) and bool(raw_seen))
    before = len(raw_seen)

    caplog.set_level(logging.WARNING, logger="truav.bus.transport")
    garbage = [b"\xc1 not msgpack", b"\xc1 still not", msgpack.packb({"v": 1, "kind": "obs"}),
               msgpack.packb([1, 2])]
    for payload in garbage:
        world.publish_raw(key, payload)
    stray = schema.Sequencer("world").stamp(beacon(uav=1))  # a valid beacon on an obs key
    world.publish_raw(key, schema.encode(stray))
    # Just over an observation's limit: within the router's slack, so the application refuses it by length
    # (anything much bigger never leaves the router: test_router_drops_oversized_puts_...).
    world.publish_raw(key, b"\x00" * (schema.MAX_SMALL_PAYLOAD_BYTES + 1))
    assert transport.congestion_control(key) == zenoh.CongestionControl.BLOCK  # so none of this is lost
    world.publish(key, obs(uav=1, tick=99))  # the subscriber keeps working afterwards

    assert wait_until(lambda: any(m.tick == 99 for m in inbox.msgs()))
    assert wait_until(lambda: len(raw_seen) >= before + len(garbage) + 3)
    assert agent.dropped_malformed == {schema.R_NOT_MSGPACK: 2, schema.R_MISSING_FIELD: 1, schema.R_NOT_MAP: 1,
                                       transport.R_KEY_MISMATCH: 1, schema.R_TOO_LARGE: 1}
    assert agent.stats().dropped_malformed == 6
    assert [m.tick for m in inbox.msgs()][-1] == 99 and all(isinstance(m, Obs) for m in inbox.msgs())
    assert set(garbage) <= set(raw_seen)  # the raw subscription sees everything
    lines = [r.getMessage() for r in caplog.records if "malformed" in r.getMessage()]
    assert len(lines) == 5  # once per reason, not once per message
    assert any(key in line and "unknown sender" in line and "missing_field" in line for line in lines)
    assert any(key in line and "from world" in line and transport.R_KEY_MISMATCH in line for line in lines)


def test_callback_errors_do_not_kill_the_subscription(bus_factory) -> None:
    world, agent = bus_factory("world"), bus_factory("uav/2")
    seen: list[int] = []

    def flaky(key: str, msg: schema.Message, raw: bytes, recv_ns: int) -> None:
        seen.append(msg.tick)
        if msg.tick % 2:
            raise RuntimeError("boom")

    agent.subscribe(keys.uav_obs(RUN, 2), flaky)
    sync(lambda: world.publish(keys.uav_obs(RUN, 2), obs(uav=2, tick=0)), lambda: bool(seen))
    for tick in (1, 2, 3, 4):
        world.publish(keys.uav_obs(RUN, 2), obs(uav=2, tick=tick))
    assert wait_until(lambda: 4 in seen)
    assert agent.stats().callback_errors == 2


# --- link filter ------------------------------------------------------------------------
class KeyFilter:
    """Drops or delays messages whose key ends with a suffix; records its calls."""

    def __init__(self) -> None:
        self.drop_suffix: str | None = None
        self.delay_suffix: str | None = None
        self.delay_s = 0.0
        self.calls: list[tuple[str, str, str]] = []

    def decide(self, key: str, src: str, dst: str, now_ns: int) -> tuple[bool, float]:
        self.calls.append((key, src, dst))
        if self.drop_suffix and key.endswith(self.drop_suffix):
            return False, 0.0
        if self.delay_suffix and key.endswith(self.delay_suffix):
            return True, self.delay_s
        return True, 0.0


def test_link_filter_drops(bus_factory) -> None:
    flt = KeyFilter()
    listener, sender = bus_factory("world", link_filter=flt), bus_factory("uav/1")
    inbox = Inbox()
    listener.subscribe(f"{keys.uav_prefix(RUN, 1)}/*", inbox)
    sync(lambda: sender.publish(keys.uav_action(RUN, 1), Action(uav=1, tick=0, action=0)),
         lambda: bool(inbox.msgs()))
    assert (keys.uav_action(RUN, 1), "uav/1", "world") in flt.calls

    flt.drop_suffix = "/action"
    for tick in range(1, 6):
        sender.publish(keys.uav_action(RUN, 1), Action(uav=1, tick=tick, action=3))
    # >= : on a busy host more of sync()'s tick-0 resends may still be on their way, and are dropped too
    assert wait_until(lambda: listener.stats().filtered >= 5)
    # other keys still pass (beacons are droppable under congestion: resend until one lands)
    sync(lambda: sender.publish(keys.uav_beacon(RUN, 1), beacon(1, 9)),
         lambda: any(isinstance(m, Beacon) for m in inbox.msgs()))
    assert not [m for m in inbox.msgs() if isinstance(m, Action) and m.tick > 0]


def test_link_filter_delays_on_one_scheduler_thread(bus_factory) -> None:
    flt = KeyFilter()
    listener, sender = bus_factory("world", link_filter=flt), bus_factory("uav/3")
    inbox = Inbox()
    listener.subscribe(keys.all_actions(RUN), inbox)
    sync(lambda: sender.publish(keys.uav_action(RUN, 3), Action(uav=3, tick=0, action=0)),
         lambda: bool(inbox.msgs()))

    flt.delay_suffix, flt.delay_s = "/action", DELAY_S
    threads_before = threading.active_count()
    sent_at: dict[int, float] = {}
    for tick in range(100, 120):
        sent_at[tick] = time.monotonic()
        sender.publish(keys.uav_action(RUN, 3), Action(uav=3, tick=tick, action=1))
    assert threading.active_count() == threads_before  # no thread per delayed message
    assert wait_until(lambda: sum(m.tick >= 100 for m in inbox.msgs()) == 20)
    delayed = [item for item in inbox.items if item[1].tick >= 100]
    latencies = [arrived - sent_at[msg.tick] for _, msg, _, _, arrived, _ in delayed]
    assert min(latencies) >= DELAY_S
    assert max(latencies) < DELAY_S + 1.0  # generous: loaded CI machines
    assert all(recv_ns - msg.t >= DELAY_S * 1e9 for _, msg, _, recv_ns, _, _ in delayed)
    assert [m.tick for _, m, *_ in delayed] == list(range(100, 120))  # equal delays keep order
    assert listener.stats().delayed == 20


# --- permissions ---------------------------------------------------------------------------
def test_publish_permission_check(bus_factory) -> None:
    agent, world = bus_factory("uav/3"), bus_factory("world")
    agent.publish(keys.uav_beacon(RUN, 3), beacon(3))  # own key: fine
    agent.declare_liveliness(keys.alive_uav(RUN, 3))
    for key in (keys.uav_beacon(RUN, 4), keys.world_tick(RUN), keys.uav_beacon("other_run", 3),
                keys.metrics_step(RUN)):
        with pytest.raises(PermissionError, match="uav/3"):
            agent.publish(key, beacon(3))
    with pytest.raises(PermissionError):
        agent.publish_raw(keys.uav_action(RUN, 4), b"x")
    with pytest.raises(PermissionError):
        agent.declare_liveliness(keys.alive_uav(RUN, 4))
    with pytest.raises(PermissionError):
        agent.declare_liveliness(keys.alive_world(RUN))
    with pytest.raises(ValueError, match="wildcards"):
        agent.publish(f"{keys.uav_prefix(RUN, 3)}/*", beacon(3))
    with pytest.raises(SchemaError):  # a beacon on an action key would be dropped by receivers
        agent.publish(keys.uav_action(RUN, 3), beacon(3))
    with pytest.raises(SchemaError):  # and so would a beacon about another UAV
        agent.publish(keys.uav_beacon(RUN, 3), beacon(4))
    world.publish(keys.uav_obs(RUN, 3), obs(uav=3))  # the world may address any agent
    with pytest.raises(SchemaError):
        world.publish(keys.metrics_step(RUN), schema.Metrics(scope=schema.SCOPE_EPISODE, tick=0, episode=0,
                                                              values={}))
    with pytest.raises(SchemaError):
        world.publish(keys.fault(RUN, "loss"), schema.Fault(fault="crash", phase="start", target="uav/1",
                                                            params={}))
    with pytest.raises(PermissionError):
        world.publish(keys.world_tick("other_run"), schema.Tick(tick=0, episode=0, sim_time=0.0,
                                                                deadline_ms=1.0, n_uavs=1))
    with pytest.raises(ValueError):
        bus_factory("uav/5000")


# --- liveliness -------------------------------------------------------------------------------
def test_liveliness_join_and_leave(bus_factory) -> None:
    recorder = bus_factory("recorder")
    early = bus_factory("uav/5")
    early.declare_liveliness(keys.alive_uav(RUN, 5))
    joins: list[str] = []
    leaves: list[tuple[str, float]] = []
    recorder.watch_liveliness(keys.all_alive(RUN), joins.append, lambda k: leaves.append((k, time.monotonic())))
    assert wait_until(lambda: keys.alive_uav(RUN, 5) in joins)  # history: tokens alive before the watch

    late = bus_factory("uav/6")
    late.declare_liveliness(keys.alive_uav(RUN, 6))
    assert wait_until(lambda: keys.alive_uav(RUN, 6) in joins)
    both = [keys.alive_uav(RUN, 5), keys.alive_uav(RUN, 6)]
    assert wait_until(lambda: recorder.alive(keys.all_alive_uavs(RUN)) == both)

    closed_at = time.monotonic()
    late.close()
    assert wait_until(lambda: any(k == keys.alive_uav(RUN, 6) for k, _ in leaves), LEAVE_BUDGET_S)
    left_at = next(t for k, t in leaves if k == keys.alive_uav(RUN, 6))
    assert left_at - closed_at < LEAVE_BUDGET_S
    assert wait_until(lambda: recorder.alive(keys.all_alive_uavs(RUN)) == [keys.alive_uav(RUN, 5)])
    assert keys.alive_uav(RUN, 5) not in [k for k, _ in leaves]


def test_closed_bus_refuses_work(bus_factory) -> None:
    bus = bus_factory("world")
    bus.close()
    bus.close()  # idempotent
    assert bus.closed
    with pytest.raises(RuntimeError):
        bus.publish(keys.uav_obs(RUN, 0), obs())


# --- router -------------------------------------------------------------------------------
def test_run_router_serves_clients_until_stopped() -> None:
    ep = f"tcp/127.0.0.1:{free_port()}"
    stop = threading.Event()
    thread = threading.Thread(target=transport.run_router, args=([ep],), kwargs={"stop": stop}, daemon=True)
    thread.start()
    conf = transport.make_config("client", connect=[ep], connect_timeout_ms=int(WAIT_S * 1000))
    with zenoh.open(conf) as session:
        assert wait_until(lambda: len(session.info.routers_zid()) == 1)
    stop.set()
    thread.join(WAIT_S)
    assert not thread.is_alive()


def test_router_drops_oversized_puts_before_any_subscriber_sees_them(endpoint) -> None:
    """The router's low-pass filter (Zenoh's own) refuses a put larger than its key's kind may be:
    an attacker's 1 MB observation is never copied to the agent or the recorder."""
    conf = transport.make_config("client", connect=[endpoint])
    small_limit = schema.size_limit(schema.KIND_OBS)
    with zenoh.open(conf) as attacker, zenoh.open(transport.make_config("client", connect=[endpoint])) as victim:
        got: list[tuple[str, int]] = []
        victim.declare_subscriber(f"truav/{RUN}/**", lambda s: got.append((str(s.key_expr), len(s.payload))))
        obs_key, pos_key = keys.uav_obs(RUN, 0), keys.world_positions(RUN)
        assert wait_matched(attacker, obs_key) and wait_matched(attacker, pos_key)  # the subscription is known
        block = zenoh.CongestionControl.BLOCK  # not dropped by a congested session (a busy host): only the filter drops
        attacker.put(obs_key, b"x" * (small_limit + 2048), congestion_control=block)  # too big for an observation
        attacker.put(pos_key, b"x" * (small_limit + 2048), congestion_control=block)  # fine for positions (1 MiB)
        attacker.put(pos_key, b"x" * (schema.MAX_PAYLOAD_BYTES + 4096), congestion_control=block)  # too big for all
        attacker.put(obs_key, b"x" * 100, congestion_control=block)  # a small one still passes
        assert wait_until(lambda: len(got) >= 2, 30.0), got
        time.sleep(0.3)
    assert got == [(pos_key, small_limit + 2048), (obs_key, 100)]


def test_await_subscribers_says_whether_someone_listens_before_a_one_shot_put(bus_factory):
    # `truav-swarm down` sends one message from a fresh session: without the wait its publisher
    # drops it when the router has not yet told it of the world's subscription.
    sender, listener = bus_factory("supervisor"), bus_factory("world")
    key = keys.control(RUN, "shutdown")
    assert sender.await_subscribers(key, 0.3) is False
    got = []
    listener.subscribe(keys.all_control(RUN), lambda k, msg, raw, t: got.append(msg.command))
    assert sender.await_subscribers(key, 5.0) is True
    sender.publish(key, schema.Control(command="shutdown", args={}))
    deadline = time.monotonic() + 5
    while not got and time.monotonic() < deadline:
        time.sleep(0.01)
    assert got == ["shutdown"]


def test_close_while_another_thread_publishes_does_not_raise(bus_factory) -> None:
    """An agent's shutdown closes its Bus while a callback may still be inside a put: close()
    must finish (it raised "Already borrowed" from the busy publisher, failing the shutdown), and
    the put gets the Bus's "closed" RuntimeError that publishers handle, not Zenoh's "session closed"
    (which escaped an agent's health thread)."""
    for _ in range(20):
        world = bus_factory("world")
        stop = threading.Event()
        errors: list[BaseException] = []

        def hammer() -> None:
            while not stop.is_set():
                try:
                    world.publish(keys.uav_obs(RUN, 0), obs(tick=1))
                except RuntimeError:  # "bus world is closed" (also when close() ran during the put): the end
                    return
                except BaseException as exc:  # anything else is a bug
                    errors.append(exc)
                    return

        t = threading.Thread(target=hammer, daemon=True)
        t.start()
        time.sleep(0.005)
        try:
            world.close()  # must not raise
        finally:
            stop.set()
            t.join(5)
        assert not errors, errors
