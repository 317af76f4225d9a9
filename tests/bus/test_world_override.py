"""The world's handling of overrides (control/override/<i>): the newest per UAV is applied at the next acting
tick, each start and end is told on fault/override and kept in the statistics, a flood costs one entry per UAV."""

from __future__ import annotations

import numpy as np

from tests.support.waits import wait_until
from truav.config import Config
from truav.wire import keys, schema

RUN = "override"


def test_world_steers_the_newest_override_and_tells_each_start_and_end(bus_factory) -> None:
    from world.process.world_process import WorldNode, WorldOptions
    cfg = Config().replace(scenario={"n_vehicles": 20, "n_uavs": 3, "steps_per_episode": 5})
    node = WorldNode(cfg, WorldOptions(run=RUN), bus_factory("world"))
    heard: list[schema.Fault] = []
    listener = bus_factory("recorder")
    listener.subscribe(keys.fault(RUN, "override"), lambda k, m, r, t: heard.append(m))
    assert wait_until(lambda: node.bus.await_subscribers(keys.fault(RUN, "override"), 0.1), 10)
    stamp = schema.Sequencer("operator").stamp
    obs = node.world.reset([np.random.default_rng(0)])
    pos = obs.pos[0]
    for k in range(1000):  # a flood for UAV 1: only the newest counts
        node._on_override("k", stamp(schema.Override(uav=1, release=False, goal=(float(k), 0.0), speed=0.0)), b"", 0)
    node._on_override("k", stamp(schema.Override(uav=2, release=True, goal=(0.0, 0.0), speed=0.0)), b"", 0)  # not overridden
    east = pos[1, 0] < 2500.0
    goal = (float(pos[1, 0] + (1000.0 if east else -1000.0)), float(pos[1, 1]))
    node._on_override("k", stamp(schema.Override(uav=1, release=False, goal=goal, speed=0.0)), b"", 0)
    assert len(node._override_inbox) == 2
    actions = node._steer(4, obs, np.array([[3, 3, 3]], np.int64))
    assert actions[0, 0] == 3 and actions[0, 2] == 3 and actions[0, 1] == (8 if east else 12)  # full speed east / west
    assert node.overrides == {1: (goal[0], goal[1], 0.0)} and not node._override_inbox
    assert node._steer(5, obs, np.array([[1, 1, 1]], np.int64))[0, 1] == actions[0, 1]  # lasts until released
    node._on_override("k", stamp(schema.Override(uav=1, release=True, goal=(0.0, 0.0), speed=0.0)), b"", 0)
    assert node._steer(6, obs, np.array([[1, 1, 1]], np.int64)).tolist() == [[1, 1, 1]]
    assert [(o["uav"], o["phase"], o["tick"], o["by"]) for o in node.stats.overrides] == \
        [(1, "start", 4, "operator"), (1, "end", 6, "operator")]
    assert wait_until(lambda: len(heard) == 2, 10)
    assert [(m.phase, m.target, m.params["tick"], m.src) for m in heard] == \
        [("start", "uav/1", 4, "world"), ("end", "uav/1", 6, "world")]
