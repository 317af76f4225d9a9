"""A what-if branched from a recorded lock-step run: restore the run at a tick, change the policy or a learner
setting, run on, and set the outcome beside the recorded one.

Restoring: from the latest state snapshot the recording holds at or before the branch tick
(recorder.resim_snapshots; `truav-swarm up --lockstep --record` takes one every --snapshot-every ticks),
else from tick 0; from there the world and every agent are re-run to the branch tick and checked against the
recording on the way (recorder.resim_verify), so the state at the tick (world, vehicles, queues, generators,
Q-tables) is the recorded run's exactly, or the branch is refused. From the tick on, what changes: the
agents' Q-tables (another run's, ``tables``), greedy acting without learning (``greedy``), the learner's
settings (``learner``: rates, exploration, reward weights, geofence; settings that change the state encoding
or the world are refused). The branch's messages are
compared with the recording too: the first one that differs is where the what-if departs from the run.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from recorder.reader import iter_messages
from recorder.resim import RecordedRun, Resimulation, Round
from recorder.resim_snapshots import latest_snapshot
from recorder.resim_verify import Divergence, RecordedTicks, Verification, compare_round, verify
from truav.config import Config, ConfigError, config_from_dict, to_dict
from truav.errors import UserError
from truav.wire import keys, schema

BRANCH_LEARNER_KEYS = ("learning_rate", "discount", "epsilon_start", "epsilon_end", "epsilon_decay_fraction",
                       "episodes", "geofence", "w_relay", "w_coverage", "w_energy", "w_overlap")
"""The `learner.*` settings a branch may change at its tick: what the agents' learning and acting read. The
others shape the state encoding (a table of another shape) or the world, which the branch restores as it was."""
OUTCOME_METRICS = (("coverage_pct", "coverage %"), ("pdr", "PDR"), ("delay_ms", "delay ms"), ("energy_j", "energy J"))
"""The per-episode outcome set side by side (world.env.World.episode_summary names)."""


def branch_config(cfg: Config, overrides: dict[str, dict[str, Any]]) -> Config:
    """``cfg`` with the ``--set`` overrides a branch may apply; UserError naming the first it may not."""
    for section, values in overrides.items():
        for key in values:
            if section != "learner" or key not in BRANCH_LEARNER_KEYS:
                raise UserError(f"--set {section}.{key}: a branch restores the recorded world and state encoding; "
                                f"it can change only learner.{{{','.join(BRANCH_LEARNER_KEYS)}}}")
    data = to_dict(cfg)
    data["learner"] = {**data["learner"], **overrides.get("learner", {})}
    try:
        return config_from_dict(data)
    except ConfigError as exc:
        raise UserError(f"--set: {exc}") from None


@dataclass
class BranchResult:
    """A what-if's outcome beside the recorded run's."""

    from_tick: int
    from_episode: int
    changes: list[str]
    restored: Verification
    """The re-simulation from the snapshot (or tick 0) to the branch tick, checked against the recording."""
    snapshot_tick: int | None = None
    """The tick of the snapshot restored; None: none (the recording has none at or before the branch tick, or
    snapshots were not used): re-simulated from tick 0."""
    after: Verification = field(default_factory=Verification)
    """The branch from its tick on, compared with the recording: where it departs from the run."""
    recorded: dict[int, dict[str, float]] = field(default_factory=dict)
    """Episode -> the world's recorded episode metrics (metrics/episode)."""
    branch: dict[int, dict[str, float]] = field(default_factory=dict)
    """Episode -> the branch's episode metrics (before the branch episode: the re-simulated run's)."""

    @property
    def departed(self) -> Divergence | None:
        return self.after.first

    def outcome_rows(self) -> list[tuple[int, list[tuple[float, float]]]]:
        """(episode, [(recorded, branch) per OUTCOME_METRICS]) for every episode either side has."""
        nan = float("nan")
        return [(e, [(self.recorded.get(e, {}).get(k, nan), self.branch.get(e, {}).get(k, nan))
                     for k, _ in OUTCOME_METRICS])
                for e in sorted(set(self.recorded) | set(self.branch))]

    def table_lines(self) -> list[str]:
        head = "episode  " + "  ".join(f"{name:>21}" for _, name in OUTCOME_METRICS)
        sub = "         " + "  ".join(f"{'recorded':>10} {'branch':>10}" for _ in OUTCOME_METRICS)
        lines = [head, sub]
        for e, pairs in self.outcome_rows():
            mark = "*" if e >= self.from_episode else " "
            lines.append(f"{e:>6}{mark}  " + "  ".join(f"{r:>10.4g} {b:>10.4g}" for r, b in pairs))
        lines.append(f"(* from the branch: tick {self.from_tick}, episode {self.from_episode})")
        return lines


