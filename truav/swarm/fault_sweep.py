"""`truav experiment faults`: what beacon loss and beacon latency cost the
swarm. Each point is a real swarm run (router, world, agent processes,
real time) of the same seed flying the same policy greedily, with a plan
that drops a share of every beacon or delays every beacon. Writes
faults.csv and faults.png (coverage, PDR, delay, energy against loss and
against latency).
"""

from __future__ import annotations

import csv
import json
import math
import os
import signal
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Callable

import numpy as np

from truav import jsonio
from truav.csvio import row_cells
from truav.config import Config
from truav.stats import effect_text, paired_effect
from truav.stopping import STOP_SIGNALS, exit_code_for, stopped_by

METRICS = (("coverage_pct", "coverage (%)", 1.0), ("pdr", "PDR (%)", 100.0),
           ("delay_ms", "relay delay (ms)", 1.0), ("energy_j", "energy (kJ/UAV/episode)", 1e-3))
# Smallest y span a panel shows (absolute for percentages, relative to the no-fault value
# otherwise), so a change of a few hundredths is drawn flat, not as a steep line.
MIN_SPAN = {"coverage_pct": 10.0, "pdr": 10.0, "delay_ms": 0.25, "energy_j": 0.05}
RELATIVE_SPAN = ("delay_ms", "energy_j")


def y_limits(key: str, values: np.ndarray) -> tuple[float, float]:
    lo, hi = float(np.nanmin(values)), float(np.nanmax(values))
    span = MIN_SPAN[key] * (abs(values[0]) if key in RELATIVE_SPAN else 1.0)
    if hi - lo >= span:
        pad = 0.1 * (hi - lo)
        return lo - pad, hi + pad
    mid = (lo + hi) / 2
    return max(0.0, mid - span / 2) if lo >= 0 else mid - span / 2, max(0.0, mid - span / 2) + span if lo >= 0 \
        else mid + span / 2


@dataclass(frozen=True)
class SweepSize:
    loss: tuple[float, ...]
    latency_ms: tuple[float, ...]
    episodes: int
    steps: int
    train_episodes: int


SIZES = {
    # quick: 3 episodes per point, the fewest that give each effect an interval (paired over episodes)
    "quick": SweepSize((0.0, 0.25, 0.5), (0.0, 250.0, 500.0), 3, 60, 200),
    "full": SweepSize((0.0, 0.1, 0.2, 0.3, 0.4, 0.5), (0.0, 100.0, 200.0, 300.0, 400.0, 500.0), 3, 100, 2000),
}


def plan_text(kind: str, level: float) -> str:
    if kind == "loss":
        return f'[[fault]]\nkind = "loss"\nstart = 0.0\nprobability = {level}\nkeys = "uav/*/beacon"\n'
    return f'[[fault]]\nkind = "latency"\nstart = 0.0\nfixed_ms = {level}\nkeys = "uav/*/beacon"\n'


def train_policy(cfg: Config, out: Path, episodes: int, seed: int) -> Path:
    """A quick in-process TRUAV policy for the swarm to fly (one seed)."""
    from truav.analysis import runio
    from truav.analysis.trainer import run_parallel
    run = out / "policy"
    run.mkdir(parents=True, exist_ok=True)
    cfg = cfg.replace(learner={"episodes": episodes})
    result = run_parallel("truav", cfg, [seed], episodes, workers=1)
    runio.write_config(run, cfg)
    runio.write_qtables(run, [seed], result.q, cfg=cfg)
    return run


class PointInterrupted(KeyboardInterrupt):
    """A stop signal (Ctrl-C, SIGTERM, SIGHUP) ended a sweep during its point ``number`` of ``total``: that point
    is unfinished (a re-run redoes it from scratch), the ones before it are kept. ``code``: the exit code."""

    def __init__(self, number: int, total: int, name: str, code: int) -> None:
        super().__init__(f"interrupted at point {number}/{total} ({name})")
        self.number, self.total, self.name, self.code = number, total, name, code


class PointFailed(RuntimeError):
    """A sweep point's swarm run failed (its logs say why); the points before it are kept."""


STOP_CODES = frozenset(exit_code_for(s) for s in STOP_SIGNALS)
"""A swarm run stopped by a signal exits with one of these (truav.swarm.swarm_options.Outcome.exit_code)."""


