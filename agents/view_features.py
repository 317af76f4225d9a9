"""An agent's view (agents.api.LocalView) as a fixed-size float32 feature vector, each feature scaled to O(1).

What a learner built with the field's libraries observes: the PettingZoo environment
(`truav.analysis.pettingzoo_env`) encodes every UAV's LocalView with `ViewEncoder`, and an agent process
holding a LocalView encodes it the same way, so a policy trained on one acts on the other from the same
numbers. The features, in order (`observation_features` gives each one's name, unit, scale, bounds and
meaning; docs/reference/pettingzoo-observation.md is generated from it):

- own state: position, full speed, vehicles in range, covered, exclusive, queued, relayed, energy,
  distance to the nearest RSU, the share of peers heard, episode progress (step / T);
- the densest sensed sector as a one-hot over learner.sense_sectors (all zero with sensing off or
  nothing sensed);
- the K nearest heard peers (K = `peers`) in slots k = 1..K, nearest first (ties by UAV id): relative
  position, the peer's velocity, distance and a mask (1: a heard peer; 0: padding, with each feature's
  documented fill);
- with ``memory`` on (off by default), last: what the UAV itself did at the previous step, which a view does
  not hold and the caller remembers (a `Memory`): its action one-hot (N_ACTIONS + 1 slots, the last HOVER;
  all 0 at step 0), its velocity (that action's) and the change of its vehicles in range since then;
- with ``disc`` on (off by default), the densest sensed disc (LocalView.disc_offset over the sensing range,
  disc_vehicles over the fair share; all 0 unless learner.sense_disc is on);
- with ``claim`` on (off by default), the climbing heuristic's own state (agents.claim_agent.CLAIM_FEATURES: its
  climb heading, whether its exclusive vehicles fell, whether the sensed sector is left to a peer, ...), which the
  caller computes from the UAV's own views by running that rule beside it (``ClaimAgent.features``).

Open-ended values (relayed, energy) are capped at `CAP`; every value lies in the declared bounds.
Beacon fields (`HeardBeacon.fields`) are not encoded: they are what an agent class chose to say.
Pure computation: no I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from agents.api import BatchedViews, LocalView
from agents.claim_agent import CLAIM_FEATURES
from truav.actions import HOVER, N_ACTIONS
from truav.config import Config

DEFAULT_PEERS = 4
"""K, the heard peers encoded by default: every peer of the default swarm of 5 UAVs."""
CAP = 10.0
"""The cap of the open-ended features (relayed, energy), after scaling."""
SPEED_SCALE_MPS = 25.0
"""The scale of speed_max: the fastest speed of the velocity experiment (5-25 m/s)."""
DIAGONAL = math.sqrt(2.0)
"""How far apart the area's farthest two points are after scaling by its side: the diagonal over the side."""
N_OWN = 12
"""The own-state features, first in the vector."""
PEER_FIELDS = ("dx", "dy", "vx", "vy", "distance", "mask")
"""The features of each heard-peer slot, in order."""
NO_ACTION = -2
"""A Memory's action before the first step of an episode (its one-hot is all 0)."""


@dataclass(frozen=True)
class Memory:
    """What a UAV did at the previous step (the memory features): its action (0..N_ACTIONS-1, HOVER, or
    NO_ACTION at step 0) and its vehicles in range then (0 at step 0). Scalars for one UAV, (B, U) arrays for
    ``ViewEncoder.batch``."""

    action: object = NO_ACTION
    in_range: object = 0


