"""The decentralized heuristic: sense, claim, spread (registered as ``spread``; agents.api).

A rule of thumb, not a learner: the bar a learner must clear (docs/results/heuristic.md). Each UAV, each step,
from its own view and the beacons it heard:

1. serving: once it is the only UAV in range of ``stay_exclusive`` vehicles (``exclusive``), it stays while it
   is the only one in range of ``leave_exclusive``, pushed off only by lower-id peers overlapping it (the
   lower id keeps the spot), and goes on with its last move while that brings more vehicles in range;
2. chasing: else, if sensing finds vehicles beyond its range (``densest_sector``: sensing on,
   ``learner.sense_range_m``; SENSE_RANGE_M in the comparisons), it heads for a goal ``goal_m`` into the
   densest sector, unless a peer is within comm range of that goal or a lower-id peer's claimed goal is
   within ``claim_m`` of it; it says its goal in its beacon (fields ``goal_x``, ``goal_y``; -1: none);
3. else it keeps what it has in range (hovers), or with nothing in range wanders on its heading (first
   (uav + 0.5) x 360 / n_uavs degrees, reflected at the area's edge);

and, chasing or wandering, it is pushed off every peer nearer than ``repel_m`` (their discs overlap). The
pull and the pushes add up; the action is the heading nearest their sum, at full speed (half speed for a
goal nearer than a full step), or HOVER when they cancel.

Pure and deterministic: no random numbers, no I/O. The batched form (SpreadBatched) runs the same arithmetic
(:func:`decide`, peers summed in id order) for every UAV of every seed at once, so the trainer and a swarm
(the per-UAV form) fly the same actions.
"""

from __future__ import annotations

import math

import numpy as np

from agents.api import HOVER, BatchedAgents, BatchedViews, LocalView, UavAgent
from truav.config import Config

SENSE_RANGE_M = 1500.0
"""The sensing radius the heuristic is designed and measured for: comparisons that fly it turn
learner.sense_range_m on at this value where the run leaves sensing off (:func:`with_sensing`)."""
NAMES = ("spread", "agents.spread_agent:SpreadAgent")
"""How a comparison names this scheme (its entry point and its class path)."""
DISC_NAMES = ("ppo-disc", "agents.ppo_agent:PpoDiscAgent")
"""The schemes that also observe the densest sensed disc (learner.sense_disc): agents.ppo_agent.PpoDiscAgent."""
SENSING_NAMES = NAMES + ("claim", "agents.claim_agent:ClaimAgent", "ppo-claim", "agents.ppo_agent:PpoClaimAgent") \
    + DISC_NAMES
"""The schemes designed around sensing at SENSE_RANGE_M: this one, ``claim`` (agents/claim_agent.py, which
flies this one's decide with a climb), ``ppo-claim`` (agents.ppo_agent.PpoClaimAgent, cloned from claim) and
DISC_NAMES."""


def with_sensing(scheme: str, cfg: Config) -> Config:
    """The config a comparison flies ``scheme`` with: for these heuristics (SENSING_NAMES), sensing on
    (SENSE_RANGE_M) unless the run already sets learner.sense_range_m, and learner.sense_disc on for DISC_NAMES;
    every other scheme's as it is."""
    if scheme in SENSING_NAMES and cfg.learner.sense_range_m == 0.0:
        cfg = cfg.replace(learner={"sense_range_m": SENSE_RANGE_M})
    if scheme in DISC_NAMES and not cfg.learner.sense_disc:
        cfg = cfg.replace(learner={"sense_disc": True})
    return cfg


class Params:
    """The heuristic's constants in units of the scenario, tuned on training seeds (docs/results/heuristic.md)."""

    def __init__(self, cfg: Config, stay_share: float = 0.75, leave_share: float = 1.0, goal_ranges: float = 1.5,
                 claim_ranges: float = 2.0, repel_ranges: float = 2.0, wall_ranges: float = 0.5):
        sc, R = cfg.scenario, cfg.scenario.comm_range_m
        fair = sc.n_vehicles / sc.n_uavs
        self.stay_exclusive = max(1.0, stay_share * fair)
        """Start serving (stay) when the only UAV in range of this many vehicles: a share of the fair share."""
        self.leave_exclusive = leave_share * self.stay_exclusive
        """Go on serving while the only UAV in range of this many (a share of stay_exclusive)."""
        self.goal_m, self.claim_m, self.repel_m, self.wall_m = (goal_ranges * R, claim_ranges * R, repel_ranges * R,
                                                                wall_ranges * R)
        self.comm_m, self.area, self.step_m = R, sc.area_m, sc.uav_speed_mps * sc.step_s
        self.sectors = cfg.learner.sense_sectors


