"""The public agent API, version 1: one class per decentralized UAV algorithm.

A user's algorithm is a subclass of :class:`UavAgent` (or any class with the same methods and
``api_version = 1``): one instance per UAV, seeing only what that UAV's agent process sees
(:class:`LocalView`: its own observation and the beacons it heard), returning an action index,
learning from its local reward. ``truav train --agent pkg.module:Class`` trains it in process
(agents/api_controller.py adapts it to the batched driver); docs/how-to/your-own-agent.md is the tutorial.

The call order, per UAV and episode (T = scenario.steps_per_episode)::

    begin_episode(episode, train)
    a = act(view_0); fields = beacon_fields()
    for t in 1..T:  learn(view_t, reward_t, done = t == T); if t < T: a = act(view_t); fields = beacon_fields()

The optional batched form (:class:`BatchedAgents`, offered as the class attribute ``batched``)
takes the same calls for all UAVs of all seeds at once, arrays with leading axes (B seeds, U UAVs);
the fast trainer uses it when a class offers it, and it must then compute what the per-UAV form
computes. Pure computation: no I/O, no bus.

Versioning: :data:`API_VERSION` grows when a promise here changes incompatibly; a class declares
the version it was written for (``api_version``), and a loader refuses versions it does not serve
(:data:`SUPPORTED_API_VERSIONS`). Adding a field to LocalView or an optional method is compatible.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar, Mapping

import numpy as np

from truav.actions import HOVER, N_ACTIONS
from truav.config import Config
from truav.wire.field_checks import _beacon_fields as _wire_beacon_fields
from truav.wire.schema_names import MAX_BEACON_FIELD_NAME, MAX_BEACON_FIELDS, SchemaError

API_VERSION = 1
SUPPORTED_API_VERSIONS = (1,)
"""The versions this TRUAV drives (agents.loader refuses a class declaring another)."""

# beacon_fields(): at most MAX_BEACON_FIELDS entries, printable names of 1-MAX_BEACON_FIELD_NAME characters,
# values bool, int64 or finite float: a beacon stays small. The wire checks the same (truav.wire.field_checks).

REQUIRED_METHODS = ("act", "learn", "state_dict", "load_state_dict")
_LEARNER = Config().learner
"""The config's defaults: a view built without the sensing fields (e.g. in a user's own test) has the default's."""


@dataclass(frozen=True)
class HeardBeacon:
    """A peer's beacon as this UAV heard it (one per peer heard at this step)."""

    uav: int
    """The peer's id, 0..scenario.n_uavs - 1 (never this UAV's own)."""
    pos: tuple[float, float]
    """The peer's position (x, y) in m at this step, each in [0, scenario.area_m]."""
    vel: tuple[float, float]
    """The velocity (vx, vy) in m/s of the peer's last action: (0, 0) before its first action of an episode and
    while it hovers; its length is half or all of speed_max."""
    fields: Mapping[str, bool | int | float] = field(default_factory=dict)
    """What the peer's beacon_fields() returned after its last action ({} before its first, and from a class
    without beacon_fields or a batched form)."""


