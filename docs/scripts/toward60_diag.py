"""Where coverage goes: per-step diagnostics of a scheme under --preset paper at 15 m/s, sensing 1500 m
(docs/results/learned-policy.md, "Toward 60%").

    python docs/scripts/toward60_diag.py agent:spread agent:agents.claim_agent:ClaimAgent [--oracle]

Each scheme flies SEEDS held-out seeds (world seed + EVAL_SEED_OFFSET) x EPISODES greedy episodes; the steps of
episodes SKIP.. are measured (the swarm and the traffic settled): coverage; vehicles in range summed over UAVs
(its excess over coverage: vehicles in two UAVs' range); how many of the five UAVs have fewer than 10, 10-29 and
30 or more vehicles in range; how many sit within 300 m of a traffic hotspot's site, and how many of those share
their site with another; the share of vehicles within
a comm range of a site. --oracle adds the greedy teleport oracle's coverage of the same steps (every 5th step;
docs/scripts/oracle_ceiling.py).
"""

from __future__ import annotations

import argparse

import numpy as np
from oracle_ceiling import candidates, greedy

from truav import seeding
from truav.analysis.sumo_traffic import make_world
from truav.analysis.trainer import make_controller
from truav.config import Config
from truav.presets import preset_overrides
from truav.seeding import EVAL_SEED_OFFSET

SEEDS, EPISODES, SKIP = 4, 10, 5


def run(kind: str, oracle: bool) -> dict[str, float]:
    cfg = Config().replace(**preset_overrides("paper")).replace(learner={"sense_range_m": 1500.0})
    seeds = [s + EVAL_SEED_OFFSET for s in range(SEEDS)]
    world, ctl = make_world(cfg, len(seeds)), make_controller(kind, cfg, seeds, False, None)
    obs = world.reset([seeding.world_rng(s) for s in seeds])
    R, block = cfg.scenario.comm_range_m, cfg.roads.block_m
    acc: dict[str, list[float]] = {k: [] for k in ("coverage", "in_range_sum", "uavs_below_10", "uavs_10_29",
                                                   "uavs_30_up", "uavs_on_a_site", "uavs_sharing_a_site",
                                                   "vehicles_near_sites", "teleport")}
    for ep in range(EPISODES):
        if ep:
            obs = world.start_episode()
        ctl.begin_episode(ep, obs)
        done, t = False, 0
        while not done:
            obs, _, done = world.step(ctl.act(t))
            ctl.observe(obs, done)
            t += 1
            if ep < SKIP:
                continue
            xy, uav = world.vehicle_xy(), world.uav_pos
            for b in range(len(seeds)):
                inr = np.hypot(*(xy[b][:, None, :] - uav[b][None]).transpose(2, 0, 1)) <= R  # (N, U)
                n = inr.sum(0)
                acc["coverage"].append(inr.any(1).mean())
                acc["in_range_sum"].append(inr.sum() / len(xy[b]))
                acc["uavs_below_10"].append((n < 10).sum())
                acc["uavs_10_29"].append(((n >= 10) & (n < 30)).sum())
                acc["uavs_30_up"].append((n >= 30).sum())
                sites = np.unique(world.hotspots[b], axis=0) * block
                to_site = np.hypot(*(uav[b][:, None] - sites[None]).transpose(2, 0, 1))  # (U, sites)
                on = to_site.min(1) < 300.0
                acc["uavs_on_a_site"].append(on.sum())
                acc["uavs_sharing_a_site"].append(on.sum() - len(set(to_site.argmin(1)[on].tolist())))
                acc["vehicles_near_sites"].append(
                    (np.hypot(*(xy[b][:, None] - sites[None]).transpose(2, 0, 1)).min(1) <= R).mean())
                if oracle and t % 5 == 0:
                    cand = candidates(cfg.scenario.area_m, xy[b])
                    cover = ((cand[:, None] - xy[b][None]) ** 2).sum(-1) <= R * R
                    left = np.ones(cover.shape[1], bool)
                    for k in greedy(cover, cfg.scenario.n_uavs):
                        left &= ~cover[k]
                    acc["teleport"].append(1.0 - left.mean())
    return {k: float(np.mean(v)) for k, v in acc.items() if v}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("schemes", nargs="+", help="trainer kinds, e.g. agent:spread")
    ap.add_argument("--oracle", action="store_true", help="also the teleport oracle's coverage of the same steps")
    args = ap.parse_args()
    for kind in args.schemes:
        print(kind, {k: round(v, 3) for k, v in run(kind, args.oracle).items()}, flush=True)


if __name__ == "__main__":
    main()
