"""Resumable experiment cells on every core.

An experiment is a list of cells. A cell is one scheme at one setting (UAV
speed, swarm and traffic size) for a chunk of seeds, run as one batch:
training for `episodes` episodes, then `eval_episodes` episodes of the
trained policy (greedy) on held-out traffic (world seed + EVAL_SEED_OFFSET).
Its results go to `<out>/cells/<key>.npz`, written atomically; the key
names the scheme, setting, seeds and budget and hashes the cell's effective
config, so a restarted run skips exactly the cells already finished with the
same inputs. Worker processes (fork) take cells from a queue, one at a time;
or, with the Ray executor (truav.experiments.ray_executor), Ray tasks on a
local instance or a cluster run them and return their results to this
process, which writes the cell files.
"""

from __future__ import annotations

import hashlib
import multiprocessing as mp
import os
import queue as queue_mod
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from truav.config import Config, to_dict

EVAL_SEED_OFFSET = 10_000
"""Evaluation runs on held-out traffic: world seed = training seed + this (as `truav evaluate`)."""
CELLS_DIR = "cells"
COST_ORDER = {"central": 0, "truav": 1, "patrol": 2, "patrol_ctrl": 3}
"""Expensive schemes start first, so the last cells running are the short ones."""
UNUSED_SECTIONS = {"truav": ("patrol", "central"), "patrol": ("learner", "central"), "central": ("patrol",),
                   "patrol_ctrl": ("learner",),
                   "random": ("learner", "patrol", "central"), "hover": ("learner", "patrol", "central")}
"""Config sections a scheme never reads: left out of its cells' keys, so that
changing, say, the SAC settings does not re-run finished TRUAV cells."""


@dataclass(frozen=True)
class Cell:
    scheme: str
    speed: float
    seeds: tuple[int, ...]
    episodes: int
    eval_episodes: int
    overrides: tuple[tuple[str, str, Any], ...] = ()
    """Extra (section, key, value) config changes of this cell (e.g. n_uavs)."""

    def config(self, base: Config) -> Config:
        sections: dict[str, dict[str, Any]] = {"scenario": {"uav_speed_mps": self.speed},
                                               "learner": {"episodes": self.episodes}}
        for section, key, value in self.overrides:
            sections.setdefault(section, {})[key] = value
        return base.replace(**sections)

    def key(self, base: Config) -> str:
        cfg = self.config(base)
        used = {k: v for k, v in to_dict(cfg).items() if k not in UNUSED_SECTIONS.get(self.scheme, ())}
        digest = hashlib.sha256(f"{used!r}|{self.eval_episodes}".encode()).hexdigest()[:10]
        sc = cfg.scenario
        return (f"{self.scheme}_v{self.speed:g}_u{sc.n_uavs}_n{sc.n_vehicles}_s{self.seeds[0]}-{self.seeds[-1]}"
                f"_e{self.episodes}_{digest}")

    @property
    def env_episodes(self) -> int:
        return len(self.seeds) * (self.episodes + self.eval_episodes)


@dataclass
class CellResult:
    cell: Cell
    train: dict[str, np.ndarray]
    """{metric: (E, B)} per training episode."""
    eval: dict[str, np.ndarray]
    """{metric: (E_eval, B)} per evaluation episode."""
    wall_s: float
    meta: dict[str, float] = field(default_factory=dict)


def cell_path(out: Path, base: Config, cell: Cell) -> Path:
    return Path(out) / CELLS_DIR / f"{cell.key(base)}.npz"


def _evaluate(scheme: str, cfg: Config, seeds: list[int], controller, episodes: int, on_episode,
              world=None):
    from truav import seeding
    from truav.driver import run_episodes  # here, like the trainer: the CLI's parser loads this module
    from truav.trainer import make_controller
    eval_seeds = [s + EVAL_SEED_OFFSET for s in seeds]
    if scheme == "truav":
        ctrl = make_controller("truav", cfg, eval_seeds, False, controller.learners.q)
    elif scheme == "central":
        controller.train = False  # the trained actor, greedy; its control plane still runs
        ctrl = controller
    else:
        ctrl = make_controller(scheme, cfg, eval_seeds, False, None)
    if world is not None:
        world.rngs = [seeding.world_rng(s) for s in eval_seeds]
    return run_episodes(cfg, eval_seeds, ctrl, episodes, on_episode, world=world)