@dataclass(frozen=True)
class LocalView:
    """What one UAV's agent sees at one step: its own sensing and the beacons it heard. Counts are of the
    whole step the UAV just flew (at step 0: of the start position, nothing relayed, no energy spent).
    Every field is filled in every run; those that depend on an option say what they hold when it is off."""

    uav: int
    """This UAV's id, 0..scenario.n_uavs - 1."""
    episode: int
    """The episode, counted from 0 (in training and in an evaluation alike)."""
    step: int
    """The step within the episode, 0..T, T = scenario.steps_per_episode (the view at T, after the last
    action, is given to learn only)."""
    pos: tuple[float, float]
    """Own position (x, y) in m, x east and y north, each in [0, scenario.area_m]."""
    vehicles_in_range: int
    """Vehicles within scenario.comm_range_m (horizontal distance) of this UAV, 0..scenario.n_vehicles."""
    queued_packets: int
    """Packets waiting in the queues of the vehicles this UAV serves (see covered), 0 or more (at most
    traffic.queue_limit per vehicle)."""
    relayed: int
    """Packets this UAV relayed to an RSU in the last step, 0 or more (0 at step 0)."""
    covered: int
    """Vehicles this UAV served in the last step (those in range whose nearest UAV it is),
    0..vehicles_in_range."""
    energy_j: float
    """Energy this UAV spent in the last step, in J (0 at step 0): (energy.hover_w + (energy.move_w -
    energy.hover_w) x speed / energy.move_ref_speed_mps) x scenario.step_s, plus its radio's (world/step.py;
    at the defaults 200 J hovering, 230 J at 15 m/s, before the radio's)."""
    speed_max: float
    """Full speed in m/s (scenario.uav_speed_mps): actions 8-15 fly at it, 0-7 at half of it."""
    densest_sector: int
    """Sensing of denser areas: with sensing on (sense_range_m > 0), 1 + the direction sector holding the
    most vehicles beyond comm range and within sense_range_m (sector k, from 0, spans the angles
    k x 360/sense_sectors to (k + 1) x 360/sense_sectors degrees counter-clockwise from east; the first on
    ties), so 1..sense_sectors, and 0 when none is sensed. Always 0 with sensing off (the default): check
    sense_range_m."""
    exclusive: int
    """Vehicles in this UAV's range and no other UAV's, 0..vehicles_in_range: the coverage the swarm loses
    without it."""
    nearest_rsu_m: float
    """Horizontal distance in m to the nearest RSU (RSU sites are known a priori: scenario.rsu_intersections);
    inf without RSUs."""
    beacons: tuple[HeardBeacon, ...]
    """The beacons heard at this step, in UAV-id order: in the in-process trainer every other UAV's; in a swarm
    those the links delivered in time (none from a crashed or partitioned peer, links.* and fault plans)."""
    sense_range_m: float = _LEARNER.sense_range_m
    """The sensing radius in m (learner.sense_range_m): 0 means sensing is off and densest_sector is always 0;
    when on, above scenario.comm_range_m."""
    sense_sectors: int = _LEARNER.sense_sectors
    """The number of direction sectors of densest_sector (learner.sense_sectors, 1..16; 4: sector 1 is
    east to north, 2 north to west, 3 west to south, 4 south to east)."""
    disc_offset: tuple[float, float] = (0.0, 0.0)
    """Where the densest disc it senses is, with sensing on and learner.sense_disc (off by default): among the
    vehicles within sense_range_m (comm range included), the one with the most vehicles within
    scenario.comm_range_m of it (the first on ties): its position minus own position (dx, dy) in m, so within
    sense_range_m; (0, 0) when none is sensed or it is off (then disc_vehicles is 0)."""
    disc_vehicles: int = 0
    """The vehicles within scenario.comm_range_m of that centre (itself counted), 0..scenario.n_vehicles; 0 when
    none is sensed or learner.sense_disc is off."""


class UavAgent:
    """Base class of a per-UAV agent (API version 1). Override act and learn; the rest has defaults.

    One instance flies one UAV of one seed. Every random number must come from ``rng``
    (seeded per seed and UAV by TRUAV), so the same seed gives the same run."""

    api_version: ClassVar[int] = API_VERSION
    batched: ClassVar[type | None] = None
    """Optional: a :class:`BatchedAgents` subclass computing the same as this class for all UAVs at once."""
    call_limit_s: ClassVar[float] = 1.0
    """The longest one call (begin_episode, act, learn, beacon_fields, state_dict, load_state_dict) may take,
    in seconds, at most 60. A call past it fails like a call that raised: in a swarm this UAV hovers for that
    tick (counted, logged), in training the run stops resumably with one line. (In real time at 10 Hz an
    action later than the tick's deadline is missed anyway.)"""

    def __init__(self, cfg: Config, uav: int, rng: np.random.Generator):
        self.cfg, self.uav, self.rng = cfg, uav, rng
        self.training = True

    def begin_episode(self, episode: int, train: bool) -> None:
        """An episode starts; ``train`` False: a greedy evaluation (learn is still called: update nothing)."""
        self.training = train

    def act(self, view: LocalView) -> int:
        """The action for this step: an int in 0..N_ACTIONS-1 (truav.actions: 8 headings x half/full
        speed), or HOVER (-1) to stay in place."""
        raise NotImplementedError

    def learn(self, view: LocalView, reward: float, done: bool) -> None:
        """The outcome of the last action: the next view, this UAV's local reward, whether the episode ended."""

    def beacon_fields(self) -> dict[str, bool | int | float]:
        """Extra fields of this UAV's beacon after each act (bounded: MAX_BEACON_FIELDS); peers hear them
        at the next step."""
        return {}

    def state_dict(self) -> dict[str, np.ndarray]:
        """Everything learned, as named arrays (the same names and shapes for every UAV and seed of a run):
        saved after training, loaded for evaluation and by a restarted or re-simulated agent."""
        return {}

    def load_state_dict(self, state: Mapping[str, np.ndarray]) -> None:
        """Restore what state_dict returned."""


