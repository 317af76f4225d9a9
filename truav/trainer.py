"""Train and evaluate controllers over many seeds, using every core.

TRUAV runs all seeds as one batch in this process: its fused episode kernel
(agents/fused.py) spreads the environments over `workers` threads. Other
controllers split the seeds into contiguous chunks, one worker process per
chunk, each running `driver.run_episodes` on its chunk as one batch. A batch
of seeds gives exactly what each seed gives alone, so neither split changes a
number.
"""

from __future__ import annotations

import multiprocessing as mp
import queue as queue_mod
from dataclasses import dataclass
from typing import Callable

import numpy as np

from agents.controller import TruavController
from agents.policies import HoverController, RandomController
from truav.config import Config
from truav.driver import run_episodes

CONTROLLERS = ("truav", "random", "hover", "patrol", "central", "patrol_ctrl")
LIVE_METRICS = ("coverage_pct", "pdr", "delay_ms", "energy_j")

ProgressCallback = Callable[[int, dict[str, float]], None]
"""on_progress(env-episodes just finished, live metric means) in the caller's process."""


@dataclass
class RunResult:
    """Per-episode metrics {name: (E, B)} and, for TRUAV, Q-tables (B, U, S, 16)."""

    seeds: list[int]
    metrics: dict[str, np.ndarray]
    q: np.ndarray | None
    uav_pos: np.ndarray | None = None
    """(B, U, 2) where the UAVs were at the end: a persist-trained swarm's station."""
    policy: dict[str, np.ndarray] | None = None
    """The central scheme: its trained actors {actor0..actor5: (B, ...)} (agents.sac.BatchedSAC.state_dict)."""


def make_controller(kind: str, cfg: Config, seeds: list[int], train: bool, q: np.ndarray | None):
    if kind == "truav":
        return TruavController(cfg, seeds, train=train, q=q)
    if kind == "random":
        return RandomController(cfg, seeds)
    if kind == "hover":
        return HoverController(cfg, seeds)
    if kind == "patrol":
        from agents.patrol import PatrolController
        return PatrolController(cfg, seeds)
    if kind == "central":
        from agents.central import CentralController  # needs the optional `central` extra (torch)
        if cfg.central.geofence:
            from agents.central_fence import FencedCentralController
            return FencedCentralController(cfg, seeds, train=train, params=q)
        return CentralController(cfg, seeds, train=train, params=q)
    if kind == "patrol_ctrl":  # the patrol flying under the centralized control plane
        from agents.central import WithControlPlane
        from agents.patrol import PatrolController
        return WithControlPlane(PatrolController(cfg, seeds), cfg, len(seeds))
    raise ValueError(f"unknown controller {kind!r} (known: {', '.join(CONTROLLERS)})")


def run_chunk(kind: str, cfg: Config, seeds: list[int], episodes: int, train: bool = True,
              q: np.ndarray | None = None, on_episode=None, start_pos: np.ndarray | None = None) -> RunResult:
    """One batch of seeds in this process (start_pos: see driver.run_episodes)."""
    controller = make_controller(kind, cfg, seeds, train, q)
    end_pos = np.zeros((len(seeds), cfg.scenario.n_uavs, 2))
    metrics = run_episodes(cfg, seeds, controller, episodes, on_episode, start_pos, end_pos)
    table = controller.learners.q if isinstance(controller, TruavController) else None
    policy = None
    if kind == "central":
        policy = {k: v for k, v in controller.sac.state_dict().items() if k.startswith("actor")}
    return RunResult(list(seeds), metrics, table, end_pos, policy)


def _live(summary: dict[str, np.ndarray]) -> dict[str, float]:
    return {k: float(np.nanmean(summary[k])) if np.isfinite(summary[k]).any() else float("nan")
            for k in LIVE_METRICS}


def _worker(index, kind, cfg, seeds, episodes, train, q, start_pos, out):
    try:
        if kind == "truav":  # the cores are shared out as processes (run_parallel)
            from agents.fused import set_threads
            set_threads(1)
        result = run_chunk(kind, cfg, seeds, episodes, train, q,
                           lambda e, m: out.put(("episode", index, len(seeds), _live(m))), start_pos)
        out.put(("done", index, result))
    except BaseException as exc:  # report, then let the process end
        out.put(("error", index, f"{type(exc).__name__}: {exc}"))


def split(seq: list, parts: int) -> list[list]:
    """Split a list into at most `parts` contiguous, non-empty chunks."""
    parts = max(1, min(parts, len(seq)))
    bounds = np.linspace(0, len(seq), parts + 1).round().astype(int)
    return [seq[a:b] for a, b in zip(bounds[:-1], bounds[1:])]


def run_parallel(kind: str, cfg: Config, seeds: list[int], episodes: int, workers: int = 1,
                 train: bool = True, q: np.ndarray | None = None,
                 on_progress: ProgressCallback | None = None, start_pos: np.ndarray | None = None) -> RunResult:
    """run_chunk over seed chunks in `workers` processes; results in seed order.

    TRUAV's fused kernel runs on one thread in each worker process: two
    processes of 5 seeds train 10 seeds at 1.4-1.5x the rate of one process
    whose kernel runs the 10 on two threads (measured: 124k against 85k
    env-steps/s steady, bench/bench_trainer.py), and a batch equals its seeds
    one by one, so the split changes no number. A single chunk (one seed, or
    one worker) gives the kernel every thread instead."""
    chunks = split(list(seeds), workers)
    if len(chunks) == 1:
        if kind == "truav":  # the workers set one thread each (_worker): this process keeps its own setting
            from agents.fused import set_threads
            set_threads(workers)
        return run_chunk(kind, cfg, list(seeds), episodes, train, q,
                         None if on_progress is None else lambda e, m: on_progress(len(seeds), _live(m)), start_pos)
    ctx = mp.get_context("fork")
    out = ctx.Queue()
    bounds = np.cumsum([0] + [len(c) for c in chunks])
    procs = [ctx.Process(target=_worker, daemon=True,
                         args=(i, kind, cfg, c, episodes, train, None if q is None else q[lo:hi],
                               None if start_pos is None else start_pos[lo:hi], out))
             for i, (c, lo, hi) in enumerate(zip(chunks, bounds[:-1], bounds[1:]))]
    for p in procs:
        p.start()
    results: dict[int, RunResult] = {}
    try:
        while len(results) < len(procs):
            try:
                msg = out.get(timeout=2.0)
            except queue_mod.Empty:
                dead = [p for i, p in enumerate(procs) if i not in results and not p.is_alive()]
                if dead:
                    raise RuntimeError(f"worker {dead[0].pid} died with exit code {dead[0].exitcode}")
                continue
            if msg[0] == "episode" and on_progress is not None:
                on_progress(msg[2], msg[3])
            elif msg[0] == "done":
                results[msg[1]] = msg[2]
            elif msg[0] == "error":
                raise RuntimeError(f"worker {msg[1]} failed: {msg[2]}")
    finally:
        for p in procs:
            if p.is_alive():
                p.terminate()
            p.join(timeout=5)
    ordered = [results[i] for i in range(len(procs))]
    metrics = {k: np.concatenate([r.metrics[k] for r in ordered], axis=1) for k in ordered[0].metrics}
    q_all = None if ordered[0].q is None else np.concatenate([r.q for r in ordered])
    policy = None if ordered[0].policy is None else \
        {k: np.concatenate([r.policy[k] for r in ordered]) for k in ordered[0].policy}
    return RunResult(list(seeds), metrics, q_all, np.concatenate([r.uav_pos for r in ordered]), policy)
