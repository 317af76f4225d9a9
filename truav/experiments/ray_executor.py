"""Experiment cells as Ray tasks, for sweeps that outgrow one machine.

    truav experiment velocity --executor ray                        # a local Ray instance, --workers CPUs
    truav experiment velocity --executor ray --address HOST:6379    # an existing cluster (`ray start --head`)

Each cell is one task (one CPU). Its result comes back to this process,
which writes the cell file under --out as it arrives, so --out needs no
shared storage and an interrupted sweep resumes like a local one. Every node
needs this package installed (`pip install -e '.[ray]'`, same version).
The swarm fault sweep (`experiment faults`) sends each point as a task too;
see run_points_on_ray.
"""

from __future__ import annotations

from contextlib import contextmanager
from pathlib import Path
from typing import Callable

from truav.config import Config
from truav.experiments.cells import Cell, CellResult, cell_path, run_cell, save_cell, single_threaded


def _cell_task(base: Config, cell: Cell) -> CellResult:
    single_threaded()
    return run_cell(base, cell)


@contextmanager
def ray_session(workers: int, address: str | None):
    """Connect to the cluster at `address`, or start a local instance of
    `workers` CPUs (loopback, no dashboard) and stop it afterwards."""
    import ray
    if ray.is_initialized():
        yield ray
        return
    if address:
        ray.init(address=address, log_to_driver=False)
    else:
        # address="local": an instance of its own, even beside a cluster already running on this machine
        # (without it ray.init joins that cluster, another run's or another user's, and refuses num_cpus)
        ray.init(address="local", num_cpus=max(1, workers), include_dashboard=False, _node_ip_address="127.0.0.1",
                 log_to_driver=False)
    try:
        yield ray
    finally:
        ray.shutdown()


def run_cells_on_ray(base: Config, out: Path, todo: list[Cell], workers: int, address: str | None,
                     on_episode: Callable[[int], None] | None = None,
                     on_cell: Callable[[Cell, float], None] | None = None) -> None:
    """Run `todo` as Ray tasks; write each result's cell file as it returns."""
    with ray_session(workers, address) as ray:
        task = ray.remote(num_cpus=1, max_retries=0)(_cell_task)
        cell_of = {task.remote(base, cell): cell for cell in todo}
        pending = list(cell_of)
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            cell = cell_of[ready[0]]
            try:
                result = ray.get(ready[0])
            except Exception as exc:  # a task's own error, re-raised by Ray
                cause = getattr(exc, "cause", None) or exc
                raise RuntimeError(f"cell {cell.scheme} at {cell.speed:g} m/s, seeds {cell.seeds} failed: "
                                   f"{type(cause).__name__}: {cause}") from None
            save_cell(cell_path(out, base, cell), result)
            if on_episode:
                on_episode(cell.env_episodes)
            if on_cell:
                on_cell(cell, result.wall_s)


def run_points_on_ray(run_point: Callable, points: list, workers: int, address: str | None,
                      cpus_per_task: int = 1) -> list:
    """run_point(point) for each point as a Ray task of `cpus_per_task` CPUs
    (the swarm fault sweep); returns their results in order."""
    with ray_session(workers, address) as ray:
        task = ray.remote(num_cpus=cpus_per_task, max_retries=0)(run_point)
        return ray.get([task.remote(p) for p in points])
