"""Association, relay routing and per-step packet service, batched.

Per step and environment (`relay_step`, a numba kernel parallel over envs):

1. Packets born this step join their vehicle's queue (bounded).
2. Every vehicle within comm_range of a UAV associates with the nearest one
   (coverage = associated vehicles / all vehicles).
3. Each UAV's route to an RSU is the min-time path over UAV-UAV and UAV-RSU
   links (Bellman-Ford over the UAVs), the per-packet time of a hop being
   transmission (bits / rate) plus propagation.
4. A UAV's radio time in a step (dt) is shared round-robin (TDMA) among
   its associated vehicles with packets: each round, each of them sends one
   packet (oldest first) costing c_v = uplink time + route time, while the
   UAV has time left. (Transit packets do not use the airtime of
   intermediate UAVs; this keeps the step cheap and favours no scheme.)
5. Relay delay of a packet = its completion time within the UAV's frame:
   the time of the packets sent before it plus its own c_v.
6. Packets reaching the deadline expire.
7. Transmit airtime (for energy) is charged to every UAV along a route.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from truav import kernel_cache  # noqa: F401, I001 - numba's cache set up before numba loads a kernel
from numba import njit

from truav.config import Config
from world import packets
from world import channel_models
from world.channel import SPEED_OF_LIGHT, ChannelParams, RateTables, a2g_rate, backhaul_rate, relay_rate

# Columns of the per-UAV output (B, U, UAV_COLUMNS).
IN_RANGE, COVERED, QUEUED, RELAYED, TX_TIME, DENSEST, EXCLUSIVE, DISC_DX, DISC_DY, DISC_VEHICLES = range(10)
UAV_COLUMNS = 10
OLD_UAV_COLUMNS = 7
"""The per-UAV columns before the disc columns: a snapshot recorded then is restored with them 0."""
"""DENSEST: with sensing on (learner.sense_range_m > 0), 1 + the direction
sector (counter-clockwise from east, learner.sense_sectors of them) holding
the most vehicles beyond comm range and within the sensing radius, the first
such sector on ties; 0 if none is sensed. Always 0 with sensing off.
EXCLUSIVE: vehicles within this UAV's comm range and no other UAV's: the
coverage the swarm would lose without it (the difference reward's term,
agents/reward.py). A UAV can count it itself from the position beacons (CAMs)
of the vehicles in its range and its neighbours' beacon positions; the world
counts it in the loop that counts the vehicles in range.
DISC_DX, DISC_DY, DISC_VEHICLES: with sensing on and learner.sense_disc, the
densest disc a UAV senses: among the vehicles within the sensing radius
(comm range included), the one with the most vehicles within comm range of
it (itself counted; the first by vehicle index on ties): its position minus
the UAV's (m) and that count; 0, 0, 0 when none is sensed or it is off."""
# Columns of the per-env output (B, ENV_COLUMNS).
E_COVERED, E_GENERATED, E_OVERFLOW, E_DELIVERED, E_EXPIRED, E_DELAY_S, E_WAIT_STEPS = range(7)
ENV_COLUMNS = 7
TABLE_RESOLUTION_M = 0.5
RSU_TIE_MARGIN, RSU_TIE_MARGIN_M = 1e-6, 1e-3
"""RSUs this close to a UAV's nearest (relative, absolute) are all evaluated in `routes`."""


class RelayParams(NamedTuple):
    comm_range: float
    dt: float
    bits: float
    queue_limit: int
    block: float
    uav_rsu_height: float
    uav_tx_w: float
    rsu: np.ndarray  # (K, 2)
    uplink_rate: np.ndarray  # vehicle->UAV rate sampled every TABLE_RESOLUTION_M
    nearest_rsu_only: bool  # the UAV-RSU hop time grows with distance: see `routes`
    sense_range: float  # learner.sense_range_m: 0 = no sensing beyond comm range (DENSEST stays 0)
    sense_sectors: int
    sense_disc: bool  # learner.sense_disc: the DISC_* columns (with sensing on)


def rsu_positions(cfg: Config) -> np.ndarray:
    """RSU sites (K, 2) in metres: the configured intersections near the corners."""
    return np.array(cfg.scenario.rsu_intersections, dtype=np.float64).reshape(-1, 2) * cfg.roads.block_m


