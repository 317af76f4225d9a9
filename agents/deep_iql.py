"""A deep decentralized learner written only against the public agent API (agents.api): independent DQN.

Registered as ``iql`` (``truav train --agent iql``; or ``agents.deep_iql:DeepIql``). Each UAV owns one
small MLP Q-network (no parameter sharing, no central critic), trained from its own replay buffer with
a target network and Adam (agents/deep_iql_core.py, pure numpy), on features of its LocalView and the
beacons it heard (:func:`features`). Exploration follows the project's learner schedule
(learner.epsilon_*, learner.episodes), the discount is learner.discount, and with learner.geofence on
(the `paper` preset) it never picks an action whose full move leaves the area, as TRUAV does.

Both API forms: :class:`DeepIql` flies one UAV (a core of one network); its ``batched`` form,
:class:`DeepIqlBatched`, steps the B x U networks of a training as one core (batched matmuls), and
computes exactly what the per-UAV form computes (tests/unit/test_deep_iql.py). Hyper-parameters are
the class attribute ``hp`` (:class:`DeepIqlConfig`): subclass both classes to change them.
docs/results/deep-learner.md has its results at the paper's budget.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Mapping

import numpy as np

from agents.api import BatchedAgents, BatchedViews, LocalView, N_ACTIONS, UavAgent
from agents.deep_iql_core import IqlCore
from truav.config import Config


@dataclass(frozen=True)
class DeepIqlConfig:
    """The learner's hyper-parameters (the scenario's and learner.* settings come from the run's config)."""

    hidden: tuple[int, ...] = (32, 32)
    """Hidden layer widths (ReLU). Small: a training steps B x U of them 500,000 times on a CPU."""
    learning_rate: float = 5e-4
    """Adam's step size."""
    adam_beta1: float = 0.9
    """Adam's first-moment decay."""
    adam_beta2: float = 0.999
    """Adam's second-moment decay."""
    adam_eps: float = 1e-8
    """Adam's denominator floor."""
    batch_size: int = 32
    """Transitions per update, drawn uniformly from the UAV's own buffer."""
    replay_capacity: int = 20_000
    """Transitions kept per UAV (200 episodes of 100 steps), oldest overwritten."""
    warmup: int = 1_000
    """Transitions stored before the first update."""
    train_every: int = 4
    """One update per this many stored transitions."""
    target_every: int = 250
    """Updates between copies of the online network into the target network."""
    td_clip: float = 1.0
    """The TD error is clipped to +-this in the gradient (the Huber loss)."""
    k_peers: int = 3
    """The nearest heard peers whose relative position and velocity are features."""
    peer_scale_comm_ranges: float = 4.0
    """Relative peer positions are divided by this many comm ranges and clipped to [-1, 1]: beyond, a peer
    is just 'far' (the tabular state's neighbour levels stop at 4R as well)."""
    position_frequencies: tuple[int, ...] = (1, 2, 4)
    """sin/cos of 2 pi f x / area for each f: a small network can then represent where in the city a UAV
    is (hotspot sites) better than from x / area alone."""


def n_features(cfg: Config, hp: DeepIqlConfig) -> int:
    return 2 + 4 * len(hp.position_frequencies) + 8 + cfg.learner.sense_sectors + 1 + 6 * hp.k_peers


