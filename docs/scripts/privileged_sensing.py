"""Would a finer sensing let the student learn from the privileged teacher? (docs/results/learned-policy.md,
"A privileged teacher")

    python docs/scripts/privileged_sensing.py --speed 5 [--teacher local-oracle --reach 1000] \
        [--compare docs/figures/privileged-teacher.csv --variant local1000_5]

A measurement, not a policy that can fly: the student of docs/scripts/privileged_dagger.py observes, beside its
local features, SENSED_DISC_FEATURES (truav.analysis.privileged_teacher.sensed_disc: the offset and count of the
densest disc among the vehicles within its sensing range), which the world computes for it here; no LocalView
carries them, so the agent API cannot fly it. Trained as privileged_dagger.py trains (16 training environments,
10 cloning episodes of 10 epochs, 3 DAgger rounds), then flown greedy in the vector environment on the held-out
seeds with `claim` (the features' rule) beside it in the same environment; ``--compare`` pairs it with that CSV's
`spread` and `claim` rows of ``--variant`` (the agent API's evaluation of the same held-out seeds: the `claim`
printed here must equal that CSV's, seed for seed, for the pairing to hold).
"""

from __future__ import annotations

import argparse
import csv

import numpy as np
import torch
from gymnasium import spaces

import truav.analysis.ppo_train as ppo_train
from agents.ppo_policy import NumpyPolicy
from agents.spread_agent import SENSE_RANGE_M
from truav.analysis.ppo_vec_env import TruavVecEnv, to_slot_actions
from truav.analysis.privileged_teacher import (SENSED_DISC_FEATURES, LocalOracleTeacher, OracleTeacher,
                                               sensed_disc)
from truav.config import Config
from truav.presets import preset_overrides
from truav.seeding import EVAL_SEED_OFFSET
from truav.stats import effect_text, mean_ci, paired_effect


class SensedVecEnv(TruavVecEnv):
    """TruavVecEnv whose observations end with SENSED_DISC_FEATURES."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        k = len(SENSED_DISC_FEATURES)
        low = np.concatenate([self.encoder.low, np.array([-1.0, -1.0, 0.0])]).astype(np.float32)
        high = np.concatenate([self.encoder.high, np.ones(k)]).astype(np.float32)
        self.observation_space = spaces.Box(low, high, (self.encoder.size + k,), np.float32)

    def _obs(self, advance: bool = True) -> np.ndarray:
        base = super()._obs(advance)
        sc = self.cfg.scenario
        extra = sensed_disc(self.world.vehicle_xy(), np.asarray(self.driver.views.pos, np.float64),
                            self.cfg.learner.sense_range_m, sc.comm_range_m)
        return np.concatenate([base, extra.reshape(self.B * self.U, -1).astype(base.dtype)], axis=1)


def fly(arrays: dict | None, cfg: Config, seeds: list[int], episodes: int) -> np.ndarray:
    """Each seed's mean coverage (%): the exported student greedy (arrays), or `claim` (None)."""
    env = SensedVecEnv(cfg, seeds, 4, claim=True)
    policy = None if arrays is None else NumpyPolicy(arrays)
    obs, cov = env.reset(), []
    for _ in range(episodes):
        while True:
            a = env.shadow_actions if policy is None else policy.greedy(obs)
            obs, _, done, infos = env.step(to_slot_actions(a).reshape(-1))
            if done[0]:
                cov.append([infos[b * env.U]["episode_coverage"] for b in range(env.B)])
                break
    return np.mean(cov, axis=0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--speed", type=float, default=5.0)
    ap.add_argument("--teacher", choices=("oracle", "local-oracle"), default="local-oracle")
    ap.add_argument("--reach", type=float, default=1000.0, help="local-oracle's reach, m (default %(default)s)")
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--episodes", type=int, default=20)
    ap.add_argument("--compare", help="a CSV of privileged_dagger.py's rows (variant, speed_mps, design, seed, ...)")
    ap.add_argument("--variant", help="the CSV's variant whose spread and claim rows to pair with")
    args = ap.parse_args()
    torch.set_num_threads(1)
    cfg = Config().replace(**preset_overrides("paper")).replace(scenario={"uav_speed_mps": args.speed},
                                                                learner={"sense_range_m": SENSE_RANGE_M})
    teacher = OracleTeacher if args.teacher == "oracle" else type("T", (LocalOracleTeacher,), {"reach_m": args.reach})
    ppo_train.TruavVecEnv = SensedVecEnv  # train() builds its environment from this name
    model, times = ppo_train.train(cfg, list(range(16)), bc_episodes=10, bc_epochs=10, dagger_rounds=3,
                                   coverage_bonus=5.0, seed=0, teacher=teacher, claim=True, say=lambda s: None)
    print(f"cloning accuracy {times['accuracy']:.3f} ({times['total_s']:.0f} s)", flush=True)
    held_out = [s + EVAL_SEED_OFFSET for s in range(args.seeds)]
    cov = {"student": fly(ppo_train.export(model, cfg, 4, False, True), cfg, held_out, args.episodes),
           "claim (here)": fly(None, cfg, held_out, args.episodes)}
    if args.compare:
        rows = [r for r in csv.DictReader(open(args.compare)) if r["variant"] == args.variant]
        for design in ("spread", "claim"):
            got = {int(r["seed"]): float(r["coverage_pct"]) for r in rows if r["design"] == design}
            cov[design] = np.array([got[s] for s in range(args.seeds)])
    for key, v in cov.items():
        per_seed = ", ".join(f"{x:.2f}" for x in v)
        print(f"  {key}: {mean_ci(v)[0]:.1f} ± {mean_ci(v)[1]:.1f}%  (per seed {per_seed})")
    for base in ("spread", "claim"):
        if base in cov:
            gain = paired_effect(cov[base], cov["student"])
            print(f"  student minus {base}: {effect_text(gain, digits=1, noun='seeds')}")


if __name__ == "__main__":
    main()
