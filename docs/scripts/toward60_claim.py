"""A learner cloned from the climbing heuristic, observing that heuristic's state (docs/results/learned-policy.md,
"Toward 60%").

    python docs/scripts/toward60_claim.py --seeds 4 --episodes 5                       # the screen
    python docs/scripts/toward60_claim.py --weights agents/weights/ppo_claim_paper_15mps.npz \
        --out docs/figures/toward60-claim-learner                                       # the confirmation
    python docs/scripts/toward60_claim.py --load --weights agents/weights/ppo_claim_paper_15mps.npz \
        --first-seed 10 --out docs/figures/toward60-claim-learner-seeds10-19            # fresh seeds

The pipeline of docs/scripts/toward60_dagger.py (Stable-Baselines3's network, 16 training environments, cloning
episodes, DAgger rounds; agents.claim_agent.ClaimBatched the teacher) with the claim features
(agents/view_features.py, ``claim``: the heuristic's climb heading, whether its exclusive vehicles fell, the peer
in its sector, ...) in the observation. Then flies the exported network greedy through the agent API
(agents.ppo_agent.PpoBatched), `spread` and the heuristic on the same held-out seeds (world seed +
EVAL_SEED_OFFSET) at 15 m/s with sensing 1500 m; prints each with its 95% interval and the paired differences,
writes the weights (--weights) and OUT.csv (one row per design and seed).
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import numpy as np
import torch

from agents.api_controller import ApiController
from agents.claim_agent import ClaimAgent, ClaimBatched
from agents.ppo_agent import PpoAgent, PpoBatched, load_policy
from agents.spread_agent import SENSE_RANGE_M, SpreadAgent
from truav.analysis.driver import run_episodes
from truav.analysis.ppo_train import export, train
from truav.config import Config
from truav.presets import preset_overrides
from truav.seeding import EVAL_SEED_OFFSET
from truav.stats import effect_text, mean_ci, paired_effect


def learner(weights: Path) -> type:
    """PpoAgent flying ``weights``, with its batched form."""
    batched = type("LearnerBatched", (PpoBatched,), {"weights": weights})
    return type("Learner", (PpoAgent,), {"weights": weights, "batched": batched})


def fly_against_heuristics(cfg: Config, held_out: list[int], weights: Path, episodes: int) -> dict[str, np.ndarray]:
    """The learner of ``weights``, `claim` and `spread` flown greedy through the agent API on ``held_out`` world
    seeds: each one's coverage per seed (%), printed with the learner's paired differences."""
    cov = {}
    for key, cls in (("learner", learner(weights)), ("claim", ClaimAgent), ("spread", SpreadAgent)):
        got = run_episodes(cfg, held_out, ApiController(key, cls, cfg, held_out, train=False), episodes)
        cov[key] = np.nanmean(got["coverage_pct"], axis=0)
        m, h = mean_ci(cov[key])
        print(f"  {key}: {m:.1f} ± {h:.1f}%", flush=True)
    for a, b in (("spread", "learner"), ("claim", "learner")):
        print(f"  {b} minus {a}: {effect_text(paired_effect(cov[a], cov[b]), digits=1, noun='seeds')}")
    return cov


def add_cloning_args(ap: argparse.ArgumentParser) -> None:
    """The evaluation's seeds and the cloning's budget, shared by the scripts that clone a teacher."""
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--first-seed", type=int, default=0, help="held-out seeds FIRST_SEED.. (default %(default)s)")
    ap.add_argument("--episodes", type=int, default=20)
    ap.add_argument("--bc-episodes", type=int, default=10)
    ap.add_argument("--dagger", type=int, default=3)
    ap.add_argument("--epochs", type=int, default=10, help="cloning epochs (default %(default)s)")
    ap.add_argument("--net", default="64,64", help="hidden widths (default %(default)s)")
    ap.add_argument("--ppo-steps", type=int, default=0, help="PPO fine-tuning slot-steps after the cloning")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_cloning_args(ap)
    ap.add_argument("--weights", default="/tmp/ppo_claim.npz", help="where the weights go (default %(default)s)")
    ap.add_argument("--load", action="store_true", help="fly --weights, no training")
    ap.add_argument("--out", help="OUT.csv: per-seed coverage")
    args = ap.parse_args()
    torch.set_num_threads(1)
    cfg = Config().replace(**preset_overrides("paper")).replace(scenario={"uav_speed_mps": 15.0},
                                                                learner={"sense_range_m": SENSE_RANGE_M})
    weights = Path(args.weights)
    if not args.load:
        model, times = train(cfg, list(range(16)), bc_episodes=args.bc_episodes, bc_epochs=args.epochs,
                             dagger_rounds=args.dagger, ppo_steps=args.ppo_steps, coverage_bonus=5.0, seed=0,
                             teacher=ClaimBatched, claim=True, say=lambda s: None,
                             net=[int(w) for w in args.net.split(",")])
        print(f"cloning accuracy {times['accuracy']:.3f} ({times['total_s']:.0f} s)", flush=True)
        np.savez(weights, **export(model, cfg, 4, False, True))
        load_policy.cache_clear()
    seeds = list(range(args.first_seed, args.first_seed + args.seeds))
    held_out = [s + EVAL_SEED_OFFSET for s in seeds]
    cov = fly_against_heuristics(cfg, held_out, weights, args.episodes)
    if args.out:
        with open(Path(args.out).with_suffix(".csv"), "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["design", "seed", "coverage_pct"])
            for key, v in cov.items():
                w.writerows([key, seed, f"{x:.4f}"] for seed, x in zip(seeds, v))


if __name__ == "__main__":
    main()
