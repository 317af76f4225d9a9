"""One step of one environment, compiled: UAV motion, vehicle mobility, packet
relay, UAV energy and the episode's running totals.

`World.step` runs `env_step` for each environment of its batch; the fused
TRUAV trainer (agents/fused.py) runs it inside its per-environment episode
loop. Both drivers therefore step the very same code. The arithmetic is that
of the numpy expressions it replaced, operation for operation (sums over UAVs
use numpy's pairwise order), so every number is unchanged.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from truav import kernel_cache  # noqa: F401, I001 - numba's cache set up before numba loads a kernel
from numba import njit

from truav.config import Config
from world import uavs
from world.network import (E_COVERED, E_DELAY_S, E_DELIVERED, E_EXPIRED, E_GENERATED, E_OVERFLOW,
                           E_WAIT_STEPS, TX_TIME, _relay_env)
from world.roads import _mobility_env, mobility_scratch

# Columns of the running episode totals (B, TOTAL_COLUMNS).
(T_COVERED, T_GENERATED, T_DELIVERED, T_DROPPED, T_DELAY_S, T_WAIT_S, T_ENERGY,
 T_ENERGY_ABOVE_HOVER) = range(8)
TOTAL_COLUMNS = 8


class UavParams(NamedTuple):
    dt: float
    area: float
    speed_max: float
    unit_velocity: np.ndarray  # (N_ACTIONS + 1, 2); the last row is HOVER
    hover_w: float
    move_w: float
    ref_speed: float
    tx_w: float


def uav_params(cfg: Config) -> UavParams:
    sc, e = cfg.scenario, cfg.energy
    return UavParams(sc.step_s, sc.area_m, sc.uav_speed_mps, uavs.ACTION_UNIT_VELOCITY, e.hover_w, e.move_w,
                     e.move_ref_speed_mps, cfg.channel.uav_tx_w)


@njit(cache=True)
def _pairwise_block(a, lo, n):
    if n < 8:
        res = 0.0
        for i in range(lo, lo + n):
            res += a[i]
        return res
    r0, r1, r2, r3 = a[lo], a[lo + 1], a[lo + 2], a[lo + 3]
    r4, r5, r6, r7 = a[lo + 4], a[lo + 5], a[lo + 6], a[lo + 7]
    i = 8
    while i < n - (n % 8):
        j = lo + i
        r0 += a[j]
        r1 += a[j + 1]
        r2 += a[j + 2]
        r3 += a[j + 3]
        r4 += a[j + 4]
        r5 += a[j + 5]
        r6 += a[j + 6]
        r7 += a[j + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += a[lo + i]
        i += 1
    return res


@njit(cache=True)
def pairwise_sum(a, lo, n):
    """Sum of a[lo:lo+n] in numpy's pairwise order (np.add.reduce of a
    contiguous float64 row: blocks of at most 128, halves split at a multiple
    of 8), so compiled totals equal the numpy ones bit for bit. Iterative:
    numba's cache does not take recursive functions."""
    if n <= 128:
        return _pairwise_block(a, lo, n)
    # Post-order walk of numpy's split tree: (lo, n) expands, n < 0 combines the last two sums.
    todo_lo, todo_n = np.empty(128, np.int64), np.empty(128, np.int64)
    sums = np.empty(64)
    top, depth = 0, 0
    todo_lo[0], todo_n[0] = lo, n
    top = 1
    while top > 0:
        top -= 1
        lo_k, n_k = todo_lo[top], todo_n[top]
        if n_k < 0:
            depth -= 1
            sums[depth - 1] = sums[depth - 1] + sums[depth]
        elif n_k <= 128:
            sums[depth] = _pairwise_block(a, lo_k, n_k)
            depth += 1
        else:
            half = n_k // 2
            half -= half % 8
            todo_lo[top], todo_n[top] = 0, -1
            todo_lo[top + 1], todo_n[top + 1] = lo_k + half, n_k - half
            todo_lo[top + 2], todo_n[top + 2] = lo_k, half
            top += 3
    return sums[0]


