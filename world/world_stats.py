"""What the world process counts and writes at exit: WorldStats, the per-episode action digest
and the stats file (world.json). Pure bookkeeping: no bus, no simulation."""

from __future__ import annotations

import hashlib
import threading
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from truav import jsonio
from truav.atomic import write_atomic_text


@dataclass
class WorldStats:
    episodes: list[dict[str, float]] = field(default_factory=list)
    tick_lateness_ms: list[float] = field(default_factory=list)
    deadline_misses: int = 0
    """Actions that did not come (in time): those UAVs hovered."""
    lockstep_missed: int = 0
    """Lock-step: answers (actions or `done` acknowledgements) of live agents the world went on without
    after lockstep_wait_s: the run is no longer exact."""
    lockstep_missed_from_tick: int | None = None
    """Lock-step: the first tick it went on without a live agent's answer."""
    actions_received: int = 0
    late_actions: int = 0
    """Actions that came after their tick's round had closed (real time: past the deadline); not applied."""
    stale_actions: int = 0
    """Actions for a tick older than one the same agent had already answered (delayed, overtaken); not applied."""
    ticks: int = 0
    joins: list[str] = field(default_factory=list)
    losses: list[str] = field(default_factory=list)
    rejected: dict[str, dict[str, int]] = field(default_factory=dict)
    """Messages the bus refused, {reason: {sender: count}} (truav.wire.guard)."""
    actions_digest: list[str] = field(default_factory=list)
    """Per episode: blake2b of the (U,) int64 actions applied at every step (HOVER where missing),
    to compare a run's actions with another's or the in-process driver's (action_digest)."""
    end_positions: list[list[list[float]]] = field(default_factory=list)
    """Per episode: every UAV's position at its end (m)."""
    hover_answers: int = 0
    """Actions that were an agent's explicit hover (the central scheme's autopilot without commands)."""
    controller_losses: list[float] = field(default_factory=list)
    """Scheme central: seconds since the first tick at which the controller's liveliness token vanished."""
    first_tick_wall_s: float | None = None
    """Wall clock (time.time) when tick 0 was published: with last_tick_wall_s, the ticking window
    (bench/bench_swarm.py's ticks/s and CPU rates exclude start-up and shutdown)."""
    last_tick_wall_s: float | None = None
    """Wall clock when the last tick's round ended."""
    acks_missed: int = 0
    """Lock-step: `done` acknowledgements that did not come before the world went on (each also in
    its UAV's ``missed``): sum of per_uav missed = deadline_misses + acks_missed."""
    silent_marked: int = 0
    """Lock-step: times a live UAV was marked silent (it missed a round; not waited for until it answers again)."""
    silent_at_end: list[int] = field(default_factory=list)
    """Lock-step: the UAVs still marked silent when the run ended."""
    rejections_sent: int = 0
    """Rejection messages the world sent its agents (on uav/<i>/rejected; at most one per UAV per
    REJECTION_PERIOD_S, whatever the flood: truav.wire.rejection_notices)."""
    stalls: list[dict] = field(default_factory=list)
    """Real time: each time the world's clock jumped (it was paused, or the host stalled) at least
    STALL_MIN_S past a tick's due time: {"tick", "s" (how late), "ticks_skipped"}. The world resumes from
    the current time instead of publishing the missed ticks in a burst no agent could answer."""
    ticks_skipped: int = 0
    """Real time: tick periods that passed without a tick (every late start of a whole period or more,
    stalls included): the run took this many periods longer; no simulated step was lost."""
    rejoins: int = 0
    """An agent's liveliness token that vanished and came back within REJOIN_S (the world's or its own
    connection flapped, e.g. after a stall): not an agent that left, so not in ``losses``."""
    overrides: list[dict] = field(default_factory=list)
    """Every start and end of a UAV steered from outside (control/override/<i>), in order: {"tick" (the first
    tick it applied to / the first its agent flew again), "uav", "phase" (start, end), "by" (its sender), and
    for a start "x", "y" (m, the goal clipped to the area), "speed" (m/s, 0: full)}; also told on fault/override."""
    overridden_at_end: list[int] = field(default_factory=list)
    """The UAVs still overridden when the run ended."""
    per_uav: list[dict] = field(default_factory=list)
    """Per UAV id 0..n_uavs-1: {"uav", "received", "applied", "late", "stale", "missed", "rejected": {reason: n}}
    (UavAccounts.per_uav); received = applied + late + stale, missed = acting ticks it hovered without an
    applied action + lock-step `done` acknowledgements the world went on without, rejected = the messages refused
    on that UAV's keys (the key's UAV, whatever the payload says)."""


