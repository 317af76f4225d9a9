"""The heuristic ``spread`` that climbs where it would hover and leaves a peer's sector to it (agents.api; by
class path ``agents.claim_agent:ClaimAgent``).

Measured against the oracle (docs/results/learned-policy.md, "Toward 60%"), ``spread`` loses little to duplicated
coverage and much to where its UAVs are: about two of its five UAVs have fewer than 10 vehicles in range at any
step. This agent flies ``spread``'s decision (agents.spread_agent.decide: chase the densest sensed sector, the
claims in beacons, the pushes) with these changes:

1. the climb: each hover over vehicles in range becomes a move on ``climb`` (a heading, full speed); every
   ``window`` steps it compares the mean of its objective (the vehicles only it has in range, ``exclusive``, or
   all in range) with the window before, and when it fell the heading turns by ``turn_deg``. It goes on while the
   UAV is not chasing and has vehicles in range, where ``spread`` hovers for good once one step brought no more;
2. peers' sectors: a sensed densest sector holding a heard peer nearer than ``peer_sector_m`` is left to that
   peer (its vehicles are presumably the peer's): sensing then says nothing, and the UAV climbs where it is;
3. the chase's goal one comm range into the sector (``spread``: 1.5), and a push off peers nearer than one comm
   range (``spread``: two, every overlap of discs).

Pure and deterministic: no random numbers, no I/O. The batched form runs the same arithmetic for every UAV of
every seed, so a swarm (the per-UAV form) flies what the in-process evaluation flies.
"""

from __future__ import annotations

import math

import numpy as np

from agents.api import HOVER, BatchedAgents, BatchedViews, LocalView, UavAgent
from agents.spread_agent import Params, decide, first_heading
from truav.config import Config


class ClimbParams:
    """The climb's constants (docs/results/learned-policy.md, "Toward 60%": chosen on screens of 10 episodes per
    seed; measured on held-out traffic)."""

    def __init__(self, window: int = 1, turn_deg: float = 135.0, full_speed: bool = True,
                 objective: str = "exclusive", peer_sector_m: float = 2000.0, lost_repel: bool = False):
        if objective not in ("exclusive", "in_range"):
            raise ValueError(f"objective must be 'exclusive' or 'in_range', not {objective!r}")
        self.window, self.full_speed, self.objective = int(window), bool(full_speed), objective
        self.peer_sector_m = float(peer_sector_m)
        """A sensed sector holding a heard peer nearer than this is left to it (0: never)."""
        self.lost_repel = bool(lost_repel)
        """With nothing in range or sensed, fly away from every heard peer (weights 1 / distance) instead of
        wandering on a fixed heading."""
        a = math.radians(turn_deg)
        self.rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])


def climb_step(c: ClimbParams, active: np.ndarray, objective: np.ndarray, climb: np.ndarray, window: np.ndarray,
               info: dict | None = None):
    """One step of the climb of N UAVs: active (N,) bool, those not chasing with vehicles in range; objective
    (N,); climb (N, 2) unit headings; window (N, 3): the objective's sum over the current window, the steps in it
    and the mean of the window before (-1: none). Returns (actions (N,): the climb's, HOVER where not active),
    climb, window); ``info`` (a dict) gets "fell" (N,) bool: the heading turned."""
    window = np.where(active[:, None], window, np.array([0.0, 0.0, -1.0]))  # a climb starts afresh
    total, n = window[:, 0] + np.where(active, objective, 0.0), window[:, 1] + active
    full = n >= c.window
    mean = total / np.maximum(n, 1.0)
    fell = full & (window[:, 2] >= 0.0) & (mean < window[:, 2])
    climb = np.where(fell[:, None], climb @ c.rot.T, climb)
    if info is not None:
        info["fell"] = fell
    window = np.where(full[:, None], np.stack([np.zeros_like(mean), np.zeros_like(mean), mean], -1),
                      np.stack([total, n, window[:, 2]], -1))
    sector = np.round(np.arctan2(climb[:, 1], climb[:, 0]) / (math.pi / 4)).astype(np.int64) % 8
    action = np.where(active, sector + (8 if c.full_speed else 0), HOVER)
    return action, climb, window


