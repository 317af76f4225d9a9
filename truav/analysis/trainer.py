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
import os
import pickle
import queue as queue_mod
import signal
import threading
import time
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from agents.controller import TruavController
from agents.policies import HoverController, RandomController
from truav.analysis.driver import run_episodes
from truav.analysis.runio import CHECKPOINT_EVERY_S
from truav.config import Config
from truav.stopping import STOP_SIGNALS, die_with_parent, note_stop_signal

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
    stopped: bool = False
    """Stopped early (Checkpointing.stop): metrics hold the episodes every chunk finished; q is None."""


def resumable(kind: str) -> bool:
    """Whether a training of controller ``kind`` continues exactly from a checkpoint: TRUAV's and an agent
    API class's (its instances pickled; truav.analysis.agent_loader.checkpoint_problem), not the central SAC's (its
    torch state is not pickled) nor the fixed baselines' (nothing to continue)."""
    from truav.analysis.agent_loader import AGENT_KIND_PREFIX
    return kind == "truav" or kind.startswith(AGENT_KIND_PREFIX)


@dataclass
class Checkpointing:
    """Checkpoints of a training at episode boundaries, for an exact continuation.

    A chunk's state (episode reached, its World and controller with every generator, the metrics so
    far) is pickled after an episode when ``every_s`` seconds passed since the last one, and when
    ``stop`` is set (SIGINT, see run_parallel), which also ends the chunk there. ``save(chunk, data)``
    and ``load(chunk) -> data | None`` are the caller's (files); they run in the chunk's process."""

    save: Callable[[int, bytes], None]
    load: Callable[[int], bytes | None]
    every_s: float = CHECKPOINT_EVERY_S
    stop: Any = None


def make_controller(kind: str, cfg: Config, seeds: list[int], train: bool, q: np.ndarray | None):
    if kind.startswith("agent:"):  # an agents.api class, by name (truav.analysis.agent_loader; q: its state arrays)
        from agents.api_controller import ApiController
        from truav.analysis.agent_loader import resolve
        name = kind[len("agent:"):]
        return ApiController(name, resolve(name), cfg, seeds, train=train, state=q)
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


def _state_bytes(episode: int, world, controller, history: dict) -> bytes:
    draw_map, world.draw_map = world.draw_map, map  # the driver's thread pool is not part of the state
    try:
        return pickle.dumps({"episode": episode, "world": world, "controller": controller, "history": history},
                            protocol=pickle.HIGHEST_PROTOCOL)
    finally:
        world.draw_map = draw_map


def saved_episodes(saved: bytes) -> int:
    """Episodes a chunk checkpoint (checked by :func:`check_saved_chunk`) had finished for each seed."""
    return pickle.loads(saved)["episode"]


def check_saved_chunk(saved: bytes, n_seeds: int) -> str | None:
    """What is wrong with a chunk checkpoint (runio.read_chunk_state) of ``n_seeds`` seeds, or None."""
    try:
        state = pickle.loads(saved)
    except Exception as exc:  # truncated or overwritten: any unpickling error
        return f"{type(exc).__name__}: {exc}"
    if not (isinstance(state, dict) and {"episode", "world", "controller", "history"} <= state.keys()
            and isinstance(state["episode"], int) and isinstance(state["history"], dict)):
        return "not a training checkpoint"
    if getattr(state["world"], "batch", None) != n_seeds:
        return f"it holds {getattr(state['world'], 'batch', None)} seeds, the chunk {n_seeds}"
    return None


def run_chunk(kind: str, cfg: Config, seeds: list[int], episodes: int, train: bool = True,
              q: np.ndarray | None = None, on_episode=None, start_pos: np.ndarray | None = None,
              ckpt: Checkpointing | None = None, index: int = 0) -> RunResult:
    """One batch of seeds in this process (start_pos: see driver.run_episodes); with ``ckpt``, from
    and to chunk ``index``'s checkpoint."""
    from truav.analysis.sumo_traffic import make_world
    saved = ckpt.load(index) if ckpt is not None else None
    if saved is not None:  # the caller's own file of an earlier run of this command (runio.read_chunk_state)
        state = pickle.loads(saved)
        first, world, controller, history = state["episode"], state["world"], state["controller"], state["history"]
    else:
        world, controller = make_world(cfg, len(seeds)), make_controller(kind, cfg, seeds, train, q)
        first, history = 0, {}
    end_pos = np.zeros((len(seeds), cfg.scenario.n_uavs, 2))
    last_save = [time.monotonic()]

    def episode_done(e: int, summary: dict) -> None:
        for key, value in summary.items():
            history.setdefault(key, []).append(np.array(value))
        if on_episode is not None:
            on_episode(e, summary)

    def after_episode(e: int) -> bool:
        if ckpt is None or e + 1 >= episodes:
            return False
        stop = ckpt.stop is not None and ckpt.stop.is_set()
        if stop or time.monotonic() - last_save[0] >= ckpt.every_s:
            ckpt.save(index, _state_bytes(e + 1, world, controller, history))
            last_save[0] = time.monotonic()
        return stop

    run_episodes(cfg, seeds, controller, episodes, episode_done, start_pos, end_pos, world=world,
                 first_episode=first, after_episode=after_episode)
    metrics = {k: np.stack(v) for k, v in history.items()}
    stopped = bool(history) and len(next(iter(history.values()))) < episodes
    if stopped:
        return RunResult(list(seeds), metrics, None, end_pos, None, stopped=True)
    table = controller.learners.q if isinstance(controller, TruavController) else None
    policy = None
    if kind == "central":
        policy = {k: v for k, v in controller.sac.state_dict().items() if k.startswith("actor")}
    elif kind.startswith("agent:"):
        policy = controller.state_arrays()
    return RunResult(list(seeds), metrics, table, end_pos, policy)


