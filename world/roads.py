"""Grid road network and car-following mobility, batched over environments.

Every array has a leading batch axis B (independent environments) and a
vehicle axis N. A vehicle drives on one lane of a two-lane road: its
`heading` (0:+x, 1:+y, 2:-x, 3:-y) fixes the axis and direction, `road` the
index of the road (fixed coordinate = road * block_m), `s` the coordinate
along the road. Lanes of opposite directions do not interact.

Longitudinal motion is the Intelligent Driver Model (Treiber et al. 2000)
behind the leader on the same lane; drivers slow to the turning speed before
an intersection where they will turn or that is major (signalised). At an
intersection a driver takes the turn chosen when it entered the block: with
probability p_attract the one that brings it closest to its home (the
intersection its traffic cluster gathers at), otherwise a Manhattan draw
(straight/left/right). Each vehicle belongs to one cluster; clusters start at
the major intersections and, if `roads.hotspot_move_prob` > 0, move between
intersections over time (`move_hotspots`), their vehicles following. A turner
whose landing spot on the new lane is taken goes straight instead, or waits
at the road end, so no lane ever holds overlapping vehicles.

The step is a numba kernel, parallel over environments.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from truav import kernel_cache  # noqa: F401, I001 - numba's cache set up before numba loads a kernel
from numba import njit

from truav.config import VEHICLE_SLOT_M, Config, n_grid_roads

STRAIGHT, LEFT, RIGHT = 0, 1, 2
# Unit steps of the four headings on the grid of intersections.
HEADING_DI = np.array([1, 0, -1, 0])
HEADING_DJ = np.array([0, 1, 0, -1])
HEADING_DIR = np.array([1.0, 1.0, -1.0, -1.0])
# Heading after going straight / left / right (headings run counter-clockwise).
TURN_OFFSET = np.array([0, 1, 3])
MAX_BRAKE = 9.0  # m/s^2, physical emergency braking bound on IDM decelerations


@dataclass
class Vehicles:
    """Vehicle state, all arrays (B, N)."""

    heading: np.ndarray  # int64
    road: np.ndarray  # int64
    s: np.ndarray  # float64, m along the road
    v: np.ndarray  # float64, m/s
    home: np.ndarray  # int64, intersection i * n_roads + j its cluster gathers at
    next_turn: np.ndarray  # int64, STRAIGHT/LEFT/RIGHT at the next intersection
    cluster: np.ndarray  # int64, index of its traffic cluster (a major intersection at the start)
    lane_order: np.ndarray | None = None
    """int64, the lane sort's order of the last step: a hint that makes the next sort
    nearly free (vehicles keep their order within a lane); any permutation gives the
    same step. None: vehicle index order."""

    FIELDS = ("heading", "road", "s", "v", "home", "next_turn", "cluster", "lane_order")

    def __post_init__(self):
        if self.lane_order is None:
            self.lane_order = np.broadcast_to(np.arange(self.s.shape[-1]), self.s.shape).copy()

    def xy(self, block_m: float) -> tuple[np.ndarray, np.ndarray]:
        """Planar positions (x, y), each (B, N)."""
        along_x = (self.heading & 1) == 0
        fixed = self.road * block_m
        return np.where(along_x, self.s, fixed), np.where(along_x, fixed, self.s)

    @classmethod
    def concat(cls, parts: list["Vehicles"]) -> "Vehicles":
        return cls(*(np.ascontiguousarray(np.concatenate([getattr(p, f) for p in parts])) for f in cls.FIELDS))


class MobilityParams(NamedTuple):
    """Everything the mobility kernel needs, in numba-friendly form."""

    block: float
    n_roads: int
    extent: float
    length: float
    v0: float
    headway: float
    accel: float
    decel: float
    jam_gap: float
    exponent: float
    turn_speed: float
    p_attract: float
    p_straight: float
    p_left: float
    p_right: float
    is_major: np.ndarray  # (n_roads, n_roads) bool
    home_i: np.ndarray  # (n_roads**2,) int64: grid i of intersection index i * n_roads + j
    home_j: np.ndarray


@njit(cache=True)
def next_intersection(h, road, s, block):
    """Along-road index k of the next intersection at or ahead of s, and its
    grid coordinates (i, j)."""
    x = s / block
    k = int(np.ceil(x - 1e-9)) if h < 2 else int(np.floor(x + 1e-9))
    if (h & 1) == 0:
        return k, k, road
    return k, road, k


@njit(cache=True)
def choose_turn(h, road, s, home, u_attract, u_pick, p):
    """Turn (STRAIGHT/LEFT/RIGHT) to take at the next intersection ahead."""
    _, i, j = next_intersection(h, road, s, p.block)
    probs = (p.p_straight, p.p_left, p.p_right)
    best, best_score, total = -1, np.inf, 0.0
    feasible = 0  # bit c: turn c stays on the grid (a bit mask, not an array: no allocation per vehicle)
    for c in range(3):
        hc = (h + TURN_OFFSET[c]) & 3
        ni, nj = i + HEADING_DI[hc], j + HEADING_DJ[hc]
        if 0 <= ni < p.n_roads and 0 <= nj < p.n_roads:
            feasible |= 1 << c
            # Euclidean, so that past its home a driver turns back around the
            # block instead of driving straight on; ties prefer straight, left, right.
            score = (ni - p.home_i[home]) ** 2 + (nj - p.home_j[home]) ** 2 + 0.1 * c
            if score < best_score:
                best, best_score = c, score
            total += probs[c]
    if u_attract < p.p_attract or total <= 0.0:
        return best
    x, acc = u_pick * total, 0.0
    for c in range(3):
        if feasible >> c & 1 and probs[c] > 0.0:
            acc += probs[c]
            if x < acc:
                return c
    return best


def lane_sort_sizes(n: int, n_roads: int) -> tuple[int, int]:
    """(floats, ints) of scratch `_lane_sort_into` takes for n vehicles."""
    return n, 2 * 4 * n_roads + 1 + n


@njit(cache=True)
def mobility_scratch(n, n_roads):
    """Scratch (floats, int64, bools) `_mobility_env` takes for n vehicles."""
    return np.empty(6 * n), np.empty(2 * 4 * n_roads + 1 + 5 * n, np.int64), np.empty(6 * n, np.bool_)


@njit(cache=True)
def _lane_sort(h, road, s, p, hint):
    """_lane_sort_into with scratch of its own."""
    n_floats, n_ints = s.size, 2 * 4 * p.n_roads + 1 + s.size
    return _lane_sort_into(h, road, s, p, hint, np.empty(n_floats), np.empty(n_ints, np.int64))


@njit(cache=True)
def _lane_sort_into(h, road, s, p, hint, floats, ints):
    """Vehicles ordered by lane, then along the lane in driving direction:
    (order, key, lane_start) with lane_start (4 n_roads + 1,) the first
    position in `order` of each lane (lane = heading * n_roads + road).
    A counting sort by lane then an insertion sort within each (a lane
    holds a few vehicles): the order of np.argsort(key), keys being distinct
    (vehicles on a lane never overlap), at a fraction of its cost. The
    counting sort visits the vehicles in the order of `hint` (a permutation,
    e.g. the last step's order, in which vehicles that stayed on their lane
    are already sorted), so the insertion sort has little to move; the
    result does not depend on it, keys being distinct. Scratch (views into
    it are returned): floats (>= n,), ints (>= 2 * lanes + 1 + n,) int64
    (`lane_sort_sizes`), so that a step allocates nothing."""
    span = 4.0 * (p.extent + 1.0)
    n, n_lanes = s.size, 4 * p.n_roads
    key = floats[:n]
    lane_start = ints[:n_lanes + 1]
    lane_start[:] = 0
    for i in range(n):
        key[i] = (h[i] * p.n_roads + road[i]) * span + HEADING_DIR[h[i]] * s[i]
        lane_start[h[i] * p.n_roads + road[i] + 1] += 1
    for lane in range(n_lanes):
        lane_start[lane + 1] += lane_start[lane]
    fill = ints[n_lanes + 1:2 * n_lanes + 1]
    fill[:] = lane_start[:-1]
    order = ints[2 * n_lanes + 1:2 * n_lanes + 1 + n]
    for m in range(n):
        i = hint[m]
        lane = h[i] * p.n_roads + road[i]
        order[fill[lane]] = i
        fill[lane] += 1
    for lane in range(n_lanes):
        for k in range(lane_start[lane] + 1, lane_start[lane + 1]):
            x = order[k]
            j = k - 1
            while j >= lane_start[lane] and key[order[j]] > key[x]:
                order[j + 1] = order[j]
                j -= 1
            order[j + 1] = x
    return order, key, lane_start


@njit(cache=True)
def _overlaps(x, h, road, s, length, order, lane_start, lane_n_roads, is_turner, turners):
    """Whether vehicle x (a turner) overlaps another vehicle of its current
    lane: the vehicles that did not turn are still where the lane sort put
    them (their lane is unchanged), the turners are checked one by one."""
    lane = h[x] * lane_n_roads + road[x]
    for k in range(lane_start[lane], lane_start[lane + 1]):
        y = order[k]
        if not is_turner[y] and abs(s[y] - s[x]) < length:
            return True
    for y in turners:
        if y != x and h[y] == h[x] and road[y] == road[x] and abs(s[y] - s[x]) < length:
            return True
    return False


# error_model="numpy": a division by zero would give inf instead of raising (none
# happens: v0 >= turn speed > 0, dt > 0), which lets the car-following loop compile to SIMD.
@njit(cache=True, error_model="numpy")
def _mobility_env(h, road, s, v, home, next_turn, lane_order, u, dt, p, work_f, work_i, work_b):
    """One env's step. Scratch: work_f, work_i (int64), work_b (bool), at
    least `mobility_scratch`'s sizes: a step allocates nothing."""
    n = s.size
    same_lane = 2.0 * p.extent + 1.0
    sort_f, sort_i = n, 2 * 4 * p.n_roads + 1 + n  # lane_sort_sizes
    order, key, lane_start = _lane_sort_into(h, road, s, p, lane_order, work_f[:sort_f], work_i[:sort_i])
    lane_order[:] = order
    floats = work_f[sort_f:sort_f + 5 * n]
    gap, v_lead, s_int, s_lane, v_new = floats[:n], floats[n:2 * n], floats[2 * n:3 * n], floats[3 * n:4 * n], \
        floats[4 * n:]
    ints = work_i[sort_i:sort_i + 4 * n]
    k_int, old_h, old_road, turner_list = ints[:n], ints[n:2 * n], ints[2 * n:3 * n], ints[3 * n:]
    flags = work_b[:6 * n]
    flags[:] = False
    slow, crossing, active = flags[:n], flags[n:2 * n], flags[2 * n:3 * n]
    straight_ok, waiting, is_turner = flags[3 * n:4 * n], flags[4 * n:5 * n], flags[5 * n:]
    gap[:] = np.inf
    v_lead[:] = 0.0
    for k in range(n - 1):
        a, c = order[k], order[k + 1]
        if key[c] - key[a] < same_lane:
            gap[a] = key[c] - key[a] - p.length
            v_lead[a] = v[c]

    # First the car-following step of every vehicle as if it stayed on its
    # lane, branch-free so that it compiles to SIMD; then the turns.
    brake_term = 1.0 / (2.0 * np.sqrt(p.accel * p.decel))
    quartic = p.exponent == 4.0
    turn_speed2 = p.turn_speed ** 2
    for x in range(n):
        hx = h[x]
        # next_intersection, inlined
        along = s[x] / p.block
        k = int(np.ceil(along - 1e-9)) if hx < 2 else int(np.floor(along + 1e-9))
        i, j = (k, road[x]) if (hx & 1) == 0 else (road[x], k)
        k_int[x] = k
        s_int[x] = k * p.block
        # Slow to the turning speed before a turn or a major intersection.
        slow[x] = (next_turn[x] != STRAIGHT) | p.is_major[i, j]
    # The same loop twice, so that the quartic one (the default exponent)
    # never evaluates pow: branch-free, a select would compute both sides.
    if quartic:
        for x in range(n):
            direction = 1.0 if h[x] < 2 else -1.0  # HEADING_DIR[h[x]]
            d_int = direction * (s_int[x] - s[x])
            v0_turn = np.sqrt(turn_speed2 + 2.0 * p.decel * d_int)
            v0 = min(p.v0, v0_turn) if slow[x] else p.v0
            vx = v[x]
            g = gap[x]
            s_star = p.jam_gap + max(0.0, vx * p.headway + vx * (vx - v_lead[x]) * brake_term)
            interaction = (s_star / max(g, 0.1)) ** 2 if g < np.inf else 0.0
            ratio = vx / v0
            free = ratio * ratio * ratio * ratio
            acc = max(p.accel * (1.0 - free - interaction), -MAX_BRAKE)
            vn = max(vx + acc * dt, 0.0)
            ds = min(0.5 * (vx + vn) * dt, max(g, 0.0))  # never into the leader's old rear
            vn = min(vn, 2.0 * ds / dt)
            s_lane[x] = s[x] + direction * ds
            v_new[x] = vn
    else:
        for x in range(n):
            direction = 1.0 if h[x] < 2 else -1.0
            d_int = direction * (s_int[x] - s[x])
            v0_turn = np.sqrt(turn_speed2 + 2.0 * p.decel * d_int)
            v0 = min(p.v0, v0_turn) if slow[x] else p.v0
            vx = v[x]
            g = gap[x]
            s_star = p.jam_gap + max(0.0, vx * p.headway + vx * (vx - v_lead[x]) * brake_term)
            interaction = (s_star / max(g, 0.1)) ** 2 if g < np.inf else 0.0
            ratio = vx / v0
            free = ratio ** p.exponent
            acc = max(p.accel * (1.0 - free - interaction), -MAX_BRAKE)
            vn = max(vx + acc * dt, 0.0)
            ds = min(0.5 * (vx + vn) * dt, max(g, 0.0))
            vn = min(vn, 2.0 * ds / dt)
            s_lane[x] = s[x] + direction * ds
            v_new[x] = vn

    for x in range(n):
        overshoot = HEADING_DIR[h[x]] * (s_lane[x] - s_int[x])
        crossing[x] = overshoot > 0.0
        if crossing[x] and next_turn[x] != STRAIGHT:
            k = k_int[x]
            i, j = (k, road[x]) if (h[x] & 1) == 0 else (road[x], k)
            ni, nj = i + HEADING_DI[h[x]], j + HEADING_DJ[h[x]]
            straight_ok[x] = 0 <= ni < p.n_roads and 0 <= nj < p.n_roads
            old_h[x], old_road[x] = h[x], road[x]
            ht = (h[x] + TURN_OFFSET[next_turn[x]]) & 3
            s[x] = road[x] * p.block + HEADING_DIR[ht] * overshoot
            road[x] = k
            h[x] = ht
            v[x] = min(v_new[x], p.turn_speed)
            active[x] = True
        else:
            s[x] = s_lane[x]
            v[x] = v_new[x]

    # A turner may land on a taken spot; put it back (straight, or waiting at
    # a road end) until no lane holds overlapping vehicles. Only turners can
    # overlap anyone: within a lane, the IDM step above keeps every gap >= 0.
    n_turners = 0  # np.flatnonzero(active), into scratch
    for x in range(n):
        if active[x]:
            turner_list[n_turners] = x
            n_turners += 1
    turners = turner_list[:n_turners]
    is_turner[:] = active
    changed = turners.size > 0
    while changed:
        changed = False
        for x in turners:
            if active[x] and _overlaps(x, h, road, s, p.length, order, lane_start, p.n_roads, is_turner, turners):
                active[x] = False
                changed = True
                h[x], road[x] = old_h[x], old_road[x]
                if straight_ok[x]:
                    s[x], v[x] = s_lane[x], v_new[x]
                else:
                    s[x], v[x] = s_int[x], 0.0
                    waiting[x] = True
    for x in range(n):
        if crossing[x] and not waiting[x]:
            next_turn[x] = choose_turn(h[x], road[x], s[x], home[x], u[x, 0], u[x, 1], p)


