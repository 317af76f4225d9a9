"""A plan sent to a live run (`truav-swarm faults`) goes into the supervisor's fault schedule
(truav.swarm.fault_control.FaultController): the old plan's link faults under way end then, its pending ones
are dropped, the new plan's are told (start, end) as a --fault-plan's are; its process faults are not taken."""

from __future__ import annotations

import time
from types import SimpleNamespace

from tests.support.waits import wait_until
from truav.bus.fault_filter import CONTROL_FAULTS
from truav.faults import plan_from_dict
from truav.swarm.fault_control import FaultController
from truav.wire import schema


class FakeBus:
    """What the controller uses of a Bus: subscribe (the control/faults callback kept) and publish (kept)."""

    def __init__(self):
        self.published: list[tuple[str, object]] = []
        self.callbacks: dict[str, object] = {}

    def subscribe(self, key, callback):
        self.callbacks[key] = callback

    def publish(self, key, message):
        self.published.append((key, message))


def _send(bus: FakeBus, plan: dict) -> None:
    (callback,) = [cb for key, cb in bus.callbacks.items() if key.endswith("/control/faults")]
    callback("k", SimpleNamespace(command=CONTROL_FAULTS, args=plan, src="supervisor"), b"", 0)


def test_a_plan_sent_live_replaces_the_link_faults_and_is_told_as_a_plans_are():
    bus = FakeBus()
    plan = plan_from_dict({"fault": [{"kind": "loss", "start": 0.0, "duration": 100.0, "probability": 0.5},
                                     {"kind": "latency", "start": 50.0, "duration": 1.0, "fixed_ms": 10.0}]})
    ctl = FaultController(bus, "r", plan, hooks={})
    ctl.start(time.monotonic())
    try:
        assert wait_until(lambda: len(ctl.events) == 1, 10.0), ctl.events
        time.sleep(0.05)  # the new plan's partition (0-0.01 s) is over when it comes
        _send(bus, {"fault": [{"kind": "loss", "start": 0.0, "duration": 0.3, "probability": 1.0},
                              {"kind": "partition", "start": 0.0, "duration": 0.01, "groups": [[0], [1]]},
                              {"kind": "crash", "start": 0.0, "uav": 1}]})  # over already / a process fault: neither
        assert wait_until(lambda: len(ctl.events) == 4, 10.0), ctl.events
        time.sleep(0.2)  # nothing else comes: the old plan's latency at 50 s was dropped
    finally:
        ctl.stop()
    assert [(kind, phase) for _, kind, phase in ctl.events] == [
        ("loss", "start"), ("loss", "end"), ("loss", "start"), ("loss", "end")], ctl.events
    assert [m.phase for _, m in bus.published] == [schema.PHASE_START, schema.PHASE_END, schema.PHASE_START,
                                                  schema.PHASE_END]
    assert [p["link_faults"] for p in ctl.plans_sent] == [2] and ctl.plans_sent[0]["src"] == "supervisor"


def test_a_bad_plan_sent_live_changes_nothing():
    bus = FakeBus()
    ctl = FaultController(bus, "r", plan_from_dict({}), hooks={})
    _send(bus, {"fault": [{"kind": "loss", "start": -1.0}]})
    assert ctl.plans_sent == [] and ctl.events == []
