"""Trajectory-knowledge baseline (after Zhou et al.): pre-planned patrols.

Each UAV gets a circular orbit centred on one of the city's major
intersections (`roads.major_intersections`, where traffic clusters; four of
them carry the RSUs). The plan is made once, at deployment (the start of an
episode), from the known start positions, and is a function of time: every
UAV's planned position at every step is known in advance.

- Orbit slot k is site k mod M (M sites); UAVs sharing a site are phased
  evenly around it. Slot k's clock position at step t is
  c + r (cos(phi_k + w t), sin(phi_k + w t)), w = v / r, counter-clockwise.
- Assignment of slots to UAVs: "nearest" (greedy minimum-transit matching of
  start positions to orbits) or "fixed" (UAV k flies slot k).
- Transit: a UAV flies a straight line, at most at cruise speed v, to the
  first point of its slot's clock it can reach on time (the rendezvous), then
  rides the clock. Before the rendezvous its planned positions lie on that
  line; after it, on the orbit.
- Tracking: the world takes the paper's 16 discrete actions (8 headings x
  half/full speed, or hover), so each step the UAV picks the action that
  lands closest to its next planned position; plans cruise at
  v cos(22.5 deg) (`TRACKABLE`), the speed the headings hold in any
  direction, so the residual stays within the action lattice (tested).

Routing uses the same min-time routes over the UAVs' positions that the
world computes for every scheme (see `world.network`). For the patrol those
positions are known in advance from the plan, so its routing needs no
position messages at all: `PatrolController.planned_routes` computes the
routing table from the plan alone. A time-dependent (earliest-arrival)
routing over the planned positions, as in Zhou et al., reduces here to the
min-time route at the current positions: every UAV always has a link to an
RSU (the Shannon rate never drops to zero) whose per-packet time is far below
one step, so carrying a packet to a later, better position never arrives
sooner (see docs/results/reproduction.md).
"""

from __future__ import annotations

import numpy as np

from truav.config import Config
from world import network
from world.env import LocalObs
from world.uavs import ACTION_UNIT_VELOCITY, HOVER, N_ACTIONS


TRACKABLE = float(np.cos(np.pi / 8))
"""Plans cruise at this fraction of the commanded speed: alternating two
neighbouring headings of the 16 actions, a UAV holds any direction at up to
v cos(22.5 deg), so a plan at that speed can be tracked with bounded error."""


def orbit_sites(cfg: Config) -> np.ndarray:
    """Centres (M, 2) of the patrol orbits in metres: the major intersections."""
    return np.asarray(cfg.roads.major_intersections, dtype=np.float64).reshape(-1, 2) * cfg.roads.block_m


def orbit_slots(cfg: Config) -> tuple[np.ndarray, np.ndarray]:
    """Per slot k (U of them): centre (U, 2) and clock phase at t = 0 (U,)."""
    sites = orbit_sites(cfg)
    n_uav, m = cfg.scenario.n_uavs, len(sites)
    centre = sites[np.arange(n_uav) % m]
    share = np.bincount(np.arange(n_uav) % m, minlength=m)  # UAVs per site
    rank = np.arange(n_uav) // m
    phase = 2.0 * np.pi * rank / share[np.arange(n_uav) % m]
    return centre, phase


def assign_slots(start: np.ndarray, centre: np.ndarray, radius: float, how: str) -> np.ndarray:
    """Slot of each UAV (U,) from start positions (U, 2). "nearest": greedy
    matching, shortest distance to an orbit first; "fixed": identity."""
    n = len(start)
    if how == "fixed":
        return np.arange(n)
    d = np.abs(np.linalg.norm(start[:, None, :] - centre[None, :, :], axis=-1) - radius)  # (uav, slot)
    slot = np.full(n, -1)
    taken = np.zeros(n, bool)
    for flat in np.argsort(d, axis=None, kind="stable"):
        u, k = divmod(int(flat), n)
        if slot[u] < 0 and not taken[k]:
            slot[u], taken[k] = k, True
    return slot


def plan_trajectories(start: np.ndarray, centre: np.ndarray, phase: np.ndarray, radius: float,
                      speed: float, dt: float, steps: int) -> tuple[np.ndarray, np.ndarray]:
    """Planned positions (steps + 1, U, 2) from start (U, 2) for UAVs flying
    slots with the given centres and phases, and the rendezvous step (U,)."""
    n = len(start)
    omega = speed / radius if radius > 0 else 0.0
    far = np.linalg.norm(start - centre, axis=1) + radius
    horizon = int(np.ceil(far.max() / max(speed * dt, 1e-12))) + 2
    t = np.arange(horizon + 1)
    ang = phase[None, :] + omega * dt * t[:, None]  # (H, U)
    clock = centre[None] + radius * np.stack([np.cos(ang), np.sin(ang)], axis=-1)  # (H, U, 2)
    reach = np.linalg.norm(clock - start[None], axis=-1) <= speed * dt * t[:, None] + 1e-9
    meet = reach.argmax(axis=0)  # first step the clock point is reachable (always exists by `horizon`)
    k = np.arange(steps + 1)[:, None]
    frac = np.clip(k / np.maximum(meet[None, :], 1), 0.0, 1.0)[..., None]
    line = start[None] + frac * (clock[meet, np.arange(n)] - start)[None]
    ks = np.minimum(np.arange(steps + 1), horizon)
    plan = np.where((k >= meet[None, :])[..., None], clock[ks], line)
    return plan, meet