def first_heading(uav: int, n_uavs: int) -> tuple[float, float]:
    a = (uav + 0.5) * 2.0 * math.pi / n_uavs
    return math.cos(a), math.sin(a)


def decide(p: Params, uav: np.ndarray, pos: np.ndarray, in_range: np.ndarray, exclusive: np.ndarray,
           densest: np.ndarray, heading: np.ndarray, last: np.ndarray, peer_id: np.ndarray, peer_pos: np.ndarray,
           peer_goal: np.ndarray, heard: np.ndarray):
    """Actions (N,), goals (N, 2) (-1 where none), headings (N, 2) and memories (N, 4) of N UAVs: uav, in_range,
    exclusive, densest (N,); pos, heading (N, 2); last (N, 4), the memory of the last step: vehicles in range,
    the move (unit, 2), serving (1.0) or not; their P peers' ids (N, P), positions and claimed goals (N, P, 2),
    heard (N, P)."""
    N, P = heard.shape
    serving = exclusive >= np.where(last[:, 3] > 0, p.leave_exclusive, p.stay_exclusive)
    # the goal: goal_m into the sensed sector, inside the area
    angle = (densest - 0.5) * (2.0 * math.pi / p.sectors)
    goal = np.clip(pos + p.goal_m * np.stack([np.cos(angle), np.sin(angle)], -1), p.wall_m, p.area - p.wall_m)
    taken = np.zeros(N, np.bool_)
    push, push_lower = np.zeros((N, 2)), np.zeros((N, 2))
    for m in range(P):  # in id order: the per-UAV form and the batched form add the same numbers
        h = heard[:, m]
        taken |= h & (np.hypot(*(peer_pos[:, m] - goal).T) < p.comm_m)
        claimed = (peer_goal[:, m, 0] >= 0.0) & (peer_id[:, m] < uav)
        taken |= h & claimed & (np.hypot(*(peer_goal[:, m] - goal).T) < p.claim_m)
        away = pos - peer_pos[:, m]
        d = np.hypot(*away.T)
        w = np.where(h & (d < p.repel_m), (p.repel_m - d) / (p.repel_m * np.maximum(d, 1e-9)), 0.0)
        push = push + w[:, None] * away
        push_lower = push_lower + np.where(peer_id[:, m] < uav, w, 0.0)[:, None] * away
    # the area's edge: a heading out of it is reflected (wandering), a move out of it turned back
    out_lo, out_hi = pos < p.wall_m, pos > p.area - p.wall_m
    heading = np.where((out_lo & (heading < 0)) | (out_hi & (heading > 0)), -heading, heading)
    chasing = ~serving & (densest > 0) & ~taken
    to_goal = goal - pos
    dist = np.hypot(*to_goal.T)
    idle = ~serving & ~chasing & (in_range > 0)  # nothing to chase: keep what is in range
    pull = np.where(chasing[:, None], to_goal / np.maximum(dist, 1e-9)[:, None], np.where(idle[:, None], 0.0, heading))
    # serving: settle on the cluster, going on with the last move while it brings more vehicles in range
    climb = np.where((in_range > last[:, 0])[:, None], last[:, 1:3], 0.0)
    settle = np.where(np.hypot(*push_lower.T)[:, None] > 0.0, push_lower, climb)
    move = np.where(serving[:, None], settle, pull + push)
    move = move + np.where(out_lo, 1.0, 0.0) - np.where(out_hi, 1.0, 0.0)
    norm = np.hypot(*move.T)
    sector = np.round(np.arctan2(move[:, 1], move[:, 0]) / (math.pi / 4)).astype(np.int64) % 8
    half = chasing & (dist < p.step_m)
    action = np.where(norm < 1e-6, HOVER, np.where(half, sector, sector + 8))
    goal = np.where(chasing[:, None], goal, -1.0)
    unit = np.where(norm[:, None] < 1e-6, 0.0, move / np.maximum(norm, 1e-9)[:, None])
    memory = np.concatenate([in_range.astype(np.float64)[:, None], unit, serving.astype(np.float64)[:, None]], axis=1)
    return action.astype(np.int64), goal, heading, memory


