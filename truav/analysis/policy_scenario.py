"""A trained policy carries the scenario it was trained in; flying it in another one is refused.

`truav train` stores :func:`record` of its config beside the tables (array ``scenario`` of qtables.npz or
policy.npz, a JSON string). A Q-table's states mean something only under the encoding, speed, grid and
traffic it was learned in: flown at another speed or with another state design it acts on states it never
saw, and its results say nothing about the design. :func:`check` compares the record with the run's
config: a difference is one line naming it (a UserError, exit 2) unless the user opts in
(``--allow-scenario-mismatch``), and then the run records it (:func:`as_json`).
"""

from __future__ import annotations

import json
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from truav import jsonio
from truav.config import Config
from truav.errors import UserError

RECORD_ARRAY = "scenario"
"""The array of qtables.npz / policy.npz that holds the record."""
ALLOW_FLAG = "--allow-scenario-mismatch"

KEYS = (
    # speed, UAVs, grid
    "scenario.uav_speed_mps", "scenario.n_uavs", "scenario.area_m", "learner.grid_cells", "scenario.comm_range_m",
    "scenario.mobility", "roads.block_m",
    # the state design (agents/state.py)
    "learner.density_edges", "learner.queue_edges", "learner.neighbour_edges_m", "learner.rsu_edges_m",
    "learner.neighbour_sectors", "learner.sense_range_m", "learner.sense_sectors", "learner.predict_sectors",
    "learner.predict_cells",
    # what the presets set (truav.presets)
    "scenario.uav_start", "roads.hotspot_move_prob", "roads.hotspot_step_blocks", "learner.geofence",
    "central.geofence",
)
"""What a trained table is tied to: its speed, UAV count and grid, the state design, and what the presets
set. Learning rates, episode length and reward weights are not (they shape how it was learned, not what
its states mean)."""


def record(cfg: Config) -> dict:
    """{section.key: value} of :data:`KEYS` in ``cfg`` (tuples as lists, as JSON reads them back)."""
    out = {}
    for key in KEYS:
        section, name = key.split(".")
        value = getattr(getattr(cfg, section), name)
        out[key] = list(value) if isinstance(value, tuple) else value
    return out


def record_array(cfg: Config) -> np.ndarray:
    """The record as the 0-d string array stored in the .npz (loads without pickle)."""
    return np.array(jsonio.dumps(record(cfg), sort_keys=True))


def read_record(path: str | Path) -> dict | None:
    """The record of a qtables.npz / policy.npz; None when its tables are older than the record (or it is
    unreadable: the table readers say why)."""
    try:
        with np.load(path, allow_pickle=False) as data:
            if RECORD_ARRAY not in data.files:
                return None
            text = str(data[RECORD_ARRAY])
        got = json.loads(text)
    except (OSError, EOFError, ValueError, zipfile.BadZipFile, zlib.error):
        return None
    return got if isinstance(got, dict) else None


def _say(key: str, trained, now) -> str:
    if key == "scenario.uav_speed_mps":
        return f"was trained at {trained:g} m/s; this run flies at {now:g} m/s"
    if key == "scenario.n_uavs":
        return f"was trained with {trained} UAVs; this run has {now}"
    return f"was trained with {key} = {trained}; this run has {now}"


def differences(rec: dict, cfg: Config, exact_uavs: bool = True) -> list[str]:
    """What differs between the record and ``cfg``, each as "was trained ...; this run ..." (keys the
    record does not hold, from an older version, are not compared). Not ``exact_uavs``: flying fewer UAVs
    than were trained (the first tables) is no difference."""
    now = record(cfg)
    out = []
    for key in KEYS:
        if key not in rec:
            continue
        trained, current = rec[key], now[key]
        if key == "scenario.n_uavs" and not exact_uavs and isinstance(trained, int) and current <= trained:
            continue
        if trained != current:
            out.append(_say(key, trained, current))
    return out


@dataclass
class Fit:
    """How a trained policy fits the run that flies it."""

    path: str
    status: str
    """"matches", "not recorded" (older tables), or "mismatch allowed" (flown anyway, by the user's choice)."""
    differences: tuple[str, ...] = ()

    def line(self) -> str | None:
        """What the run's summary says (None when it matches)."""
        if self.status == "not recorded":
            return f"policy {self.path}: its training scenario is not recorded (tables of an older truav train)"
        if self.status == "mismatch allowed":
            return f"policy {self.path} flown outside its training scenario ({ALLOW_FLAG}): it " + \
                "; it ".join(self.differences)
        return None

    def as_json(self) -> dict:
        return {"path": self.path, "status": self.status, "differences": list(self.differences)}


def check(flag: str, path: str | Path, npz: str | Path, cfg: Config, allow: bool = False,
          exact_uavs: bool = True) -> Fit:
    """The fit of the policy file ``npz`` (given as ``flag path``) to ``cfg``; a difference is a UserError
    naming it unless ``allow``."""
    rec = read_record(npz)
    if rec is None:
        return Fit(str(path), "not recorded")
    diffs = differences(rec, cfg, exact_uavs)
    if not diffs:
        return Fit(str(path), "matches")
    if not allow:
        raise UserError(f"{flag} {path} ".lstrip() + "; it ".join(diffs) + f" ({ALLOW_FLAG} to fly it anyway)")
    return Fit(str(path), "mismatch allowed", tuple(diffs))


def add_allow_arg(p) -> None:
    """The opt-in flag, on an argparse parser of a command that flies a trained policy."""
    p.add_argument(ALLOW_FLAG, action="store_true",
                   help="fly a trained policy in another scenario than it was trained in (speed, UAVs, grid, "
                        "state design, preset); the summary records the difference")


__all__ = ["add_allow_arg", "ALLOW_FLAG", "Fit", "KEYS", "RECORD_ARRAY", "check", "differences", "read_record", "record",
           "record_array"]