def action_velocity(action: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """An action's velocity as a share of full speed (east, north): 0 hovering or before the first step."""
    a = np.asarray(action, np.int64)
    moving = (a >= 0) & (a < N_ACTIONS)
    angle = (a % 8) * (math.pi / 4)
    speed = np.where(moving, np.where(a >= 8, 1.0, 0.5), 0.0)
    return speed * np.cos(angle), speed * np.sin(angle)


@dataclass(frozen=True)
class Feature:
    """One feature of the vector: its raw value in ``unit`` divided by ``scale``."""

    name: str
    group: str
    """The name with its slot or sector as {k} or {s} (the name itself for a single feature): the features
    of a group share everything but the slot."""
    unit: str
    """The raw value's unit ("1" for a count or a flag)."""
    scale: float
    """The raw value is divided by it."""
    scale_of: str
    """What the scale is, in config keys."""
    low: float
    high: float
    """Bounds of the scaled value (the observation space's Box)."""
    meaning: str
    fill_value: float | None = None
    """A padded peer slot's value (None for features that are never padding)."""


def observation_features(cfg: Config, peers: int = DEFAULT_PEERS, memory: bool = False,
                         claim: bool = False, disc: bool = False) -> tuple[Feature, ...]:
    """Every feature of the vector for a run of ``cfg`` with ``peers`` heard-peer slots (and the memory
    features with ``memory``, the densest sensed disc's with ``disc``, the climbing heuristic's with ``claim``),
    in order."""
    sc, e, tr = cfg.scenario, cfg.energy, cfg.traffic
    share, U, area, speed = sc.n_vehicles / sc.n_uavs, float(sc.n_uavs), float(sc.area_m), float(sc.uav_speed_mps)
    fair = "scenario.n_vehicles / scenario.n_uavs (the fair share)"
    packets = max(tr.packet_rate_hz * sc.n_vehicles * sc.step_s / sc.n_uavs, 1e-9)
    per_step = ("traffic.packet_rate_hz x scenario.n_vehicles x scenario.step_s / scenario.n_uavs (the fair share's "
                "packets per step)")
    own = [  # name, unit, scale, scale_of, low, high, meaning
        ("x", "m", area, "scenario.area_m", 0.0, 1.0, "own position, east"),
        ("y", "m", area, "scenario.area_m", 0.0, 1.0, "own position, north"),
        ("speed_max", "m/s", SPEED_SCALE_MPS, f"{SPEED_SCALE_MPS:g} m/s", 0.0, 100.0 / SPEED_SCALE_MPS,
         "full speed (scenario.uav_speed_mps): actions 8-15 fly at it, 0-7 at half of it"),
        ("vehicles_in_range", "1", share, fair, 0.0, U, "vehicles within scenario.comm_range_m"),
        ("covered", "1", share, fair, 0.0, U, "vehicles this UAV served in the last step"),
        ("exclusive", "1", share, fair, 0.0, U, "vehicles in this UAV's range and no other UAV's"),
        ("queued", "1", packets, per_step, 0.0, CAP,
         f"packets queued at the vehicles this UAV serves (capped at {CAP:g})"),
        ("relayed", "1", packets, per_step, 0.0, CAP, f"packets relayed to an RSU in the last step (capped at {CAP:g})"),
        ("energy", "J", max(e.move_w * sc.step_s, 1e-9), "energy.move_w x scenario.step_s", 0.0, CAP,
         f"energy spent in the last step (capped at {CAP:g})"),
        ("nearest_rsu", "m", area, "scenario.area_m", 0.0, DIAGONAL,
         "distance to the nearest RSU (capped at the area's diagonal, sqrt 2; sqrt 2 without RSUs)"),
        ("heard_peers", "1", float(max(sc.n_uavs - 1, 1)), "scenario.n_uavs - 1", 0.0, 1.0,
         "beacons heard at this step (all of them, not only the K encoded)"),
        ("progress", "steps", float(sc.steps_per_episode), "scenario.steps_per_episode", 0.0, 1.0,
         "the step within the episode"),
    ]
    out = [Feature(name, name, *rest) for name, *rest in own]
    out += [Feature(f"densest_sector_{s}", "densest_sector_{s}", "1", 1.0, "1", 0.0, 1.0,
                    "1 if sector s of learner.sense_sectors (counter-clockwise from east, sector 1 starting at "
                    "east) holds the most vehicles sensed beyond comm range; all 0 with sensing off or none sensed")
            for s in range(1, cfg.learner.sense_sectors + 1)]
    peer = [  # field, unit, scale, scale_of, low, high, meaning, fill
        ("dx", "m", area, "scenario.area_m", -1.0, 1.0, "peer k's x minus own x", 0.0),
        ("dy", "m", area, "scenario.area_m", -1.0, 1.0, "peer k's y minus own y", 0.0),
        ("vx", "m/s", speed, "scenario.uav_speed_mps (the view's speed_max)", -1.0, 1.0,
         "peer k's velocity east: its last action's, 0 hovering (own velocity is not in the view)", 0.0),
        ("vy", "m/s", speed, "scenario.uav_speed_mps (the view's speed_max)", -1.0, 1.0,
         "peer k's velocity north", 0.0),
        ("distance", "m", area, "scenario.area_m", 0.0, DIAGONAL, "peer k's distance", DIAGONAL),
        ("mask", "1", 1.0, "1", 0.0, 1.0, "1 if slot k holds a heard peer, 0 for padding", 0.0),
    ]
    out += [Feature(f"peer{k}_{field}", f"peer{{k}}_{field}", *rest)
            for k in range(1, peers + 1) for field, *rest in peer]
    if memory:
        out += [Feature(f"last_action_{a}", "last_action_{a}", "1", 1.0, "1", 0.0, 1.0,
                        f"1 if the UAV's action at the previous step was a (0..{N_ACTIONS - 1}; {N_ACTIONS}: hover); "
                        "all 0 at step 0") for a in range(N_ACTIONS + 1)]
        out += [Feature(f"last_{c}", f"last_{c}", "m/s", speed, "scenario.uav_speed_mps", -1.0, 1.0,
                        f"own velocity {d} at the previous step (its action's; 0 hovering or at step 0)")
                for c, d in (("vx", "east"), ("vy", "north"))]
        out.append(Feature("in_range_change", "in_range_change", "1", share, fair, -U, U,
                           "vehicles in range now minus at the previous step (0 before it: now)"))
    if disc:
        sense = max(float(cfg.learner.sense_range_m), 1.0)
        out += [Feature("disc_dx", "disc_dx", "m", sense, "learner.sense_range_m", -1.0, 1.0,
                        "the densest sensed disc's centre, east of own position (LocalView.disc_offset; 0 none "
                        "sensed or learner.sense_disc off)"),
                Feature("disc_dy", "disc_dy", "m", sense, "learner.sense_range_m", -1.0, 1.0,
                        "the densest sensed disc's centre, north of own position"),
                Feature("disc_vehicles", "disc_vehicles", "1", share, fair, 0.0, U,
                        "the vehicles within comm range of that centre (LocalView.disc_vehicles)")]
    if claim:
        out += [Feature(f"claim_{name}", f"claim_{name}", "1", 1.0, "1", -1.0, 1.0, meaning)
                for name, meaning in CLAIM_FEATURES]
    return tuple(out)


class ViewEncoder:
    """A LocalView -> its feature vector (float32, :func:`observation_features` order) for runs of ``cfg``."""

    def __init__(self, cfg: Config, peers: int = DEFAULT_PEERS, memory: bool = False, claim: bool = False,
                 disc: bool = False):
        if isinstance(peers, bool) or not isinstance(peers, int) or peers < 0:
            raise ValueError(f"peers must be an int >= 0 (the heard peers encoded), got {peers!r}")
        self.cfg, self.peers, self.memory, self.claim, self.disc = cfg, peers, bool(memory), bool(claim), bool(disc)
        self.features = observation_features(cfg, peers, self.memory, self.claim, self.disc)
        self._sense = max(float(cfg.learner.sense_range_m), 1.0)
        self.size = len(self.features)
        self.low = np.array([f.low for f in self.features], np.float32)
        self.high = np.array([f.high for f in self.features], np.float32)
        self._names = {f.name: i for i, f in enumerate(self.features)}
        self._scale = [f.scale for f in self.features[:N_OWN]]
        self._sectors = cfg.learner.sense_sectors
        self._fill = [f.fill_value for f in self.features[N_OWN + self._sectors:]][: len(PEER_FIELDS) * peers]
        self._share = cfg.scenario.n_vehicles / cfg.scenario.n_uavs
        self._area = float(cfg.scenario.area_m)

    def index(self, name: str) -> int:
        """The position of the feature ``name`` in the vector."""
        return self._names[name]

    def _memory(self, last: Memory, in_range) -> list[np.ndarray]:
        a = np.asarray(last.action, np.int64)
        index = np.where(a == HOVER, N_ACTIONS, a)
        onehot = [(index == k).astype(np.float64) for k in range(N_ACTIONS + 1)]
        vx, vy = action_velocity(a)
        change = (np.asarray(in_range, np.float64) - np.asarray(last.in_range, np.float64)) / self._share
        return onehot + [vx, vy, change]

    def _claim(self, claim) -> list:
        if not self.claim:
            return []
        if claim is None:
            raise ValueError("this encoder observes the claim features: give claim (ClaimAgent.features())")
        return [claim]

    def __call__(self, view: LocalView, last: Memory | None = None, claim: np.ndarray | None = None) -> np.ndarray:
        """``claim``: the UAV's ClaimAgent.features() (with ``claim`` on)."""
        # Plain Python floats (float64) for a few dozen numbers: several times cheaper than numpy's calls.
        s = self._scale
        raw = (view.pos[0], view.pos[1], view.speed_max, view.vehicles_in_range, view.covered, view.exclusive,
               view.queued_packets, view.relayed, view.energy_j, view.nearest_rsu_m, len(view.beacons), view.step)
        out = [v / k for v, k in zip(raw, s)]
        onehot = [0.0] * self._sectors
        if 1 <= view.densest_sector <= self._sectors:
            onehot[view.densest_sector - 1] = 1.0
        out += onehot
        slots = list(self._fill)
        if self.peers and view.beacons:
            x, y = view.pos
            area, speed = self._area, view.speed_max if view.speed_max > 0 else 1.0
            rel = [(math.hypot(b.pos[0] - x, b.pos[1] - y), b) for b in view.beacons]
            rel.sort(key=lambda r: r[0])  # stable: beacons come in UAV-id order, so ties go by id
            n = len(PEER_FIELDS)
            for k, (d, b) in enumerate(rel[: self.peers]):
                slots[n * k: n * k + n] = ((b.pos[0] - x) / area, (b.pos[1] - y) / area, b.vel[0] / speed,
                                           b.vel[1] / speed, d / area, 1.0)
        out += slots
        if self.memory:
            out += [float(v) for v in self._memory(last or Memory(), view.vehicles_in_range)]
        if self.disc:
            out += [view.disc_offset[0] / self._sense, view.disc_offset[1] / self._sense,
                    view.disc_vehicles / self._share]
        out += [float(v) for c in self._claim(claim) for v in np.asarray(c, np.float64).reshape(-1)]
        vec = np.array(out, np.float32)
        # the caps (an RSU-less city's inf distance: the diagonal); np.clip's own checks cost twice this
        return np.minimum(np.maximum(vec, self.low, out=vec), self.high, out=vec)

    def batch(self, views: BatchedViews, last: Memory | None = None, claim: np.ndarray | None = None) -> np.ndarray:
        """Every UAV's vector at once, (B, U, size) float32: what __call__ gives each UAV's LocalView built from
        the same step (the heard peers, nearest first, ties by id; a vectorized environment's observations),
        ``last`` holding (B, U) arrays, ``claim`` (B, U, len(CLAIM_FEATURES)) (ClaimBatched.features())."""
        pos = np.asarray(views.pos, np.float64)
        B, U = pos.shape[:2]
        raw = (pos[..., 0], pos[..., 1], np.full((B, U), float(views.speed_max)), views.vehicles_in_range,
               views.covered, views.exclusive, views.queued_packets, views.relayed, views.energy_j,
               views.nearest_rsu_m, np.asarray(views.heard).sum(-1), np.full((B, U), float(views.step)))
        own = [np.asarray(v, np.float64) / k for v, k in zip(raw, self._scale)]
        densest = np.asarray(views.densest_sector)
        onehot = [(densest == s).astype(np.float64) for s in range(1, self._sectors + 1)]
        slots = []
        if self.peers:
            heard = np.asarray(views.heard, np.bool_)
            rel = np.asarray(views.peer_pos, np.float64) - pos[:, :, None, :]
            dist = np.hypot(rel[..., 0], rel[..., 1])
            order = np.argsort(np.where(heard, dist, np.inf), axis=-1, kind="stable")[..., : self.peers]
            take = lambda a: np.take_along_axis(a, order, axis=-1)  # noqa: E731
            speed = float(views.speed_max) if views.speed_max > 0 else 1.0
            vel = np.asarray(views.peer_vel, np.float64)
            got = (take(rel[..., 0]) / self._area, take(rel[..., 1]) / self._area, take(vel[..., 0]) / speed,
                   take(vel[..., 1]) / speed, take(dist) / self._area, np.ones(order.shape))
            mask = take(heard)
            n = len(PEER_FIELDS)
            for k in range(self.peers):
                for j in range(n):
                    fill = self._fill[n * k + j]
                    slots.append(np.where(mask[..., k], got[j][..., k], fill) if k < order.shape[-1]
                                 else np.full((B, U), fill))
        mem = []
        if self.memory:
            last = last or Memory(np.full((B, U), NO_ACTION), np.zeros((B, U)))
            mem = [np.broadcast_to(m, (B, U)) for m in self._memory(last, views.vehicles_in_range)]
        disc = []
        if self.disc:
            off = np.zeros((B, U, 2)) if views.disc_offset is None else np.asarray(views.disc_offset, np.float64)
            n = np.zeros((B, U)) if views.disc_vehicles is None else np.asarray(views.disc_vehicles, np.float64)
            disc = [off[..., 0] / self._sense, off[..., 1] / self._sense, n / self._share]
        cl = [np.asarray(c, np.float64)[..., i] for c in self._claim(claim) for i in range(len(CLAIM_FEATURES))]
        vec = np.stack(own + onehot + slots + mem + disc + cl, axis=-1).astype(np.float32)
        return np.minimum(np.maximum(vec, self.low, out=vec), self.high, out=vec)


__all__ = ["CAP", "DEFAULT_PEERS", "Feature", "Memory", "NO_ACTION", "PEER_FIELDS", "ViewEncoder", "action_velocity",
           "observation_features"]