def _live(summary: dict[str, np.ndarray]) -> dict[str, float]:
    return {k: float(np.nanmean(summary[k])) if np.isfinite(summary[k]).any() else float("nan")
            for k in LIVE_METRICS}


def _worker(parent_pid, index, kind, cfg, seeds, episodes, train, q, start_pos, out, ckpt=None):
    die_with_parent(parent_pid)
    try:
        if ckpt is not None:  # Ctrl-C (systemd's and Slurm's SIGTERM too) reaches the whole group: the parent sets ckpt.stop
            for sig in STOP_SIGNALS:
                signal.signal(sig, signal.SIG_IGN)
        if kind == "truav":  # the cores are shared out as processes (run_parallel)
            from agents.fused import set_threads
            set_threads(1)
        result = run_chunk(kind, cfg, seeds, episodes, train, q,
                           lambda e, m: out.put(("episode", index, len(seeds), _live(m))), start_pos, ckpt, index)
        out.put(("done", index, result))
    except BaseException as exc:  # report, then let the process end
        from agents.api_controller import AgentFailure
        out.put(("agent_failure", index, str(exc)) if isinstance(exc, AgentFailure) else
                ("error", index, f"{type(exc).__name__}: {exc}"))


def _rows(q, lo: int, hi: int):
    """Seeds lo..hi-1 of a controller's parameters: an array, or named arrays (an API agent's state)."""
    if q is None:
        return None
    return {k: v[lo:hi] for k, v in q.items()} if isinstance(q, dict) else q[lo:hi]


def split(seq: list, parts: int) -> list[list]:
    """Split a list into at most `parts` contiguous, non-empty chunks."""
    parts = max(1, min(parts, len(seq)))
    bounds = np.linspace(0, len(seq), parts + 1).round().astype(int)
    return [seq[a:b] for a, b in zip(bounds[:-1], bounds[1:])]


class _StopOnSigint:
    """While a checkpointed run lasts, the first SIGINT, SIGTERM or SIGHUP sets ``stop`` (every chunk
    checkpoints at its episode's end and ends); a second one interrupts at once, as usual."""

    def __init__(self, stop) -> None:
        self.stop, self.previous = stop, {}

    def __enter__(self):
        if threading.current_thread() is threading.main_thread():  # Python's handlers run there only
            for sig in STOP_SIGNALS:
                # SIGINT ignored (started in the background, nohup) stays ignored.
                if sig != signal.SIGINT or signal.getsignal(sig) is not signal.SIG_IGN:
                    self.previous[sig] = signal.signal(sig, self._on_signal)
        return self

    def _on_signal(self, signum, frame) -> None:
        note_stop_signal(signum)
        if self.stop.is_set():
            raise KeyboardInterrupt
        self.stop.set()

    def __exit__(self, *exc) -> None:
        for sig, previous in self.previous.items():
            signal.signal(sig, previous)


def _merge(seeds: list[int], ordered: list[RunResult]) -> RunResult:
    if any(r.stopped for r in ordered):  # the episodes every chunk finished
        done = min(len(next(iter(r.metrics.values()), [])) for r in ordered)
        metrics = {k: np.concatenate([r.metrics[k][:done] for r in ordered], axis=1) for k in ordered[0].metrics} \
            if done else {}
        return RunResult(list(seeds), metrics, None, None, None, stopped=True)
    metrics = {k: np.concatenate([r.metrics[k] for r in ordered], axis=1) for k in ordered[0].metrics}
    q_all = None if ordered[0].q is None else np.concatenate([r.q for r in ordered])
    policy = None if ordered[0].policy is None else \
        {k: np.concatenate([r.policy[k] for r in ordered]) for k in ordered[0].policy}
    return RunResult(list(seeds), metrics, q_all, np.concatenate([r.uav_pos for r in ordered]), policy)