class PatrolController:
    """Pre-planned orbits around the major intersections, B envs x U UAVs."""

    def __init__(self, cfg: Config, seeds: list[int]):
        self.cfg = cfg
        sc, pc = cfg.scenario, cfg.patrol
        self.batch, self.n_uavs = len(seeds), sc.n_uavs
        # cos(pi/8): the largest speed the 8 headings hold along any direction.
        self.speed = sc.uav_speed_mps * pc.speed_fraction * TRACKABLE
        self.centre, self.phase = orbit_slots(cfg)
        self._cand = np.concatenate([ACTION_UNIT_VELOCITY[:N_ACTIONS], ACTION_UNIT_VELOCITY[-1:]]) * sc.uav_speed_mps
        self._cand_action = np.concatenate([np.arange(N_ACTIONS), [HOVER]])
        self.plan = np.zeros((sc.steps_per_episode + 1, self.batch, self.n_uavs, 2))
        self.slot = np.zeros((self.batch, self.n_uavs), np.int64)
        self.meet = np.zeros((self.batch, self.n_uavs), np.int64)
        self.pos = np.zeros((self.batch, self.n_uavs, 2))
        self._err_sum = np.zeros(self.batch)
        self._err_n = 0
        self._channel, self._relay = network.relay_params(cfg)
        self.fused = True
        """The driver runs whole episodes through run_episode; False steps through act/observe."""
        self.draws_in_kernel = True
        """run_episode's kernel makes the world's per-episode draws (in parallel over envs)."""

    def run_episode(self, world) -> None:
        """Steps 0..T-1 of the world's current episode in one compiled kernel
        (agents.fused): the same numbers as act/observe through World.step."""
        from agents.fused import run_patrol_episode
        run_patrol_episode(world, self)

    def begin_episode(self, episode: int, obs: LocalObs) -> None:
        self.pos = obs.pos.copy()
        for b in range(self.batch):
            self.plan_env(b, self.pos[b])
        self._err_sum[:] = 0.0
        self._err_n = 0

    def plan_env(self, b: int, start: np.ndarray) -> None:
        """Env b's plan from the UAVs' start positions (U, 2): made once, at deployment."""
        sc, pc = self.cfg.scenario, self.cfg.patrol
        slot = assign_slots(start, self.centre, pc.radius_m, pc.assignment)
        plan, meet = plan_trajectories(start, self.centre[slot], self.phase[slot], pc.radius_m,
                                       self.speed, sc.step_s, sc.steps_per_episode)
        self.plan[:, b], self.slot[b], self.meet[b] = plan, slot, meet

    def act(self, t: int) -> np.ndarray:
        """The discrete action landing closest to each UAV's planned position at t+1."""
        sc = self.cfg.scenario
        land = np.clip(self.pos[:, :, None, :] + self._cand[None, None] * sc.step_s, 0.0, sc.area_m)
        miss = np.sum((land - self.plan[t + 1][:, :, None, :]) ** 2, axis=-1)  # (B, U, 17)
        return self._cand_action[np.argmin(miss, axis=-1)]

    def act_one(self, t: int, b: int, u: int, pos) -> int:
        """act(t) for UAV u of env b alone, from its own position (2,): the same arithmetic, so the
        swarm's patrol agent (agents.process.scheme_process) flies exactly what this controller flies."""
        sc = self.cfg.scenario
        land = np.clip(np.asarray(pos, np.float64)[None, :] + self._cand * sc.step_s, 0.0, sc.area_m)
        miss = np.sum((land - self.plan[t + 1, b, u][None, :]) ** 2, axis=-1)  # (17,)
        return int(self._cand_action[np.argmin(miss)])

    def observe(self, obs: LocalObs, done: bool) -> None:
        self.pos = obs.pos.copy()
        self._err_n += 1
        err = np.linalg.norm(self.pos - self.plan[self._err_n], axis=-1)
        self._err_sum += err.mean(axis=1)

    def episode_stats(self) -> dict[str, np.ndarray]:
        """Mean distance (m) between actual and planned positions."""
        return {"plan_error_m": self._err_sum / max(self._err_n, 1)}

    def planned_routes(self, t: int) -> tuple[np.ndarray, np.ndarray]:
        """Routing table of step t from the plan alone: per-packet route time
        (B, U) and next hop (B, U) (-1: straight to an RSU)."""
        time = np.zeros((self.batch, self.n_uavs))
        hop = np.zeros((self.batch, self.n_uavs), np.int64)
        for b in range(self.batch):
            rt, nh, _ = network.routes(np.ascontiguousarray(self.plan[t, b]), self._relay, self._channel)
            time[b], hop[b] = rt, nh
        return time, hop