def free_sector(p: Params, c: ClimbParams, pos, densest, peer_pos, heard):
    """densest (N,), 0 where a heard peer nearer than c.peer_sector_m lies in that sector (its vehicles are
    presumably the peer's)."""
    away = peer_pos - pos[:, None, :]
    d = np.hypot(away[..., 0], away[..., 1])
    sector = np.floor((np.arctan2(away[..., 1], away[..., 0]) % (2.0 * math.pi)) / (2.0 * math.pi / p.sectors))
    inside = heard & (d < c.peer_sector_m) & (d > 0.0) & (sector.astype(np.int64) + 1 == densest[:, None])
    return np.where(inside.any(axis=1), 0, densest)


def decide_climb(p: Params, c: ClimbParams, uav, pos, in_range, exclusive, densest, heading, last, peer_id, peer_pos,
                 peer_goal, heard, climb, window, info: dict | None = None):
    """spread's decide (same arguments), its hovers over vehicles in range replaced by the climb. Returns actions,
    goals, headings, memories (as decide), climbs and windows (as climb_step); ``info`` (a dict) gets the rule's
    intermediate quantities (N,) bool: "fell" (climb_step), "left" (the sensed sector left to a peer), "active"
    (the climb goes on) and "climbing" (spread's hover replaced by the climb), read by claim_features."""
    sensed = densest
    if c.peer_sector_m > 0.0:
        densest = free_sector(p, c, pos, densest, peer_pos, heard)
    action, goal, heading, memory = decide(p, uav, pos, in_range, exclusive, densest, heading, last, peer_id,
                                           peer_pos, peer_goal, heard)
    active = (goal[:, 0] < 0.0) & (in_range > 0)  # not chasing, vehicles in range: the climb goes on
    objective = (exclusive if c.objective == "exclusive" else in_range).astype(np.float64)
    climbed, climb, window = climb_step(c, active, objective, climb, window, info)
    hovering = active & (action == HOVER)
    if info is not None:
        info.update(left=(np.asarray(sensed) > 0) & (np.asarray(densest) == 0), active=active, climbing=hovering)
    action = np.where(hovering, climbed, action)
    if c.lost_repel:
        lost = (goal[:, 0] < 0.0) & (in_range == 0) & ~hovering
        away = pos[:, None, :] - peer_pos
        d2 = np.maximum((away ** 2).sum(-1), 1.0)
        move = (np.where(heard, 1.0 / d2, 0.0)[..., None] * away).sum(axis=1)
        lo, hi = pos < p.wall_m + p.comm_m, pos > p.area - p.wall_m - p.comm_m  # keep off the edge: nothing there
        move = move / np.maximum(np.hypot(*move.T), 1e-12)[:, None] + np.where(lo, 1.0, 0.0) - np.where(hi, 1.0, 0.0)
        sector = np.round(np.arctan2(move[:, 1], move[:, 0]) / (math.pi / 4)).astype(np.int64) % 8
        action = np.where(lost & (np.hypot(*move.T) > 1e-6), sector + 8, action)
    # the memory says the move made (spread's climb reads it): the climb's heading where it flew
    memory = memory.copy()
    memory[:, 1:3] = np.where(hovering[:, None], climb, memory[:, 1:3])
    if info is not None:
        info["serving"] = memory[:, 3] > 0
    return action.astype(np.int64), goal, heading, memory, climb, window


