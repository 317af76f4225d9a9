"""Where a trained TRUAV swarm's coverage goes (issue 32): of the vehicles the UAVs have in range,
how many are counted twice (in two or more discs: what a difference reward removes), under
greedy evaluation, trained and evaluated as `truav experiment velocity` does (held-out traffic,
the persistent swarm going on in the world its training ran in).

    python docs/scripts/overlap_share.py --preset paper --seeds 3 --episodes 1000 --eval-episodes 50 \
        --set learner.grid_cells=1 --set learner.sense_range_m=1500 [--set ...]
"""

from __future__ import annotations

import argparse

import numpy as np

from agents.controller import TruavController
from truav import seeding
from truav.analysis.driver import run_episodes
from truav.analysis.sumo_traffic import make_world
from truav.cli.config import parse_sets
from truav.config import load_config
from truav.presets import preset_overrides
from truav.seeding import EVAL_SEED_OFFSET


class Recording(TruavController):
    """The greedy controller, stepped (not fused), summing what each observation says."""

    sums = None

    def observe(self, obs, done):
        s = np.array([obs.vehicles_in_range.sum(), obs.covered.sum(), obs.exclusive.sum()], np.float64)
        Recording.sums = s if Recording.sums is None else Recording.sums + s
        super().observe(obs, done)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--preset", default="paper")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--episodes", type=int, default=1000)
    ap.add_argument("--eval-episodes", type=int, default=50)
    ap.add_argument("--set", action="append", default=[])
    a = ap.parse_args()
    overrides = preset_overrides(a.preset)
    for section, values in parse_sets(a.set).items():
        overrides.setdefault(section, {}).update(values)
    overrides.setdefault("learner", {})["episodes"] = a.episodes  # the exploration schedule, as --episodes sets it
    cfg = load_config(overrides=overrides)
    seeds = list(range(a.seeds))
    ctrl = TruavController(cfg, seeds)
    world = make_world(cfg, len(seeds))
    run_episodes(cfg, seeds, ctrl, a.episodes, world=world)
    ev_seeds = [s + EVAL_SEED_OFFSET for s in seeds]
    ev = Recording(cfg, ev_seeds, train=False, q=ctrl.learners.q)
    ev.fused = False
    world.rngs = [seeding.world_rng(s) for s in ev_seeds]
    m = run_episodes(cfg, ev_seeds, ev, a.eval_episodes, world=world)
    in_range, covered, exclusive = Recording.sums
    print(f"greedy coverage {np.mean(m['coverage_pct']):.1f}%; of the vehicle-UAV pairs in range, "
          f"{100 * (in_range - covered) / in_range:.1f}% are a vehicle already in another disc "
          f"(vehicles in two or more discs: {100 * (covered - exclusive) / covered:.1f}% of those covered)")


if __name__ == "__main__":
    main()
