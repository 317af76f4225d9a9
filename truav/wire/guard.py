"""Defence in depth on the receive side, in every mode (with or without ``--secure``).

A message that passed the schema (:mod:`truav.wire.schema`, which bounds sizes
and msgpack lengths before parsing) is further checked by the :class:`Guard`
a process installs on its Bus:

* **who may send it**: ticks, observations, positions, metrics and rejections only from
  ``world``; beacons, actions, state uploads, Q shares and health reports only from ``uav/<i>`` about UAV ``i``;
  commands only from ``controller``; a replay's status only from ``replay``;
  control only from ``supervisor`` (and the world's end-of-run ``shutdown``);
  an override (a UAV steered from outside) only from ``supervisor`` or ``operator``, its goal inside the area;
  fault announcements only from the supervisor (and the world's ``override`` events).  Without ``--secure`` the
  ``src`` field can be forged, so this stops mistakes and naive forgeries;
  with ``--secure`` the router's ACL makes the key itself proof of the sender.
* **values the world can produce** (:class:`Bounds`, from the scenario): UAV
  ids below ``n_uavs``, positions inside the area, counts bounded by the
  number of vehicles and their queues, speeds below the UAV's, ticks near the
  current one, so a forged or buggy message cannot poison a Q-table or pin a
  neighbour with a tick of 2^62;
* **one action per UAV per tick** (an older tick's action passes: a late
  answer, which the world counts as such).

:class:`Rejections` counts every rejected message by reason and sender, with
a bounded number of distinct senders (a flood of unique names adds nothing
past the cap) and one log line per (sender, reason).
"""

from __future__ import annotations

import logging
import time
import threading
from dataclasses import dataclass

from truav.wire import keys, schema

log = logging.getLogger("truav.wire.guard")

MAX_TRACKED_SENDERS = 256
"""Distinct senders counted (and logged) one by one; the rest are pooled under OTHER_SENDERS."""
OTHER_SENDERS = "(other senders)"
TICK_WINDOW = 64
"""A message's tick must lie within this many ticks of the current one."""
TICK_RESYNC_S = 1.0
"""After this long without a tick or observation accepted (the router was down, or restarted), a world
tick, observation or step metric ahead of the window is accepted and moves the window (only the world
sends them): the world went on meanwhile, and every later message would be refused otherwise.  The
jump may reach at most TICK_WINDOW + RESYNC_TICKS_PER_S per second of silence."""
RESYNC_TICKS_PER_S = 1000
AREA_MARGIN_M = 1.0
SPEED_MARGIN = 1.01

# Rejection reasons added by the guard (schema.R_* and transport reasons are counted the same way).
R_SENDER = "forbidden_sender"
R_IMPLAUSIBLE = "implausible"
R_TICK = "tick_out_of_window"
R_DUPLICATE = "duplicate_action"
R_REPLAYED = "replayed"

SUPERVISOR = "supervisor"
CONTROL_SHUTDOWN = "shutdown"


class Rejections:
    """Counts of rejected messages by (reason, sender); bounded; logs each pair once."""

    def __init__(self, owner: str, max_senders: int = MAX_TRACKED_SENDERS, logger: logging.Logger = log) -> None:
        self._owner = owner
        self._log = logger
        self._max = max_senders
        self._senders: set[str] = set()
        self._counts: dict[tuple[str, str], int] = {}
        self._lock = threading.Lock()
        self.quiet_reasons: frozenset[str] = frozenset()
        """Reasons counted but logged at debug level only: an observer that lags (the supervisor's monitor in a fast
        lock-step run) drops messages outside its tick window through its own lateness, not the sender's fault."""

    def add(self, reason: str, sender: str | None, key: str = "", detail: str = "") -> None:
        shown = sender or "unknown sender"
        sender = sender or "?"
        with self._lock:
            if sender not in self._senders:
                if len(self._senders) >= self._max:
                    sender = OTHER_SENDERS
                else:
                    self._senders.add(sender)
            pair = (reason, sender)
            first = pair not in self._counts
            self._counts[pair] = self._counts.get(pair, 0) + 1
        if first:
            (self._log.debug if reason in self.quiet_reasons else self._log.warning)("%s: dropping malformed message on %s from %s: %s (further '%s' drops from this "
                              "sender only counted)", self._owner, key or "?",
                              OTHER_SENDERS if sender == OTHER_SENDERS else shown, detail[:160] or reason, reason)

    def total(self) -> int:
        with self._lock:
            return sum(self._counts.values())

    def by_reason(self) -> dict[str, int]:
        out: dict[str, int] = {}
        with self._lock:
            for (reason, _), n in self._counts.items():
                out[reason] = out.get(reason, 0) + n
        return out

    def as_dict(self) -> dict[str, dict[str, int]]:
        """``{reason: {sender: count}}``."""
        out: dict[str, dict[str, int]] = {}
        with self._lock:
            for (reason, sender), n in sorted(self._counts.items()):
                out.setdefault(reason, {})[sender] = n
        return out