@njit(cache=True)
def mobility_step(heading, road, s, v, home, next_turn, lane_order, u_turn, dt, p):
    """Advance all vehicles (B, N) by dt in place; u_turn (B, N, 2) uniforms."""
    work_f, work_i, work_b = mobility_scratch(s.shape[1], p.n_roads)
    for b in range(s.shape[0]):
        _mobility_env(heading[b], road[b], s[b], v[b], home[b], next_turn[b], lane_order[b], u_turn[b], dt, p,
                      work_f, work_i, work_b)


@njit(cache=True)
def choose_turns(heading, road, s, home, u, p):
    """choose_turn for flat arrays; u (N, 2)."""
    out = np.empty(s.size, np.int64)
    for x in range(s.size):
        out[x] = choose_turn(heading[x], road[x], s[x], home[x], u[x, 0], u[x, 1], p)
    return out


class HotspotParams(NamedTuple):
    move_prob: float  # roads.hotspot_move_prob
    steps: np.ndarray  # (4, 2) int64: the four moves of roads.hotspot_step_blocks
    lo: np.ndarray  # (2,) int64: the box spanned by the major intersections
    hi: np.ndarray
    n_roads: int


@njit(cache=True)
def move_hotspots_env(site, u, p, home, cluster):
    """Move one env's traffic hotspots in place and re-home its vehicles.

    site (K, 2) grid indices of the K cluster sites (updated); u (K, 2)
    uniforms: with probability roads.hotspot_move_prob (u[:, 0]) a site
    steps roads.hotspot_step_blocks along one of the four directions
    (u[:, 1]) that keep it inside the box spanned by the major
    intersections, so clusters shift between intersections of the city
    map while its RSUs and signals stay put. home, cluster (N,)."""
    choices = np.empty((4, 2), np.int64)
    for k in range(site.shape[0]):
        if u[k, 0] >= p.move_prob:
            continue
        n_ok = 0
        for d in range(4):
            ti, tj = site[k, 0] + p.steps[d, 0], site[k, 1] + p.steps[d, 1]
            if p.lo[0] <= ti <= p.hi[0] and p.lo[1] <= tj <= p.hi[1]:
                choices[n_ok, 0], choices[n_ok, 1] = ti, tj
                n_ok += 1
        if n_ok > 0:
            pick = min(int(u[k, 1] * n_ok), n_ok - 1)
            site[k, 0], site[k, 1] = choices[pick, 0], choices[pick, 1]
    for x in range(home.size):
        c = cluster[x]
        home[x] = site[c, 0] * p.n_roads + site[c, 1]