class BatchedAgents:
    """Optional batched form: all U UAVs of B seeds in one object, arrays with leading axes (B, U).

    ``rngs[b][u]`` is the generator the per-UAV instance of seed b, UAV u would get. state_dict
    returns each per-UAV array stacked to (B, U, ...), under the per-UAV names."""

    call_limit_s: ClassVar[float] = 10.0
    """As UavAgent.call_limit_s, for one call over all B x U UAVs."""

    def __init__(self, cfg: Config, rngs: list[list[np.random.Generator]]):
        self.cfg, self.rngs = cfg, rngs
        self.training = True

    def begin_episode(self, episode: int, train: bool) -> None:
        self.training = train

    def act(self, views: "BatchedViews") -> np.ndarray:
        """Actions (B, U) ints in 0..N_ACTIONS-1 or HOVER."""
        raise NotImplementedError

    def learn(self, views: "BatchedViews", reward: np.ndarray, done: bool) -> None:
        """reward (B, U)."""

    # Optional, the whole-episode form: a batched form with a method
    #
    #     run_episode(world, obs) -> np.ndarray   # each seed's mean reward per step, (B,)
    #
    # runs every step of the world's current episode itself (act, world.step, learn), typically in one
    # compiled kernel, from its first observations obs (world.env.LocalObs) after begin_episode; the
    # trainer then hands it whole episodes. It sees the world's arrays, so it is for compiled forms that
    # compute exactly what the per-UAV form computes from its views (tested so: TRUAV's TruavBatched); a
    # class attribute draws_in_kernel = True says it also makes the world's deferred per-episode draws
    # (world.env.World.start_episode(defer_draws=True)). The swarm always runs the per-UAV form.

    def state_dict(self) -> dict[str, np.ndarray]:
        return {}

    def load_state_dict(self, state: Mapping[str, np.ndarray]) -> None:
        pass


@dataclass(frozen=True)
class BatchedViews:
    """LocalView for every UAV of every seed: arrays (B, U) unless noted. Beacons: every UAV hears every
    other (peer m of UAV u is UAV m; ``heard[b, u, u]`` is False)."""

    episode: int
    step: int
    pos: np.ndarray
    """(B, U, 2)"""
    vehicles_in_range: np.ndarray
    queued_packets: np.ndarray
    relayed: np.ndarray
    covered: np.ndarray
    energy_j: np.ndarray
    speed_max: float
    densest_sector: np.ndarray
    exclusive: np.ndarray
    nearest_rsu_m: np.ndarray
    peer_pos: np.ndarray
    """(B, U, U, 2) the heard beacons' positions."""
    peer_vel: np.ndarray
    """(B, U, U, 2) their velocities."""
    heard: np.ndarray
    """(B, U, U) bool."""
    sense_range_m: float = _LEARNER.sense_range_m
    """As LocalView.sense_range_m (0: sensing off)."""
    sense_sectors: int = _LEARNER.sense_sectors
    """As LocalView.sense_sectors."""
    disc_offset: np.ndarray | None = None
    """(B, U, 2) as LocalView.disc_offset; None: all (0, 0)."""
    disc_vehicles: np.ndarray | None = None
    """As LocalView.disc_vehicles; None: all 0."""


def sensing(cfg: Config) -> tuple[float, int]:
    """(sense_range_m, sense_sectors) of a view in a run of ``cfg``: what says whether densest_sector senses."""
    return float(cfg.learner.sense_range_m), int(cfg.learner.sense_sectors)


def beacon_problem(fields: Any) -> str | None:
    """What is wrong with a beacon_fields() result, or None (what the wire's beacon would refuse)."""
    if not isinstance(fields, dict):
        return f"beacon_fields returned {type(fields).__name__}, not a dict"
    try:
        _wire_beacon_fields("beacon_fields", fields)
    except SchemaError as exc:
        return exc.detail
    return None


def action_problem(action: Any) -> str | None:
    """What is wrong with an act() result, or None."""
    if isinstance(action, (bool, np.bool_)) or not isinstance(action, (int, np.integer)):
        return f"act returned {action!r} ({type(action).__name__}), not an int action in 0..{N_ACTIONS - 1} or HOVER"
    if not HOVER <= action < N_ACTIONS:
        return f"act returned {action}, not an action in 0..{N_ACTIONS - 1} or HOVER ({HOVER})"
    return None


__all__ = ["API_VERSION", "SUPPORTED_API_VERSIONS", "MAX_BEACON_FIELDS", "HeardBeacon", "LocalView", "UavAgent", "sensing",
           "BatchedAgents", "BatchedViews", "HOVER", "N_ACTIONS"]