def is_finished(text: str, episodes: int) -> bool:
    """Whether a point's summary.json text is a finished run's: result ok (not interrupted, not failed) and
    every one of the ``episodes`` asked for. Only such a point is kept by a re-run; any other is run again."""
    try:
        summary = json.loads(text)
    except ValueError:
        return False
    if not isinstance(summary, dict) or summary.get("interrupted"):
        return False
    outcome, world = summary.get("outcome") or {}, summary.get("world") or {}
    return outcome.get("result") == "ok" and len(world.get("episodes") or []) >= episodes


def finished_point(path: Path, episodes: int) -> str | None:
    """The summary.json text at ``path`` if its point finished (:func:`is_finished`), else None."""
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError):
        return None
    return text if is_finished(text, episodes) else None


def swarm_point(n: int, total: int, name: str, run_dir: Path, episodes: int, label: str,
                start: Callable[[], int]) -> str:
    """Sweep point ``n`` (from 0) of ``total``: its summary.json text, kept if the point finished before,
    else from ``start()``, a swarm run into ``run_dir`` that replaces its earlier files (an interrupted or
    failed run of the point). A stop signal raises PointInterrupted, a failed run PointFailed."""
    summary = run_dir / "summary.json"
    text = finished_point(summary, episodes)
    if text is not None:
        return text
    print(f"[{n + 1}/{total}] {label}", flush=True)
    try:
        rc = start()
    except KeyboardInterrupt:  # before the swarm took the signals over, or after it gave them back
        raise PointInterrupted(n + 1, total, name, exit_code_for(stopped_by() or signal.SIGINT)) from None
    if rc in STOP_CODES:
        raise PointInterrupted(n + 1, total, name, rc)
    if rc:
        raise PointFailed(f"swarm run {name} failed (exit {rc}; see {run_dir / 'logs'})")
    text = finished_point(summary, episodes)
    if text is None:
        raise PointFailed(f"swarm run {name} ended without finishing its {episodes} episode(s) (see {summary})")
    return text


def run_point(cfg: Config, out: Path, seed: int, qtable: str, rate_hz: float, episodes: int, total: int,
              n: int, kind: str, level: float) -> str:
    """One sweep point's swarm run (kept if finished); returns its summary.json text."""
    from truav.swarm.supervisor import SwarmOptions, run_swarm  # here: the parser loads this module
    name = f"{kind}-{level:g}"

    def start() -> int:
        out.mkdir(parents=True, exist_ok=True)
        plan = out / f"{name}.toml"
        plan.write_text(plan_text(kind, level))
        return run_swarm(cfg, SwarmOptions(run=f"sweep{n}", seed=seed, episodes=episodes, rate_hz=rate_hz,
                                           qtable=qtable, greedy=True, out=str(out / name), plot=False,
                                           references=False, quiet=True, fault_plan=str(plan),
                                           force=True,  # unfinished: afresh, its partial files replaced
                                           # Real time on a busy host misses actions: that is reported
                                           # (missed_actions, a warning), not a reason to lose the sweep.
                                           max_missed_share=1.0))
    return swarm_point(n, total, name, out / name, episodes, f"beacon {kind} {level:g}", start)


def missed_share(summary: dict, n_uavs: int) -> float:
    """The share of the actions the world waited for that did not come (0 when it never ticked)."""
    world = summary.get("world") or {}
    acting = (world.get("ticks", 0) - len(world.get("episodes") or [])) * n_uavs
    return 1.0 - world.get("actions_received", 0) / acting if acting > 0 else 0.0


SWARM_CPUS = 2
"""CPUs a Ray task of one sweep point asks for: a swarm is a router, a world and an agent per UAV."""