@dataclass(frozen=True)
class Bounds:
    """What the world of one scenario can produce."""

    n_uavs: int
    area_m: float
    max_count: int
    """Vehicles in range, covered: at most the number of vehicles."""
    max_packets: int
    """Queued or relayed packets: at most every vehicle's full queue."""
    max_speed: float
    max_energy_j: float

    @classmethod
    def from_config(cls, cfg) -> Bounds:
        sc = cfg.scenario
        return cls(n_uavs=sc.n_uavs, area_m=sc.area_m, max_count=sc.n_vehicles,
                   max_packets=sc.n_vehicles * cfg.traffic.queue_limit, max_speed=sc.uav_speed_mps,
                   # 100 kW for a step: far above any UAV's power, far below what poisons a table.
                   max_energy_j=1e5 * sc.step_s)

    def in_area(self, pos: tuple[float, float]) -> bool:
        lo, hi = -AREA_MARGIN_M, self.area_m + AREA_MARGIN_M
        return lo <= pos[0] <= hi and lo <= pos[1] <= hi


class Guard:
    """Sender, range and tick checks for one process; install with ``bus.guard = Guard(...)``.

    ``check(key, msg)`` returns None to accept or ``(reason, detail)``; the Bus
    counts the rejection.  The current tick is learnt from the world's ticks and
    observations this process accepts and from what it publishes itself.
    """

    def __init__(self, bounds: Bounds) -> None:
        self.bounds = bounds
        self._tick: int | None = None
        self._last_action = [-1] * bounds.n_uavs
        self._lock = threading.Lock()
        self._advanced_at = time.monotonic()

    @property
    def tick(self) -> int | None:
        return self._tick

    def sent(self, msg: schema.Message) -> None:
        """Called by the Bus for each message this process publishes."""
        tick = getattr(msg, "tick", None)
        if isinstance(msg, (schema.Tick, schema.Obs, schema.Action, schema.Beacon, schema.State, schema.Command)) \
                and tick is not None:
            self._advance(tick)

    def _advance(self, tick: int) -> None:
        with self._lock:
            self._advanced_at = time.monotonic()
            if self._tick is None or tick > self._tick:
                self._tick = tick

    def _resync(self, tick: int) -> bool:
        """Whether a world tick ahead of the window ends a silence (see TICK_RESYNC_S)."""
        silence = time.monotonic() - self._advanced_at
        cur = self._tick
        if cur is None or tick <= cur or silence < TICK_RESYNC_S \
                or tick > cur + TICK_WINDOW + RESYNC_TICKS_PER_S * silence:
            return False
        log.info("tick %d after %.1f s without one (last %d): following the world again", tick, silence, cur)
        self._advance(tick)
        return True

    def _near(self, tick: int) -> bool:
        cur = self._tick
        return cur is None or cur - TICK_WINDOW <= tick <= cur + TICK_WINDOW

    def check(self, key: str, msg: schema.Message) -> tuple[str, str] | None:
        """None to accept ``msg`` (on ``key``), else ``(reason, detail)``.

        The kinds that arrive most (beacons, actions, observations, ticks, state uploads, commands, health)
        go to a check of their own (one lookup by type, no chain of isinstance); every other message
        to :meth:`_check_any`.  Both say the same of every message, in the same order of checks."""
        own = _BY_TYPE.get(type(msg))
        return own(self, msg) if own is not None else self._check_any(key, msg)

    def _check_any(self, key: str, msg: schema.Message) -> tuple[str, str] | None:
        b, src = self.bounds, msg.src
        if isinstance(msg, (schema.Tick, schema.Obs, schema.Positions, schema.Metrics, schema.Rejection)):
            if src != keys.SRC_WORLD:
                return R_SENDER, f"{msg.KIND} from {src}"
        elif isinstance(msg, (schema.Beacon, schema.Action, schema.State, schema.Health)):
            if src != f"uav/{msg.uav}":
                return R_SENDER, f"{msg.KIND} of uav {msg.uav} from {src}"
        elif isinstance(msg, schema.Control):
            if not (src == SUPERVISOR or (src == keys.SRC_WORLD and msg.command == CONTROL_SHUTDOWN)):
                return R_SENDER, f"control {msg.command!r} from {src}"
        elif isinstance(msg, schema.Fault):
            if not (src == SUPERVISOR or (src == keys.SRC_WORLD and msg.fault == schema.FAULT_OVERRIDE)):
                return R_SENDER, f"fault from {src}"
        elif isinstance(msg, schema.Override):
            if src not in (SUPERVISOR, keys.SRC_OPERATOR):
                return R_SENDER, f"override from {src}"
        elif isinstance(msg, schema.Command):
            if src != keys.SRC_CONTROLLER:
                return R_SENDER, f"command from {src}"
        elif isinstance(msg, schema.ReplayStatus):
            if src != keys.SRC_REPLAY:
                return R_SENDER, f"replay status from {src}"
        uav = getattr(msg, "uav", None)
        if uav is not None and uav >= b.n_uavs:
            return R_IMPLAUSIBLE, f"uav {uav} >= n_uavs {b.n_uavs}"
        tick = getattr(msg, "tick", None)
        resyncs = isinstance(msg, (schema.Tick, schema.Obs, schema.Metrics))  # the world's own (sender checked)
        if tick is not None and not self._near(tick) and not (resyncs and self._resync(tick)):
            return R_TICK, f"tick {tick}, current {self._tick}"
        if isinstance(msg, schema.Obs):
            if not b.in_area(msg.pos):
                return R_IMPLAUSIBLE, f"pos {msg.pos} outside the area"
            if max(msg.vehicles_in_range, msg.covered, msg.exclusive, msg.disc_vehicles) > b.max_count \
                    or max(msg.queued_packets, msg.relayed) > b.max_packets:
                return R_IMPLAUSIBLE, "counts above the scenario's vehicles and queues"
            if max(abs(msg.disc_offset[0]), abs(msg.disc_offset[1])) > b.area_m:
                return R_IMPLAUSIBLE, f"disc offset {msg.disc_offset} beyond the area"
            if msg.energy_j > b.max_energy_j or msg.speed_max > b.max_speed * SPEED_MARGIN:
                return R_IMPLAUSIBLE, f"energy {msg.energy_j} J or speed {msg.speed_max} m/s"
            self._advance(msg.tick)
        elif isinstance(msg, schema.Tick):
            if msg.n_uavs != b.n_uavs:
                return R_IMPLAUSIBLE, f"tick for {msg.n_uavs} UAVs, scenario has {b.n_uavs}"
            self._advance(msg.tick)
        elif isinstance(msg, schema.State):
            if not b.in_area(msg.pos) or max(msg.vehicles_in_range, msg.covered) > b.max_count \
                    or max(msg.queued_packets, msg.relayed) > b.max_packets or msg.energy_j > b.max_energy_j:
                return R_IMPLAUSIBLE, f"state of uav {msg.uav}: values the world cannot produce"
        elif isinstance(msg, schema.Beacon):
            vx, vy = msg.vel
            if not b.in_area(msg.pos) or (vx * vx + vy * vy) ** 0.5 > b.max_speed * SPEED_MARGIN:
                return R_IMPLAUSIBLE, f"beacon pos {msg.pos} vel {msg.vel}"
        elif isinstance(msg, schema.Action):
            with self._lock:
                if msg.tick == self._last_action[msg.uav]:
                    return R_DUPLICATE, f"second action of uav {msg.uav} for tick {msg.tick}"
                # An older tick's action is an answer delayed behind a newer one, not malformed: passed on,
                # the world counts it as stale (world.process.world_process).
                self._last_action[msg.uav] = max(self._last_action[msg.uav], msg.tick)
        elif isinstance(msg, schema.Override):
            if not msg.release and not b.in_area(msg.goal):
                return R_IMPLAUSIBLE, f"override goal {msg.goal} outside the area"
        elif isinstance(msg, schema.Positions):
            if len(msg.uavs) != b.n_uavs or len(msg.vehicles) > b.max_count:
                return R_IMPLAUSIBLE, f"{len(msg.uavs)} UAVs, {len(msg.vehicles)} vehicles"
        return None

    # -- one check per kind that arrives often: _check_any's steps for that type, in its order --
    def _tick_window(self, tick: int) -> tuple[str, str] | None:
        cur = self._tick
        if cur is None or cur - TICK_WINDOW <= tick <= cur + TICK_WINDOW:
            return None
        return R_TICK, f"tick {tick}, current {self._tick}"

    def _check_beacon(self, msg: schema.Beacon) -> tuple[str, str] | None:  # the most frequent: all inline
        src, uav, b = msg.src, msg.uav, self.bounds
        own = _UAV_SRCS.get(uav) if type(uav) is int else None
        if src != (own if own is not None else f"uav/{uav}"):
            return R_SENDER, f"{msg.KIND} of uav {msg.uav} from {src}"
        if uav is not None and uav >= b.n_uavs:
            return R_IMPLAUSIBLE, f"uav {uav} >= n_uavs {b.n_uavs}"
        tick = msg.tick
        if tick is not None:
            cur = self._tick
            if not (cur is None or cur - TICK_WINDOW <= tick <= cur + TICK_WINDOW):
                return R_TICK, f"tick {tick}, current {self._tick}"
        pos = msg.pos
        if type(b) is Bounds:  # Bounds.in_area, inline
            hi = b.area_m + AREA_MARGIN_M
            inside = -AREA_MARGIN_M <= pos[0] <= hi and -AREA_MARGIN_M <= pos[1] <= hi
        else:
            inside = b.in_area(pos)
        vx, vy = msg.vel
        if not inside or (vx * vx + vy * vy) ** 0.5 > b.max_speed * SPEED_MARGIN:
            return R_IMPLAUSIBLE, f"beacon pos {msg.pos} vel {msg.vel}"
        return None

    def _uav_sender_and_id(self, msg) -> tuple[str, str] | None:
        """A UAV's message: sent by that UAV, about a UAV of the scenario (_check_any's first steps)."""
        src, uav = msg.src, msg.uav
        if src != _uav_src(uav):
            return R_SENDER, f"{msg.KIND} of uav {msg.uav} from {src}"
        if uav is not None and uav >= self.bounds.n_uavs:
            return R_IMPLAUSIBLE, f"uav {uav} >= n_uavs {self.bounds.n_uavs}"
        return None

    def _uav_message(self, msg) -> tuple[str, str] | None:
        """:meth:`_uav_sender_and_id`, then its tick in the window."""
        refused = self._uav_sender_and_id(msg)
        if refused is None and msg.tick is not None:
            refused = self._tick_window(msg.tick)
        return refused

    def _check_action(self, msg: schema.Action) -> tuple[str, str] | None:
        refused = self._uav_message(msg)
        if refused is not None:
            return refused
        with self._lock:
            if msg.tick == self._last_action[msg.uav]:
                return R_DUPLICATE, f"second action of uav {msg.uav} for tick {msg.tick}"
            self._last_action[msg.uav] = max(self._last_action[msg.uav], msg.tick)
        return None

    def _check_state(self, msg: schema.State) -> tuple[str, str] | None:
        refused = self._uav_message(msg)
        if refused is not None:
            return refused
        b = self.bounds
        if not b.in_area(msg.pos) or max(msg.vehicles_in_range, msg.covered) > b.max_count \
                or max(msg.queued_packets, msg.relayed) > b.max_packets or msg.energy_j > b.max_energy_j:
            return R_IMPLAUSIBLE, f"state of uav {msg.uav}: values the world cannot produce"
        return None

    def _check_qshare(self, msg: schema.QShare) -> tuple[str, str] | None:
        """A federated Q share's part: from its UAV, near the current tick, its arrays of one length (the
        receiver's merge rule, agents.federated.check_share, bounds the values against its own table)."""
        refused = self._uav_message(msg)
        if refused is not None:
            return refused
        if msg.part >= msg.parts or len(msg.counts) != len(msg.states) or len(msg.q) != 16 * len(msg.states):
            return R_IMPLAUSIBLE, (f"qshare of uav {msg.uav}: part {msg.part} of {msg.parts}, {len(msg.states)} states, "
                                   f"{len(msg.counts)} counts, {len(msg.q)} values")
        return None

    def _check_health(self, msg: schema.Health) -> tuple[str, str] | None:
        return self._uav_sender_and_id(msg)

    def _check_command(self, msg: schema.Command) -> tuple[str, str] | None:
        src, uav, b = msg.src, msg.uav, self.bounds
        if src != keys.SRC_CONTROLLER:
            return R_SENDER, f"command from {src}"
        if uav is not None and uav >= b.n_uavs:
            return R_IMPLAUSIBLE, f"uav {uav} >= n_uavs {b.n_uavs}"
        tick = msg.tick
        if tick is not None:
            return self._tick_window(tick)
        return None

    def _check_obs(self, msg: schema.Obs) -> tuple[str, str] | None:
        src, uav, b = msg.src, msg.uav, self.bounds
        if src != keys.SRC_WORLD:
            return R_SENDER, f"{msg.KIND} from {src}"
        if uav is not None and uav >= b.n_uavs:
            return R_IMPLAUSIBLE, f"uav {uav} >= n_uavs {b.n_uavs}"
        tick = msg.tick
        if tick is not None and not self._near(tick) and not self._resync(tick):
            return R_TICK, f"tick {tick}, current {self._tick}"
        if not b.in_area(msg.pos):
            return R_IMPLAUSIBLE, f"pos {msg.pos} outside the area"
        if max(msg.vehicles_in_range, msg.covered, msg.exclusive, msg.disc_vehicles) > b.max_count \
                or max(msg.queued_packets, msg.relayed) > b.max_packets:
            return R_IMPLAUSIBLE, "counts above the scenario's vehicles and queues"
        if max(abs(msg.disc_offset[0]), abs(msg.disc_offset[1])) > b.area_m:
            return R_IMPLAUSIBLE, f"disc offset {msg.disc_offset} beyond the area"
        if msg.energy_j > b.max_energy_j or msg.speed_max > b.max_speed * SPEED_MARGIN:
            return R_IMPLAUSIBLE, f"energy {msg.energy_j} J or speed {msg.speed_max} m/s"
        self._advance(msg.tick)
        return None

    def _check_tick(self, msg: schema.Tick) -> tuple[str, str] | None:
        src, b = msg.src, self.bounds
        if src != keys.SRC_WORLD:
            return R_SENDER, f"{msg.KIND} from {src}"
        tick = msg.tick
        if tick is not None and not self._near(tick) and not self._resync(tick):
            return R_TICK, f"tick {tick}, current {self._tick}"
        if msg.n_uavs != b.n_uavs:
            return R_IMPLAUSIBLE, f"tick for {msg.n_uavs} UAVs, scenario has {b.n_uavs}"
        self._advance(msg.tick)
        return None


_UAV_SRCS = {i: f"uav/{i}" for i in range(keys.MAX_UAVS)}


def _uav_src(uav: int) -> str:
    """``f"uav/{uav}"``, made once per valid UAV id."""
    src = _UAV_SRCS.get(uav) if type(uav) is int else None
    return src if src is not None else f"uav/{uav}"


_BY_TYPE = {schema.Beacon: Guard._check_beacon, schema.Action: Guard._check_action, schema.State: Guard._check_state,
            schema.Health: Guard._check_health, schema.Command: Guard._check_command, schema.Obs: Guard._check_obs,
            schema.Tick: Guard._check_tick, schema.QShare: Guard._check_qshare}


def for_config(cfg) -> Guard:
    """The guard of a world or agent process of scenario ``cfg``."""
    return Guard(Bounds.from_config(cfg))
