"""Local state of a TRUAV agent, discretised to one table index.

The paper's four locally observable categories plus a fine spatial grid:

- grid cell of the UAV (grid_cells x grid_cells over the area),
- vehicle density in range (ordinal level, `density_edges`),
- packets queued at the connected vehicles (`queue_edges`),
- distance to the nearest neighbour UAV, from beacons (`neighbour_edges_m`),
- distance to the nearest RSU, RSU sites being known a priori (`rsu_edges_m`).

Selectable refinements (all off by default, the index then being
exactly the five factors above):

- direction of the nearest neighbour in `neighbour_sectors` sectors,
- the densest direction beyond comm range, sensed by the world
  (`sense_range_m`, `sense_sectors`; world.network.DENSEST);
- the direction of the densest cell of the UAV's own decayed
  density map, where it expects traffic (`predict_sectors`; agents/prediction.py).

A level is the number of edges <= the value, so k edges give k+1 levels.
Everything here uses only what one UAV senses itself or hears in beacons.
Kernels are numba-compiled loops over (B, U) agents.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import numpy as np
from truav import kernel_cache  # noqa: F401, I001 - numba's cache set up before numba loads a kernel
from numba import njit

from truav.config import Config
from world.network import rsu_positions, sector


@njit(cache=True)
def neighbour_one(x, y, peers, heard, comm_range_m):
    """One UAV at (x, y): nearest heard neighbour distance (m, inf if none) and
    coverage overlap, from peers (M, 2) and heard (M,) (see neighbour_features)."""
    nearest, overlap = np.inf, 0.0
    for m in range(heard.size):
        if not heard[m]:
            continue
        d = np.sqrt((peers[m, 0] - x) ** 2 + (peers[m, 1] - y) ** 2)
        nearest = min(nearest, d)
        c = min(d / (2.0 * comm_range_m), 1.0)
        if c < 1.0:  # at c = 1 the lens term is (2/pi) (acos(1) - 1 sqrt(0)) = +0.0 exactly: adds nothing
            overlap += (2.0 / np.pi) * (np.arccos(c) - c * np.sqrt(1.0 - c * c))
    return nearest, overlap


@njit(cache=True)
def neighbour_features(own, peers, heard, comm_range_m):
    """Nearest heard neighbour distance (m, inf if none) and coverage overlap.

    own (B, U, 2); peers (B, U, M, 2) positions from beacons; heard (B, U, M)
    which of them were heard. Overlap is the sum over heard neighbours of the
    lens area two coverage discs of radius R share, as a fraction of one disc
    (0 beyond 2R apart, 1 when co-located). Returns two (B, U) arrays."""
    n_env, n_uav, _ = heard.shape
    nearest = np.full((n_env, n_uav), np.inf)
    overlap = np.zeros((n_env, n_uav))
    for b in range(n_env):
        for u in range(n_uav):
            nearest[b, u], overlap[b, u] = neighbour_one(own[b, u, 0], own[b, u, 1], peers[b, u], heard[b, u],
                                                         comm_range_m)
    return nearest, overlap


@njit(cache=True)
def nearest_sector_one(x, y, peers, heard, sectors):
    """Direction sector (world.network.sector) of the nearest heard neighbour
    of the UAV at (x, y), the first of equally near ones; 0 if none is heard."""
    best, best_m = np.inf, -1
    for m in range(heard.size):
        if heard[m]:
            d = np.sqrt((peers[m, 0] - x) ** 2 + (peers[m, 1] - y) ** 2)
            if d < best:
                best, best_m = d, m
    if best_m < 0:
        return 0
    return sector(peers[best_m, 0] - x, peers[best_m, 1] - y, sectors)


@njit(cache=True)
def nearest_sectors(own, peers, heard, sectors):
    """nearest_sector_one for (B, U) agents (arrays as in neighbour_features)."""
    n_env, n_uav, _ = heard.shape
    out = np.zeros((n_env, n_uav), np.int64)
    for b in range(n_env):
        for u in range(n_uav):
            out[b, u] = nearest_sector_one(own[b, u, 0], own[b, u, 1], peers[b, u], heard[b, u], sectors)
    return out


def all_peers(pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every UAV of an env hears every other: peers (B, U, U, 2), heard (B, U, U)."""
    b, u, _ = pos.shape
    return np.repeat(pos[:, None, :, :], u, axis=1), _others_mask(b, u)


@functools.lru_cache(maxsize=16)
def _others_mask(b: int, u: int) -> np.ndarray:
    mask = np.repeat(~np.eye(u, dtype=np.bool_)[None], b, axis=0)
    mask.flags.writeable = False
    return mask


class StateParams(NamedTuple):
    cells: int
    cell_m: float
    density_edges: np.ndarray
    queue_edges: np.ndarray
    neighbour_edges: np.ndarray
    rsu_edges: np.ndarray
    rsu: np.ndarray  # (K, 2)
    neighbour_sectors: int  # 0: no direction factor
    sense_levels: int  # 1: no sensing factor, else sense_sectors + 1
    predict_levels: int  # 1: no prediction factor, else predict_sectors + 1


@njit(cache=True)
def _level(edges, value):
    level = 0
    for e in edges:
        if value >= e:
            level += 1
    return level


