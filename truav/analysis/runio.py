"""Files of a training run: per-episode metrics (CSV), Q-tables (.npz), the
effective config (TOML). A run directory holds:

    config.toml     the effective configuration
    metrics.csv     one row per (seed, episode)
    qtables.npz     q (B, U, S, 16) float64 (what the learners compute, as in a swarm agent's
                    checkpoint; a float32 file of older versions still loads), seeds (B,)
    convergence.png sliding-window curves (see truav.analysis.plots)
    resume/         while a training is unfinished (interrupted): resume.json (seeds, scheme, the
                    chunks of seeds) and chunk<i>.pkl, each chunk's state at an episode boundary
                    (`truav train --resume` continues from it exactly); removed when it completes
"""

from __future__ import annotations

import csv
import json
import os
import shutil
import zipfile
import zlib
from pathlib import Path

import numpy as np

from truav.errors import UserError
from truav.config import Config, load_config, to_toml
from truav import jsonio
from truav.csvio import cell, cells
from truav.atomic import write_atomic

CHECKPOINT_EVERY_S = 60.0
"""Seconds between the checkpoints of a running `truav train` (its --checkpoint-every)."""

CONFIG_FILE = "config.toml"
METRICS_FILE = "metrics.csv"
QTABLE_FILE = "qtables.npz"
CONVERGENCE_FILE = "convergence.png"


RESUME_DIR = "resume"
RESUME_FILE = "resume.json"


class RunDirError(UserError):
    """A run directory is missing or incomplete (a user mistake, not a bug)."""


def fresh_dir(path: str | Path, force: bool = False) -> Path:
    """Create an output directory; refuse to overwrite a non-empty one unless force."""
    from truav.checks import check_out_dir, make_dir
    p = check_out_dir("--out", os.fspath(path))
    if p.exists() and any(p.iterdir()) and not force:
        raise RunDirError(f"--out {p}: exists and is not empty (choose another --out, or --force)")
    return make_dir("--out", p)


def atomic_write_bytes(path: Path, data: bytes) -> None:
    write_atomic(path, lambda f: f.write(data))


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
                w.writerow(cells(extra.values()) + [seed, e] + [cell(metrics[k][e, b], ".6g") for k in names])
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


def write_qtables(run: Path, seeds: list[int], q: np.ndarray, uav_pos: np.ndarray | None = None,
                  cfg: Config | None = None) -> None:
    """Q-tables and, if given, where the UAVs ended training (B, U, 2): a
    persist-trained swarm is evaluated from there (read_uav_positions); with ``cfg``, the scenario they
    were trained in (truav.analysis.policy_scenario)."""
    tmp = run / (QTABLE_FILE + ".tmp.npz")
    extra = {} if uav_pos is None else {"uav_pos": np.asarray(uav_pos, np.float64)}
    extra.update(_scenario(cfg))
    np.savez_compressed(tmp, q=np.asarray(q, np.float64), seeds=np.asarray(seeds), **extra)
    os.replace(tmp, run / QTABLE_FILE)


def _scenario(cfg: Config | None) -> dict[str, np.ndarray]:
    from truav.analysis.policy_scenario import RECORD_ARRAY, record_array
    return {} if cfg is None else {RECORD_ARRAY: record_array(cfg)}


NPZ_MAGIC = b"PK\x03\x04"
"""How every .npz file (a zip archive) starts."""


def check_npz(p: Path, what: str) -> None:
    """``p`` is an .npz archive, or a RunDirError naming what it should be: np.load would try another file
    (a CSV, a TOML) as a pickle and answer with its allow_pickle message."""
    try:
        with open(p, "rb") as f:
            head = f.read(len(NPZ_MAGIC))
    except OSError as exc:
        raise RunDirError(f"{p}: cannot read it ({exc.strerror or exc})") from None
    if head != NPZ_MAGIC and not head.startswith(b"\x93NUMPY"):
        kind = "an empty file" if not head else f"a {p.suffix.lstrip('.')} file" if p.suffix else "another kind of file"
        raise RunDirError(f"{p}: not {what} (an .npz archive); this is {kind}")


def qtable_file(path: str | Path) -> Path:
    """The Q-table file of a run directory, or the .npz file itself; RunDirError if there is none."""
    p = Path(path)
    if p.is_dir():
        p = p / QTABLE_FILE
    if not p.is_file():
        raise RunDirError(f"no Q-tables at {p}")
    return p


