"""The file of a run of `truav train --agent NAME`: the agent's learned state (agents.api).

    agent.npz   agent (its name as given, 0-d str), api_version, seeds (B,), uav_pos (B, U, 2) where the
                UAVs ended, and state.<key> (B, U, ...) for each key of the agents' state_dict
"""

from __future__ import annotations

import os
import zipfile
import zlib
from pathlib import Path

import numpy as np

from truav.analysis.runio import RunDirError

AGENT_FILE = "agent.npz"
STATE_PREFIX = "state."


def write_agent_state(run: Path, name: str, api_version: int, seeds: list[int], state: dict[str, np.ndarray],
                      uav_pos: np.ndarray | None) -> None:
    tmp = run / (AGENT_FILE + ".tmp.npz")
    extra = {} if uav_pos is None else {"uav_pos": np.asarray(uav_pos, np.float64)}
    np.savez_compressed(tmp, agent=np.array(name), api_version=np.array(api_version), seeds=np.asarray(seeds),
                        **extra, **{STATE_PREFIX + k: np.asarray(v) for k, v in state.items()})
    os.replace(tmp, run / AGENT_FILE)


def is_agent_run(path: str | Path) -> bool:
    p = Path(path)
    return (p / AGENT_FILE).is_file() if p.is_dir() else p.name == AGENT_FILE


def read_agent_state(path: str | Path) -> tuple[str, list[int], dict[str, np.ndarray], np.ndarray | None]:
    """(agent name, seeds, state {key: (B, U, ...)}, uav_pos or None) of a run directory or its agent.npz."""
    p = Path(path)
    p = p / AGENT_FILE if p.is_dir() else p
    try:
        with np.load(p, allow_pickle=False) as data:
            if not {"agent", "seeds"} <= set(data.files):
                raise RunDirError(f"{p}: not an agent file of 'truav train --agent' (needs agent and seeds)")
            name, seeds = str(data["agent"]), data["seeds"]
            state = {k[len(STATE_PREFIX):]: data[k] for k in data.files if k.startswith(STATE_PREFIX)}
            uav_pos = data["uav_pos"].astype(np.float64) if "uav_pos" in data.files else None
    except RunDirError:
        raise
    except (OSError, EOFError, ValueError, zipfile.BadZipFile, zlib.error) as exc:
        raise RunDirError(f"{p}: not a readable .npz file ({type(exc).__name__}: {exc})") from None
    if seeds.ndim != 1 or not np.issubdtype(seeds.dtype, np.integer):
        raise RunDirError(f"{p}: seeds must be one integer per seed")
    for k, v in state.items():
        if v.ndim < 2 or v.shape[0] != len(seeds):
            raise RunDirError(f"{p}: state.{k} is shaped {v.shape}, not (seeds {len(seeds)}, UAVs, ...)")
    return name, [int(s) for s in seeds], state, uav_pos
