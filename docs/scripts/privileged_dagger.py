"""A learner taught by a privileged teacher ("learning by cheating"; docs/results/learned-policy.md, "A privileged
teacher").

    python docs/scripts/privileged_dagger.py --speed 5 --first-seed 20 --seeds 4 --episodes 5     # a screen
    python docs/scripts/privileged_dagger.py --speed 5 --weights W.npz --out docs/figures/NAME    # confirmation
    python docs/scripts/privileged_dagger.py --speed 10 --load --weights W.npz --out ...          # fly W at 10 m/s
    python docs/scripts/privileged_dagger.py --speed 5 --teacher-only                             # the teacher
    python docs/scripts/privileged_dagger.py --speed 5 --sectors 16 --weights W.npz --out ...      # finer sensing

The pipeline of docs/scripts/toward60_claim.py (Stable-Baselines3's network, 16 training environments, seeds 0-15,
cloning episodes, DAgger rounds, the claim features in the observation) with the DAgger labels of a teacher that
sees the whole world at each step (truav.analysis.privileged_teacher.OracleTeacher: the greedy max-coverage discs,
the UAVs matched to them, each flying toward its own); the student observes its local features only, as it flies.
``--teacher claim`` labels with the climbing heuristic instead (toward60_claim.py's learner, at --speed). Then flies
the exported network greedy through the agent API (agents.ppo_agent.PpoBatched), `spread` and `claim` on the same
held-out seeds (world seed + EVAL_SEED_OFFSET) with sensing 1500 m; prints each with its 95% interval and the
paired differences (``--compare``: also with another CSV's `spread` and `claim`, as at another sensing), writes
the weights (--weights) and OUT.csv (one row per design and seed). ``--sectors``: the view's sensing sectors
(learner.sense_sectors) for all three. ``--teacher-only``
flies the teacher itself and `claim` in the vector environment (truav.analysis.ppo_vec_env) on the same held-out
seeds instead: the teacher needs the world, which the agent API does not give.
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import numpy as np
import torch

from agents.claim_agent import ClaimBatched
from agents.ppo_agent import load_policy
from agents.spread_agent import SENSE_RANGE_M
from truav.analysis.ppo_train import export, train
from truav.analysis.ppo_vec_env import TruavVecEnv, to_slot_actions
from truav.analysis.privileged_teacher import LocalOracleTeacher, OracleTeacher
from truav.config import Config
from truav.presets import preset_overrides
from truav.seeding import EVAL_SEED_OFFSET
from truav.stats import effect_text, mean_ci, paired_effect

from toward60_claim import add_cloning_args, fly_against_heuristics  # a sibling script (docs/scripts is on the path when run)

TEACHERS = {"oracle": OracleTeacher, "local-oracle": LocalOracleTeacher, "claim": ClaimBatched}


def fly_teacher(cfg: Config, seeds: list[int], episodes: int, teacher_cls: type) -> dict[str, np.ndarray]:
    """Each seed's mean coverage (%) over ``episodes`` episodes of the teacher and of `claim` (the features' rule,
    the fallback), each flying its own vector environment of ``seeds``."""
    out = {}
    for key in ("teacher", "claim"):
        env = TruavVecEnv(cfg, seeds, claim=True)
        teacher = teacher_cls(cfg, [[None] * env.U for _ in seeds])
        env.reset()
        cov = []
        for _ in range(episodes):
            while True:
                if key == "teacher":
                    teacher.see(env.world.vehicle_xy(), env.shadow_actions)
                a = teacher.act(env.views) if key == "teacher" else env.shadow_actions
                _, _, done, infos = env.step(to_slot_actions(a).reshape(-1))
                if done[0]:
                    cov.append([infos[b * env.U]["episode_coverage"] for b in range(env.B)])
                    break
        out[key] = np.mean(cov, axis=0)
    return out


def make_config(speed: float, sectors: int = 4, disc: bool = False) -> Config:
    """The paper preset at ``speed`` m/s, sensing SENSE_RANGE_M over ``sectors`` direction sectors (and the densest
    sensed disc with ``disc``)."""
    return Config().replace(**preset_overrides("paper")).replace(
        scenario={"uav_speed_mps": speed},
        learner={"sense_range_m": SENSE_RANGE_M, "sense_sectors": sectors, "sense_disc": disc})


def write_csv(out: Path, seeds: list[int], cov: dict[str, np.ndarray]) -> None:
    """OUT.csv: one row per design and seed."""
    with open(out.with_suffix(".csv"), "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["design", "seed", "coverage_pct"])
        for key, v in cov.items():
            w.writerows([key, seed, f"{x:.4f}"] for seed, x in zip(seeds, v))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--speed", type=float, default=5.0, help="UAV speed, m/s (default %(default)s)")
    ap.add_argument("--teacher", choices=sorted(TEACHERS), default="oracle")
    ap.add_argument("--reach", type=float, help="local-oracle: discs farther than REACH m left to claim "
                    "(default: LocalOracleTeacher's)")
    ap.add_argument("--sectors", type=int, default=4, choices=range(1, 17), metavar="1..16",
                    help="learner.sense_sectors, the view's direction sectors of sensing, for the student, spread "
                    "and claim alike (default %(default)s)")
    add_cloning_args(ap)
    ap.add_argument("--no-claim", action="store_true", help="observe without the claim features")
    ap.add_argument("--disc", action="store_true", help="observe the densest sensed disc too (learner.sense_disc)")
    ap.add_argument("--train-seed", type=int, default=0, help="the training's seed (default %(default)s)")
    ap.add_argument("--weights", default="/tmp/privileged.npz", help="where the weights go (default %(default)s)")
    ap.add_argument("--load", action="store_true", help="fly --weights, no training")
    ap.add_argument("--teacher-only", action="store_true", help="fly the teacher and claim, no training")
    ap.add_argument("--out", help="OUT.csv: per-seed coverage")
    ap.add_argument("--compare", help="also pair the learner with this CSV's spread and claim rows of --variant "
                    "(docs/figures/privileged-teacher.csv: the same held-out seeds, another sensing)")
    ap.add_argument("--variant", help="the --compare CSV's variant")
    args = ap.parse_args()
    torch.set_num_threads(1)
    cfg = make_config(args.speed, args.sectors, args.disc)
    weights, claim = Path(args.weights), not args.no_claim
    teacher = TEACHERS[args.teacher]
    if args.reach is not None:
        teacher = type("Teacher", (teacher,), {"reach_m": args.reach})
    seeds = list(range(args.first_seed, args.first_seed + args.seeds))
    held_out = [s + EVAL_SEED_OFFSET for s in seeds]
    if args.teacher_only:
        cov = fly_teacher(cfg, held_out, args.episodes, teacher)
        for key, v in cov.items():
            print(f"  {key}: {mean_ci(v)[0]:.1f} ± {mean_ci(v)[1]:.1f}%")
        gain = paired_effect(cov["claim"], cov["teacher"])
        print(f"  teacher minus claim: {effect_text(gain, digits=1, noun='seeds')}")
        if args.out:
            write_csv(Path(args.out), seeds, cov)
        return
    if not args.load:
        model, times = train(cfg, list(range(16)), bc_episodes=args.bc_episodes, bc_epochs=args.epochs,
                             dagger_rounds=args.dagger, ppo_steps=args.ppo_steps, coverage_bonus=5.0,
                             seed=args.train_seed, teacher=teacher, claim=claim, disc=args.disc, say=lambda s: None,
                             net=[int(w) for w in args.net.split(",")])
        print(f"cloning accuracy {times['accuracy']:.3f} ({times['total_s']:.0f} s)", flush=True)
        np.savez(weights, **export(model, cfg, 4, False, claim, args.disc))
        load_policy.cache_clear()
    cov = fly_against_heuristics(cfg, held_out, weights, args.episodes)
    if args.compare:
        rows = [r for r in csv.DictReader(open(args.compare)) if r["variant"] == args.variant]
        for a in ("spread", "claim"):
            got = {int(r["seed"]): float(r["coverage_pct"]) for r in rows if r["design"] == a}
            bar = np.array([got.get(s, np.nan) for s in seeds])
            print(f"  learner minus {a} of {args.variant} ({mean_ci(bar)[0]:.1f} ± {mean_ci(bar)[1]:.1f}%): "
                  f"{effect_text(paired_effect(bar, cov['learner']), digits=1, noun='seeds')}")
    if args.out:
        write_csv(Path(args.out), seeds, cov)


if __name__ == "__main__":
    main()