def relay_params(cfg: Config) -> tuple[ChannelParams | RateTables, RelayParams]:
    sc, ch = cfg.scenario, cfg.channel
    cp = ChannelParams.from_config(ch)
    # The uplink rate is tabulated over horizontal distance (linear interpolation
    # between 0.5 m samples): the exact formula costs ~10 transcendental calls.
    samples = np.arange(0.0, sc.comm_range_m + 2 * TABLE_RESOLUTION_M, TABLE_RESOLUTION_M)
    height = sc.uav_altitude_m - sc.rsu_height_m
    if ch.model == "paper":
        table = a2g_rate(samples, sc.uav_altitude_m, ch.vehicle_tx_w, cp)
        # With the UAVs above the RSUs and NLoS no better than LoS, a farther RSU
        # means a lower elevation (less LoS), more path loss and more propagation:
        # a longer hop, always (los_a, los_b >= 0 by the config's bounds).
        nearest_only = height >= 0.0 and ch.eta_nlos_db >= ch.eta_los_db
    else:
        table, cp = _model_tables(cfg, samples)
        # A rate that never rises with distance (and propagation that grows) makes the nearest RSU's hop the shortest.
        nearest_only = bool(np.all(np.diff(cp.backhaul) <= 0.0))
    return cp, RelayParams(sc.comm_range_m, sc.step_s, cfg.traffic.packet_bytes * 8.0, cfg.traffic.queue_limit,
                       cfg.roads.block_m, height, ch.uav_tx_w, rsu_positions(cfg), table, nearest_only,
                       float(cfg.learner.sense_range_m), int(cfg.learner.sense_sectors),
                       bool(cfg.learner.sense_disc))


def _model_tables(cfg: Config, uplink_m: np.ndarray) -> tuple[np.ndarray, RateTables]:
    """Uplink rate at uplink_m, and the backhaul and relay rate tables over every horizontal
    distance within the area, of a model other than the paper's (world/channel_models.py)."""
    sc, ch, m = cfg.scenario, cfg.channel, cfg.channel.model
    far = np.arange(0.0, sc.area_m * np.sqrt(2.0) + 2 * TABLE_RESOLUTION_M, TABLE_RESOLUTION_M)

    def rate(tx_w: float, loss_db: np.ndarray) -> np.ndarray:
        return channel_models.shannon_rate(tx_w, loss_db, ch.antenna_gain_dbi, ch.noise_w, ch.bandwidth_hz)

    uplink = rate(ch.vehicle_tx_w, channel_models.uplink_loss_db(m, ch.environment, uplink_m, sc.uav_altitude_m,
                                                                 ch.carrier_hz))
    backhaul = rate(ch.uav_tx_w, channel_models.backhaul_loss_db(m, ch.environment, far, sc.uav_altitude_m,
                                                                 sc.rsu_height_m, ch.carrier_hz))
    relay = rate(ch.uav_tx_w, channel_models.relay_loss_db(m, far, ch.carrier_hz))
    return uplink, RateTables(TABLE_RESOLUTION_M, backhaul, relay)


@njit(cache=True)
def sector(dx, dy, sectors):
    """Which of `sectors` equal direction sectors (counter-clockwise from east,
    the first starting at angle 0) the vector (dx, dy) points into."""
    angle = np.arctan2(dy, dx)
    if angle < 0.0:
        angle += 2.0 * np.pi
    return min(int(angle * sectors / (2.0 * np.pi)), sectors - 1)


@njit(cache=True)
def uplink_rate(p, horizontal_m):
    x = min(horizontal_m / TABLE_RESOLUTION_M, p.uplink_rate.size - 2.0)
    i = int(x)
    frac = x - i
    return p.uplink_rate[i] * (1.0 - frac) + p.uplink_rate[i + 1] * frac