def run_cell(base: Config, cell: Cell, on_episode: Callable[[int], None] | None = None) -> CellResult:
    """Train then evaluate one cell in this process."""
    from truav.driver import run_episodes
    from truav.trainer import make_controller
    from world.env import World
    cfg = cell.config(base)
    seeds = list(cell.seeds)
    cb = None if on_episode is None else (lambda e, m: on_episode(len(seeds)))
    t0 = time.perf_counter()
    controller = make_controller(cell.scheme, cfg, seeds, True, None)
    world = World(cfg, len(seeds))
    train = run_episodes(cfg, seeds, controller, cell.episodes, cb, world=world)
    t_train = time.perf_counter() - t0
    # Under "persist" the swarm and the city go on: every scheme is evaluated in
    # the world its training ran in, its future drawn from the held-out streams.
    go_on = world if cfg.scenario.uav_start == "persist" else None
    ev = _evaluate(cell.scheme, cfg, seeds, controller, cell.eval_episodes, cb, go_on) if cell.eval_episodes else {}
    wall = time.perf_counter() - t0
    steps = len(seeds) * cell.episodes * cfg.scenario.steps_per_episode
    meta = {"train_s": t_train, "train_env_steps_per_s": steps / max(t_train, 1e-9)}
    if cell.scheme == "truav":  # how much of its state space each agent has seen (docs/reproduction.md ablation)
        from agents.qlearning import states_visited
        from truav import seeding
        rngs = [seeding.agent_rng(s, i) for s in seeds for i in range(cfg.scenario.n_uavs)]
        visited = states_visited(controller.learners.q, cfg.learner, rngs)
        meta.update(states_visited_mean=float(visited.mean()), states_visited_min=float(visited.min()),
                    states_visited_max=float(visited.max()), n_states=float(controller.encoder.n_states))
    return CellResult(cell, train, ev, wall, meta)


def save_cell(path: Path, result: CellResult) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    arrays = {f"train/{k}": v for k, v in result.train.items()}
    arrays.update({f"eval/{k}": v for k, v in result.eval.items()})
    arrays["seeds"] = np.asarray(result.cell.seeds)
    arrays["wall_s"] = np.asarray(result.wall_s)
    arrays.update({f"meta/{k}": np.asarray(v) for k, v in result.meta.items()})
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez_compressed(tmp, **arrays)
    os.replace(tmp, path)


def load_cell(path: Path, cell: Cell) -> CellResult:
    with np.load(path) as data:
        train = {k[6:]: data[k] for k in data.files if k.startswith("train/")}
        ev = {k[5:]: data[k] for k in data.files if k.startswith("eval/")}
        meta = {k[5:]: float(data[k]) for k in data.files if k.startswith("meta/")}
        wall = float(data["wall_s"])
    return CellResult(cell, train, ev, wall, meta)


def single_threaded() -> None:
    """One compute thread in this process: a pool of them already uses the cores."""
    try:
        import torch  # noqa: F401  (if installed)
        torch.set_num_threads(1)
    except ImportError:
        pass
    from agents.fused import set_threads
    set_threads(1)


def _worker(base: Config, out: Path, tasks, results) -> None:
    single_threaded()
    while True:
        try:
            cell = tasks.get(timeout=0.5)
        except queue_mod.Empty:
            continue
        if cell is None:
            return
        try:
            result = run_cell(base, cell, lambda n: results.put(("episode", n)))
            save_cell(cell_path(out, base, cell), result)
            results.put(("done", cell, result.wall_s))
        except BaseException as exc:  # report, then stop this worker
            results.put(("error", cell, f"{type(exc).__name__}: {exc}"))
            return


def pending_cells(base: Config, out: Path, cells: list[Cell]) -> list[Cell]:
    return [c for c in cells if not cell_path(out, base, c).is_file()]


def run_cells(base: Config, out: Path, cells: list[Cell], workers: int,
              on_episode: Callable[[int], None] | None = None,
              on_cell: Callable[[Cell, float], None] | None = None,
              executor: str = "local", address: str | None = None) -> None:
    """Run the unfinished cells on `workers` processes (in this process if 1),
    or as Ray tasks (executor "ray": on the cluster at `address`, or on a
    local instance of `workers` CPUs if None)."""
    todo = sorted(pending_cells(base, out, cells), key=lambda c: (COST_ORDER.get(c.scheme, 9), -c.speed))
    if not todo:
        return
    if executor == "ray":
        from truav.experiments.ray_executor import run_cells_on_ray
        run_cells_on_ray(base, out, todo, workers, address, on_episode, on_cell)
        return
    workers = max(1, min(workers, len(todo)))
    if workers == 1:
        for cell in todo:
            result = run_cell(base, cell, on_episode)
            save_cell(cell_path(out, base, cell), result)
            if on_cell:
                on_cell(cell, result.wall_s)
        return
    ctx = mp.get_context("fork")
    tasks, results = ctx.Queue(), ctx.Queue()
    for cell in todo:
        tasks.put(cell)
    for _ in range(workers):
        tasks.put(None)
    procs = [ctx.Process(target=_worker, args=(base, out, tasks, results), daemon=True) for _ in range(workers)]
    for p in procs:
        p.start()
    done = 0
    try:
        while done < len(todo):
            try:
                msg = results.get(timeout=2.0)
            except queue_mod.Empty:
                if not any(p.is_alive() for p in procs):
                    raise RuntimeError("all workers ended before the cells were done")
                continue
            if msg[0] == "episode":
                if on_episode:
                    on_episode(msg[1])
            elif msg[0] == "done":
                done += 1
                if on_cell:
                    on_cell(msg[1], msg[2])
            else:
                raise RuntimeError(f"cell {msg[1].scheme} at {msg[1].speed:g} m/s, seeds {msg[1].seeds} failed: {msg[2]}")
    finally:
        for p in procs:
            if p.is_alive():
                p.terminate()
            p.join(timeout=5)


def seed_chunks(seeds: list[int], per_cell: int) -> list[tuple[int, ...]]:
    per_cell = max(1, per_cell)
    return [tuple(seeds[i:i + per_cell]) for i in range(0, len(seeds), per_cell)]