@njit(cache=True)
def encode_one(x, y, vehicles_in_range, queued, nearest_neighbour_m, neighbour_sector, densest_sector,
               predicted_sector, p):
    """One agent's state index from its position and features; the sector
    arguments are ignored (may be 0) when their factor is off."""
    cx = min(max(int(x // p.cell_m), 0), p.cells - 1)
    cy = min(max(int(y // p.cell_m), 0), p.cells - 1)
    rsu_d = np.inf
    for k in range(p.rsu.shape[0]):
        rsu_d = min(rsu_d, np.sqrt((x - p.rsu[k, 0]) ** 2 + (y - p.rsu[k, 1]) ** 2))
    index = cx * p.cells + cy
    index = index * (p.density_edges.size + 1) + _level(p.density_edges, vehicles_in_range)
    index = index * (p.queue_edges.size + 1) + _level(p.queue_edges, queued)
    index = index * (p.neighbour_edges.size + 1) + _level(p.neighbour_edges, nearest_neighbour_m)
    index = index * (p.rsu_edges.size + 1) + _level(p.rsu_edges, rsu_d)
    if p.neighbour_sectors > 0:
        index = index * p.neighbour_sectors + min(max(neighbour_sector, 0), p.neighbour_sectors - 1)
    if p.sense_levels > 1:
        index = index * p.sense_levels + min(max(densest_sector, 0), p.sense_levels - 1)
    if p.predict_levels > 1:
        index = index * p.predict_levels + min(max(predicted_sector, 0), p.predict_levels - 1)
    return index


@njit(cache=True)
def encode_states(pos, vehicles_in_range, queued, nearest_neighbour_m, neighbour_sector, densest_sector,
                  predicted_sector, p):
    """State indices (B, U) from own position (B, U, 2) and (B, U) features."""
    n_env, n_uav = vehicles_in_range.shape
    out = np.empty((n_env, n_uav), np.int64)
    for b in range(n_env):
        for u in range(n_uav):
            out[b, u] = encode_one(pos[b, u, 0], pos[b, u, 1], vehicles_in_range[b, u], queued[b, u],
                                   nearest_neighbour_m[b, u], neighbour_sector[b, u], densest_sector[b, u],
                                   predicted_sector[b, u], p)
    return out


class StateEncoder:
    """Maps local features to a state index in [0, n_states)."""

    def __init__(self, cfg: Config):
        lc, sc = cfg.learner, cfg.scenario
        sense_levels = lc.sense_sectors + 1 if lc.sense_range_m > 0.0 else 1
        self.params = StateParams(lc.grid_cells, sc.area_m / lc.grid_cells, np.array(lc.density_edges),
                                  np.array(lc.queue_edges), np.array(lc.neighbour_edges_m),
                                  np.array(lc.rsu_edges_m), rsu_positions(cfg), int(lc.neighbour_sectors),
                                  int(sense_levels), int(lc.predict_sectors) + 1)
        p = self.params
        self.levels = (p.cells * p.cells, p.density_edges.size + 1, p.queue_edges.size + 1,
                       p.neighbour_edges.size + 1, p.rsu_edges.size + 1, max(p.neighbour_sectors, 1),
                       p.sense_levels, p.predict_levels)
        self.n_states = int(np.prod(self.levels))

    def neighbour_sectors(self, own: np.ndarray, peers: np.ndarray, heard: np.ndarray) -> np.ndarray:
        """The nearest heard neighbour's direction sector (B, U) if the state uses it, else zeros."""
        if self.params.neighbour_sectors == 0:
            return np.zeros(heard.shape[:2], np.int64)
        return nearest_sectors(np.ascontiguousarray(own, dtype=np.float64), np.ascontiguousarray(peers, np.float64),
                               np.ascontiguousarray(heard, np.bool_), self.params.neighbour_sectors)

    def encode(self, pos: np.ndarray, vehicles_in_range: np.ndarray, queued: np.ndarray,
               nearest_neighbour_m: np.ndarray, neighbour_sector: np.ndarray | None = None,
               densest_sector: np.ndarray | None = None, predicted_sector: np.ndarray | None = None) -> np.ndarray:
        """State indices (B, U) from own position (B, U, 2) and (B, U) features
        (the sectors may be omitted when their factors are off)."""
        shape = np.shape(vehicles_in_range)
        zeros = np.zeros(shape, np.int64)
        return encode_states(np.ascontiguousarray(pos, dtype=np.float64),
                             np.asarray(vehicles_in_range, np.float64), np.asarray(queued, np.float64),
                             np.asarray(nearest_neighbour_m, np.float64),
                             zeros if neighbour_sector is None else np.asarray(neighbour_sector, np.int64),
                             zeros if densest_sector is None else np.asarray(densest_sector, np.int64),
                             zeros if predicted_sector is None else np.asarray(predicted_sector, np.int64),
                             self.params)


QTABLE_MAX_BYTES = 8 << 30
"""What the Q-tables of one command (every seed's and UAV's) may take: a config whose tables would exceed it
is refused in one line before anything is allocated, naming the keys that size them."""


def check_qtable_memory(cfg: Config, tables: int, what: str) -> None:
    """Refuse (ConfigError) a config whose ``tables`` Q-tables (``what``: e.g. "10 seeds x 5 UAVs") would
    take more than QTABLE_MAX_BYTES: at grid_cells 50 with every sector factor at 16 a table is 800 GiB."""
    from truav.config import ConfigError
    from world.uavs import N_ACTIONS
    n_states = StateEncoder(cfg).n_states
    size = tables * n_states * N_ACTIONS * 8
    if size > QTABLE_MAX_BYTES:
        lc = cfg.learner
        raise ConfigError(f"learner.grid_cells = {lc.grid_cells} with learner.neighbour_sectors, sense_sectors and "
                          f"predict_sectors: {n_states:,} states x {N_ACTIONS} actions x {what}: the Q-tables would "
                          f"take {size / 2**30:.1f} GiB, more than {QTABLE_MAX_BYTES / 2**30:.0f} GiB; use fewer "
                          f"cells or sectors, or fewer seeds or UAVs")
