"""The SUMO scenario of a config, pure: netgenerate's and randomTrips.py's
arguments, the hotspot weights of trip destinations, the trace's cache key,
and the driving loop that keeps every vehicle on the road. No I/O of its own:
truav/analysis/sumo_traffic.py runs the tools and hands `drive` a simulation.

The network is the world's grid (scenario.area_m / roads.block_m + 1 roads
per axis, junction (i, j) at (i, j) x block_m: netgenerate's ids "i/j", and
its coordinates kept unshifted so the RSUs and major intersections sit where
the world puts them). SUMO's own car following (Krauss) and junction model
drive the vehicles; traffic lights stand at the major intersections.
"""

from __future__ import annotations

import hashlib
from typing import Callable

import numpy as np

from truav.config import Config, n_grid_roads, to_dict
from world.roads import RoadGrid, move_hotspots_env
from truav import jsonio


def node_id(i: int, j: int) -> str:
    """netgenerate's id of grid junction (i, j) (with --alphanumerical-ids false)."""
    return f"{i}/{j}"


def netgenerate_args(cfg: Config, net_file: str) -> list[str]:
    """netgenerate's arguments for the scenario's grid, written to net_file."""
    sm, r = cfg.sumo, cfg.roads
    args = ["--grid", "--grid.number", str(n_grid_roads(cfg)), "--grid.length", repr(float(r.block_m)),
            "--alphanumerical-ids", "false", "--default.lanenumber", str(sm.lanes_per_direction),
            "--default.speed", repr(float(cfg.idm.desired_speed_mps)),
            "--offset.disable-normalization", "true", "--seed", str(sm.trace_seed), "--no-warnings", "true",
            "--output-file", net_file]
    if sm.signals_at_major:
        args += ["--tls.set", ",".join(node_id(i, j) for i, j in r.major_intersections)]
    return args


def hotspot_weights(centres: np.ndarray, cfg: Config) -> np.ndarray:
    """Weight (E,) of each edge as a trip destination, centres (E, 2) its
    midpoints: 1 + sumo.hotspot_weight x exp(-(d / sumo.hotspot_radius_m)^2),
    d the distance to the nearest major intersection."""
    majors = np.array(cfg.roads.major_intersections, np.float64).reshape(-1, 2) * cfg.roads.block_m
    d = np.sqrt(((centres[:, None, :] - majors[None, :, :]) ** 2).sum(axis=-1)).min(axis=1)
    return 1.0 + cfg.sumo.hotspot_weight * np.exp(-(d / cfg.sumo.hotspot_radius_m) ** 2)


def home_edges(edge_ids: list[str], centres: np.ndarray, sites: np.ndarray, cfg: Config) -> list[list[str]]:
    """For each hotspot site (K, 2) (grid indices: at first the major
    intersections), the edges whose midpoints (centres (E, 2)) lie within
    sumo.hotspot_radius_m of it: where its cluster's vehicles drive to."""
    xy = np.asarray(sites, np.float64).reshape(-1, 2) * cfg.roads.block_m
    d = np.sqrt(((centres[:, None, :] - xy[None, :, :]) ** 2).sum(axis=-1))
    return [[e for e, near in zip(edge_ids, d[:, m] <= cfg.sumo.hotspot_radius_m) if near] for m in range(len(xy))]


def weights_xml(edge_ids: list[str], weights: np.ndarray) -> str:
    """An edgedata file of weights, as randomTrips.py's --weights-prefix reads it."""
    rows = "".join(f'    <edge id="{e}" value="{w:.6f}"/>\n' for e, w in zip(edge_ids, weights))
    return f'<edgedata>\n  <interval begin="0" end="1">\n{rows}  </interval>\n</edgedata>\n'