def read_qtables(path: str | Path) -> tuple[list[int], np.ndarray]:
    """(seeds, q (B, U, S, 16) float64) from a run directory or a .npz file."""
    p = qtable_file(path)
    check_npz(p, "a Q-table file of 'truav train'")
    # What np.load raises on an empty, truncated or foreign file: a user's file, not a bug.
    try:
        data = np.load(p, allow_pickle=False)
        if not isinstance(data, np.lib.npyio.NpzFile):
            raise RunDirError(f"{p}: a bare .npy array, not a Q-table file of 'truav train' (.npz with q and seeds)")
        with data:
            if not {"q", "seeds"} <= set(data.files):
                raise RunDirError(f"{p}: not a Q-table file of 'truav train' (needs arrays q and seeds, "
                                  f"has {', '.join(data.files) or 'none'})")
            seeds, q = data["seeds"], data["q"]
    except RunDirError:
        raise
    except (OSError, EOFError, ValueError, zipfile.BadZipFile, zlib.error) as exc:
        raise RunDirError(f"{p}: not a readable .npz file ({type(exc).__name__}: {exc})") from None
    if q.ndim != 4 or seeds.ndim != 1 or len(seeds) != q.shape[0] or not np.issubdtype(seeds.dtype, np.integer):
        raise RunDirError(f"{p}: q must be (seeds, UAVs, states, actions) with one integer seed per table, "
                          f"got q {q.shape} and seeds {seeds.shape}")
    if not np.issubdtype(q.dtype, np.floating) or not np.isfinite(q).all():
        raise RunDirError(f"{p}: q must hold finite floating-point values")
    return [int(s) for s in seeds], q.astype(np.float64)


def qtable_shapes(path: str | Path) -> tuple[int, tuple[int, ...]]:
    """(number of seeds, shape of q) from the array headers alone: the cheap check an agent
    process makes before it loads the tables (`truav-swarm up` has read them in full)."""
    p = qtable_file(path)
    check_npz(p, "a Q-table file of 'truav train'")
    try:
        with zipfile.ZipFile(p) as z:
            shapes = {}
            for name in ("q", "seeds"):
                with z.open(f"{name}.npy") as f:
                    version = np.lib.format.read_magic(f)
                    shapes[name] = np.lib.format.read_array_header_1_0(f)[0] if version == (1, 0) else \
                        np.lib.format.read_array_header_2_0(f)[0]
    except KeyError:
        raise RunDirError(f"{p}: not a Q-table file of 'truav train' (needs arrays q and seeds)") from None
    except (OSError, EOFError, ValueError, zipfile.BadZipFile, zlib.error) as exc:
        raise RunDirError(f"{p}: not a readable .npz file ({type(exc).__name__}: {exc})") from None
    q, seeds = shapes["q"], shapes["seeds"]
    if len(q) != 4 or len(seeds) != 1 or seeds[0] != q[0]:
        raise RunDirError(f"{p}: q must be (seeds, UAVs, states, actions) with one seed per table, "
                          f"got q {q} and seeds {seeds}")
    return seeds[0], q


def check_qtables(path: str | Path, shape: tuple[int, ...], cfg: Config, exact_uavs: bool = True) -> None:
    """Q-tables of ``shape`` (B, U, S, A) fit the scenario of ``cfg``: its UAVs (all of them,
    or at least, when not ``exact_uavs``), its state encoding and the action set."""
    from agents.state import StateEncoder
    from world.uavs import N_ACTIONS
    n_uavs = cfg.scenario.n_uavs
    n_states = StateEncoder(cfg).n_states
    if shape[1] < n_uavs or (exact_uavs and shape[1] != n_uavs):
        raise RunDirError(f"{path}: Q-tables hold {shape[1]} UAVs but the scenario has {n_uavs}")
    if tuple(shape[2:]) != (n_states, N_ACTIONS):
        raise RunDirError(f"{path}: Q-tables have {shape[2]} states x {shape[3]} actions but this "
                          f"config's state encoding needs {n_states} x {N_ACTIONS}")


def read_uav_positions(path: str | Path) -> np.ndarray | None:
    """(B, U, 2) UAV positions at the end of training, or None if the run has none."""
    p = Path(path)
    if p.is_dir():
        p = p / QTABLE_FILE
    with np.load(p) as data:
        return data["uav_pos"].astype(np.float64) if "uav_pos" in data.files else None


