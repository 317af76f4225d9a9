"""The TRUAV world: vehicles, packets, channel, routing and UAV energy for B
independent environments stepped together. Pure numpy, no I/O.

Randomness: environment b draws everything from its own Generator, in
per-episode blocks of fixed shape (UAV start positions, Poisson arrivals,
turn uniforms), so a batch of seeds yields exactly what each seed yields
alone, whatever the batch size.

Time: `reset` spawns the vehicles and runs `warmup_steps` of traffic so the
city starts clustered, then starts episode 0. Traffic keeps flowing across
episodes (the city does not restart); each new episode re-places the UAVs
(`scenario.uav_start`), may move the traffic hotspots
(`roads.hotspot_move_prob`, their vehicles then drive to the new sites) and
empties the packet queues, so every episode's packet accounting closes:
generated = delivered + dropped + queued at the end.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from truav.config import Config
from world import network, uavs
from world.draws import (POISSON_MULT_MAX_LAM, pcg64_state, poisson_into, rng_words, set_pcg64_state,
                         uniform_into)
from world.network import (COVERED, DENSEST, DISC_DX, DISC_DY, DISC_VEHICLES, E_COVERED, E_DELAY_S, E_DELIVERED,
                           E_EXPIRED, E_GENERATED, E_OVERFLOW, E_WAIT_STEPS, ENV_COLUMNS, EXCLUSIVE, IN_RANGE, QUEUED,
                           RELAYED, UAV_COLUMNS)
from world.packets import Queues
from world.roads import RoadGrid, Vehicles
from world.step import TOTAL_COLUMNS, grid_xy, uav_params, world_step
from world.trace import Trace


@dataclass
class LocalObs:
    """What each UAV can sense locally; arrays (B, U) unless noted."""

    pos: np.ndarray
    """(B, U, 2) own position (m)."""
    vehicles_in_range: np.ndarray
    """Vehicles within comm range (int)."""
    queued: np.ndarray
    """Packets queued at the vehicles associated with this UAV (int)."""
    relayed: np.ndarray
    """Packets this UAV relayed to an RSU in the last step (int)."""
    covered: np.ndarray
    """Vehicles associated with (served by) this UAV in the last step (int)."""
    energy_j: np.ndarray
    """Energy this UAV spent in the last step (J)."""
    densest_sector: np.ndarray | None = None
    """Sensing of denser areas nearby (int): 1 + the direction sector with the
    most vehicles beyond comm range within learner.sense_range_m, 0 if none
    or sensing is off (world.network.DENSEST). The world always fills it; None
    where an observation is rebuilt from messages without it (the central
    controller process, whose state does not use it)."""
    exclusive: np.ndarray | None = None
    """Vehicles within this UAV's comm range and no other UAV's (int): what the
    swarm's coverage would lose without it (world.network.EXCLUSIVE; the
    difference reward, learner.w_difference). None as densest_sector."""
    disc_offset: np.ndarray | None = None
    """(B, U, 2) the densest sensed disc's centre minus own position (m), 0 where none is sensed or
    learner.sense_disc is off (world.network.DISC_DX). None as densest_sector."""
    disc_vehicles: np.ndarray | None = None
    """The vehicles within comm range of that centre (int), 0 as above. None as densest_sector."""


@dataclass
class StepMetrics:
    """Network-wide outcome of one step; arrays (B,) unless noted."""

    covered: np.ndarray
    generated: np.ndarray
    delivered: np.ndarray
    dropped_overflow: np.ndarray
    dropped_deadline: np.ndarray
    delay_sum_s: np.ndarray
    """Sum over delivered packets of their relay delay (s)."""
    wait_sum_s: np.ndarray
    """Sum over delivered packets of the time they waited in the vehicle queue (s)."""
    energy_j: np.ndarray
    """(B, U) energy per UAV this step."""
    energy_above_hover_j: np.ndarray
    """(B, U) the part above hovering."""


EPISODE_FIELDS = ("coverage_pct", "pdr", "delay_ms", "energy_j", "energy_above_hover_j",
                  "throughput_kbps", "generated", "delivered", "dropped", "queued_end", "wait_s")


@dataclass
class EpisodeTotals:
    """Running sums over the current episode; arrays (B,), views of the
    columns of the world's (B, TOTAL_COLUMNS) totals that its step kernel adds to."""

    covered: np.ndarray
    generated: np.ndarray
    delivered: np.ndarray
    dropped: np.ndarray
    delay_sum_s: np.ndarray
    wait_sum_s: np.ndarray
    energy_j: np.ndarray
    energy_above_hover_j: np.ndarray

    @classmethod
    def of(cls, table: np.ndarray) -> "EpisodeTotals":
        return cls(*(table[:, k] for k in range(TOTAL_COLUMNS)))


