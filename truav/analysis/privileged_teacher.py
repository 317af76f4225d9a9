"""A privileged teacher for imitation ("learning by cheating"; centralized training, decentralized execution).

The teacher sees the whole world at a step, every vehicle and every UAV, and labels each UAV's action; the
student it teaches observes only its own local features (truav.analysis.ppo_train's DAgger). Its rule, the
oracle of docs/scripts/oracle_ceiling.py ("reachable") made into actions the world can fly:

1. place the U discs of radius comm_range by a greedy max-coverage over candidate centres (the vehicles);
2. match the UAVs to the discs by least total distance (all U! permutations: U is small);
3. each UAV flies toward its disc: full speed while one full step does not overshoot, half speed while half a
   step does not, hover on it. The heading is the nearest of the 8;
4. optionally (``reach_m`` > 0), a UAV whose disc lies farther than ``reach_m`` takes the fallback's action
   instead (the climbing heuristic's, which the student's features come from): labels the student's local
   features can predict.

Pure and deterministic: numpy arrays in, actions out; no random numbers, no I/O. ``OracleTeacher`` is the
batched-agent form ``teacher_data`` drives: before each ``act`` it is shown the vehicles (``see``).
"""

from __future__ import annotations

import itertools
import math

import numpy as np

from agents.api import HOVER, BatchedAgents, BatchedViews
from truav.config import Config


def greedy_discs(xy: np.ndarray, k: int, r: float) -> np.ndarray:
    """(at most k, 2) disc centres among the rows of ``xy`` (N, 2; NaN rows: vehicles off the road, ignored)
    covering the most vehicles within ``r``, greedily; fewer once every vehicle is covered."""
    xy = xy[~np.isnan(xy).any(axis=1)]
    if len(xy) == 0:
        return np.zeros((0, 2))
    cover = ((xy[:, None, :] - xy[None, :, :]) ** 2).sum(axis=-1) <= r * r
    left = np.ones(len(xy), bool)
    chosen = []
    for _ in range(k):
        gain = (cover & left).sum(axis=1)
        best = int(np.argmax(gain))
        if gain[best] == 0:  # every vehicle covered: fewer discs
            break
        chosen.append(best)
        left &= ~cover[best]
    return xy[chosen]


def match(pos: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """(U, 2) targets reordered so that row i is UAV i's: the permutation of least total distance from pos
    (U, 2). Fewer targets than UAVs: the UAVs left without one keep their own position."""
    U, K = len(pos), len(targets)
    d = np.zeros((U, U))  # columns K..U-1: no target, no cost
    d[:, :K] = np.linalg.norm(pos[:, None, :] - targets[None, :, :], axis=-1)
    perms = np.array(list(itertools.permutations(range(U))))
    rows = np.arange(U)
    best = perms[int(np.argmin(d[rows, perms].sum(axis=1)))]
    return np.where((best < K)[:, None], targets[np.minimum(best, max(K - 1, 0))] if K else pos, pos)


def toward(pos: np.ndarray, target: np.ndarray, step_m: float) -> np.ndarray:
    """World actions (N,) flying pos (N, 2) toward target (N, 2): full speed (8 + heading) while a full step
    ``step_m`` does not overshoot, half speed while half a step does not, HOVER within half a step."""
    gap = target - pos
    dist = np.hypot(gap[:, 0], gap[:, 1])
    sector = np.round(np.arctan2(gap[:, 1], gap[:, 0]) / (math.pi / 4)).astype(np.int64) % 8
    return np.where(dist >= step_m, sector + 8, np.where(dist >= 0.5 * step_m, sector, HOVER)).astype(np.int64)


def oracle_actions(vehicle_xy: np.ndarray, uav_pos: np.ndarray, r: float, step_m: float) -> np.ndarray:
    """(B, U) world actions of the privileged rule (the module's docstring) for vehicles (B, N, 2) and UAVs
    (B, U, 2)."""
    B, U = uav_pos.shape[:2]
    out = np.empty((B, U), np.int64)
    for b in range(B):
        out[b] = toward(uav_pos[b], match(uav_pos[b], greedy_discs(vehicle_xy[b], U, r)), step_m)
    return out


class OracleTeacher(BatchedAgents):
    """oracle_actions as a batched teacher: ``see(vehicle_xy)`` before each ``act(views)``."""

    privileged = True
    """teacher_data shows it the world's vehicles before each act."""

    reach_m: float = 0.0
    """Discs farther than this are left to the fallback's action (0: never; see the module's docstring)."""

    def __init__(self, cfg: Config, rngs: list[list[np.random.Generator]]):
        super().__init__(cfg, rngs)
        sc = cfg.scenario
        self.r, self.step_m = sc.comm_range_m, sc.uav_speed_mps * sc.step_s
        self.vehicle_xy: np.ndarray | None = None
        self.fallback: np.ndarray | None = None

    def see(self, vehicle_xy: np.ndarray, fallback: np.ndarray | None = None) -> None:
        """The world's vehicles (B, N, 2) now, and the fallback's actions (B, U) at this step (with reach_m)."""
        self.vehicle_xy = np.asarray(vehicle_xy, np.float64)
        self.fallback = None if fallback is None else np.asarray(fallback, np.int64)

    def act(self, views: BatchedViews) -> np.ndarray:
        if self.vehicle_xy is None:
            raise RuntimeError("OracleTeacher.act before see: the teacher needs the world's vehicles")
        pos = np.asarray(views.pos, np.float64)
        if self.reach_m <= 0.0:
            return oracle_actions(self.vehicle_xy, pos, self.r, self.step_m)
        if self.fallback is None:
            raise RuntimeError("OracleTeacher with reach_m needs the fallback's actions (see)")
        out = self.fallback.copy()
        for b in range(len(pos)):
            target = match(pos[b], greedy_discs(self.vehicle_xy[b], pos.shape[1], self.r))
            near = np.hypot(*(target - pos[b]).T) <= self.reach_m
            out[b] = np.where(near, toward(pos[b], target, self.step_m), out[b])
        return out


class LocalOracleTeacher(OracleTeacher):
    """OracleTeacher whose discs beyond the sensing range and one comm range (1500 + 500 m under the paper's
    sensing) are left to the climbing heuristic's action."""

    reach_m = 2000.0


__all__ = ["LocalOracleTeacher", "OracleTeacher", "greedy_discs", "match", "oracle_actions", "toward"]
