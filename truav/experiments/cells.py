"""One experiment cell: one scheme at one setting (UAV speed, swarm and traffic
size) for a chunk of seeds, run as one batch: training for `episodes`
episodes, then `eval_episodes` episodes of the trained policy (greedy) on
held-out traffic (world seed + EVAL_SEED_OFFSET). Its results go to
`<out>/cells/<key>.npz`, written atomically; the key names the scheme,
setting, seeds and budget and hashes the cell's effective config.

Where cells run (a pool of processes, Ray tasks) is truav.experiments.runner
and truav.experiments.ray_executor; both use what is here.
"""

from __future__ import annotations

import hashlib
import os
import re
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from truav.config import Config, to_dict
from truav.seeding import EVAL_SEED_OFFSET

CELLS_DIR = "cells"
BUILTIN_SCHEMES = ("truav", "central", "patrol", "patrol_ctrl")
"""The experiments' own schemes; any other name in --schemes is an agents.api class (truav.analysis.agent_loader)."""


def controller_kind(scheme: str) -> str:
    """The trainer's controller kind (trainer.make_controller) of an experiment scheme."""
    from truav.analysis.agent_loader import AGENT_KIND_PREFIX
    return scheme if scheme in BUILTIN_SCHEMES else AGENT_KIND_PREFIX + scheme
UNUSED_SECTIONS = {"truav": ("patrol", "central"), "patrol": ("learner", "central"), "central": ("patrol",),
                   "patrol_ctrl": ("learner",),
                   "random": ("learner", "patrol", "central"), "hover": ("learner", "patrol", "central")}
"""Config sections a scheme never reads: left out of its cells' keys, so that
changing, say, the SAC settings does not re-run finished TRUAV cells."""
KEYED_ONLY_IF_CHANGED = ("federated",)
"""Sections added after cells were run, left out of a cell's key while at their defaults (which change no
number), so that the cells of earlier runs keep their keys (--report-only and resuming still find them)."""


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
        from agents.spread_agent import with_sensing  # the heuristic flies with its sensing on
        return with_sensing(self.scheme, base.replace(**sections))

    def key(self, base: Config) -> str:
        cfg = self.config(base)
        defaults = to_dict(Config())
        used = {k: v for k, v in to_dict(cfg).items() if k not in UNUSED_SECTIONS.get(self.scheme, ())
                and not (k in KEYED_ONLY_IF_CHANGED and v == defaults[k])}
        digest = hashlib.sha256(f"{used!r}|{self.eval_episodes}".encode()).hexdigest()[:10]
        sc = cfg.scenario
        name = re.sub(r"[^A-Za-z0-9_.-]", "-", self.scheme)  # an agent class's name holds ':'
        return (f"{name}_v{self.speed:g}_u{sc.n_uavs}_n{sc.n_vehicles}_s{self.seeds[0]}-{self.seeds[-1]}"
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
    from truav.analysis.driver import run_episodes  # here, like the trainer: the CLI's parser loads this module
    from truav.analysis.trainer import make_controller
    eval_seeds = [s + EVAL_SEED_OFFSET for s in seeds]
    if scheme == "truav":
        ctrl = make_controller("truav", cfg, eval_seeds, False, controller.learners.q)
    elif scheme == "central" or scheme not in BUILTIN_SCHEMES:
        # the trained actor (an agent class: its trained instances, told train=False), greedy
        controller.train = False
        ctrl = controller
    else:
        ctrl = make_controller(scheme, cfg, eval_seeds, False, None)
    if world is not None:
        world.rngs = [seeding.world_rng(s) for s in eval_seeds]
    return run_episodes(cfg, eval_seeds, ctrl, episodes, on_episode, world=world)


def run_cell(base: Config, cell: Cell, on_episode: Callable[[int], None] | None = None) -> CellResult:
    """Train then evaluate one cell in this process."""
    from truav.analysis.driver import run_episodes
    from truav.analysis.sumo_traffic import make_world
    from truav.analysis.trainer import make_controller
    cfg = cell.config(base)
    seeds = list(cell.seeds)
    cb = None if on_episode is None else (lambda e, m: on_episode(len(seeds)))
    t0 = time.perf_counter()
    controller = make_controller(controller_kind(cell.scheme), cfg, seeds, True, None)
    world = make_world(cfg, len(seeds))
    train = run_episodes(cfg, seeds, controller, cell.episodes, cb, world=world)
    t_train = time.perf_counter() - t0
    # Under "persist" the swarm and the city go on: every scheme is evaluated in
    # the world its training ran in, its future drawn from the held-out streams.
    go_on = world if cfg.scenario.uav_start == "persist" else None
    ev = _evaluate(cell.scheme, cfg, seeds, controller, cell.eval_episodes, cb, go_on) if cell.eval_episodes else {}
    wall = time.perf_counter() - t0
    steps = len(seeds) * cell.episodes * cfg.scenario.steps_per_episode
    meta = {"train_s": t_train, "train_env_steps_per_s": steps / max(t_train, 1e-9)}
    if cell.scheme == "truav":  # how much of its state space each agent has seen (docs/results/reproduction.md ablation)
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
