"""The file of a run of `truav train --agent NAME`: the agent's learned state (agents.api).

    agent.npz   agent (its name as given, 0-d str), api_version, seeds (B,), uav_pos (B, U, 2) where the
                UAVs ended, scenario (what the policy is tied to: truav.analysis.policy_scenario) and state.<key>
                (B, U, ...) for each key of the agents' state_dict
"""

from __future__ import annotations

import os
import zipfile
import zlib
from pathlib import Path

import numpy as np

from truav.analysis import policy_scenario
from truav.config import Config
from truav.analysis.runio import RunDirError

AGENT_FILE = "agent.npz"
STATE_PREFIX = "state."
MAX_AGENT_FILE_BYTES = 4 << 30
"""What an agent file may declare its arrays to hold, uncompressed: a file from elsewhere is read only when
it declares at most this (a few kB compressed can declare gigabytes)."""


def write_agent_state(run: Path, name: str, api_version: int, seeds: list[int], state: dict[str, np.ndarray],
                      uav_pos: np.ndarray | None, cfg: Config) -> None:
    tmp = run / (AGENT_FILE + ".tmp.npz")
    extra = {} if uav_pos is None else {"uav_pos": np.asarray(uav_pos, np.float64)}
    extra[policy_scenario.RECORD_ARRAY] = policy_scenario.record_array(cfg)
    np.savez_compressed(tmp, agent=np.array(name), api_version=np.array(api_version), seeds=np.asarray(seeds),
                        **extra, **{STATE_PREFIX + k: np.asarray(v) for k, v in state.items()})
    os.replace(tmp, run / AGENT_FILE)


def agent_file(path: str | Path) -> Path:
    """The agent file of a run directory, or the file itself."""
    p = Path(path)
    return p / AGENT_FILE if p.is_dir() else p


def is_agent_run(path: str | Path) -> bool:
    p = Path(path)
    return (p / AGENT_FILE).is_file() if p.is_dir() else p.name == AGENT_FILE


def _declared_bytes(p: Path) -> int:
    with zipfile.ZipFile(p) as z:
        return sum(i.file_size for i in z.infolist())


def read_agent_state(path: str | Path) -> tuple[str, list[int], dict[str, np.ndarray], np.ndarray | None]:
    """(agent name, seeds, state {key: (B, U, ...)}, uav_pos or None) of a run directory or its agent.npz."""
    p = agent_file(path)
    if not p.is_file():
        raise RunDirError(f"{p}: no such agent file (a run directory of 'truav train --agent NAME' holds {AGENT_FILE})")
    try:
        if (declared := _declared_bytes(p)) > MAX_AGENT_FILE_BYTES:
            raise RunDirError(f"{p}: declares {declared / 2**30:.1f} GiB of arrays, more than an agent file may "
                              f"({MAX_AGENT_FILE_BYTES / 2**30:.0f} GiB); not read")
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


def agent_start_states(path: str | Path, name: str, n_uavs: int, index: int = 0) -> list[dict[str, np.ndarray]]:
    """Each UAV's state_dict, for a swarm of ``n_uavs`` flown by agent ``name``, from seed ``index`` of a run
    of `truav train --agent NAME` (a RunDirError says what does not fit)."""
    got, seeds, state, _ = read_agent_state(path)
    if got != name:
        raise RunDirError(f"{path}: was trained by agent {got[:100]!r}, not {name[:100]!r} (fly it with "
                          f"--agent {got[:100]})")
    if not 0 <= index < len(seeds):
        raise RunDirError(f"{path}: holds {len(seeds)} seed(s); index {index} is not one of them")
    uavs = sorted({v.shape[1] for v in state.values()})
    if uavs and uavs != [n_uavs]:
        raise RunDirError(f"{path}: its agent state holds {', '.join(map(str, uavs))} UAV(s), this swarm flies {n_uavs}")
    return [{k: np.array(v[index, u]) for k, v in state.items()} for u in range(n_uavs)]

