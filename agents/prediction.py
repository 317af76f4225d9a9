"""Prediction: where a UAV expects the traffic to be, from what it has seen.

Each UAV keeps its own map of the vehicle density it observed, over
predict_cells x predict_cells cells of the area: every observation
multiplies the map by predict_decay and adds the vehicles in range to the
cell the UAV is in. The state factor (agents.state.encode_one) is the
direction of the map's densest cell, in predict_sectors sectors
(world.network.sector), as 1 + the sector; 0 when that cell is the UAV's own
or nothing has been seen yet. Only the UAV's own observations enter the map;
it lives as long as the agent (across episodes), in the trainer's controller
and in a swarm agent process alike, both calling the functions below.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from truav import kernel_cache  # noqa: F401, I001 - numba's cache set up before numba loads a kernel
from numba import njit

from truav.config import Config
from world.network import sector


class PredictParams(NamedTuple):
    cells: int
    """Cells per side of the map (0 with prediction off: no map)."""
    cell_m: float
    decay: float
    sectors: int
    """Direction sectors of the state factor (0: prediction off)."""


def predict_params(cfg: Config) -> PredictParams:
    lc = cfg.learner
    cells = int(lc.predict_cells) if lc.predict_sectors > 0 else 0
    return PredictParams(cells, cfg.scenario.area_m / max(lc.predict_cells, 1), float(lc.predict_decay),
                         int(lc.predict_sectors))


def new_maps(p: PredictParams, *shape: int) -> np.ndarray:
    """Empty maps (*shape, cells * cells); zero cells with prediction off."""
    return np.zeros((*shape, p.cells * p.cells))


@njit(cache=True)
def _cell(v, p):
    return min(max(int(v // p.cell_m), 0), p.cells - 1)


@njit(cache=True)
def predict_one(density_map, x, y, in_range, p):
    """Add one observation (the UAV at (x, y) sees in_range vehicles) to its
    map (cells * cells,), in place, and return the state factor: 1 + the
    sector of the densest cell's centre seen from (x, y), or 0 (own cell,
    nothing seen, or prediction off)."""
    if p.sectors == 0:
        return 0
    density_map *= p.decay
    own = _cell(x, p) * p.cells + _cell(y, p)
    density_map[own] += in_range
    best, best_k = 0.0, -1
    for k in range(density_map.size):
        if density_map[k] > best:  # the first of equal cells
            best, best_k = density_map[k], k
    if best_k < 0 or best_k == own:
        return 0
    cx = (best_k // p.cells + 0.5) * p.cell_m
    cy = (best_k % p.cells + 0.5) * p.cell_m
    return 1 + sector(cx - x, cy - y, p.sectors)


@njit(cache=True)
def predict_batch(maps, pos, in_range, p):
    """predict_one for (B, U) agents: maps (B, U, cells * cells), pos (B, U, 2), in_range (B, U)."""
    n_env, n_uav = in_range.shape
    out = np.zeros((n_env, n_uav), np.int64)
    for b in range(n_env):
        for u in range(n_uav):
            out[b, u] = predict_one(maps[b, u], pos[b, u, 0], pos[b, u, 1], in_range[b, u], p)
    return out
