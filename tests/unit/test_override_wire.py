"""The override kind (control/override/<i>): a UAV steered from outside. Its schema, key, guard and limits."""

import pytest

from truav.bus import placement
from truav.config import Config
from truav.wire import guard, keys, schema


def _stamped(src="operator", **kw):
    fields = {"uav": 2, "release": False, "goal": (100.0, 250.0), "speed": 0.0, **kw}
    return schema.Sequencer(src).stamp(schema.Override(**fields))


def test_round_trip_and_size_bound():
    msg = _stamped()
    raw = schema.encode(msg)
    back = schema.decode(raw, expect=schema.KIND_OVERRIDE)
    assert back == msg and back.goal == (100.0, 250.0) and back.release is False
    assert len(raw) <= schema.size_limit(schema.KIND_OVERRIDE) == schema.MAX_SMALL_PAYLOAD_BYTES


@pytest.mark.parametrize("bad", [{"uav": -1}, {"uav": keys.MAX_UAVS}, {"speed": -1.0}, {"goal": (float("nan"), 0.0)},
                                 {"release": 1}])
def test_bad_fields_refused(bad):
    with pytest.raises(schema.SchemaError):
        schema.Override(**{"uav": 2, "release": False, "goal": (1.0, 2.0), "speed": 0.0, **bad})


def test_its_key_and_placement():
    key = keys.control_override("r1", 2)
    assert key == "truav/r1/control/override/2"
    assert placement.expected_kind(key) == schema.KIND_OVERRIDE
    assert placement.expected_kind("truav/r1/control/faults") == schema.KIND_CONTROL  # other control keys unchanged
    for odd in ("truav/r1/control/override", "truav/r1/control/override/02", "truav/r1/control/override/2/x"):
        assert placement.expected_kind(odd) is None
    placement.check_placement(key, _stamped())
    with pytest.raises(schema.SchemaError, match="override of uav 3"):
        placement.check_placement(key, _stamped(uav=3))
    with pytest.raises(schema.SchemaError):  # a control command does not belong there
        placement.check_placement(key, schema.Sequencer("supervisor").stamp(schema.Control(command="x", args={})))


def test_guard_takes_operator_and_supervisor_only():
    g = guard.for_config(Config())
    key = keys.control_override("r1", 2)
    assert g.check(key, _stamped("operator")) is None
    assert g.check(key, _stamped("supervisor")) is None
    assert g.check(key, _stamped("uav/2"))[0] == guard.R_SENDER
    assert g.check(key, _stamped("world"))[0] == guard.R_SENDER
    assert g.check(key, _stamped(goal=(-500.0, 0.0)))[0] == guard.R_IMPLAUSIBLE
    assert g.check(key, _stamped(goal=(-500.0, 0.0), release=True)) is None  # a release's goal is not used
    assert g.check(key, _stamped(uav=Config().scenario.n_uavs))[0] == guard.R_IMPLAUSIBLE


def test_world_may_announce_override_events_only():
    g = guard.for_config(Config())
    ev = schema.Sequencer("world").stamp(schema.Fault(fault=schema.FAULT_OVERRIDE, phase="start", target="uav/1",
                                                      params={"tick": 3}))
    assert g.check(keys.fault("r1", "override"), ev) is None
    other = schema.Sequencer("world").stamp(schema.Fault(fault="loss", phase="start", target="*", params={}))
    assert g.check(keys.fault("r1", "loss"), other)[0] == guard.R_SENDER
