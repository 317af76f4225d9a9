"""A clean run refuses nothing of its own: a non-zero rejection count means something happened."""

from __future__ import annotations

import time
from collections import deque

import pytest

from agents.process.agent_process import AgentOptions
from agents.process.scheme_process import DEPLOY_REPEATS, PatrolAgentNode
from tests.support.waits import wait_until
from truav.config import Config
from truav.wire import guard, keys, schema

RUN = "clean"


def _obs(uav: int, tick: int, episode: int, done: bool) -> schema.Obs:
    return schema.Obs(tick=tick, episode=episode, uav=uav, pos=(300.0 + 100 * uav, 400.0), vehicles_in_range=3,
                      queued_packets=1, relayed=0, covered=0, energy_j=0.0, speed_max=15.0, done=done)


def test_realtime_patrol_agents_refuse_none_of_their_own_repeated_deployment_beacons(bus_factory):
    """Episodes longer than the guard's tick window: the deployment beacons repeated on an episode's first
    ticks used to wait in every agent's inbox until the next deployment, then be refused as stale
    (tick_out_of_window, 250 in a default `up --scheme patrol`). Driven tick by tick, no clock involved."""
    steps = guard.TICK_WINDOW + DEPLOY_REPEATS + 2
    cfg = Config().replace(scenario={"n_uavs": 2, "n_vehicles": 60, "steps_per_episode": steps})
    nodes = [PatrolAgentNode(cfg, AgentOptions(run=RUN, uav=u, scheme="patrol", tick_period_s=0.01),
                             bus_factory(f"uav/{u}")) for u in range(2)]
    arrived = [[0, 0], [0, 0]]  # [receiver][sender]: what reached each inbox (each arrival appends to its queue)

    class Counted(deque):
        def __init__(self, i, old):
            super().__init__(old, maxlen=old.maxlen)
            self.i = i

        def append(self, entry):
            arrived[self.i][int(str(entry[1].key_expr).split("/uav/")[1].split("/")[0])] += 1
            super().append(entry)
    for i, node in enumerate(nodes):
        node._beacon_inbox._ready = Counted(i, node._beacon_inbox._ready)
    # Subscriptions reach the router asynchronously: first make sure each agent hears the other.
    assert wait_until(lambda: [n.bus.publish(keys.uav_beacon(RUN, n.opts.uav), schema.Beacon(
        uav=n.opts.uav, tick=0, pos=(300.0, 400.0), vel=(0.0, 0.0))) for n in nodes] and
        min(arrived[0][1], arrived[1][0]) > 0, 30.0, poll_s=0.2)
    time.sleep(0.2)
    base = [row[:] for row in arrived]
    tick = 0
    for episode in range(2):
        for t in range(steps + 1):  # an episode's last observation is its done one
            for node in nodes:
                node.handle(_obs(node.opts.uav, tick, episode, done=t == steps))
            if t == DEPLOY_REPEATS + 1:  # every repeat has reached both agents before the episode goes on
                want = (DEPLOY_REPEATS + 1) * (episode + 1)
                assert wait_until(lambda: all(arrived[i][j] - base[i][j] >= want for i in (0, 1) for j in (0, 1)),
                                  30.0), arrived
            tick += 1
    for node in nodes:
        node._take_beacons()  # what is left at the end is checked too (the stats file does this)
        assert node.bus.rejections.total() == 0, node.bus.rejections.as_dict()
        assert node.deployments == 2


def test_controller_stalled_beyond_the_tick_window_still_accepts_the_current_uploads(bus_factory):
    """A controller busy for more than the guard's window (an online learner's first updates on a loaded
    machine) used to refuse every later upload as tick_out_of_window, and decide nothing more all run:
    the world's ticks now keep its window current."""
    pytest.importorskip("torch")
    from agents.process.central_process import ControllerNode, ControllerOptions
    cfg = Config().replace(scenario={"n_uavs": 2, "n_vehicles": 60})
    node = ControllerNode(cfg, ControllerOptions(run=RUN), bus_factory("controller"))
    world, uav = bus_factory("world"), bus_factory("uav/0")
    tick = 10 * guard.TICK_WINDOW  # the controller was busy from tick 0 on (the fault plan heard tick 0)
    for t in range(0, tick + 1, guard.TICK_WINDOW // 2):  # the world ticks on (a tick far from the last is refused)
        assert wait_until(lambda: world.publish(keys.world_tick(RUN), schema.Tick(
            tick=t, episode=0, sim_time=float(t), deadline_ms=80.0, n_uavs=2)) and node.bus.guard.tick == t,
            30.0, poll_s=0.2)
    uav.publish(keys.uav_state(RUN, 0), schema.State(
        uav=0, tick=tick, episode=0, step=4, pos=(100.0, 100.0), vehicles_in_range=1, queued_packets=0, relayed=0,
        covered=1, energy_j=1.0, done=False, pad=b""))
    assert wait_until(lambda: node.stats["states"] == 1, 30.0)
    assert node.bus.rejections.total() == 0, node.bus.rejections.as_dict()