def trips_needed(cfg: Config) -> int:
    """Trips to draw: enough destinations for every vehicle over the whole run
    (a trip lasts well over 60 s on a grid of 250 m blocks), plus one to start."""
    duration = cfg.sumo.warmup_s + cfg.sumo.trace_episodes * cfg.scenario.steps_per_episode * cfg.scenario.step_s
    return cfg.scenario.n_vehicles * (int(duration // 60.0) + 2)


def randomtrips_args(cfg: Config, net_file: str, weights_prefix: str, trips_file: str, routes_file: str) -> list[str]:
    """randomTrips.py's arguments: trips_needed trips, source and destination
    edges weighted towards the major intersections, at least two blocks apart,
    validated by duarouter (its routes into routes_file; unroutable trips dropped)."""
    return ["--net-file", net_file, "--output-trip-file", trips_file, "--route-file", routes_file,
            "--weights-prefix", weights_prefix,
            "--seed", str(cfg.sumo.trace_seed), "--begin", "0", "--end", str(trips_needed(cfg)), "--period", "1",
            "--min-distance", repr(2.0 * cfg.roads.block_m)]


def sumo_args(cfg: Config, net_file: str) -> list[str]:
    """sumo's arguments (libsumo's or traci's start, after the binary's name)."""
    return ["--net-file", net_file, "--step-length", repr(float(cfg.scenario.step_s)), "--begin", "0",
            "--seed", str(cfg.sumo.trace_seed), "--no-step-log", "true", "--no-warnings", "true",
            "--xml-validation", "never", "--time-to-teleport", "-1"]


TRACE_KEYS = {"scenario": ("area_m", "n_vehicles", "step_s", "steps_per_episode"),
              "roads": ("block_m", "major_intersections", "p_attract", "hotspot_move_prob", "hotspot_step_blocks"),
              "idm": ("desired_speed_mps",), "sumo": None}
"""The config keys a trace depends on (None: the whole section)."""
DRIVE_VERSION = 3
"""Bumped whenever `drive` or the tools' arguments change what a trace holds: cached traces of older ones are
not reused."""


def cache_key(cfg: Config, sumo_version: str) -> str:
    """Name of a trace in the cache: a hash of what it depends on and SUMO's version."""
    data = to_dict(cfg)
    picked = {sec: (data[sec] if keys is None else {k: data[sec][k] for k in keys}) for sec, keys in TRACE_KEYS.items()}
    text = jsonio.dumps({"sumo": sumo_version, "drive": DRIVE_VERSION, "cfg": picked}, sort_keys=True, default=list)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def drive(sim, cfg: Config, trips: list[tuple[str, str]], edges: tuple[list[str], np.ndarray],
          on_row: Callable[[int, np.ndarray, np.ndarray], None]):
    """Drive a started SUMO simulation `sim` (the libsumo or traci module, which
    share one API) and hand on_row(row, positions (N, 2), active (N,)) every
    recorded row: sumo.warmup_s first, then rows_needed rows one step apart.

    Vehicle n departs on trip n (departing at a random free spot of its first
    edge) and, whenever it reaches the last edge of its route, is sent on: with
    probability roads.p_attract to an edge near its home hotspot (site n mod K,
    `home_edges` of the network's edges (ids, midpoints): the clusters of the
    built-in model, at first the major intersections), else to the destination
    of the next unused trip; so the N vehicles stay on the road (no arrival,
    teleports off) and gather near the hotspots. With
    roads.hotspot_move_prob > 0 the sites move at every window's start as the
    world moves them at an episode's (roads.move_hotspots_env), and the
    vehicles head for the new ones. A slot is inactive only until its vehicle
    is inserted.
    Draws come from a generator seeded by sumo.trace_seed, and SUMO is seeded:
    the same inputs give the same run."""
    rng = np.random.default_rng(cfg.sumo.trace_seed)
    grid = RoadGrid(cfg)
    sites, hotspots = grid.majors.copy(), grid.hotspot_params()
    homes = home_edges(*edges, sites, cfg)
    no_vehicles = np.zeros(0, np.int64)
    n = cfg.scenario.n_vehicles
    if len(trips) < n:
        raise ValueError(f"{len(trips)} trips for {n} vehicles")
    ids = [f"v{k}" for k in range(n)]
    for k, (src, dst) in enumerate(trips[:n]):
        route = sim.simulation.findRoute(src, dst).edges
        sim.route.add(f"r{k}", list(route) if route else [src])
        sim.vehicle.add(ids[k], f"r{k}", depart="0", departPos="random_free", departSpeed="0", departLane="best")
    next_trip = n
    route_len = [0] * n
    warm = int(round(cfg.sumo.warmup_s / cfg.scenario.step_s))
    rows = cfg.sumo.trace_episodes * cfg.scenario.steps_per_episode + 1
    pos = np.full((n, 2), np.nan)
    active = np.zeros(n, np.bool_)
    for step in range(warm + rows):
        if step:
            sim.simulationStep()
        row = step - warm
        if row > 0 and row % cfg.scenario.steps_per_episode == 0 and hotspots.move_prob > 0.0:
            move_hotspots_env(sites, rng.random((len(sites), 2)), hotspots, no_vehicles, no_vehicles)
            homes = home_edges(*edges, sites, cfg)
        present = set(sim.vehicle.getIDList())
        for k, vid in enumerate(ids):
            if vid not in present:
                active[k], pos[k] = False, np.nan
                continue
            if not route_len[k]:
                route_len[k] = len(sim.vehicle.getRoute(vid))
            if sim.vehicle.getRouteIndex(vid) >= route_len[k] - 1:  # on its last edge: on to the next destination
                here = sim.vehicle.getRoadID(vid)
                home = homes[k % len(homes)]
                for _ in range(len(trips) if not here.startswith(":") else 0):
                    if home and rng.random() < cfg.roads.p_attract:
                        dst = home[int(rng.integers(len(home)))]
                    else:
                        dst = trips[next_trip % len(trips)][1]
                        next_trip += 1
                    if dst == here:
                        continue
                    try:
                        sim.vehicle.changeTarget(vid, dst)
                    except sim.TraCIException:  # unreachable from here: the next one
                        continue
                    route_len[k] = len(sim.vehicle.getRoute(vid))
                    break
            active[k] = True
            pos[k] = sim.vehicle.getPosition(vid)
        if row >= 0:
            on_row(row, pos, active)
