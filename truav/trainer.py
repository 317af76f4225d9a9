"""The fast in-process driver: B seeds x U independent Q-learning agents,
stepped as one batch. Pure computation; files and progress bars live in the
CLI. `run_truav` trains or evaluates; `train_parallel` spreads seeds over
worker processes (a batch of seeds gives exactly what each seed gives alone,
so the split does not change any number).
"""

from __future__ import annotations

import multiprocessing as mp
import os
from dataclasses import dataclass
from typing import Callable

import numpy as np

from agents.qlearning import QLearners
from agents.reward import Reward
from agents.state import StateEncoder, all_peers, neighbour_features
from truav import seeding
from truav.config import Config
from world.env import EPISODE_FIELDS, World

EpisodeCallback = Callable[[int, dict[str, np.ndarray]], None]
"""Called after each episode with (episode index, metrics of shape (B,))."""

METRIC_FIELDS = EPISODE_FIELDS + ("reward", "epsilon")


@dataclass
class RunResult:
    """Per-episode metrics {name: (E, B)} and final Q-tables (B, U, S, 16)."""

    seeds: list[int]
    metrics: dict[str, np.ndarray]
    q: np.ndarray


def make_learners(cfg: Config, seeds: list[int], encoder: StateEncoder, q: np.ndarray | None = None) -> QLearners:
    U = cfg.scenario.n_uavs
    rngs = [seeding.agent_rng(s, i) for s in seeds for i in range(U)]
    return QLearners(cfg.learner, encoder.n_states, rngs, len(seeds), U, q=q)


def run_truav(cfg: Config, seeds: list[int], episodes: int | None = None, train: bool = True,
              q: np.ndarray | None = None, on_episode: EpisodeCallback | None = None) -> RunResult:
    """Train (or, with train=False, run greedily) TRUAV agents for each seed."""
    episodes = cfg.learner.episodes if episodes is None else episodes
    world = World(cfg, len(seeds))
    encoder, reward = StateEncoder(cfg), Reward(cfg)
    learners = make_learners(cfg, seeds, encoder, q)
    R = cfg.scenario.comm_range_m
    history: dict[str, list[np.ndarray]] = {k: [] for k in METRIC_FIELDS}

    obs = world.reset([seeding.world_rng(s) for s in seeds])
    for episode in range(episodes):
        if episode:
            obs = world.start_episode()
        learners.begin_episode(episode, cfg.scenario.steps_per_episode, greedy=not train)
        nearest, _ = neighbour_features(obs.pos, *all_peers(obs.pos), R)
        state = encoder.encode(obs.pos, obs.vehicles_in_range, obs.queued, nearest)
        reward_sum = np.zeros(len(seeds))
        done, t = False, 0
        while not done:
            action = learners.act(state, t)
            obs, _, done = world.step(action)
            nearest, overlap = neighbour_features(obs.pos, *all_peers(obs.pos), R)
            r = reward(obs.relayed, obs.covered, obs.energy_j, overlap)
            next_state = encoder.encode(obs.pos, obs.vehicles_in_range, obs.queued, nearest)
            if train:
                learners.update(state, action, r, next_state, done)
            reward_sum += r.mean(axis=1)
            state, t = next_state, t + 1
        summary = world.episode_summary()
        summary["reward"] = reward_sum
        summary["epsilon"] = np.full(len(seeds), learners.epsilon)
        for k in METRIC_FIELDS:
            history[k].append(summary[k])
        if on_episode is not None:
            on_episode(episode, summary)
    return RunResult(list(seeds), {k: np.stack(v) for k, v in history.items()}, learners.q)


def _worker(cfg, seeds, episodes, train, q, queue):
    def report(episode, summary):
        queue.put(("episode", os.getpid(), episode, {k: summary[k].tolist() for k in ("coverage_pct", "pdr", "delay_ms", "energy_j")}, len(seeds)))
    result = run_truav(cfg, seeds, episodes, train, q, report)
    queue.put(("done", os.getpid(), result))


def split(seq: list, parts: int) -> list[list]:
    """Split a list into at most `parts` contiguous, non-empty chunks."""
    parts = max(1, min(parts, len(seq)))
    bounds = np.linspace(0, len(seq), parts + 1).round().astype(int)
    return [seq[a:b] for a, b in zip(bounds[:-1], bounds[1:])]


def train_parallel(cfg: Config, seeds: list[int], workers: int, episodes: int | None = None,
                   train: bool = True, q: np.ndarray | None = None,
                   on_progress: Callable[[int, dict], None] | None = None) -> RunResult:
    """run_truav over seed chunks in `workers` processes; results in seed order.

    on_progress(n_env_episodes_done, latest metrics) is called in this process."""
    chunks = split(list(seeds), workers)
    if len(chunks) == 1:
        def report(episode, summary):
            if on_progress:
                on_progress(len(seeds), {k: float(np.nanmean(summary[k])) for k in ("coverage_pct", "pdr", "delay_ms", "energy_j")})
        return run_truav(cfg, list(seeds), episodes, train, q, report)
    ctx = mp.get_context("fork")
    queue = ctx.Queue()
    offsets = np.cumsum([0] + [len(c) for c in chunks])
    procs = []
    for c, lo, hi in zip(chunks, offsets[:-1], offsets[1:]):
        qc = None if q is None else q[lo:hi]
        p = ctx.Process(target=_worker, args=(cfg, c, episodes, train, qc, queue), daemon=True)
        p.start()
        procs.append(p)
    by_pid: dict[int, RunResult] = {}
    try:
        while len(by_pid) < len(procs):
            try:
                msg = queue.get(timeout=5.0)
            except Exception:
                dead = [p for p in procs if not p.is_alive() and p.pid not in by_pid]
                if dead and queue.empty():
                    raise RuntimeError(f"training worker {dead[0].pid} died (exit code {dead[0].exitcode})")
                continue
            if msg[0] == "episode" and on_progress:
                on_progress(msg[4], {k: float(np.nanmean(v)) for k, v in msg[3].items()})
            elif msg[0] == "done":
                by_pid[msg[1]] = msg[2]
    finally:
        for p in procs:
            if p.is_alive():
                p.terminate()
            p.join(timeout=5)
    results = [by_pid[p.pid] for p in procs]
    metrics = {k: np.concatenate([r.metrics[k] for r in results], axis=1) for k in results[0].metrics}
    return RunResult(list(seeds), metrics, np.concatenate([r.q for r in results]))
