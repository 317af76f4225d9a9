"""Coverage ceilings of a scenario: what no trajectory planner can beat.

    python docs/scripts/oracle_ceiling.py --preset paper [--seeds 5] [--episodes 20] [--skip 0] [--speed 15] [--held-out]

Runs the world's own vehicles (UAVs hovering: traffic does not depend on
them) and, at every step, places the U discs of radius comm_range by a
greedy max-coverage over candidate centres (every vehicle and a 100 m grid):

- ``teleport``: fresh discs every step, as if UAVs could jump anywhere. The
  greedy is within 1 - 1/e of the optimum and in practice close to it, so
  this is an estimate of the ceiling, not a proof;
- ``fixed``: the best U fixed positions for the whole episode, chosen in
  hindsight (what hovering on the right spots gives);
- ``reachable``: UAVs that fly at the UAV speed towards the teleport
  oracle's discs (matched to them by least total distance every step),
  going on across episodes like a persisting swarm. A simple chaser, not an
  optimum: it shows how much of the teleport ceiling motion costs.

Coverage is the world's: a vehicle within comm_range (horizontal) of any UAV.
Traffic gathers at its clusters over the first episodes (and, under the
paper preset, at each moved cluster's new site): --skip leaves out the first
episodes, so the figure is the ceiling a trained swarm meets.
"""
from __future__ import annotations

import argparse
import itertools
import json

import numpy as np

from truav import seeding
from truav.config import load_config
from truav.presets import preset_overrides
from world.env import World
from world.uavs import HOVER

GRID_STEP_M = 100.0


def candidates(area: float, xy: np.ndarray) -> np.ndarray:
    """(C, 2) disc centres: the vehicles (N, 2) and a GRID_STEP_M lattice."""
    g = np.arange(0.0, area + 1e-9, GRID_STEP_M)
    gx, gy = np.meshgrid(g, g)
    return np.concatenate([xy, np.stack([gx.ravel(), gy.ravel()], axis=1)])


def greedy(cover: np.ndarray, k: int) -> list[int]:
    """Indices of k rows of the (C, M) bool matrix covering the most columns, greedily."""
    left = np.ones(cover.shape[1], bool)
    chosen = []
    for _ in range(k):
        gain = (cover & left).sum(axis=1)
        best = int(np.argmax(gain))
        chosen.append(best)
        left &= ~cover[best]
    return chosen


def nearest_match(src: np.ndarray, dst: np.ndarray) -> tuple[int, ...]:
    """The permutation p minimising sum |src[i] - dst[p[i]]| (U is small: all U! of them)."""
    d = np.linalg.norm(src[:, None, :] - dst[None, :, :], axis=-1)
    rows = np.arange(len(src))
    return min(itertools.permutations(rows), key=lambda p: d[rows, list(p)].sum())


def covered_by(xy: np.ndarray, centres: np.ndarray, r: float) -> int:
    d2 = ((xy[:, None, :] - centres[None, :, :]) ** 2).sum(axis=-1)
    return int((d2 <= r * r).any(axis=1).sum())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="literal")
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--episodes", type=int, default=20)
    ap.add_argument("--speed", type=float, default=15.0)
    ap.add_argument("--skip", type=int, default=0, help="episodes left out of the means (warm-up)")
    ap.add_argument("--json", help="write the per-seed figures here")
    ap.add_argument("--held-out", action="store_true",
                    help="the evaluations' held-out traffic: world seeds + EVAL_SEED_OFFSET (default: seeds 0..)")
    a = ap.parse_args()
    over = preset_overrides(a.preset)
    over.setdefault("scenario", {})["uav_speed_mps"] = a.speed
    cfg = load_config(None, over)
    sc = cfg.scenario
    r, U, N, T = sc.comm_range_m, sc.n_uavs, sc.n_vehicles, sc.steps_per_episode
    step_m = a.speed * sc.step_s
    world = World(cfg, a.seeds)
    offset = seeding.EVAL_SEED_OFFSET if a.held_out else 0
    world.reset([seeding.world_rng(s + offset) for s in range(a.seeds)])
    hover = np.full((a.seeds, U), HOVER)
    out = {k: np.zeros((a.seeds, a.episodes)) for k in ("teleport", "fixed", "reachable")}
    chaser = [None] * a.seeds
    for ep in range(a.episodes):
        if ep:
            world.start_episode()
        frames = []
        for t in range(T):
            world.step(hover)
            frames.append(world.vehicle_xy())
        frames = np.stack(frames, axis=1)  # (B, T, N, 2)
        for b in range(a.seeds):
            tele, reach = 0, 0
            allc = candidates(sc.area_m, np.zeros((0, 2)))
            fixed_cover = np.zeros((len(allc), T * N), bool)
            for t in range(T):
                xy = frames[b, t]
                cand = candidates(sc.area_m, xy)
                cover = ((cand[:, None, :] - xy[None, :, :]) ** 2).sum(axis=-1) <= r * r
                pick = cand[greedy(cover, U)]
                tele += covered_by(xy, pick, r)
                if chaser[b] is None:
                    chaser[b] = pick.copy()
                pick = pick[list(nearest_match(chaser[b], pick))]
                gap = pick - chaser[b]
                dist = np.linalg.norm(gap, axis=1, keepdims=True)
                chaser[b] = np.where(dist <= step_m, pick, chaser[b] + gap / np.maximum(dist, 1e-9) * step_m)
                reach += covered_by(xy, chaser[b], r)
                fixed_cover[:, t * N:(t + 1) * N] = cover[N:]  # the grid rows: the same centres every step
            fixed = covered_by(frames[b].reshape(-1, 2), allc[greedy(fixed_cover, U)], r)
            out["teleport"][b, ep] = 100.0 * tele / (T * N)
            out["reachable"][b, ep] = 100.0 * reach / (T * N)
            out["fixed"][b, ep] = 100.0 * fixed / (T * N)
    print(f"preset {a.preset}, {a.speed:g} m/s, {a.seeds} seeds x {a.episodes} episodes "
          f"(means over episodes {a.skip}-{a.episodes - 1}), "
          f"{U} discs of {r:g} m, {N} vehicles:")
    summary = {}
    for k, v in out.items():
        per_seed = v[:, a.skip:].mean(axis=1)
        summary[k] = {"mean": float(per_seed.mean()), "sd": float(per_seed.std(ddof=1)) if a.seeds > 1 else 0.0,
                      "per_seed": per_seed.round(2).tolist()}
        print(f"  {k:9s} coverage {per_seed.mean():5.1f} % (sd over seeds {summary[k]['sd']:.1f}; "
              f"per seed {', '.join(f'{x:.1f}' for x in per_seed)})")
    if a.json:
        with open(a.json, "w") as f:
            json.dump({"preset": a.preset, "speed_mps": a.speed, "seeds": a.seeds, "episodes": a.episodes,
                       "skip": a.skip,
                       "per_episode_mean": {k: v.mean(axis=0).round(2).tolist() for k, v in out.items()},
                       **summary}, f, indent=1)


if __name__ == "__main__":
    main()