@njit(cache=True)
def routes(uav_pos, p, ch):
    """Min-time routes of all UAVs (U, 2) of one env to any RSU. Returns
    per-packet route time (U,), next hop (U,) as a UAV index or -1 for an RSU,
    and the per-packet time of the first hop (U,)."""
    n_uav, n_rsu = uav_pos.shape[0], p.rsu.shape[0]
    times = np.empty((2 + n_uav, n_uav))  # one allocation: best, hop, t_uu
    best, hop, t_uu = times[0], times[1], times[2:]
    best[:] = np.inf
    next_hop = np.full(n_uav, -1)
    for u in range(n_uav):
        # Under p.nearest_rsu_only the min over RSUs is that of the nearest:
        # the (transcendental) hop time is computed only for RSUs within a
        # margin of the nearest distance, far wider than any rounding, so the
        # minimum taken is the very number the full loop takes.
        cutoff = np.inf
        if p.nearest_rsu_only:
            h_min = np.inf
            for k in range(n_rsu):
                h_min = min(h_min, np.sqrt((uav_pos[u, 0] - p.rsu[k, 0]) ** 2 + (uav_pos[u, 1] - p.rsu[k, 1]) ** 2))
            cutoff = h_min * (1.0 + RSU_TIE_MARGIN) + RSU_TIE_MARGIN_M
        for k in range(n_rsu):
            h = np.sqrt((uav_pos[u, 0] - p.rsu[k, 0]) ** 2 + (uav_pos[u, 1] - p.rsu[k, 1]) ** 2)
            if h > cutoff:
                continue
            t = p.bits / backhaul_rate(h, p.uav_rsu_height, p.uav_tx_w, ch) \
                + np.sqrt(h * h + p.uav_rsu_height ** 2) / SPEED_OF_LIGHT
            best[u] = min(best[u], t)
    hop[:] = best
    t_uu[:] = np.inf
    for u in range(n_uav):
        for j in range(u + 1, n_uav):  # symmetric: (a - b)^2 == (b - a)^2 exactly
            d = np.sqrt((uav_pos[u, 0] - uav_pos[j, 0]) ** 2 + (uav_pos[u, 1] - uav_pos[j, 1]) ** 2)
            t_uu[u, j] = t_uu[j, u] = p.bits / relay_rate(d, p.uav_tx_w, ch) + d / SPEED_OF_LIGHT
    for _ in range(n_uav - 1):
        changed = False
        for u in range(n_uav):
            for j in range(n_uav):
                cand = t_uu[u, j] + best[j]
                if cand < best[u]:
                    best[u], next_hop[u], hop[u] = cand, j, t_uu[u, j]
                    changed = True
        if not changed:
            break
    return best, next_hop, hop


@njit(cache=True)
def _relay_env(xy, uav_pos, slots, total, arrivals, t, serve_packets, p, ch, busy0, out_uav, out_env,
               work_f, work_i):
    """One env's step; xy (N, 2) the vehicles' positions (NaN: a vehicle not on
    the road, which nothing covers); scratch work_f (>= 2N floats), work_i (>= 2N int64)."""
    n, n_uav = xy.shape[0], uav_pos.shape[0]
    out_uav[:] = 0.0
    out_env[:] = 0.0
    for i in range(n):
        accepted = packets.arrive_row(slots, i, total[i], t, arrivals[i], p.queue_limit)
        total[i] += accepted
        out_env[E_GENERATED] += arrivals[i]
        out_env[E_OVERFLOW] += arrivals[i] - accepted

    r2 = p.comm_range * p.comm_range
    sense2 = p.sense_range * p.sense_range
    sensing = p.sense_range > 0.0
    sensed = np.zeros((n_uav, p.sense_sectors if sensing else 1))
    nearest, senders = work_i[:n], work_i[n:2 * n]
    nearest[:] = -1
    floats = work_f[:2 * n]
    floats[:] = 0.0
    dist, cost = floats[:n], floats[n:]
    for i in range(n):
        x, y = xy[i, 0], xy[i, 1]
        best = np.inf
        in_ranges = 0
        for u in range(n_uav):
            d2 = (x - uav_pos[u, 0]) ** 2 + (y - uav_pos[u, 1]) ** 2
            if d2 <= r2:
                out_uav[u, IN_RANGE] += 1.0
                in_ranges += 1
                if d2 < best:
                    best, nearest[i] = d2, u
            elif sensing and d2 <= sense2:
                sensed[u, sector(x - uav_pos[u, 0], y - uav_pos[u, 1], p.sense_sectors)] += 1.0
        if in_ranges == 1:
            out_uav[nearest[i], EXCLUSIVE] += 1.0
        if nearest[i] >= 0:
            dist[i] = np.sqrt(best)
            out_uav[nearest[i], COVERED] += 1.0
            out_env[E_COVERED] += 1.0

    if serve_packets:
        route_time, next_hop, hop_time = routes(uav_pos, p, ch)
        for i in range(n):
            if nearest[i] >= 0:
                cost[i] = p.bits / uplink_rate(p, dist[i]) + route_time[nearest[i]]
        # Round-robin TDMA: each round, every associated vehicle with packets
        # sends one (oldest first) while its UAV has radio time left this step.
        clock = busy0.copy()  # radio time already taken (e.g. control-plane traffic)
        start = t % n  # rotate who goes first, so no vehicle is favoured
        # Each round visits the vehicles still able to send, in rotation order.
        # One that cannot send now never can again this step (its queue only
        # shrinks, its UAV's clock only grows), so it leaves the list: the same
        # sends in the same order as visiting all n every round, at the cost
        # of the senders only.
        n_senders = 0
        for k in range(n):
            i = start + k if start + k < n else start + k - n
            if nearest[i] >= 0 and total[i] > 0:
                senders[n_senders] = i
                n_senders += 1
        while n_senders > 0:
            kept = 0
            for k in range(n_senders):
                i = senders[k]
                u = nearest[i]
                if total[i] == 0 or clock[u] + cost[i] > p.dt:
                    continue
                served, age = packets.serve_row(slots, i, t, 1)
                total[i] -= served
                clock[u] += cost[i]
                out_uav[u, RELAYED] += 1.0
                out_env[E_DELAY_S] += clock[u]  # its completion time in the frame
                out_env[E_WAIT_STEPS] += age
                senders[kept] = i
                kept += 1
            n_senders = kept
        flows = np.zeros((2, n_uav))
        flow, forwarded = flows[0], flows[1]
        for u in range(n_uav):
            out_env[E_DELIVERED] += out_uav[u, RELAYED]
            flow[u] = out_uav[u, RELAYED]
        for _ in range(n_uav):  # each hop's sender pays its transmit airtime
            forwarded[:] = 0.0
            for u in range(n_uav):
                out_uav[u, TX_TIME] += flow[u] * hop_time[u]
                if next_hop[u] >= 0:
                    forwarded[next_hop[u]] += flow[u]
            flow, forwarded = forwarded, flow
        for i in range(n):
            dropped = packets.expire_row(slots, i, t)
            total[i] -= dropped
            out_env[E_EXPIRED] += dropped

    for i in range(n):
        if nearest[i] >= 0:
            out_uav[nearest[i], QUEUED] += total[i]
    if sensing:
        for u in range(n_uav):
            top = 0.0
            for k in range(p.sense_sectors):
                if sensed[u, k] > top:
                    top = sensed[u, k]
                    out_uav[u, DENSEST] = k + 1.0
        if p.sense_disc:
            _densest_discs(xy, uav_pos, r2, sense2, out_uav)


