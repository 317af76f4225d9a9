"""Files of a training run: per-episode metrics (CSV), Q-tables (.npz), the
effective config (TOML). A run directory holds:

    config.toml     the effective configuration
    metrics.csv     one row per (seed, episode)
    qtables.npz     q (B, U, S, 16) float32, seeds (B,)
    convergence.png sliding-window curves (see truav.plots)
"""

from __future__ import annotations

import csv
import os
from pathlib import Path

import numpy as np

from truav.config import Config, load_config, to_toml

CONFIG_FILE = "config.toml"
METRICS_FILE = "metrics.csv"
QTABLE_FILE = "qtables.npz"
CONVERGENCE_FILE = "convergence.png"


class RunDirError(ValueError):
    """A run directory is missing or incomplete (a user mistake, not a bug)."""


def fresh_dir(path: str | Path, force: bool = False) -> Path:
    """Create an output directory; refuse to overwrite a non-empty one unless force."""
    p = Path(path)
    if p.exists() and any(p.iterdir()) and not force:
        raise RunDirError(f"{p} exists and is not empty (choose another --out, or --force)")
    p.mkdir(parents=True, exist_ok=True)
    return p


def atomic_write_bytes(path: Path, data: bytes) -> None:
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def write_config(run: Path, cfg: Config) -> None:
    atomic_write_bytes(run / CONFIG_FILE, to_toml(cfg).encode())


def read_config(run: Path) -> Config:
    p = Path(run) / CONFIG_FILE
    if not p.is_file():
        raise RunDirError(f"{run} has no {CONFIG_FILE}: is it a run directory of 'truav train'?")
    return load_config(p)


def write_metrics(path: Path, seeds: list[int], metrics: dict[str, np.ndarray], extra: dict[str, object] | None = None) -> None:
    """Rows (seed, episode, metrics...) from {name: (E, B)} arrays."""
    names = list(metrics)
    extra = extra or {}
    episodes = metrics[names[0]].shape[0]
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(list(extra) + ["seed", "episode"] + names)
        for b, seed in enumerate(seeds):
            for e in range(episodes):
                w.writerow(list(extra.values()) + [seed, e] + [f"{metrics[k][e, b]:.6g}" for k in names])
    os.replace(tmp, path)


def read_metrics(path: Path) -> tuple[list[int], dict[str, np.ndarray]]:
    """Inverse of write_metrics: seeds and {name: (E, B)}."""
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    if not rows:
        raise RunDirError(f"{path} has no rows")
    seeds = sorted({int(r["seed"]) for r in rows}, key=[int(r["seed"]) for r in rows].index)
    episodes = max(int(r["episode"]) for r in rows) + 1
    names = [k for k in rows[0] if k not in ("seed", "episode")]
    col = {s: i for i, s in enumerate(seeds)}
    out = {k: np.full((episodes, len(seeds)), np.nan) for k in names}
    for r in rows:
        for k in names:
            try:
                out[k][int(r["episode"]), col[int(r["seed"])]] = float(r[k])
            except ValueError:
                pass
    return seeds, out


def write_qtables(run: Path, seeds: list[int], q: np.ndarray) -> None:
    tmp = run / (QTABLE_FILE + ".tmp.npz")
    np.savez_compressed(tmp, q=q.astype(np.float32), seeds=np.asarray(seeds))
    os.replace(tmp, run / QTABLE_FILE)


def read_qtables(path: str | Path) -> tuple[list[int], np.ndarray]:
    """(seeds, q (B, U, S, 16) float64) from a run directory or a .npz file."""
    p = Path(path)
    if p.is_dir():
        p = p / QTABLE_FILE
    if not p.is_file():
        raise RunDirError(f"no Q-tables at {p}")
    with np.load(p) as data:
        return [int(s) for s in data["seeds"]], data["q"].astype(np.float64)
