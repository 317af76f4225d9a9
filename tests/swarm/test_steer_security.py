"""Under --secure only an allowed identity may steer a UAV from outside: the router forwards an override put
by `operator` (or `supervisor`) and drops one put by a UAV's identity; the world may announce override events.

Bare zenoh sessions on a loopback TLS router (what Zenoh itself enforces, not the application)."""

from __future__ import annotations

import time

import pytest

from tests.support.secure_router import client, secure_router, until
from tests.support.waits import wait_matched
from truav.bus import security
from truav.wire import keys

RUN = "steersec"
N = 3
WAIT_S = 1.0  # how long a subscriber listens for puts that must not arrive (they would take ~1 ms)


@pytest.fixture(scope="module")
def creds(tmp_path_factory):
    with secure_router(tmp_path_factory.mktemp("creds"), RUN, N) as issued:
        yield issued


def test_operator_is_issued_and_may_put_overrides_only():
    table = {g.identity: g for g in security.grants(RUN, N)}
    assert "operator" in table and table["operator"].put == (keys.all_overrides(RUN),)
    lines = security.explain(tuple(table.values()), key=keys.control_override(RUN, 1))
    by_id = {line.split()[0]: line for line in lines[:-1]}
    assert "may put" in by_id["operator"] and "may put" in by_id["supervisor"]
    assert "may put" not in by_id["uav/1"] and "may put" not in by_id["uav/2"] and "may subscribe" in by_id["world"]


def test_router_forwards_an_operators_override_and_drops_a_uavs(creds):
    world, operator, agent2 = client(creds, "world"), client(creds, "operator"), client(creds, "uav/2")
    try:
        got: list[tuple[str, bytes]] = []
        world.declare_subscriber(keys.all_control(RUN), lambda s: got.append((str(s.key_expr), s.payload.to_bytes())))
        assert wait_matched(operator, keys.control_override(RUN, 1))  # the subscription reached the router
        agent2.put(keys.control_override(RUN, 1), b"from uav/2")
        agent2.put(keys.control_override(RUN, 2), b"own uav, still not allowed")
        operator.put(keys.control(RUN, "shutdown"), b"operator may not stop the run")
        operator.put(keys.control_override(RUN, 1), b"from operator")
        assert until(lambda: (keys.control_override(RUN, 1), b"from operator") in got)
        time.sleep(WAIT_S)
        assert got == [(keys.control_override(RUN, 1), b"from operator")]
    finally:
        for s in (agent2, operator, world):
            s.close()


def test_operator_hears_the_worlds_override_events(creds):
    world, operator = client(creds, "world"), client(creds, "operator")
    try:
        got: list[str] = []
        operator.declare_subscriber(keys.fault(RUN, "override"), lambda s: got.append(str(s.key_expr)))
        assert wait_matched(world, keys.fault(RUN, "override"))
        world.put(keys.fault(RUN, "override"), b"x")
        assert until(lambda: got == [keys.fault(RUN, "override")])
    finally:
        for s in (operator, world):
            s.close()
