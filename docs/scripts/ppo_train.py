"""Train the learned policy `ppo` and measure it against the heuristic and the patrol
(docs/results/learned-policy.md; needs the `marl` extra).

    python docs/scripts/ppo_train.py                 # train, write agents/weights/ppo_paper_15mps.npz, evaluate
    python docs/scripts/ppo_train.py --eval-only     # evaluate the shipped weights
    python docs/scripts/ppo_train.py --eval-only --speed 5 --out docs/figures/learned-policy-5mps   # at 5 m/s

Training (truav.analysis.ppo_train): under --preset paper at 15 m/s with learner.sense_range_m = 1500, on
training seeds 0..ENVS-1 (ENVS environments x 5 UAVs = the vector's slots): behaviour cloning of the heuristic
`spread` (BC_EPISODES episodes, then DAGGER rounds of the learner flying and the heuristic labelling), then PPO
with shared parameters for PPO_STEPS slot-steps on the local reward plus a team term (COVERAGE_BONUS x the
share of all vehicles covered). Evaluation: the agent `ppo` through the agent API (the per-UAV
form a swarm flies), `spread` and the patrol, SEEDS seeds x EPISODES greedy episodes on held-out traffic
(world seed + EVAL_SEED_OFFSET); prints means with 95% intervals and the paired differences, writes OUT.csv.
"""

from __future__ import annotations

import argparse
import csv
import time
from pathlib import Path

import numpy as np

from agents.ppo_agent import WEIGHTS
from agents.spread_agent import SENSE_RANGE_M
from truav.analysis.trainer import run_chunk
from truav.config import Config
from truav.presets import preset_overrides
from truav.seeding import EVAL_SEED_OFFSET
from truav.stats import effect_text, mean_ci, paired_effect

SCHEMES = (("agent:ppo", "ppo (learned)"), ("agent:spread", "spread (heuristic)"), ("patrol", "patrol"))


def config(speed: float = 15.0) -> Config:
    cfg = Config().replace(**preset_overrides("paper"))
    return cfg.replace(scenario={"uav_speed_mps": speed}, learner={"sense_range_m": SENSE_RANGE_M})


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--eval-only", action="store_true", help="evaluate the shipped weights, train nothing")
    ap.add_argument("--envs", type=int, default=16, help="training environments (default %(default)s)")
    ap.add_argument("--bc-episodes", type=int, default=10)
    ap.add_argument("--bc-epochs", type=int, default=10)
    ap.add_argument("--dagger", type=int, default=3, help="DAgger rounds (default %(default)s)")
    ap.add_argument("--ppo-steps", type=int, default=320_000, help="PPO slot-steps after cloning (default %(default)s)")
    ap.add_argument("--lr", type=float, default=3e-5)
    ap.add_argument("--coverage-bonus", type=float, default=5.0, help="the team term's weight (TruavVecEnv)")
    ap.add_argument("--n-steps", type=int, default=100)
    ap.add_argument("--memory", action="store_true",
                    help="observe the memory features too (own previous action, velocity, change in range)")
    ap.add_argument("--seed", type=int, default=0, help="the training's seed (default %(default)s)")
    ap.add_argument("--ent-coef", type=float, default=0.0)
    ap.add_argument("--speed", type=float, default=15.0, help="scenario.uav_speed_mps of the evaluation (and training)")
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--episodes", type=int, default=20)
    ap.add_argument("--out", default="docs/figures/learned-policy", help="OUT.csv (default %(default)s)")
    args = ap.parse_args()
    cfg = config(args.speed)
    if not args.eval_only:
        import torch

        from truav.analysis.ppo_train import export, train
        torch.set_num_threads(1)
        model, times = train(cfg, list(range(args.envs)), bc_episodes=args.bc_episodes, bc_epochs=args.bc_epochs,
                             dagger_rounds=args.dagger, ppo_steps=args.ppo_steps, lr=args.lr, n_steps=args.n_steps,
                             ent_coef=args.ent_coef, coverage_bonus=args.coverage_bonus, memory=args.memory,
                             seed=args.seed)
        np.savez(WEIGHTS, **export(model, cfg, 4, args.memory))
        print(f"trained in {times['total_s']:.0f} s (cloning {times['clone_s']:.0f} s); wrote {WEIGHTS}")
    seeds = [s + EVAL_SEED_OFFSET for s in range(args.seeds)]
    cov = {}
    for kind, label in SCHEMES:
        t = time.perf_counter()
        cov[kind] = np.nanmean(run_chunk(kind, cfg, seeds, args.episodes, train=False).metrics["coverage_pct"], axis=0)
        m, h = mean_ci(cov[kind])
        print(f"{label}: {m:.1f} ± {h:.1f}% ({time.perf_counter() - t:.0f} s)", flush=True)
    for kind, label in SCHEMES[1:]:
        print(f"ppo - {label}: {effect_text(paired_effect(cov[kind], cov['agent:ppo']), digits=1, noun='seeds')}")
    out = Path(args.out).with_suffix(".csv")
    with open(out, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["scheme", "speed_mps", "seed", "coverage_pct"])
        for kind, values in cov.items():
            w.writerows([kind, args.speed, seed, f"{v:.4f}"] for seed, v in enumerate(values))


if __name__ == "__main__":
    main()
