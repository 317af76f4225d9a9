"""The TRUAV world: vehicles, packets, channel, routing and UAV energy for B
independent environments stepped together. Pure numpy, no I/O.

Randomness: environment b draws everything from its own Generator, in
per-episode blocks of fixed shape (UAV start positions, Poisson arrivals,
turn uniforms), so a batch of seeds yields exactly what each seed yields
alone, whatever the batch size.

Time: `reset` spawns the vehicles and runs `warmup_steps` of traffic so the
city starts clustered, then starts episode 0. Traffic keeps flowing across
episodes (the city does not restart); each new episode re-places the UAVs and
empties the packet queues, so every episode's packet accounting closes:
generated = delivered + dropped + queued at the end.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from truav.config import Config
from world import network, uavs
from world.network import (COVERED, E_COVERED, E_DELAY_S, E_DELIVERED, E_EXPIRED, E_GENERATED,
                           E_OVERFLOW, E_WAIT_STEPS, ENV_COLUMNS, IN_RANGE, QUEUED, RELAYED, TX_TIME,
                           UAV_COLUMNS)
from world.packets import Queues
from world.roads import RoadGrid, Vehicles


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
    """Running sums over the current episode; arrays (B,)."""

    covered: np.ndarray
    generated: np.ndarray
    delivered: np.ndarray
    dropped: np.ndarray
    delay_sum_s: np.ndarray
    wait_sum_s: np.ndarray
    energy_j: np.ndarray
    energy_above_hover_j: np.ndarray

    @classmethod
    def zeros(cls, batch: int) -> "EpisodeTotals":
        return cls(*(np.zeros(batch) for _ in range(8)))

    def add(self, m: StepMetrics) -> None:
        self.covered += m.covered
        self.generated += m.generated
        self.delivered += m.delivered
        self.dropped += m.dropped_overflow + m.dropped_deadline
        self.delay_sum_s += m.delay_sum_s
        self.wait_sum_s += m.wait_sum_s
        n_uav = m.energy_j.shape[1]
        self.energy_j += np.add.reduce(m.energy_j, axis=1) / n_uav
        self.energy_above_hover_j += np.add.reduce(m.energy_above_hover_j, axis=1) / n_uav


@dataclass
class _EpisodeDraws:
    arrivals: np.ndarray  # (T, B, N)
    turn_u: np.ndarray  # (T, B, N, 2)
    uav_start: np.ndarray  # (B, U, 2)


class World:
    """B environments of the paper's scenario. Actions are (B, U) ints in
    [-1, 16); -1 (uavs.HOVER) hovers, e.g. when an agent's action is missing."""

    def __init__(self, cfg: Config, batch: int):
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
        self.t = 0
        self.episode = -1
        self.totals = EpisodeTotals.zeros(batch)
        self._draws: _EpisodeDraws | None = None
        self._out_uav = np.zeros((batch, self.n_uavs, UAV_COLUMNS))
        self._out_env = np.zeros((batch, ENV_COLUMNS))
        self._no_arrivals = np.zeros((batch, self.n_vehicles), np.int64)

    # -- episode control ------------------------------------------------------
    def reset(self, rngs: list[np.random.Generator]) -> LocalObs:
        """Spawn traffic from each env's generator, warm it up, start episode 0."""
        if len(rngs) != self.batch:
            raise ValueError(f"need {self.batch} generators, got {len(rngs)}")
        self.rngs = list(rngs)
        self.vehicles = Vehicles.concat([self.grid.spawn(rng, self.n_vehicles) for rng in self.rngs])
        warm = self.cfg.roads.warmup_steps
        if warm:
            u = np.stack([rng.random((warm, self.n_vehicles, 2)) for rng in self.rngs], axis=1)
            for k in range(warm):
                self.grid.step(self.vehicles, self.cfg.scenario.step_s, u[k])
        self.episode = -1
        return self.start_episode()

    def start_episode(self) -> LocalObs:
        """Re-place the UAVs, empty the queues and draw this episode's randomness."""
        sc, T, N, U = self.cfg.scenario, self.cfg.scenario.steps_per_episode, self.n_vehicles, self.n_uavs
        lam = self.cfg.traffic.packet_rate_hz * sc.step_s
        arrivals, turns, starts = [], [], []
        first = self.episode < 0
        for b, rng in enumerate(self.rngs):
            # Drawn every episode whatever the mode, so streams never depend on it.
            drawn = rng.random((U, 2)) * sc.area_m
            if sc.uav_start == "random" or (sc.uav_start == "persist" and first):
                starts.append(drawn)
            elif sc.uav_start == "persist":
                starts.append(self.uav_pos[b].copy())
            else:
                starts.append(np.full((U, 2), sc.area_m / 2.0))
            arrivals.append(rng.poisson(lam, (T, N)))
            turns.append(rng.random((T, N, 2)))
        self._draws = _EpisodeDraws(np.stack(arrivals, 1), np.stack(turns, 1), np.stack(starts))
        self.uav_pos = self._draws.uav_start.copy()
        self._velocity = np.zeros((self.batch, U, 2))
        self.queues.clear()
        self.totals = EpisodeTotals.zeros(self.batch)
        self.t = 0
        self.episode += 1
        self._run_relay(self._no_arrivals, serve_packets=False)
        return self._observe(np.zeros((self.batch, U)))

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
        actions = np.asarray(actions)
        if actions.shape != (self.batch, self.n_uavs):
            raise ValueError(f"actions must be shaped {(self.batch, self.n_uavs)}, got {actions.shape}")
        if actions.size and (actions.min() < uavs.HOVER or actions.max() >= uavs.N_ACTIONS):
            raise ValueError(f"actions must lie in [{uavs.HOVER}, {uavs.N_ACTIONS})")
        dt = sc.step_s
        velocity = uavs.action_velocity(actions, sc.uav_speed_mps)
        delay = np.clip(np.broadcast_to(np.asarray(action_delay_s, np.float64), actions.shape), 0.0, dt)
        if np.any(delay > 0):
            velocity = (self._velocity * delay[..., None] + velocity * (dt - delay)[..., None]) / dt
        self._velocity = velocity
        self.uav_pos, speed = uavs.move(self.uav_pos, velocity, dt, sc.area_m)
        self.grid.step(self.vehicles, dt, self._draws.turn_u[t])
        control = np.zeros(actions.shape) if control_airtime_s is None else \
            np.clip(np.asarray(control_airtime_s, np.float64), 0.0, dt)
        self._run_relay(self._draws.arrivals[t], serve_packets=True, busy0=control)
        out_uav, out_env = self._out_uav, self._out_env
        tx_time = out_uav[:, :, TX_TIME] + control
        energy = uavs.flight_energy(speed, dt, cfg.energy) + cfg.channel.uav_tx_w * tx_time
        metrics = StepMetrics(
            covered=out_env[:, E_COVERED].copy(),
            generated=out_env[:, E_GENERATED].copy(),
            delivered=out_env[:, E_DELIVERED].copy(),
            dropped_overflow=out_env[:, E_OVERFLOW].copy(),
            dropped_deadline=out_env[:, E_EXPIRED].copy(),
            delay_sum_s=out_env[:, E_DELAY_S].copy(),
            wait_sum_s=out_env[:, E_WAIT_STEPS] * dt,
            energy_j=energy,
            energy_above_hover_j=energy - cfg.energy.hover_w * dt,
        )
        self.totals.add(metrics)
        self.t += 1
        return self._observe(energy), metrics, self.t >= sc.steps_per_episode

    # -- sensing --------------------------------------------------------------
    def _run_relay(self, arrivals: np.ndarray, serve_packets: bool, busy0: np.ndarray | None = None) -> None:
        v = self.vehicles
        busy0 = np.zeros((self.batch, self.n_uavs)) if busy0 is None else np.ascontiguousarray(busy0)
        network.relay_step(v.heading, v.road, v.s, self.uav_pos, self.queues.slots, self.queues.total,
                           np.ascontiguousarray(arrivals), self.t, serve_packets, self.relay, self.channel,
                           busy0, self._out_uav, self._out_env)

    def _observe(self, energy: np.ndarray) -> LocalObs:
        o = self._out_uav
        return LocalObs(self.uav_pos.copy(), o[:, :, IN_RANGE].astype(np.int64), o[:, :, QUEUED].astype(np.int64),
                        o[:, :, RELAYED].astype(np.int64), o[:, :, COVERED].astype(np.int64), energy)

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
        """(B, N, 2) vehicle positions."""
        x, y = self.vehicles.xy(self.grid.block)
        return np.stack([x, y], axis=-1)