class SpreadAgent(UavAgent):
    """One UAV's heuristic (see the module docstring)."""

    def __init__(self, cfg: Config, uav: int, rng: np.random.Generator):
        super().__init__(cfg, uav, rng)
        self.p = Params(cfg)
        self.heading = np.array([first_heading(uav, cfg.scenario.n_uavs)], np.float64)
        self.goal, self.last = np.full((1, 2), -1.0), np.zeros((1, 4))

    def act(self, view: LocalView) -> int:
        P = len(view.beacons)
        peer_goal = np.array([[b.fields.get("goal_x", -1.0), b.fields.get("goal_y", -1.0)] for b in view.beacons],
                             np.float64).reshape(1, P, 2)
        action, self.goal, self.heading, self.last = decide(
            self.p, np.array([view.uav]), np.array([view.pos], np.float64), np.array([view.vehicles_in_range]),
            np.array([view.exclusive]), np.array([view.densest_sector]), self.heading, self.last,
            np.array([[b.uav for b in view.beacons]]).reshape(1, P),
            np.array([b.pos for b in view.beacons], np.float64).reshape(1, P, 2), peer_goal, np.ones((1, P), np.bool_))
        return int(action[0])

    def beacon_fields(self) -> dict[str, float]:
        return {"goal_x": float(self.goal[0, 0]), "goal_y": float(self.goal[0, 1])}

    def state_dict(self) -> dict[str, np.ndarray]:
        return {"heading": self.heading[0].copy(), "last": self.last[0].copy()}

    def load_state_dict(self, state) -> None:
        self.heading = np.asarray(state["heading"], np.float64).reshape(1, 2).copy()
        self.last = np.asarray(state["last"], np.float64).reshape(1, 4).copy()


class SpreadBatched(BatchedAgents):
    """SpreadAgent for every UAV of every seed at once: the same :func:`decide`, the peers' goals its own
    (the goals each peer said at its last act, as its beacon carries them)."""

    def __init__(self, cfg: Config, rngs: list[list[np.random.Generator]]):
        super().__init__(cfg, rngs)
        B, U = len(rngs), len(rngs[0])
        self.p, self.shape = Params(cfg), (B, U)
        self.heading = np.tile(np.array([first_heading(u, U) for u in range(U)]), (B, 1))
        self.goal, self.last = np.full((B * U, 2), -1.0), np.zeros((B * U, 4))
        self.uav = np.tile(np.arange(U), B)
        self.peer_id = np.tile(np.arange(U), (B * U, 1))

    def act(self, views: BatchedViews) -> np.ndarray:
        B, U = self.shape
        if views.step == 0:  # no peer has acted yet this episode: no beacon carries a goal
            self.goal[:] = -1.0
        peer_goal = np.repeat(self.goal.reshape(B, 1, U, 2), U, axis=1).reshape(B * U, U, 2)
        action, self.goal, self.heading, self.last = decide(
            self.p, self.uav, views.pos.reshape(B * U, 2), views.vehicles_in_range.reshape(-1),
            views.exclusive.reshape(-1), views.densest_sector.reshape(-1), self.heading, self.last, self.peer_id, views.peer_pos.reshape(B * U, U, 2),
            peer_goal, views.heard.reshape(B * U, U))
        return action.reshape(B, U)

    def state_dict(self) -> dict[str, np.ndarray]:
        return {"heading": self.heading.reshape(*self.shape, 2).copy(), "last": self.last.reshape(*self.shape, 4).copy()}

    def load_state_dict(self, state) -> None:
        self.heading = np.asarray(state["heading"], np.float64).reshape(-1, 2).copy()
        self.last = np.asarray(state["last"], np.float64).reshape(-1, 4).copy()


SpreadAgent.batched = SpreadBatched

__all__ = ["DISC_NAMES", "SpreadAgent", "SpreadBatched", "Params", "decide", "with_sensing", "SENSE_RANGE_M",
           "SENSING_NAMES"]