UAV_METRIC_PREFIX = "uav."
"""Step-metrics values ``uav.<i>.<count>`` (missed, late, stale, rejected): the worst UAVs only."""
MAX_UAV_METRICS = 20
"""At most this many UAVs' counts in one step-metrics message (4 values each: within MAX_METRIC_VALUES)."""
UAV_METRIC_COUNTS = ("missed", "late", "stale", "rejected")


class UavAccounts:
    """Per-UAV counts of the world's actions (pure: the world node updates it under its lock) and of the
    messages it refused on each UAV's keys (``note_refused``, under a lock of its own: the bus's thread)."""

    def __init__(self, n_uavs: int):
        self.n = n_uavs
        self.applied = [0] * n_uavs
        self.late = [0] * n_uavs
        self.stale = [0] * n_uavs
        self.missed = [0] * n_uavs
        self._refused: list[dict[str, int]] = [{} for _ in range(n_uavs)]
        self._refused_lock = threading.Lock()
        self.refused_total = 0
        """Messages refused on the UAVs' keys so far (what ``refused`` sums to)."""

    def note_refused(self, uav: int, reason: str) -> None:
        """One message refused on a key of UAV ``uav`` (``truav/<run>/uav/<i>/...``): the UAV is the key's, never
        the payload's word (a forged ``src`` would blame another UAV), as for the rejection it is told."""
        if 0 <= uav < self.n:
            with self._refused_lock:
                counts = self._refused[uav]
                counts[reason] = counts.get(reason, 0) + 1
                self.refused_total += 1

    def refused(self) -> list[dict[str, int]]:
        """Per UAV id, {reason: count} of the messages refused on its keys."""
        with self._refused_lock:
            return [dict(r) for r in self._refused]

    def per_uav(self) -> list[dict]:
        """WorldStats.per_uav: one entry per UAV id, in order."""
        refused = self.refused()
        return [{"uav": i, "received": self.applied[i] + self.late[i] + self.stale[i], "applied": self.applied[i],
                 "late": self.late[i], "stale": self.stale[i], "missed": self.missed[i], "rejected": refused[i]}
                for i in range(self.n)]

    def worst_metrics(self, limit: int = MAX_UAV_METRICS) -> dict[str, float]:
        """Step-metrics values ``uav.<i>.<count>`` for at most ``limit`` UAVs with anything non-zero in missed,
        late, stale or rejected, the worst first (most of those four summed); zero counts left out."""
        refused = [sum(r.values()) for r in self.refused()]
        rows = [(self.missed[i] + self.late[i] + self.stale[i] + refused[i], i) for i in range(self.n)]
        worst = sorted((r for r in rows if r[0]), key=lambda r: (-r[0], r[1]))[:limit]
        out: dict[str, float] = {}
        for _, i in worst:
            for name, n in zip(UAV_METRIC_COUNTS, (self.missed[i], self.late[i], self.stale[i], refused[i])):
                if n:
                    out[f"{UAV_METRIC_PREFIX}{i}.{name}"] = float(n)
        return out


def missed_share(world: dict, n_uavs: int) -> float | None:
    """The share of the actions a world's run expected (every UAV, every acting tick: its ticks less one
    `done` round per episode) that were not applied, from world.json's values; None before any acting tick.
    `truav-swarm up` and a hand-started world fail past --max-missed on it."""
    acting = int(world.get("ticks", 0)) - len(world.get("episodes") or [])
    expected = acting * n_uavs
    return 1.0 - int(world.get("actions_received", 0)) / expected if expected > 0 else None


def uav_metrics(values: dict[str, float]) -> dict[int, dict[str, int]]:
    """The ``uav.<i>.<count>`` values of a step-metrics message, as {uav: {count: n}} (truav-swarm status)."""
    out: dict[int, dict[str, int]] = {}
    for k, v in values.items():
        if k.startswith(UAV_METRIC_PREFIX):
            uav, _, name = k[len(UAV_METRIC_PREFIX):].partition(".")
            if uav.isdigit() and name in UAV_METRIC_COUNTS:
                out.setdefault(int(uav), {})[name] = int(v)
    return out


def action_digest():
    """The hash WorldStats.actions_digest keeps: update it with each step's actions as int64 bytes."""
    return hashlib.blake2b(digest_size=16)


def write_stats(path: str | Path, stats: WorldStats) -> None:
    """JSON with per-episode metrics and tick lateness percentiles."""
    lat = np.array(stats.tick_lateness_ms) if stats.tick_lateness_ms else np.zeros(0)
    data = asdict(stats)
    data.pop("tick_lateness_ms")
    if lat.size:
        data["tick_lateness_ms"] = {"p50": float(np.percentile(lat, 50)), "p99": float(np.percentile(lat, 99)),
                                    "max": float(lat.max()), "n": int(lat.size)}
    p = Path(path)
    write_atomic_text(p, jsonio.dumps(data, indent=1))
