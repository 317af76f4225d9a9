"""Centralized baseline (after Chen et al.): one controller, a multi-agent
soft actor-critic over the swarm's joint state, and an explicit control plane.

Each control round (every `central.update_period_steps` steps, default every
step):

1. Upload: every UAV sends its state report (`central.upload_bytes`) to the
   controller, over the same radio and the same min-time UAV/RSU routes as
   data packets (`world.network.routes`), then over the RSU's wired backhaul.
2. The controller waits for all U reports (a synchronous round), runs the
   joint policy (`central.compute_latency_s`) and sends each UAV its command
   (`central.download_bytes`) back along the reverse route.
3. Effects on the world (`World.step` hooks): each UAV's radio is busy for
   every hop it sends or receives (control messages, both directions), which
   is taken from its packet service and charged at the UAV transmit power;
   and the new action takes effect only after the round trip

       delay_u = max_v upload_v + 2 backhaul + compute + download_u,

   the UAV flying its previous action until then.

`ControlPlaneModel` computes these from positions alone (no torch); the
counters (messages, bytes, airtime, energy, delay) are reported per episode.
The learner is `agents.sac.BatchedSAC` (torch, the `central` extra): its
global critic sees the concatenation of all U per-UAV states; each UAV's
reward is TRUAV's local reward (agents.reward), so the two schemes optimise
the same objective and differ in learner and control plane.
"""

from __future__ import annotations

import numpy as np
from truav import kernel_cache  # noqa: F401, I001 - numba's cache set up before numba loads a kernel
from numba import njit

from agents.reward import Reward
from agents.state import all_peers, neighbour_features
from truav import seeding
from truav.config import Config
from world import network
from world.env import LocalObs
from world.uavs import N_ACTIONS

STATE_FEATURES = ("x", "y", "vehicles_in_range", "queued", "relayed", "covered", "energy", "rsu_distance")
"""Per-UAV state the controller receives; its joint state concatenates U of them."""
STATE_DIM = len(STATE_FEATURES)

CONTROL_COUNTERS = ("ctrl_up_msgs", "ctrl_up_bytes", "ctrl_down_msgs", "ctrl_down_bytes", "ctrl_airtime_s",
                    "ctrl_energy_j", "ctrl_delay_ms")
"""Per-episode control-plane counters, each (B,): messages and bytes (totals
over the swarm), radio airtime and its energy (per UAV, like energy_j), mean
action delay of the rounds (ms)."""


@njit(cache=True)
def _paths(pos, params, channel, busy):
    """End-to-end time (U,) of each UAV's message over its min-time route, and
    radio busy time added to busy (U,): the sending and the receiving UAV of
    every hop of every message are busy for the hop's time."""
    route_time, next_hop, hop_time = network.routes(pos, params, channel)
    n = pos.shape[0]
    for u in range(n):
        node, hops = u, 0
        while node >= 0 and hops <= n:
            busy[node] += hop_time[node]
            if next_hop[node] >= 0:
                busy[next_hop[node]] += hop_time[node]
            node, hops = next_hop[node], hops + 1
    return route_time


@njit(cache=True)
def _control_round(pos, up, down, channel, fixed_s, airtime, delay):
    for b in range(pos.shape[0]):
        up_time = _paths(pos[b], up, channel, airtime[b])
        down_time = _paths(pos[b], down, channel, airtime[b])
        for u in range(pos.shape[1]):
            delay[b, u] = up_time.max() + fixed_s + down_time[u]


