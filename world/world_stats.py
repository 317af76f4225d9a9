"""What the world process counts and writes at exit: WorldStats, the per-episode action digest
and the stats file (world.json). Pure bookkeeping: no bus, no simulation."""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np


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
    """Messages the bus refused, {reason: {sender: count}} (truav.bus.guard)."""
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
    tmp = p.with_name(p.name + ".tmp")
    tmp.write_text(json.dumps(data, indent=1, allow_nan=True))
    tmp.replace(p)