@dataclass
class _EpisodeDraws:
    arrivals: np.ndarray  # (T, B, N)
    turn_u: np.ndarray  # (T, B, N, 2)
    uav_start: np.ndarray  # (B, U, 2)


class World:
    """B environments of the paper's scenario. Actions are (B, U) ints in
    [-1, 16); -1 (uavs.HOVER) hovers, e.g. when an agent's action is missing.

    trace: the vehicles' positions, replayed, when scenario.mobility is "sumo"
    (world/trace.py; truav/analysis/sumo_traffic.py loads it): each env starts at a
    window drawn from its generator at reset and takes the next window each
    episode; the grid's own mobility then does not run."""

    def __init__(self, cfg: Config, batch: int, trace: Trace | None = None):
        self.cfg = cfg
        self.batch = batch
        sc = cfg.scenario
        self.n_vehicles, self.n_uavs = sc.n_vehicles, sc.n_uavs
        self.grid = RoadGrid(cfg)
        self.channel, self.relay = network.relay_params(cfg)
        self.rngs: list[np.random.Generator] = []
        self.vehicles: Vehicles | None = None
        self.queues = Queues.empty(batch, self.n_vehicles, cfg.traffic.deadline_steps)
        self.uav_pos = np.zeros((batch, self.n_uavs, 2))
        self._velocity = np.zeros((batch, self.n_uavs, 2))
        self.uav = uav_params(cfg)
        self.t = 0
        self.episode = -1
        self._totals = np.zeros((batch, TOTAL_COLUMNS))
        self.totals = EpisodeTotals.of(self._totals)
        self._draws: _EpisodeDraws | None = None
        self._out_uav = np.zeros((batch, self.n_uavs, UAV_COLUMNS))
        self._out_env = np.zeros((batch, ENV_COLUMNS))
        self._energy = np.zeros((batch, self.n_uavs))
        self._above_hover = np.zeros((batch, self.n_uavs))
        self._no_arrivals = np.zeros((batch, self.n_vehicles), np.int64)
        self.trace = trace
        if (trace is None) != (sc.mobility != "sumo"):
            raise ValueError(f"scenario.mobility = {sc.mobility!r} " + ("needs a trace" if trace is None else
                                                                        "replays no trace"))
        if trace is not None and trace.mismatch(cfg):
            raise ValueError(f"the mobility trace does not fit the scenario: {trace.mismatch(cfg)}")
        self._trace = np.zeros((0, self.n_vehicles, 2)) if trace is None else \
            np.ascontiguousarray(trace.positions, np.float64)
        """(R, N, 2) the replayed positions, or (0, N, 2) for the grid's own mobility."""
        self._trace_offset = np.zeros(batch, np.int64)
        """Each env's first window of the trace (drawn at reset)."""
        self._row0 = np.zeros(batch, np.int64)
        """Each env's trace row of its current episode's start."""
        self._xy = np.zeros((batch, self.n_vehicles, 2))
        """(B, N, 2) the vehicles' positions now: what packets, channel and routing see."""
        self._zeros_bu = np.zeros((batch, self.n_uavs))
        self.draw_map = map
        """How start_episode maps its per-env draws: a thread pool's map draws
        envs in parallel (each env has its own generator, so nothing changes)."""
        self._deployed: np.ndarray | None = None
        self.episode_rng_words: np.ndarray | None = None
        """(B, 6) uint64: each env's generator (draws.rng_words) before the current episode's draws."""
        self._rng_state: np.ndarray | None = None
        """(B, 4) uint64 PCG64 states while an episode's draws are deferred (start_episode)."""

    # -- episode control ------------------------------------------------------
    def __setstate__(self, state: dict) -> None:
        """An unpickled world (a training checkpoint): pickling copies the totals' views of _totals apart."""
        self.__dict__.update(state)
        self.totals = EpisodeTotals.of(self._totals)

    def reset(self, rngs: list[np.random.Generator], uav_pos: np.ndarray | None = None,
              defer_draws: bool = False) -> LocalObs:
        """Spawn traffic from each env's generator, warm it up, start episode 0.

        uav_pos (B, U, 2): with scenario.uav_start = "persist", a swarm already
        deployed there (e.g. where training left it) instead of a random first
        deployment; the random draw is made anyway, so the streams do not change.
        defer_draws: see start_episode."""
        if len(rngs) != self.batch:
            raise ValueError(f"need {self.batch} generators, got {len(rngs)}")
        if uav_pos is not None and np.shape(uav_pos) != (self.batch, self.n_uavs, 2):
            raise ValueError(f"uav_pos must be shaped {(self.batch, self.n_uavs, 2)}, got {np.shape(uav_pos)}")
        self._deployed = None if uav_pos is None else np.array(uav_pos, np.float64)
        self.rngs = list(rngs)
        self.vehicles = Vehicles.concat([self.grid.spawn(rng, self.n_vehicles) for rng in self.rngs])
        warm = self.cfg.roads.warmup_steps
        if self.trace is not None:  # replayed traffic warmed up in SUMO; an env's windows start where its draw says
            self._trace_offset = np.array([rng.integers(self.trace.windows) for rng in self.rngs], np.int64)
        elif warm:
            u = np.stack([rng.random((warm, self.n_vehicles, 2)) for rng in self.rngs], axis=1)
            for k in range(warm):
                self.grid.step(self.vehicles, self.cfg.scenario.step_s, u[k])
        self.episode = -1
        self.hotspots = np.repeat(self.grid.majors[None], self.batch, axis=0)
        """(B, K, 2) grid indices of each env's traffic-cluster sites."""
        return self.start_episode(defer_draws)

    def start_episode(self, defer_draws: bool = False) -> LocalObs:
        """Re-place the UAVs, empty the queues and draw this episode's randomness.

        defer_draws: leave the draws after the UAV start (arrivals, turns,
        hotspot moves) to a kernel that makes them itself from each env's
        PCG64 state (`deferred_draws`, then `end_deferred_draws`), so they
        run in parallel with the episode; done here anyway where that kernel
        could not draw the same numbers (see `deferred_draws`)."""
        sc, T, N, U = self.cfg.scenario, self.cfg.scenario.steps_per_episode, self.n_vehicles, self.n_uavs
        lam = self.cfg.traffic.packet_rate_hz * sc.step_s
        first = self.episode < 0
        if self._rng_state is not None:
            raise RuntimeError("the last episode's deferred draws were never made (end_deferred_draws)")
        defer = defer_draws and lam < POISSON_MULT_MAX_LAM and all(
            type(rng.bit_generator) is np.random.PCG64 for rng in self.rngs)

        def draw(b: int):
            rng = self.rngs[b]
            # Drawn every episode whatever the mode, so streams never depend on it.
            drawn = rng.random((U, 2)) * sc.area_m
            if sc.uav_start == "persist" and first and self._deployed is not None:
                start = self._deployed[b].copy()
            elif sc.uav_start == "random" or (sc.uav_start == "persist" and first):
                start = drawn
            elif sc.uav_start == "persist":
                start = self.uav_pos[b].copy()
            else:
                start = np.full((U, 2), sc.area_m / 2.0)
            if defer:
                return start
            moves = self.episode_blocks(rng, b)
            if moves is not None and not first:  # env b's rows only, so the envs may be drawn on threads
                self.grid.move_hotspots(self.vehicles, b, self.hotspots[b], moves)
            return start

        # The last episode's arrays are refilled: fresh ones cost page faults on
        # first touch (~5 MB per 10 envs), and nothing keeps a past episode's draws.
        if self._draws is None or self._draws.arrivals.shape != (T, self.batch, N):
            self._draws = _EpisodeDraws(np.empty((T, self.batch, N), np.int64), np.empty((T, self.batch, N, 2)),
                                        np.empty((self.batch, U, 2)))
        arrivals, turns = self._draws.arrivals, self._draws.turn_u
        # Each env's generator before this episode's draws: a snapshot (world.world_state) redraws them from it.
        self.episode_rng_words = np.stack([rng_words(rng) for rng in self.rngs]) if all(
            type(rng.bit_generator) is np.random.PCG64 for rng in self.rngs) else None
        starts = list((map if defer else self.draw_map)(draw, range(self.batch)))
        if defer:  # each env's stream after its UAV start, for the kernel
            self._rng_state = np.stack([pcg64_state(rng) for rng in self.rngs])
            self._moves = np.empty((self.batch, len(self.grid.majors) if self.cfg.roads.hotspot_move_prob > 0.0
                                    else 0, 2))
            self._exp_neg_lam = math.exp(-lam)  # numpy's C exp(), i.e. the C library's
        self._draws.uav_start = np.stack(starts)
        self.uav_pos = self._draws.uav_start.copy()
        self._velocity = np.zeros((self.batch, U, 2))
        self.queues.clear()
        self._totals[:] = 0.0
        self.t = 0
        self.episode += 1
        if self.trace is None:
            v = self.vehicles
            for b in range(self.batch):
                grid_xy(v.heading[b], v.road[b], v.s[b], self.grid.block, self._xy[b])
        else:
            self._row0 = np.array([self.trace.episode_row0(int(o), self.episode) for o in self._trace_offset],
                                  np.int64)
            self._xy[:] = self._trace[self._row0]
        self._run_relay(self._no_arrivals, serve_packets=False)
        return self._observe(np.zeros((self.batch, U)))

    def episode_blocks(self, rng: np.random.Generator, b: int) -> np.ndarray | None:
        """Env b's episode draws after its UAV start, from ``rng``: its arrivals and turn uniforms into this
        episode's arrays, and the uniforms (K, 2) of its hotspot moves (None when hotspots are fixed: not
        drawn then, so fixed-hotspot streams stay unchanged)."""
        lam = self.cfg.traffic.packet_rate_hz * self.cfg.scenario.step_s
        poisson_into(rng, lam, self._draws.arrivals[:, b])  # = rng.poisson(lam, (T, N)), in place
        uniform_into(rng, self._draws.turn_u[:, b])  # = rng.random((T, N, 2))
        if self.cfg.roads.hotspot_move_prob > 0.0:
            return rng.random((len(self.grid.majors), 2))
        return None

    def deferred_draws(self):
        """What a kernel needs to make the draws start_episode(defer_draws=True)
        deferred, or None if it made them itself: (rng_state (B, 4) uint64, the
        envs' PCG64 states; exp(-lam) of the Poisson arrivals; moves (B, K, 2)
        scratch for the hotspot moves' uniforms, K = 0 when hotspots are fixed;
        whether to apply the moves (not in the first episode); the
        roads.HotspotParams). A kernel draws env b as draws.pcg64_episode_draws
        on rng_state[b], then applies roads.move_hotspots_env with
        self.hotspots[b]. Deferral needs the multiplication method of numpy's
        Poisson (lam < 10) and PCG64 generators."""
        if self._rng_state is None:
            return None
        return (self._rng_state, self._exp_neg_lam, self._moves, self.episode > 0, self.grid.hotspot_params())

    def end_deferred_draws(self) -> None:
        """The kernel made the deferred draws: its advanced states go back
        into the envs' generators."""
        for rng, words in zip(self.rngs, self._rng_state):
            set_pcg64_state(rng, words)
        self._rng_state = None

    # -- one step -----------------------------------------------------------
    def step(self, actions: np.ndarray, control_airtime_s: np.ndarray | None = None,
             action_delay_s: np.ndarray | float = 0.0) -> tuple[LocalObs, StepMetrics, bool]:
        """Apply one action per UAV and advance one step. Returns the new local
        observations, the step's metrics and whether the episode ended.

        Hooks for schemes with a control plane (e.g. a central controller):
        control_airtime_s (B, U) is radio time each UAV spends this step on
        control messages (taken from its packet service, charged at the UAV
        transmit power); action_delay_s (scalar or (B, U)) is how long each UAV
        keeps flying its previous action before the new one takes effect."""
        cfg, sc, t = self.cfg, self.cfg.scenario, self.t
        if self._draws is None or t >= sc.steps_per_episode:
            raise RuntimeError("call reset() or start_episode() first")
        if self._rng_state is not None:
            raise RuntimeError("this episode's draws were deferred to a kernel (start_episode(defer_draws=True))")
        actions = np.asarray(actions)
        if actions.shape != (self.batch, self.n_uavs):
            raise ValueError(f"actions must be shaped {(self.batch, self.n_uavs)}, got {actions.shape}")
        if actions.size and (actions.min() < uavs.HOVER or actions.max() >= uavs.N_ACTIONS):
            raise ValueError(f"actions must lie in [{uavs.HOVER}, {uavs.N_ACTIONS})")
        dt = sc.step_s
        if np.ndim(action_delay_s) == 0 and action_delay_s == 0.0:
            delay, blend = self._zeros_bu, False
        else:
            delay = np.clip(np.broadcast_to(np.asarray(action_delay_s, np.float64), actions.shape), 0.0, dt)
            blend = bool(np.any(delay > 0))
        control = self._zeros_bu if control_airtime_s is None else \
            np.clip(np.asarray(control_airtime_s, np.float64), 0.0, dt)
        v, q, draws = self.vehicles, self.queues, self._draws
        world_step(np.ascontiguousarray(actions, np.int64), blend, np.ascontiguousarray(delay),
                   np.ascontiguousarray(control), self.uav_pos, self._velocity, v.heading, v.road, v.s, v.v,
                   v.home, v.next_turn, v.lane_order, draws.turn_u[t], self._xy, self._trace, self._row0, q.slots,
                   q.total, draws.arrivals[t], t, self.uav,
                   self.grid.params, self.relay, self.channel, self._out_uav, self._out_env, self._energy,
                   self._above_hover, self._totals)
        out_env = self._out_env
        energy = self._energy.copy()
        metrics = StepMetrics(
            covered=out_env[:, E_COVERED].copy(),
            generated=out_env[:, E_GENERATED].copy(),
            delivered=out_env[:, E_DELIVERED].copy(),
            dropped_overflow=out_env[:, E_OVERFLOW].copy(),
            dropped_deadline=out_env[:, E_EXPIRED].copy(),
            delay_sum_s=out_env[:, E_DELAY_S].copy(),
            wait_sum_s=out_env[:, E_WAIT_STEPS] * dt,
            energy_j=energy,
            energy_above_hover_j=self._above_hover.copy(),
        )
        self.t += 1
        return self._observe(energy), metrics, self.t >= sc.steps_per_episode

    # -- sensing --------------------------------------------------------------
    def _run_relay(self, arrivals: np.ndarray, serve_packets: bool, busy0: np.ndarray | None = None) -> None:
        busy0 = np.zeros((self.batch, self.n_uavs)) if busy0 is None else np.ascontiguousarray(busy0)
        network.relay_step(self._xy, self.uav_pos, self.queues.slots, self.queues.total,
                           np.ascontiguousarray(arrivals), self.t, serve_packets, self.relay, self.channel,
                           busy0, self._out_uav, self._out_env)

    def _observe(self, energy: np.ndarray) -> LocalObs:
        o = self._out_uav
        return LocalObs(self.uav_pos.copy(), o[:, :, IN_RANGE].astype(np.int64), o[:, :, QUEUED].astype(np.int64),
                        o[:, :, RELAYED].astype(np.int64), o[:, :, COVERED].astype(np.int64), energy,
                        o[:, :, DENSEST].astype(np.int64), o[:, :, EXCLUSIVE].astype(np.int64),
                        o[:, :, DISC_DX:DISC_DY + 1].copy(), o[:, :, DISC_VEHICLES].astype(np.int64))

    # -- episode summary -------------------------------------------------------
    def episode_summary(self) -> dict[str, np.ndarray]:
        """Metrics of the episode so far, each (B,): coverage %, PDR, mean relay
        delay (ms), energy per UAV (J) and above hover (J), throughput (kbit/s),
        packet accounting and mean queue wait of delivered packets (s)."""
        tot, steps = self.totals, max(self.t, 1)
        sc = self.cfg.scenario
        delivered = tot.delivered
        with np.errstate(invalid="ignore", divide="ignore"):
            return {
                "coverage_pct": 100.0 * tot.covered / (steps * self.n_vehicles),
                "pdr": np.where(tot.generated > 0, delivered / tot.generated, np.nan),
                "delay_ms": np.where(delivered > 0, 1e3 * tot.delay_sum_s / delivered, np.nan),
                "energy_j": tot.energy_j.copy(),
                "energy_above_hover_j": tot.energy_above_hover_j.copy(),
                "throughput_kbps": delivered * self.relay.bits / (steps * sc.step_s) / 1e3,
                "generated": tot.generated.copy(),
                "delivered": delivered.copy(),
                "dropped": tot.dropped.copy(),
                "queued_end": self.queues.total.sum(axis=1).astype(np.float64),
                "wait_s": np.where(delivered > 0, tot.wait_sum_s / delivered, np.nan),
            }

    def vehicle_xy(self) -> np.ndarray:
        """(B, N, 2) vehicle positions (NaN: a replayed vehicle not on the road)."""
        return self._xy.copy()