CLAIM_FEATURES = (
    ("climb_x", "the climb's heading, east (unit)"), ("climb_y", "the climb's heading, north (unit)"),
    ("heading_x", "the wandering heading, east (unit)"), ("heading_y", "the wandering heading, north (unit)"),
    ("chasing", "1 if chasing a sensed sector's goal"),
    ("goal_dx", "the chased goal's x minus own x over scenario.area_m (0 not chasing)"),
    ("goal_dy", "the chased goal's y minus own y over scenario.area_m (0 not chasing)"),
    ("serving", "1 if serving its cluster (its exclusive vehicles at least the threshold)"),
    ("active", "1 if the climb goes on (not chasing, vehicles in range)"),
    ("climbing", "1 if the climb replaced a hover at this step"),
    ("fell", "1 if the exclusive vehicles fell since the last step (the climb's heading turned)"),
    ("left", "1 if the densest sensed sector holds a heard peer nearer than peer_sector_m (left to it)"),
)
"""The climb's features (agents.view_features, ``claim``): name, meaning; each in [-1, 1]."""


def claim_features(p: Params, pos: np.ndarray, goal: np.ndarray, heading: np.ndarray, climb: np.ndarray,
                   info: dict) -> np.ndarray:
    """(N, len(CLAIM_FEATURES)) float64: the quantities decide_climb computed for N UAVs at pos (N, 2) (its
    goals, headings, climbs and ``info`` after the step); what the rule knows beyond the view."""
    chasing = goal[:, 0] >= 0.0
    rel = np.where(chasing[:, None], (goal - pos) / p.area, 0.0)
    f = lambda k: np.asarray(info[k], np.float64)  # noqa: E731
    return np.column_stack([climb, heading, chasing.astype(np.float64), rel, f("serving"), f("active"),
                            f("climbing"), f("fell"), f("left")])


class ClaimAgent(UavAgent):
    """One UAV of the climbing heuristic (see the module docstring)."""

    climb_params: dict = {}
    """ClimbParams' keyword arguments (a subclass may set other constants)."""
    spread_params: dict = {"goal_ranges": 1.0, "repel_ranges": 1.0}
    """agents.spread_agent.Params' keyword arguments (the goal one comm range into the sector, not 1.5; pushed off
    peers nearer than one comm range, not two)."""

    def __init__(self, cfg: Config, uav: int, rng: np.random.Generator):
        super().__init__(cfg, uav, rng)
        self.p, self.c = Params(cfg, **self.spread_params), ClimbParams(**self.climb_params)
        self.heading = np.array([first_heading(uav, cfg.scenario.n_uavs)], np.float64)
        self.climb = self.heading.copy()
        self.goal, self.last, self.window = np.full((1, 2), -1.0), np.zeros((1, 4)), np.array([[0.0, 0.0, -1.0]])
        self.info: dict = {}

    def act(self, view: LocalView) -> int:
        P = len(view.beacons)
        peer_goal = np.array([[b.fields.get("goal_x", -1.0), b.fields.get("goal_y", -1.0)] for b in view.beacons],
                             np.float64).reshape(1, P, 2)
        action, self.goal, self.heading, self.last, self.climb, self.window = decide_climb(
            self.p, self.c, np.array([view.uav]), np.array([view.pos], np.float64),
            np.array([view.vehicles_in_range]), np.array([view.exclusive]), np.array([view.densest_sector]),
            self.heading, self.last, np.array([[b.uav for b in view.beacons]]).reshape(1, P),
            np.array([b.pos for b in view.beacons], np.float64).reshape(1, P, 2), peer_goal, np.ones((1, P), np.bool_),
            self.climb, self.window, self.info)
        self.pos = np.array([view.pos], np.float64)
        return int(action[0])

    def features(self) -> np.ndarray:
        """(len(CLAIM_FEATURES),): claim_features of the last act."""
        return claim_features(self.p, self.pos, self.goal, self.heading, self.climb, self.info)[0]

    def beacon_fields(self) -> dict[str, float]:
        return {"goal_x": float(self.goal[0, 0]), "goal_y": float(self.goal[0, 1])}

    def state_dict(self) -> dict[str, np.ndarray]:
        return {"heading": self.heading[0].copy(), "last": self.last[0].copy(), "climb": self.climb[0].copy(),
                "window": self.window[0].copy()}

    def load_state_dict(self, state) -> None:
        self.heading = np.asarray(state["heading"], np.float64).reshape(1, 2).copy()
        self.last = np.asarray(state["last"], np.float64).reshape(1, 4).copy()
        self.climb = np.asarray(state["climb"], np.float64).reshape(1, 2).copy()
        self.window = np.asarray(state["window"], np.float64).reshape(1, 3).copy()


