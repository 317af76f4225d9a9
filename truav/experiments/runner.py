"""Resumable experiment cells on every core.

An experiment is a list of cells (truav.experiments.cells: a cell is one
scheme at one setting for a chunk of seeds, trained then evaluated, its
results in `<out>/cells/<key>.npz`), so a restarted run skips exactly the
cells already finished with the same inputs. Worker processes (fork) take
cells from a queue, one at a time; or, with the Ray executor (truav.experiments.ray_executor), Ray tasks on a
local instance or a cluster run them and return their results to this
process, which writes the cell files.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import queue as queue_mod
from pathlib import Path
from typing import Callable

from truav.config import Config
from truav.experiments.cells import (  # noqa: F401  (re-exported: the cell is named from here too)
    CELLS_DIR, UNUSED_SECTIONS, Cell, CellResult, cell_path, load_cell, run_cell, save_cell, single_threaded)
from truav.experiments.ray_executor import run_cells_on_ray
from truav.stopping import die_with_parent, is_interrupt
from truav.seeding import EVAL_SEED_OFFSET  # noqa: F401

COST_ORDER = {"central": 0, "truav": 1, "patrol": 2, "patrol_ctrl": 3, "spread": 4, "claim": 5, "ppo-claim": 6}
"""Expensive schemes start first, so the last cells running are the short ones."""


def _worker(parent_pid: int, base: Config, out: Path, tasks, results) -> None:
    die_with_parent(parent_pid)
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
            if is_interrupt(exc):  # Ctrl-C reaches the whole process group: the parent says it, once
                return
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
    procs = [ctx.Process(target=_worker, args=(os.getpid(), base, out, tasks, results), daemon=True) for _ in range(workers)]
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