def run_parallel(kind: str, cfg: Config, seeds: list[int], episodes: int, workers: int = 1,
                 train: bool = True, q: np.ndarray | None = None,
                 on_progress: ProgressCallback | None = None, start_pos: np.ndarray | None = None,
                 ckpt: Checkpointing | None = None, chunks: list[list[int]] | None = None) -> RunResult:
    """run_chunk over seed chunks in `workers` processes; results in seed order.

    TRUAV's fused kernel runs on one thread in each worker process: two
    processes of 5 seeds train 10 seeds at 1.4-1.5x the rate of one process
    whose kernel runs the 10 on two threads (measured: 124k against 85k
    env-steps/s steady, bench/bench_trainer.py), and a batch equals its seeds
    one by one, so the split changes no number. A single chunk (one seed, or
    one worker) gives the kernel every thread instead.

    ckpt (resumable kinds only): checkpoint each chunk (see Checkpointing); SIGINT then stops the
    run at the chunks' next episode ends, checkpointed, and the result says ``stopped``. chunks: the
    seed split to use (a resumed run's, whatever ``workers`` is now)."""
    if ckpt is not None and not resumable(kind):
        raise ValueError(f"{kind}: training cannot be checkpointed (only truav and agent API classes)")
    chunks = chunks or split(list(seeds), workers)
    if cfg.scenario.mobility == "sumo":  # built (if not cached) once, before the workers load it
        from truav.analysis.sumo_traffic import build_trace
        build_trace(cfg)
    ctx = mp.get_context("fork")
    if ckpt is not None and ckpt.stop is None:
        ckpt.stop = ctx.Event()
    with _StopOnSigint(ckpt.stop) if ckpt is not None else _NoGuard():
        if len(chunks) == 1:
            if kind == "truav":  # the workers set one thread each (_worker): this process keeps its own setting
                from agents.fused import set_threads
                set_threads(workers)
            return run_chunk(kind, cfg, list(seeds), episodes, train, q,
                             None if on_progress is None else lambda e, m: on_progress(len(seeds), _live(m)),
                             start_pos, ckpt, 0)
        return _run_workers(ctx, kind, cfg, seeds, chunks, episodes, train, q, on_progress, start_pos, ckpt)


class _NoGuard:
    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        pass


def _run_workers(ctx, kind, cfg, seeds, chunks, episodes, train, q, on_progress, start_pos, ckpt) -> RunResult:
    out = ctx.Queue()
    bounds = np.cumsum([0] + [len(c) for c in chunks])
    procs = [ctx.Process(target=_worker, daemon=True,
                         args=(os.getpid(), i, kind, cfg, c, episodes, train, _rows(q, lo, hi),
                               None if start_pos is None else start_pos[lo:hi], out, ckpt))
             for i, (c, lo, hi) in enumerate(zip(chunks, bounds[:-1], bounds[1:]))]
    for p in procs:
        p.start()
    results: dict[int, RunResult] = {}
    failed: dict[int, str] = {}  # an API class broke in these chunks: their one lines
    try:
        while len(results) + len(failed) < len(procs):
            try:
                msg = out.get(timeout=2.0)
            except queue_mod.Empty:
                dead = [p for i, p in enumerate(procs) if i not in results and i not in failed and not p.is_alive()]
                if dead:
                    raise RuntimeError(f"worker {dead[0].pid} died with exit code {dead[0].exitcode}")
                continue
            if msg[0] == "episode" and on_progress is not None:
                on_progress(msg[2], msg[3])
            elif msg[0] == "done":
                results[msg[1]] = msg[2]
            elif msg[0] == "error":
                raise RuntimeError(f"worker {msg[1]} failed: {msg[2]}")
            elif msg[0] == "agent_failure":
                failed[msg[1]] = msg[2]
                if ckpt is None or ckpt.stop is None:
                    break
                # The other chunks end their episode and checkpoint it, as on Ctrl-C, so that a resume after
                # the fix keeps all they learned (killing them would lose it since their last checkpoint).
                ckpt.stop.set()
        if failed:  # the API class broke: the first chunk's one line
            from agents.api_controller import AgentFailure
            raise AgentFailure(failed[min(failed)])
    finally:
        for p in procs:
            if p.is_alive():  # a checkpointing worker ignores SIGTERM (see _worker); its checkpoints are atomic
                p.kill()
            p.join(timeout=5)
    return _merge(seeds, [results[i] for i in range(len(procs))])