class ControlPlaneModel:
    """Airtime, delay and traffic of one synchronous control round."""

    def __init__(self, cfg: Config):
        self.cfg = cfg
        c = cfg.central
        self.channel, relay = network.relay_params(cfg)
        self.up = relay._replace(bits=c.upload_bytes * 8.0)
        self.down = relay._replace(bits=c.download_bytes * 8.0)
        self.fixed_s = 2.0 * c.backhaul_latency_s + c.compute_latency_s

    def round(self, pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Radio airtime (B, U) and action delay (B, U) in seconds of a round
        with UAVs at pos (B, U, 2)."""
        airtime = np.zeros(pos.shape[:2])
        delay = np.zeros(pos.shape[:2])
        _control_round(np.ascontiguousarray(pos, dtype=np.float64), self.up, self.down, self.channel,
                       self.fixed_s, airtime, delay)
        return airtime, delay

    def messages(self, n_uavs: int) -> tuple[int, int, int, int]:
        """(up messages, up bytes, down messages, down bytes) of one round."""
        c = self.cfg.central
        return n_uavs, n_uavs * c.upload_bytes, n_uavs, n_uavs * c.download_bytes


class ControlCounters:
    """Runs control rounds and counts their traffic, airtime, energy and delay
    over an episode, for B envs."""

    def __init__(self, cfg: Config, batch: int):
        self.cfg, self.B = cfg, batch
        self.plane = ControlPlaneModel(cfg)
        self.counts = {k: np.zeros(batch) for k in CONTROL_COUNTERS}
        self.rounds = 0

    def reset(self) -> None:
        for v in self.counts.values():
            v[:] = 0.0
        self.rounds = 0

    def round(self, pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """One round with UAVs at pos (B, U, 2): (airtime (B, U), delay (B, U))."""
        airtime, delay = self.plane.round(pos)
        c = self.counts
        dt = self.cfg.scenario.step_s
        used_mean = _row_mean(np.minimum(airtime, dt))  # what the world charges (it clips at one step)
        c["ctrl_airtime_s"] += used_mean
        c["ctrl_energy_j"] += self.cfg.channel.uav_tx_w * used_mean
        c["ctrl_delay_ms"] += 1e3 * _row_mean(np.minimum(delay, dt))
        self.rounds += 1
        return airtime, delay

    def stats(self) -> dict[str, np.ndarray]:
        out = {k: v.copy() for k, v in self.counts.items()}
        # The same messages every round: their totals are rounds x one round's (integers, so exactly the sums).
        per_round = self.plane.messages(self.cfg.scenario.n_uavs)
        for key, count in zip(("ctrl_up_msgs", "ctrl_up_bytes", "ctrl_down_msgs", "ctrl_down_bytes"), per_round):
            out[key][:] = float(self.rounds * count)
        out["ctrl_delay_ms"] = out["ctrl_delay_ms"] / max(self.rounds, 1)
        return out


def _row_mean(x: np.ndarray) -> np.ndarray:
    """x.mean(axis=1) as numpy computes it (add.reduce, then true_divide by the count), without its Python wrapper."""
    out = np.add.reduce(x, 1)
    out /= x.shape[1]
    return out


class WithControlPlane:
    """Any controller of the driver plus the centralized control plane: its
    UAVs upload their state and wait for their command every round, as the
    centralized baseline's do. Applied to a fixed policy (the patrol), it
    measures what the control plane alone costs, learner aside."""

    def __init__(self, inner, cfg: Config, batch: int):
        self.inner, self.cfg = inner, cfg
        self.counters = ControlCounters(cfg, batch)
        self.pos = np.zeros((batch, cfg.scenario.n_uavs, 2))
        self._round = False

    def begin_episode(self, episode: int, obs: LocalObs) -> None:
        self.inner.begin_episode(episode, obs)
        self.pos = obs.pos.copy()
        self.counters.reset()

    def act(self, t: int) -> np.ndarray:
        self._round = t % self.cfg.central.update_period_steps == 0
        return self.inner.act(t)

    def control(self, t: int) -> tuple[np.ndarray | None, np.ndarray | float]:
        return self.counters.round(self.pos) if self._round else (None, 0.0)

    def observe(self, obs: LocalObs, done: bool) -> None:
        self.inner.observe(obs, done)
        self.pos = obs.pos.copy()

    def episode_stats(self) -> dict[str, np.ndarray]:
        return {**self.inner.episode_stats(), **self.counters.stats()}


def uav_states(cfg: Config, obs: LocalObs, rsu: np.ndarray) -> np.ndarray:
    """Per-UAV state reports (B, U, STATE_DIM), each feature scaled to O(1)."""
    sc, e = cfg.scenario, cfg.energy
    share = sc.n_vehicles / sc.n_uavs
    relay_share = max(cfg.traffic.packet_rate_hz * sc.n_vehicles * sc.step_s / sc.n_uavs, 1e-9)
    scale = np.array([sc.area_m, share, share * cfg.traffic.queue_limit, relay_share, share,
                      max(e.move_w * sc.step_s, 1e-9)], np.float64)
    out = np.empty(obs.pos.shape[:2] + (STATE_DIM,))
    _uav_states(np.ascontiguousarray(obs.pos, np.float64), obs.vehicles_in_range, obs.queued, obs.relayed,
                obs.covered, obs.energy_j, np.ascontiguousarray(rsu, np.float64), scale, out)
    return out


@njit(cache=True)
def _uav_states(pos, in_range, queued, relayed, covered, energy, rsu, scale, out):
    """uav_states' features, each as numpy computes them (x / scale, then capped at 10;
    the RSU distance is sqrt(dx^2 + dy^2), the nearest RSU's)."""
    area = scale[0]
    for b in range(pos.shape[0]):
        for u in range(pos.shape[1]):
            x, y = pos[b, u, 0], pos[b, u, 1]
            d = np.inf
            for k in range(rsu.shape[0]):
                dx, dy = x - rsu[k, 0], y - rsu[k, 1]
                d = min(d, np.sqrt(dx * dx + dy * dy))
            feats = (x / area, y / area, in_range[b, u] / scale[1], queued[b, u] / scale[2],
                     relayed[b, u] / scale[3], covered[b, u] / scale[4], energy[b, u] / scale[5], d / area)
            for i in range(len(feats)):
                f = feats[i]
                out[b, u, i] = f if f != f or f < 10.0 else 10.0


class CentralController:
    """The centralized MA-SAC controller for B envs x U UAVs, with its control plane."""

    def __init__(self, cfg: Config, seeds: list[int], train: bool = True,
                 params: dict[str, np.ndarray] | None = None):
        from agents.sac import BatchedSAC
        self.cfg, self.train = cfg, train
        sc = cfg.scenario
        self.B, self.U = len(seeds), sc.n_uavs
        self.plane = ControlPlaneModel(cfg)
        self.reward = Reward(cfg)
        self.rsu = network.rsu_positions(cfg)
        self.sac = BatchedSAC(cfg.central, cfg.learner.discount, self.U * STATE_DIM, self.U, N_ACTIONS,
                              [seeding.baseline_rng(s, 1) for s in seeds])
        if params is not None:
            self.sac.load_actor(params)
        self.env_steps = 0
        self.state = np.zeros((self.B, self.U * STATE_DIM))
        self.pos = np.zeros((self.B, self.U, 2))
        self.action = np.zeros((self.B, self.U), np.int64)
        self._round = False
        self.counters = ControlCounters(cfg, self.B)
        self._reward_sum = np.zeros(self.B)
        self._steps = 0

    @property
    def critic_input_dim(self) -> int:
        """The global critic's input: U x the per-UAV state dimension."""
        return self.sac.obs_dim

    def joint_state(self, obs: LocalObs) -> np.ndarray:
        return uav_states(self.cfg, obs, self.rsu).reshape(self.B, self.U * STATE_DIM)

    def begin_episode(self, episode: int, obs: LocalObs) -> None:
        self.state = self.joint_state(obs)
        self.pos = obs.pos.copy()
        self.counters.reset()
        self._reward_sum[:] = 0.0
        self._steps = 0

    def act(self, t: int) -> np.ndarray:
        self._round = t % self.cfg.central.update_period_steps == 0
        if self._round:
            if self.train and self.env_steps < self.cfg.central.learning_starts:
                self.action = self.sac.random_actions()
            else:
                self.action = self.sac.act(self.state, greedy=not (self.train or self.cfg.central.evaluate_sampled))
        return self.action

    def control(self, t: int) -> tuple[np.ndarray | None, np.ndarray | float]:
        """This step's control-plane effects (driver.ControlPlane)."""
        if not self._round:
            return None, 0.0
        return self.counters.round(self.pos)

    def observe(self, obs: LocalObs, done: bool) -> None:
        nxt = self.joint_state(obs)
        _, overlap = neighbour_features(obs.pos, *all_peers(obs.pos), self.cfg.scenario.comm_range_m)
        r = self.reward(obs.relayed, obs.covered, obs.energy_j, overlap)
        if self.train:
            self.sac.store(self.state, self.action, r * self.cfg.central.reward_scale, nxt)
            self.env_steps += 1
            c = self.cfg.central
            if self.env_steps >= c.learning_starts and self.env_steps % c.update_every == 0:
                self.sac.update()
        self._reward_sum += _row_mean(r)
        self._steps += 1
        self.state = nxt
        self.pos = obs.pos.copy()

    def episode_stats(self) -> dict[str, np.ndarray]:
        out = self.counters.stats()
        out["reward"] = self._reward_sum / max(self._steps, 1)
        out["alpha"] = self.sac.alpha
        return out