def recorded_episode_metrics(path: str | os.PathLike[str], run: str) -> dict[int, dict[str, float]]:
    """Episode -> the values of the world's metrics/episode messages in the recording."""
    out: dict[int, dict[str, float]] = {}
    for _, payload, _, _ in iter_messages(path, include=[keys.metrics_episode(run)]):
        try:
            msg = schema.decode(payload)
        except schema.SchemaError:
            continue
        if isinstance(msg, schema.Metrics) and msg.scope == schema.SCOPE_EPISODE:
            out.setdefault(msg.episode, dict(msg.values))
    return out


def run_branch(path: str | os.PathLike[str], run: str, rec: RecordedRun, sim: Resimulation, from_tick: int, *,
               tables: list[np.ndarray] | None = None, greedy: bool = False, learner: Config | None = None,
               on_round: Callable[[Round, int], None] | None = None, snapshots: bool = True,
               on_restore: Callable[[int], None] | None = None) -> BranchResult:
    """Restore ``sim`` (fresh, of ``rec``) from the recording's latest snapshot at or before ``from_tick``
    (``snapshots``; else, or without one, from tick 0; ``on_restore(tick)`` then), re-simulate it to
    ``from_tick`` checked against the recording, apply the changes, run it to the end; the outcome beside the
    recorded one. ``restored.divergent_messages`` > 0: the recording was not reproduced before the tick, and
    nothing was branched. Episodes over before the snapshot were not re-simulated: their branch metrics are
    the recorded ones. UserError when the recording's snapshot does not fit its run."""
    summaries: dict[int, dict[str, float]] = {}
    recorded_metrics = recorded_episode_metrics(path, run)
    snap = latest_snapshot(path, run, rec.cfg.scenario.n_uavs, from_tick) if snapshots else None
    if snap is not None:
        try:
            sim.restore(snap.tick, snap.world, snap.agents)
        except ValueError as exc:
            raise UserError(f"{os.fspath(path)}: its snapshot of tick {snap.tick} does not fit its run ({exc}); "
                            f"--no-snapshots re-simulates from tick 0") from None
        summaries.update({e: m for e, m in recorded_metrics.items() if e < sim.episode})
        if on_restore is not None:
            on_restore(snap.tick)

    def collect(rnd: Round, divergent: int) -> None:
        if rnd.summary is not None:
            summaries[rnd.episode] = rnd.summary
        if on_round is not None:
            on_round(rnd, divergent)

    restored = verify(path, run, sim, until_tick=from_tick, on_round=collect, stop_at_first=True)
    result = BranchResult(from_tick=from_tick, from_episode=sim.episode, changes=[], restored=restored,
                          snapshot_tick=None if snap is None else snap.tick, recorded=recorded_metrics)
    if restored.divergent_messages or restored.recording_ended or restored.snapshots_differing:
        return result
    if tables is not None:
        sim.set_tables(tables)
        result.changes.append("Q-tables replaced")
    if learner is not None:
        changed = [f"learner.{k}={getattr(learner.learner, k)!r}" for k in BRANCH_LEARNER_KEYS
                   if getattr(learner.learner, k) != getattr(rec.cfg.learner, k)]
        sim.set_learner(learner)
        result.changes += changed
    if greedy:
        sim.set_greedy()
        result.changes.append("greedy, not learning")
    recorded = RecordedTicks(path, run, result.after, from_tick=from_tick)
    for rnd in sim.rounds():
        divergent = 0
        if not result.after.recording_ended:  # past a stopped run's recording there is nothing to compare
            messages = recorded.take(rnd.tick)
            last = recorded.ended_before(rnd.tick + 1)
            divergent = compare_round(rnd, messages, run, result.after, last)
            result.after.ticks += 1
            result.after.recording_ended = last and sim.episode < sim.episodes
        collect(rnd, divergent)
    result.after.leftover = recorded.leftover()
    result.branch = summaries
    return result


__all__ = ["BRANCH_LEARNER_KEYS", "BranchResult", "OUTCOME_METRICS", "branch_config", "recorded_episode_metrics",
           "run_branch"]