@njit(cache=True)
def env_step(actions, blend, delay, control, pos, velocity, heading, road, s, v, home, next_turn, lane_order, turn_u,
             xy, replayed, slots, total, arrivals, t, up, mp, rp, ch, out_uav, out_env, energy, above_hover, totals,
             work_f, work_i, work_b):
    """Advance one environment by one step, in place.

    actions (U,) in [-1, 16); blend: whether any UAV of the batch keeps flying
    its previous velocity for delay (U,) seconds; control (U,) control-plane
    airtime (s, already clipped to [0, dt]); pos, velocity (U, 2); vehicles
    and queues of this env; turn_u (N, 2) and arrivals (N,) of step t.
    xy (N, 2) receives the vehicles' positions after the step: those of the
    grid's own mobility, or, where replayed (N, 2) is not empty, a mobility
    trace's row for this step (scenario.mobility = "sumo"; the vehicle arrays
    then stand still). Packets, channel and routing see only xy.
    Fills out_uav (U, 5), out_env (7,), energy and above_hover (U,) and adds
    the step to totals (TOTAL_COLUMNS,). work_f, work_i, work_b: scratch
    of `roads.mobility_scratch`, reused by mobility and relay."""
    n_uav = pos.shape[0]
    dt = up.dt
    hover_row = up.unit_velocity.shape[0] - 1
    speed = np.empty(n_uav)
    for u in range(n_uav):
        row = actions[u] if actions[u] >= 0 else hover_row
        vx = up.unit_velocity[row, 0] * up.speed_max
        vy = up.unit_velocity[row, 1] * up.speed_max
        if blend:
            vx = (velocity[u, 0] * delay[u] + vx * (dt - delay[u])) / dt
            vy = (velocity[u, 1] * delay[u] + vy * (dt - delay[u])) / dt
        velocity[u, 0], velocity[u, 1] = vx, vy
        # np.clip(x, 0, area): max then min, in numpy's comparison order.
        nx, ny = pos[u, 0] + vx * dt, pos[u, 1] + vy * dt
        nx = nx if nx > 0.0 else 0.0
        ny = ny if ny > 0.0 else 0.0
        nx = nx if nx < up.area else up.area
        ny = ny if ny < up.area else up.area
        sx, sy = nx - pos[u, 0], ny - pos[u, 1]
        pos[u, 0], pos[u, 1] = nx, ny
        speed[u] = np.sqrt(sx * sx + sy * sy) / dt
    if replayed.shape[0] == 0:
        _mobility_env(heading, road, s, v, home, next_turn, lane_order, turn_u, dt, mp, work_f, work_i, work_b)
        grid_xy(heading, road, s, mp.block, xy)
    else:
        xy[:, :] = replayed
    _relay_env(xy, pos, slots, total, arrivals, t, True, rp, ch, control, out_uav, out_env,
               work_f, work_i)
    for u in range(n_uav):
        energy[u] = (up.hover_w + (up.move_w - up.hover_w) * speed[u] / up.ref_speed) * dt \
            + up.tx_w * (out_uav[u, TX_TIME] + control[u])
        above_hover[u] = energy[u] - up.hover_w * dt
    totals[T_COVERED] += out_env[E_COVERED]
    totals[T_GENERATED] += out_env[E_GENERATED]
    totals[T_DELIVERED] += out_env[E_DELIVERED]
    totals[T_DROPPED] += out_env[E_OVERFLOW] + out_env[E_EXPIRED]
    totals[T_DELAY_S] += out_env[E_DELAY_S]
    totals[T_WAIT_S] += out_env[E_WAIT_STEPS] * dt
    totals[T_ENERGY] += pairwise_sum(energy, 0, n_uav) / n_uav
    totals[T_ENERGY_ABOVE_HOVER] += pairwise_sum(above_hover, 0, n_uav) / n_uav


@njit(cache=True)
def grid_xy(heading, road, s, block, xy):
    """Planar positions (N, 2) of vehicles on the grid, into xy (roads.Vehicles.xy)."""
    for i in range(s.size):
        fixed = road[i] * block
        if (heading[i] & 1) == 0:
            xy[i, 0], xy[i, 1] = s[i], fixed
        else:
            xy[i, 0], xy[i, 1] = fixed, s[i]


@njit(cache=True)
def replayed_row(trace, row0, t):
    """The trace's positions (N, 2) after step t of an episode whose start is
    row row0 (trace.window_rows); an empty (0, 2) array when there is no trace."""
    if trace.shape[0] == 0:
        return np.empty((0, 2))
    return trace[row0 + t + 1]


@njit(cache=True)
def world_step(actions, blend, delay, control, pos, velocity, heading, road, s, v, home, next_turn, lane_order, turn_u,
               xy, trace, row0, slots, total, arrivals, t, up, mp, rp, ch, out_uav, out_env, energy, above_hover,
               totals):
    """env_step for every env of the batch (leading axis B on every array but
    trace (R, N, 2), the replayed mobility or empty, whose episode starts at
    rows row0 (B,))."""
    work_f, work_i, work_b = mobility_scratch(s.shape[1], mp.n_roads)
    for b in range(pos.shape[0]):
        env_step(actions[b], blend, delay[b], control[b], pos[b], velocity[b], heading[b], road[b], s[b], v[b],
                 home[b], next_turn[b], lane_order[b], turn_u[b], xy[b], replayed_row(trace, row0[b], t), slots[b],
                 total[b], arrivals[b], t, up, mp, rp, ch,
                 out_uav[b], out_env[b], energy[b], above_hover[b], totals[b], work_f, work_i, work_b)