class ClaimBatched(BatchedAgents):
    """ClaimAgent for every UAV of every seed at once (as agents.spread_agent.SpreadBatched)."""

    climb_params: dict = {}
    spread_params: dict = {"goal_ranges": 1.0, "repel_ranges": 1.0}

    def __init__(self, cfg: Config, rngs: list[list[np.random.Generator]]):
        super().__init__(cfg, rngs)
        B, U = len(rngs), len(rngs[0])
        self.p, self.c, self.shape = Params(cfg, **self.spread_params), ClimbParams(**self.climb_params), (B, U)
        self.heading = np.tile(np.array([first_heading(u, U) for u in range(U)]), (B, 1))
        self.climb = self.heading.copy()
        self.goal, self.last = np.full((B * U, 2), -1.0), np.zeros((B * U, 4))
        self.window = np.tile(np.array([0.0, 0.0, -1.0]), (B * U, 1))
        self.uav = np.tile(np.arange(U), B)
        self.peer_id = np.tile(np.arange(U), (B * U, 1))
        self.info: dict = {}

    def act(self, views: BatchedViews) -> np.ndarray:
        B, U = self.shape
        if views.step == 0:  # no peer has acted yet this episode: no beacon carries a goal
            self.goal[:] = -1.0
        peer_goal = np.repeat(self.goal.reshape(B, 1, U, 2), U, axis=1).reshape(B * U, U, 2)
        action, self.goal, self.heading, self.last, self.climb, self.window = decide_climb(
            self.p, self.c, self.uav, views.pos.reshape(B * U, 2), views.vehicles_in_range.reshape(-1),
            views.exclusive.reshape(-1), views.densest_sector.reshape(-1), self.heading, self.last, self.peer_id,
            views.peer_pos.reshape(B * U, U, 2), peer_goal, views.heard.reshape(B * U, U), self.climb, self.window,
            self.info)
        self.pos = np.asarray(views.pos, np.float64).reshape(B * U, 2)
        return action.reshape(B, U)

    def features(self) -> np.ndarray:
        """(B, U, len(CLAIM_FEATURES)): claim_features of the last act."""
        B, U = self.shape
        return claim_features(self.p, self.pos, self.goal, self.heading, self.climb, self.info).reshape(B, U, -1)

    def state_dict(self) -> dict[str, np.ndarray]:
        B, U = self.shape
        return {"heading": self.heading.reshape(B, U, 2).copy(), "last": self.last.reshape(B, U, 4).copy(),
                "climb": self.climb.reshape(B, U, 2).copy(), "window": self.window.reshape(B, U, 3).copy()}

    def load_state_dict(self, state) -> None:
        self.heading = np.asarray(state["heading"], np.float64).reshape(-1, 2).copy()
        self.last = np.asarray(state["last"], np.float64).reshape(-1, 4).copy()
        self.climb = np.asarray(state["climb"], np.float64).reshape(-1, 2).copy()
        self.window = np.asarray(state["window"], np.float64).reshape(-1, 3).copy()


ClaimAgent.batched = ClaimBatched

__all__ = ["CLAIM_FEATURES", "ClaimAgent", "ClaimBatched", "ClimbParams", "claim_features", "climb_step",
           "decide_climb"]