@njit(cache=True)
def _densest_discs(xy, uav_pos, r2, sense2, out_uav):
    """The DISC_* columns of one env (see UAV_COLUMNS): each vehicle's neighbours within comm range (itself
    included), each pair once, swept in x order (a pair further apart in x than the range is never measured:
    about a fifth of the pairs under the paper's area and range); then each UAV's best sensed centre."""
    n = xy.shape[0]
    count = np.zeros(n)
    order = np.argsort(xy[:, 0])  # NaN (off the road) last: neither a centre nor counted
    r = np.sqrt(r2)
    for a in range(n):
        i = order[a]
        xi, yi = xy[i, 0], xy[i, 1]
        if xi != xi or yi != yi:
            break
        count[i] += 1.0
        for c in range(a + 1, n):
            j = order[c]
            dx = xy[j, 0] - xi
            if not dx <= r:  # past the range in x (or NaN): so is every later one
                break
            if dx * dx + (xy[j, 1] - yi) ** 2 <= r2:
                count[i] += 1.0
                count[j] += 1.0
    for u in range(uav_pos.shape[0]):
        best, at = 0.0, -1
        for i in range(n):
            if count[i] > best:
                dx, dy = xy[i, 0] - uav_pos[u, 0], xy[i, 1] - uav_pos[u, 1]
                if dx * dx + dy * dy <= sense2:
                    best, at = count[i], i
        if at >= 0:
            out_uav[u, DISC_DX] = xy[at, 0] - uav_pos[u, 0]
            out_uav[u, DISC_DY] = xy[at, 1] - uav_pos[u, 1]
            out_uav[u, DISC_VEHICLES] = best


@njit(cache=True)
def relay_step(xy, uav_pos, slots, total, arrivals, t, serve_packets, p, ch, busy0, out_uav, out_env):
    """One step of packets for all envs, in place on slots (B, N, D) and total
    (B, N); xy (B, N, 2) vehicle positions; arrivals (B, N). With serve_packets False only senses (association,
    queues) - used at the start of an episode. busy0 (B, U): seconds of each
    UAV's radio time already used this step (e.g. by control-plane traffic).
    Fills out_uav (B, U, UAV_COLUMNS) and out_env (B, 7), see the column constants."""
    work_f, work_i = np.empty(2 * xy.shape[1]), np.empty(2 * xy.shape[1], np.int64)
    for b in range(xy.shape[0]):
        _relay_env(xy[b], uav_pos[b], slots[b], total[b], arrivals[b], t,
                   serve_packets, p, ch, busy0[b], out_uav[b], out_env[b], work_f, work_i)
