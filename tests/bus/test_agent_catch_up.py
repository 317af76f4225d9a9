"""A real-time agent that fell behind answers the newest observation, not every stale one."""

from __future__ import annotations

import threading

import numpy as np

from tests.support.waits import wait_until
from agents.process.agent_process import AgentNode, AgentOptions
from truav.config import Config
from truav.wire import guard, schema

RUN = "catchup"


def _obs(tick: int) -> schema.Obs:
    return schema.Obs(tick=tick, episode=0, uav=0, pos=(100.0, 100.0), vehicles_in_range=3, queued_packets=1,
                      relayed=0, covered=0, energy_j=0.0, speed_max=15.0, done=False)


def _node(bus_factory, lockstep: bool) -> AgentNode:
    cfg = Config()
    return AgentNode(cfg, AgentOptions(run=RUN, uav=0, lockstep=lockstep), bus_factory("uav/0"))


def test_realtime_agent_skips_stale_observations_and_counts_them(bus_factory) -> None:
    node = _node(bus_factory, lockstep=False)
    handled: list[int] = []
    node.handle = lambda obs: (handled.append(obs.tick), node.stop() if obs.tick == 9 else None)
    for t in (5, 6, 7):  # queued while the agent was busy: only 7 is still worth answering
        node._obs.put(_obs(t))
    first = node._obs.get()
    assert node._newest_obs(first).tick == 7 and node.stale_obs_skipped == 2
    node._obs.put(_obs(9))
    node.run()
    assert handled == [9]


def test_lockstep_agent_answers_every_observation(bus_factory) -> None:
    node = _node(bus_factory, lockstep=True)
    handled: list[int] = []
    node.handle = lambda obs: (handled.append(obs.tick), node.stop() if obs.tick == 7 else None)
    for t in (5, 6, 7):
        node._obs.put(_obs(t))
    node.run()
    assert handled == [5, 6, 7] and node.stale_obs_skipped == 0


def _obs_with_reward(tick: int) -> schema.Obs:
    """An observation whose transition changes the table (a non-zero reward)."""
    return schema.Obs(tick=tick, episode=0, uav=0, pos=(100.0 + tick, 100.0), vehicles_in_range=3, queued_packets=1,
                      relayed=2, covered=4, energy_j=50.0, speed_max=15.0, done=False)


def test_realtime_agent_never_learns_from_an_observation_older_than_one_answered(bus_factory) -> None:
    """After a latency fault clears, delayed observations arrive behind newer ones: each is dropped and
    counted, with no Q update (learning from it would pair the wrong states and reward)."""
    node = _node(bus_factory, lockstep=False)
    handled: list[int] = []
    tables: dict[int, np.ndarray] = {}
    real_handle = node.handle

    def handle(obs: schema.Obs) -> None:
        real_handle(obs)
        handled.append(obs.tick)
        tables[obs.tick] = node.learners.q.copy()
        follow = {10: [11], 11: [13], 13: [12]}.get(obs.tick, [])  # 12 comes late, after 13 was answered
        for t in follow:
            node._obs.put(_obs_with_reward(t))

    node.handle = handle
    node._obs.put(_obs_with_reward(10))
    runner = threading.Thread(target=node.run)
    runner.start()
    try:
        assert wait_until(lambda: 12 in handled or getattr(node, "out_of_order_obs", 0) == 1, 30.0)
    finally:
        node.stop()
        runner.join(30.0)
    assert handled == [10, 11, 13] and node.steps == 2 and node.out_of_order_obs == 1
    assert not np.array_equal(tables[11], tables[13])  # a transition does change the table...
    assert np.array_equal(node.learners.q, tables[13])  # ...the late one did not
    # Queued together, the newest tick is answered whatever the arrival order; the older one is skipped.
    while not node._obs.empty():  # stop()'s sentinel, left when the loop saw the stop flag first (a busy host)
        node._obs.get_nowait()
    node._obs.put(_obs_with_reward(15))
    assert node._newest_obs(_obs_with_reward(16)).tick == 16 and node.stale_obs_skipped == 1


def test_world_counts_late_and_out_of_order_actions_as_such(bus_factory) -> None:
    """Not as malformed duplicates: the guard passes an older tick's action, the world counts it
    (late: after its round closed; stale: behind a newer answer of the same agent) and never applies it."""
    from world.process.world_process import WorldNode, WorldOptions
    cfg = Config().replace(scenario={"n_vehicles": 20, "n_uavs": 2, "steps_per_episode": 5})
    bus = bus_factory("world")
    node = WorldNode(cfg, WorldOptions(run=RUN), bus)

    stamp = schema.Sequencer("uav/0").stamp
    verdicts = []

    def deliver(tick: int) -> None:
        msg = stamp(schema.Action(uav=0, tick=tick, action=3))
        verdicts.append(bus.guard.check("k", msg))  # as the bus does before calling back
        if verdicts[-1] is None:
            node._on_action("k", msg, b"", 0)

    node._round, node._tick = 11, 11  # tick 11's round is open
    deliver(11)
    deliver(11)  # a second action for the same tick: a duplicate, refused by the guard
    deliver(10)  # the answer to tick 10, overtaken by the one to 11
    node._round, node._tick = 12, -1  # tick 12's round has closed
    deliver(12)
    assert [v and v[0] for v in verdicts] == [None, guard.R_DUPLICATE, None, None]
    assert node._actions == {0: 3}
    assert node.stats.stale_actions == 1 and node.stats.late_actions == 1
