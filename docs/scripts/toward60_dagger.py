"""A learner cloned from the climbing heuristic (docs/results/learned-policy.md, "Toward 60%").

    python docs/scripts/toward60_dagger.py [--memory]

The pipeline of docs/scripts/ppo_train.py (Stable-Baselines3's network, 16 training environments, 10 cloning
episodes of 10 epochs, 3 DAgger rounds) with agents.claim_agent.ClaimBatched as the teacher instead of `spread`,
no PPO; flown greedy in the vector environment on held-out traffic, 10 seeds x 20 episodes, at 15 m/s with sensing
1500 m. Prints the final cloning accuracy and the coverage; writes no weights.
"""

from __future__ import annotations

import argparse

import numpy as np
import torch

from agents.claim_agent import ClaimBatched
from agents.spread_agent import SENSE_RANGE_M
from truav.analysis.ppo_train import export, greedy_coverage, train
from truav.config import Config
from truav.presets import preset_overrides
from truav.seeding import EVAL_SEED_OFFSET
from truav.stats import mean_ci


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--memory", action="store_true", help="observe the memory features too (agents/view_features.py)")
    args = ap.parse_args()
    torch.set_num_threads(1)
    cfg = Config().replace(**preset_overrides("paper")).replace(scenario={"uav_speed_mps": 15.0},
                                                                learner={"sense_range_m": SENSE_RANGE_M})
    model, times = train(cfg, list(range(16)), bc_episodes=10, bc_epochs=10, dagger_rounds=3, ppo_steps=0,
                         coverage_bonus=5.0, memory=args.memory, seed=0, teacher=ClaimBatched)
    cov = greedy_coverage(export(model, cfg, 4, args.memory), cfg, [s + EVAL_SEED_OFFSET for s in range(10)], 20, 4)
    m, h = mean_ci(cov)
    print(f"cloning accuracy {times['accuracy']:.2f}; coverage {m:.1f} ± {h:.1f}% "
          f"(per seed: {', '.join(f'{v:.2f}' for v in np.asarray(cov))})")


if __name__ == "__main__":
    main()