def features(cfg: Config, hp: DeepIqlConfig, step: int, speed_max: float, pos, in_range, queued, relayed,
             covered, energy_j, densest, exclusive, rsu_m, peer_pos, peer_vel, heard) -> np.ndarray:
    """Features (N, n_features) of N UAVs' views: pos (N, 2), counts (N,), peers (N, P, 2) with heard (N, P).

    One function for both forms: the per-UAV form passes its view as N = 1, P = its beacons; the batched
    form every UAV with P = U (itself unheard). Peers are ranked by distance (stable: ties in id order),
    so both pick the same k nearest."""
    sc = cfg.scenario
    area, n = float(sc.area_m), len(pos)
    xy = pos / area
    cols = [xy]
    for f in hp.position_frequencies:
        cols += [np.sin(2 * np.pi * f * xy), np.cos(2 * np.pi * f * xy)]
    counts = np.stack([np.log1p(in_range) / 4.0, np.log1p(queued) / 6.0, np.log1p(relayed) / 4.0,
                       np.log1p(covered) / 4.0, np.log1p(exclusive) / 4.0,
                       energy_j / (cfg.energy.move_w * sc.step_s), np.minimum(rsu_m / area, 1.5),
                       np.full(n, step / sc.steps_per_episode)], axis=1)
    sectors = np.arange(cfg.learner.sense_sectors + 1)
    cols += [counts, (np.asarray(densest)[:, None] == sectors).astype(np.float64)]
    # k nearest heard peers: k unheard dummies appended so that fewer than k peers still give k columns
    k, scale = hp.k_peers, hp.peer_scale_comm_ranges * sc.comm_range_m
    rel = np.concatenate([peer_pos - pos[:, None, :], np.zeros((n, k, 2))], axis=1)
    vel = np.concatenate([peer_vel, np.zeros((n, k, 2))], axis=1)
    dist = np.sqrt(rel[..., 0] ** 2 + rel[..., 1] ** 2)
    dist = np.where(np.concatenate([heard, np.zeros((n, k), np.bool_)], axis=1), dist, np.inf)
    pick = np.argsort(dist, axis=1, kind="stable")[:, :k]
    d = np.take_along_axis(dist, pick, axis=1)
    present = np.isfinite(d)
    r = np.where(present[..., None], np.take_along_axis(rel, pick[..., None], axis=1), 0.0)
    v = np.where(present[..., None], np.take_along_axis(vel, pick[..., None], axis=1), 0.0)
    peer = np.concatenate([np.clip(r / scale, -1.0, 1.0), np.where(present, np.minimum(d / scale, 1.0), 1.0)[..., None],
                           present[..., None].astype(np.float64), v / max(speed_max, 1e-9)], axis=2)
    cols.append(peer.reshape(n, 6 * k))
    return np.concatenate(cols, axis=1)


def allowed_actions(cfg: Config, pos: np.ndarray) -> np.ndarray:
    """(N, 16): actions whose full move from pos (N, 2) stays in the area (all, without learner.geofence).
    Headings as truav.actions states: 45 degrees x (a % 8) from east, 0-7 at half speed."""
    if not cfg.learner.geofence:
        return np.ones((len(pos), N_ACTIONS), np.bool_)
    a = np.arange(N_ACTIONS)
    unit = np.stack([np.cos(np.pi / 4 * (a % 8)), np.sin(np.pi / 4 * (a % 8))], axis=1) * np.where(a < 8, 0.5, 1.0)[:, None]
    sc = cfg.scenario
    nxt = pos[:, None, :] + unit * (sc.uav_speed_mps * sc.step_s)
    tol = 1e-9 * sc.area_m
    return ((nxt >= -tol) & (nxt <= sc.area_m + tol)).all(axis=2)


