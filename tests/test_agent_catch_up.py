"""A real-time agent that fell behind answers the newest observation, not every stale one."""

from __future__ import annotations

from agents.agent_process import AgentNode, AgentOptions
from truav.bus import schema
from truav.config import Config

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