class RoadGrid:
    """Static geometry of the grid; spawns vehicles and steps them."""

    def __init__(self, cfg: Config):
        self.cfg = cfg
        self.block = cfg.roads.block_m
        self.n_roads = n_grid_roads(cfg)
        self.extent = (self.n_roads - 1) * self.block
        majors = np.array(cfg.roads.major_intersections, dtype=np.int64).reshape(-1, 2)
        self.majors = majors
        self.major_index = majors[:, 0] * self.n_roads + majors[:, 1]
        """Intersection index of each major intersection (the clusters' first homes)."""
        sites = np.arange(self.n_roads * self.n_roads)
        is_major = np.zeros((self.n_roads, self.n_roads), dtype=np.bool_)
        is_major[majors[:, 0], majors[:, 1]] = True
        r, idm = cfg.roads, cfg.idm
        self.params = MobilityParams(
            float(self.block), int(self.n_roads), float(self.extent), idm.vehicle_length_m,
            idm.desired_speed_mps, idm.time_headway_s, idm.max_accel, idm.comfort_decel, idm.min_gap_m,
            idm.exponent, r.turn_speed_mps, r.p_attract, r.p_straight, r.p_left, r.p_right,
            is_major, sites // self.n_roads, sites % self.n_roads)

    def spawn(self, rng: np.random.Generator, n: int) -> Vehicles:
        """N vehicles on distinct 25 m slots of random lanes, at rest, one env
        (arrays shaped (1, N)); clusters uniform over the major intersections."""
        slot_m = VEHICLE_SLOT_M
        slots_per_lane = int(self.extent // slot_m)
        n_lanes = 4 * self.n_roads
        if n > n_lanes * slots_per_lane:  # the config refuses it (truav.config.grid_vehicle_capacity)
            raise ValueError(f"{n} vehicles do not fit on the road grid")
        pick = rng.choice(n_lanes * slots_per_lane, size=n, replace=False)
        lane, slot = np.divmod(pick, slots_per_lane)
        heading, road = np.divmod(lane, self.n_roads)
        s = (slot + 0.5) * slot_m
        cluster = rng.integers(0, len(self.majors), size=n)
        home = self.major_index[cluster]
        turn = choose_turns(heading, road, s, home, rng.random((n, 2)), self.params)
        return Vehicles(heading[None], road[None], s[None], np.zeros((1, n)), home[None], turn[None], cluster[None])

    def hotspot_params(self) -> "HotspotParams":
        """roads.hotspot_* and the box of the major intersections, for `move_hotspots_env`."""
        r = self.cfg.roads
        steps = np.array([[1, 0], [0, 1], [-1, 0], [0, -1]], np.int64) * r.hotspot_step_blocks
        return HotspotParams(float(r.hotspot_move_prob), steps, self.majors.min(axis=0), self.majors.max(axis=0),
                             int(self.n_roads))

    def move_hotspots(self, veh: Vehicles, b: int, site: np.ndarray, u: np.ndarray) -> None:
        """Move env b's traffic hotspots in place and re-home their vehicles
        (`move_hotspots_env`); site (K, 2) grid indices of the K cluster sites
        (updated), u (K, 2) uniforms."""
        move_hotspots_env(site, u, self.hotspot_params(), veh.home[b], veh.cluster[b])

    def step(self, veh: Vehicles, dt: float, u_turn: np.ndarray) -> None:
        """Advance all vehicles by dt in place; u_turn (B, N, 2) uniforms."""
        mobility_step(veh.heading, veh.road, veh.s, veh.v, veh.home, veh.next_turn, veh.lane_order,
                      np.ascontiguousarray(u_turn), float(dt), self.params)

    def lane_gaps(self, veh: Vehicles) -> np.ndarray:
        """Bumper gap of every vehicle to its leader on the same lane, +inf if
        none; (B, N). Negative would mean a collision."""
        out = np.full(veh.s.shape, np.inf)
        for b in range(veh.s.shape[0]):
            order, key, _ = _lane_sort(veh.heading[b], veh.road[b], veh.s[b], self.params, veh.lane_order[b])
            ks = key[order]
            d = ks[1:] - ks[:-1]
            out[b, order[:-1]] = np.where(d < 2 * self.extent + 1, d - self.cfg.idm.vehicle_length_m, np.inf)
        return out