POLICY_FILE = "policy.npz"
"""`truav train --scheme central`: the trained actors of the centralized SAC, actor0..actor5
(weights and biases of its three layers, seed axis first) and seeds (B,)."""
ACTOR_ARRAYS = tuple(f"actor{i}" for i in range(6))


def write_policy(run: Path, seeds: list[int], params: dict[str, np.ndarray], cfg: Config | None = None) -> None:
    """The actors of a central run (agents.sac.BatchedSAC.state_dict, seed axis first); with ``cfg``, the
    scenario they were trained in."""
    tmp = run / (POLICY_FILE + ".tmp.npz")
    np.savez_compressed(tmp, seeds=np.asarray(seeds), **{k: np.asarray(params[k], np.float32) for k in ACTOR_ARRAYS},
                        **_scenario(cfg))
    os.replace(tmp, run / POLICY_FILE)


def read_policy(path: str | Path, index: int, cfg: Config) -> dict[str, np.ndarray]:
    """Seed ``index``'s actor (arrays with a seed axis of 1, for a one-env controller) from a run of
    `truav train --scheme central` or its policy.npz; RunDirError if it is none or does not fit ``cfg``."""
    from agents.central import STATE_DIM
    from world.uavs import N_ACTIONS
    p = Path(path)
    p = p / POLICY_FILE if p.is_dir() else p
    if not p.is_file():
        raise RunDirError(f"no trained controller at {p} (make one with `truav train --scheme central`)")
    check_npz(p, "a policy file of 'truav train --scheme central'")
    try:
        with np.load(p, allow_pickle=False) as data:
            if not {"seeds", *ACTOR_ARRAYS} <= set(data.files):
                raise RunDirError(f"{p}: not a policy file of 'truav train --scheme central' (needs seeds, "
                                  f"actor0..actor5)")
            seeds = data["seeds"]
            arrays = {k: data[k] for k in ACTOR_ARRAYS}
    except RunDirError:
        raise
    except (OSError, EOFError, ValueError, zipfile.BadZipFile, zlib.error) as exc:
        raise RunDirError(f"{p}: not a readable .npz file ({type(exc).__name__}: {exc})") from None
    if not 0 <= index < len(seeds):
        raise RunDirError(f"{p} holds {len(seeds)} policies (indices 0-{len(seeds) - 1}), not index {index}")
    u, h = cfg.scenario.n_uavs, cfg.central.hidden
    want = {"actor0": (u * STATE_DIM, h), "actor2": (h, h), "actor4": (h, u * N_ACTIONS)}
    for k, shape in want.items():
        if arrays[k].shape[1:] != shape:
            raise RunDirError(f"{p}: {k} is {arrays[k].shape[1:]}, this scenario ({u} UAVs, central.hidden {h}) "
                              f"needs {shape}")
    return {k: v[index:index + 1].astype(np.float32) for k, v in arrays.items()}


# -- an unfinished training's checkpoints (truav train --resume) ------------------------------------
def write_resume_info(run: Path, info: dict) -> None:
    d = Path(run) / RESUME_DIR
    d.mkdir(exist_ok=True)
    atomic_write_bytes(d / RESUME_FILE, jsonio.dumps(info, indent=1).encode())


def read_resume_info(run: Path) -> dict | None:
    """The unfinished training's resume.json, or None if ``run`` holds none (or an unreadable one)."""
    try:
        info = json.loads((Path(run) / RESUME_DIR / RESUME_FILE).read_text())
    except (OSError, ValueError):
        return None
    return info if isinstance(info, dict) else None


def write_chunk_state(run: Path, chunk: int, data: bytes) -> None:
    atomic_write_bytes(Path(run) / RESUME_DIR / f"chunk{chunk}.pkl", data)


def read_chunk_state(run: Path, chunk: int) -> bytes | None:
    """A chunk's pickled state, or None if it never checkpointed. Pickle runs code: it is read only
    from the run directory this command itself wrote, the one the user names with --out."""
    try:
        return (Path(run) / RESUME_DIR / f"chunk{chunk}.pkl").read_bytes()
    except FileNotFoundError:
        return None


def remove_resume_state(run: Path) -> None:
    shutil.rmtree(Path(run) / RESUME_DIR, ignore_errors=True)