class DeepIqlBatched(BatchedAgents):
    """All B x U networks of a training as one core (the API's optional batched form)."""

    hp: ClassVar[DeepIqlConfig] = DeepIqlConfig()

    def __init__(self, cfg: Config, rngs: list[list[np.random.Generator]]):
        super().__init__(cfg, rngs)
        self.shape = (len(rngs), len(rngs[0]))
        self.core = IqlCore(self.hp, n_features(cfg, self.hp), cfg.learner, cfg.scenario.steps_per_episode,
                            [rng for row in rngs for rng in row])
        self._seen: tuple = (None, None)

    def begin_episode(self, episode: int, train: bool) -> None:
        self.training = train
        self.core.begin_episode(episode, train)

    def _inputs(self, v: BatchedViews) -> tuple[np.ndarray, np.ndarray]:
        if v is self._seen[0]:  # act gets the view learn just got: its features once
            return self._seen[1]
        n, u = self.shape[0] * self.shape[1], self.shape[1]
        flat = lambda x: np.asarray(x).reshape(n)  # noqa: E731
        pos = np.asarray(v.pos, np.float64).reshape(n, 2)
        x = features(self.cfg, self.hp, v.step, v.speed_max, pos, flat(v.vehicles_in_range), flat(v.queued_packets),
                     flat(v.relayed), flat(v.covered), flat(v.energy_j), flat(v.densest_sector), flat(v.exclusive),
                     flat(v.nearest_rsu_m), v.peer_pos.reshape(n, u, 2), v.peer_vel.reshape(n, u, 2),
                     v.heard.reshape(n, u))
        self._seen = (v, (x, allowed_actions(self.cfg, pos)))
        return self._seen[1]

    def act(self, views: BatchedViews) -> np.ndarray:
        return self.core.act(*self._inputs(views), views.step).reshape(self.shape)

    def learn(self, views: BatchedViews, reward: np.ndarray, done: bool) -> None:
        if self.training:  # evaluation learns nothing: skip the features too
            self.core.learn(*self._inputs(views), np.asarray(reward, np.float64).ravel(), done)

    def state_dict(self) -> dict[str, np.ndarray]:
        return {k: v.reshape(self.shape + v.shape[1:]) for k, v in self.core.state().items()}

    def load_state_dict(self, state: Mapping[str, np.ndarray]) -> None:
        n = self.shape[0] * self.shape[1]
        self.core.load({k: np.asarray(v).reshape((n,) + np.shape(v)[2:]) for k, v in state.items()})


class DeepIql(UavAgent):
    """One UAV's independent DQN learner (see the module docstring)."""

    hp: ClassVar[DeepIqlConfig] = DeepIqlConfig()
    batched: ClassVar[type | None] = DeepIqlBatched

    def __init__(self, cfg: Config, uav: int, rng: np.random.Generator):
        super().__init__(cfg, uav, rng)
        self.core = IqlCore(self.hp, n_features(cfg, self.hp), cfg.learner, cfg.scenario.steps_per_episode, [rng])
        self._seen: tuple = (None, None)

    def begin_episode(self, episode: int, train: bool) -> None:
        self.training = train
        self.core.begin_episode(episode, train)

    def _inputs(self, v: LocalView) -> tuple[np.ndarray, np.ndarray]:
        if v is self._seen[0]:  # act gets the view learn just got: its features once
            return self._seen[1]
        pos = np.array([v.pos], np.float64)
        peers = np.array([b.pos for b in v.beacons], np.float64).reshape(1, len(v.beacons), 2)
        vels = np.array([b.vel for b in v.beacons], np.float64).reshape(1, len(v.beacons), 2)
        one = lambda x, kind=np.float64: np.array([x], kind)  # noqa: E731
        x = features(self.cfg, self.hp, v.step, v.speed_max, pos, one(v.vehicles_in_range), one(v.queued_packets),
                     one(v.relayed), one(v.covered), one(v.energy_j), one(v.densest_sector, np.int64),
                     one(v.exclusive), one(v.nearest_rsu_m), peers, vels, np.ones((1, len(v.beacons)), np.bool_))
        self._seen = (v, (x, allowed_actions(self.cfg, pos)))
        return self._seen[1]

    def act(self, view: LocalView) -> int:
        return int(self.core.act(*self._inputs(view), view.step)[0])

    def learn(self, view: LocalView, reward: float, done: bool) -> None:
        if self.training:
            self.core.learn(*self._inputs(view), np.array([reward], np.float64), done)

    def state_dict(self) -> dict[str, np.ndarray]:
        return {k: v[0] for k, v in self.core.state().items()}

    def load_state_dict(self, state: Mapping[str, np.ndarray]) -> None:
        self.core.load({k: np.asarray(v)[None] for k, v in state.items()})


__all__ = ["DeepIql", "DeepIqlBatched", "DeepIqlConfig", "allowed_actions", "features", "n_features"]
