"""One API agent's cycle (agents.api) over wire messages, without the bus: beacon, view, learn, act.

The agent process of `truav-swarm up --agent NAME` (agents.process.api_process) runs it for its UAV, as
TruavDecision runs TRUAV's: the view is built from the world's observation and the beacons of the
tick (in UAV-id order), the reward is the paper's local reward with the overlap of the peers heard,
exactly as agents.api_controller builds them in process, so a lock-step swarm flies what
`truav train --agent NAME` flies. What beacon_fields() returns after an act goes out in the UAV's next
beacon (truav.wire.messages.Beacon.fields) and its peers hear it in their views, as in process.
"""

from __future__ import annotations

import numpy as np

from agents.agent_decision import DONE_ACK_ACTION, peer_arrays
from agents.api import HeardBeacon, LocalView, action_problem, beacon_problem, sensing
from agents.api_controller import nearest_rsu_m
from agents.reward import Reward
from agents.state import neighbour_features
from truav import seeding
from truav.call_limit import CallTooLong, call_limited
from truav.config import Config
from truav.wire import schema
from world.network import rsu_positions
from world.uavs import action_velocity


class IllegalAction(ValueError):
    """act() returned what is not an action, or beacon_fields() failed or returned what no beacon carries
    (the message says what)."""


class ApiDecision:
    """The decision state of one API agent: its instance, the episode, its step, its velocity."""

    def __init__(self, cls: type, cfg: Config, uav: int, seed: int, train: bool = True):
        self.cfg, self.uav, self.train = cfg, uav, train
        self.rng = seeding.agent_rng(seed, uav)
        self.limit_s = float(getattr(cls, "call_limit_s", 1.0))
        """Every call into the class is bounded by it: truav.call_limit.CallTooLong past it."""
        self.agent = call_limited(self.limit_s, cls, cfg, uav, self.rng)
        self.reward = Reward(cfg)
        self.rsu = rsu_positions(cfg)
        self.episode, self.t = -1, 0
        self.velocity = (0.0, 0.0)
        self.prev_in_range = 0.0
        self.view: LocalView | None = None
        self.action = 0
        self.fields: dict = {}
        """What beacon_fields() returned after the last act: the next beacon carries it."""

    def warm_up(self) -> None:
        """Load the compiled kernels of a step (the overlap with the peers, the reward) before the agent joins, so
        its first tick is not missed while they load; calls nothing of the class and changes no state."""
        pos = np.zeros((1, 1, 2))
        peers = np.zeros((1, 1, 1, 2))
        overlap = neighbour_features(pos, peers, np.ones((1, 1, 1), np.bool_), self.cfg.scenario.comm_range_m)[1]
        zero = np.zeros((1, 1))
        self.reward(zero, zero, zero, overlap, zero, zero, zero)
        nearest_rsu_m(pos, self.rsu)

    def beacon(self, obs: schema.Obs) -> schema.Beacon:
        """This UAV's beacon for the tick of ``obs``: at an episode's first tick no action was taken yet."""
        if obs.episode != self.episode:
            self.velocity, self.fields = (0.0, 0.0), {}
        return schema.Beacon(uav=self.uav, tick=obs.tick, pos=obs.pos, vel=self.velocity, fields=self.fields)

    def learn(self, obs: schema.Obs, beacons: dict[int, schema.Beacon]) -> float | None:
        """The view of ``obs`` with the tick's beacons; at an episode's first observation begin it, else learn
        from the last step. The reward, or None at an episode's start. Exceptions are the agent's."""
        heard = tuple(HeardBeacon(j, tuple(beacons[j].pos), tuple(beacons[j].vel), beacons[j].fields) for j in sorted(beacons))
        new = obs.episode != self.episode
        if new:
            self.episode, self.t = obs.episode, 0
        else:
            self.t += 1
        pos = np.array([[obs.pos]], np.float64)
        self.view = LocalView(self.uav, obs.episode, self.t, tuple(obs.pos), obs.vehicles_in_range,
                              obs.queued_packets, obs.relayed, obs.covered, float(obs.energy_j), float(obs.speed_max),
                              obs.densest_sector, obs.exclusive, float(nearest_rsu_m(pos, self.rsu)[0, 0]), heard,
                              *sensing(self.cfg), tuple(obs.disc_offset), obs.disc_vehicles)
        r = None
        if new:
            call_limited(self.limit_s, self.agent.begin_episode, obs.episode, self.train)
        else:
            overlap = neighbour_features(pos, *peer_arrays(beacons), self.cfg.scenario.comm_range_m)[1]
            r = float(self.reward(np.array([[obs.relayed]]), np.array([[obs.covered]]), np.array([[obs.energy_j]]),
                                  overlap, np.array([[obs.exclusive]]), np.array([[obs.vehicles_in_range]]),
                                  np.array([[self.prev_in_range]]))[0, 0])
            call_limited(self.limit_s, self.agent.learn, self.view, r, obs.done)
        self.prev_in_range = float(obs.vehicles_in_range)
        return r

    def act(self, obs: schema.Obs) -> schema.Action:
        """The action for a (not `done`) observation already learned from; IllegalAction for an illegal one,
        CallTooLong for a late one."""
        a = call_limited(self.limit_s, self.agent.act, self.view)
        problem = action_problem(a)
        if problem:
            raise IllegalAction(problem)
        self.action = int(a)
        self.velocity = tuple(action_velocity(np.array(self.action), obs.speed_max))
        try:
            fields = call_limited(self.limit_s, self.agent.beacon_fields)
        except CallTooLong as exc:
            raise IllegalAction(f"beacon_fields {exc}") from None
        except Exception as exc:
            raise IllegalAction(f"beacon_fields raised {type(exc).__name__}: {' '.join(str(exc).split())}") from None
        problem = beacon_problem(fields)
        if problem:
            raise IllegalAction(problem)
        self.fields = dict(fields)
        return schema.Action(uav=self.uav, tick=obs.tick, action=self.action)

    def hover(self, obs: schema.Obs) -> schema.Action:
        """The action when the agent failed: hover (its beacons then say it stands still)."""
        self.action, self.velocity, self.fields = schema.HOVER, (0.0, 0.0), {}
        return schema.Action(uav=self.uav, tick=obs.tick, action=schema.HOVER)

    def acknowledge(self, obs: schema.Obs) -> schema.Action:
        """Lock-step: the answer to a `done` observation (learned from; no action taken)."""
        return schema.Action(uav=self.uav, tick=obs.tick, action=DONE_ACK_ACTION)


__all__ = ["ApiDecision", "IllegalAction"]