def run_sweep(cfg: Config, size_name: str, out: Path, seed: int = 0, qtable: str | None = None,
              rate_hz: float = 10.0, keep_steps: bool = False, executor: str = "local",
              address: str | None = None) -> Path:
    """The sweep of SIZES[size_name]; episodes of its length unless ``keep_steps`` (the user set
    scenario.steps_per_episode explicitly). executor "ray": points as Ray tasks."""
    size = SIZES[size_name]
    out.mkdir(parents=True, exist_ok=True)
    if not keep_steps:
        cfg = cfg.replace(scenario={"steps_per_episode": size.steps})
    if qtable is None:
        print(f"training a policy in-process ({size.train_episodes} episodes) for the swarm to fly", flush=True)
        qtable = str(train_policy(cfg, out, size.train_episodes, seed))
    points = [("loss", x) for x in size.loss] + [("latency", x) for x in size.latency_ms]
    point = partial(run_point, cfg, out, seed, qtable, rate_hz, size.episodes, len(points))
    if executor == "ray":  # points as Ray tasks; --out (policy, recordings) on storage the nodes share
        from truav.experiments.ray_executor import run_points_on_ray
        cpus = os.cpu_count() or 1
        texts = run_points_on_ray(lambda p: point(*p), [(n, k, x) for n, (k, x) in enumerate(points)],
                                  cpus, address, cpus_per_task=min(SWARM_CPUS, cpus))
        for (kind, level), text in zip(points, texts):
            done = out / f"{kind}-{level:g}" / "summary.json"
            if finished_point(done, size.episodes) is None:  # a node's run, on storage this host does not see
                done.parent.mkdir(parents=True, exist_ok=True)
                done.write_text(text)
    else:
        texts = [point(n, kind, level) for n, (kind, level) in enumerate(points)]
    # the same bar as chaos's no-fault run (chaos.BASELINE_MAX_MISSED_SHARE; chaos imports this module)
    from truav.swarm.invariants import HOST_LOAD_MISSED_SHARE as BASELINE_MAX_MISSED_SHARE
    rows = []
    per_episode: dict[tuple[str, float], dict[str, list[float]]] = {}
    for (kind, level), text in zip(points, texts):
        summary = json.loads(text)
        eps = (summary.get("world") or {}).get("episodes") or []
        per_episode[kind, level] = {key: [jsonio.num(e.get(key)) * scale for e in eps] for key, _, scale in METRICS}
        row = {"kind": kind, "level": level}
        for key, _, _ in METRICS:
            vals = [jsonio.num(e.get(key)) for e in eps]
            row[key] = float(np.nanmean(vals)) if vals else math.nan
        row["missed_actions"] = (summary.get("world") or {}).get("deadline_misses", math.nan)
        share = missed_share(summary, cfg.scenario.n_uavs)
        if share > BASELINE_MAX_MISSED_SHARE:
            print(f"warning: point {kind} {level:g} missed {100 * share:.1f}% of its actions (the host was busy?): "
                  f"its metrics mix the host's load with the fault", flush=True)
        rows.append(row)
    with open(out / "faults.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(row_cells(r) for r in rows)
    text = effects_text(per_episode)
    print(text, flush=True)
    (out / "effects.txt").write_text(text + "\n")
    return sweep_figure(rows, out / "faults.png")


def effects_text(per_episode: dict[tuple[str, float], dict[str, list[float]]]) -> str:
    """Each fault point's effect on each metric against its kind's no-fault point (level 0), paired over the
    episodes (the same seed: episode k drives the same traffic at every point), with its 95% interval."""
    lines = ["effect against the no-fault point (fault - none), paired over episodes, 95% t-interval:"]
    for (kind, level), values in per_episode.items():
        base = per_episode.get((kind, 0.0))
        if level == 0 or base is None:
            continue
        lines.append(f"beacon {kind} {level:g}:")
        for key, label, _ in METRICS:
            a, b = base[key], values[key]
            n = min(len(a), len(b))
            lines.append(f"  {label:<26}{effect_text(paired_effect(a[:n], b[:n]), noun='episodes')}")
    return "\n".join(lines)


def sweep_figure(rows: list[dict], path: Path) -> Path:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(2, 4, figsize=(15, 6.5))
    for r, (kind, xlabel, scale) in enumerate((("loss", "beacon loss (%)", 100.0),
                                                ("latency", "beacon latency (ms)", 1.0))):
        pts = sorted((row for row in rows if row["kind"] == kind), key=lambda row: row["level"])
        x = np.array([p["level"] for p in pts]) * scale
        for c, (key, label, s) in enumerate(METRICS):
            ax = axes[r, c]
            y = np.array([p[key] * s for p in pts], dtype=float)
            ax.plot(x, y, marker="o", color=f"C{r}")
            if y.size:
                ax.set_ylim(*y_limits(key, y))
                change = y[-1] - y[0]
                unit = " pts" if key in ("coverage_pct", "pdr") else f" ({100 * change / y[0]:+.1f}%)" if y[0] else ""
                ax.set_title(f"at the highest level: {change:+.2f}{unit}" if key in ("coverage_pct", "pdr")
                             else f"at the highest level: {change:+.3g}{unit}", fontsize=8, color="0.35")
            ax.set_xlabel(xlabel)
            ax.set_ylabel(label)
            ax.grid(alpha=0.3)
    fig.suptitle("TRUAV swarm under beacon loss (top) and beacon latency (bottom), greedy policy, same seed")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
