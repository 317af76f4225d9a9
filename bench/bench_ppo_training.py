"""What training the learned policy costs: Stable-Baselines3 PPO with shared parameters on TRUAV's vector
environment, beside the same loop on a standard peer task, PettingZoo's MPE simple_spread.

    python bench/bench_ppo_training.py            # 320,000 UAV-steps per task, the two alternated twice
    python bench/bench_ppo_training.py --full     # then PPO for the paper's whole budget on TRUAV (minutes)
    python bench/bench_ppo_training.py --quick    # a smoke run: 16,000 UAV-steps per task, once

TRUAV: truav.analysis.ppo_vec_env.TruavVecEnv as the shipped training uses it (docs/scripts/ppo_train.py:
--preset paper at --speed, learner.sense_range_m 1500, team term 5, --envs environments of 5 UAVs).
Peer: MPE's simple_spread (the `mpe2` package, the `peer` extra) with as many agents as TRUAV has UAVs and
the same episode length, --envs copies through truav.analysis.parallel_vec_env.ParallelVecEnv (no SuperSuit).
Both: the same SB3 PPO (truav.analysis.ppo_train.make_ppo: MlpPolicy, two tanh layers of 64, n_steps 100,
5 epochs, minibatches of 2,000, learning rate 3e-5), torch on --threads threads, device cpu. The networks'
input and output widths are each task's own (printed: observation features and actions).

Per run it times SB3's learn() (the environment and the policy built before the clock starts; a run of one
rollout per task first, not counted, so imports and compiled kernels are warm) and, inside it, the time in
the environment's reset() and step(); the rest is the learner: the policy's inference during rollouts, the
value bootstraps and the updates. An env-step is one step of one environment (all its agents); a UAV-step
one agent's step (SB3's timesteps). Each run also states its CPU seconds (process time): on a busy machine
the wall-clock rates fall with the load, the CPU figures much less. The end prints each task's median, the
ratio TRUAV / peer of env-steps/s (of the whole loop, of the environment alone: env-steps per second spent
in it, and per CPU-second), and the paper's budget (10 seeds x learner.episodes x scenario.steps_per_episode
env-steps under --preset paper) projected from TRUAV's measured loop rate; --full measures it instead.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from truav.cli.args import int_in, positive_float, run_main  # noqa: E402
from truav.config import Config  # noqa: E402
from truav.presets import preset_overrides  # noqa: E402

PAPER_SEEDS = 10
"""The paper's budget is 10 seeds x learner.episodes episodes (README, `truav train --preset paper`)."""
SHIPPED_PPO_STEPS = 320_000
"""docs/scripts/ppo_train.py's --ppo-steps default: the PPO budget of the shipped weights (UAV-steps)."""
COVERAGE_BONUS, LR, N_STEPS = 5.0, 3e-5, 100
"""docs/scripts/ppo_train.py's defaults for the team term, the learning rate and the rollout length."""


def truav_config(speed: float) -> Config:
    """The shipped training's configuration (docs/scripts/ppo_train.py's ``config``)."""
    from agents.spread_agent import SENSE_RANGE_M
    cfg = Config().replace(**preset_overrides("paper"))
    return cfg.replace(scenario={"uav_speed_mps": speed}, learner={"sense_range_m": SENSE_RANGE_M})


def make_env(task: str, cfg: Config, envs: int):
    if task == "truav":
        from truav.analysis.ppo_vec_env import TruavVecEnv
        return TruavVecEnv(cfg, list(range(envs)), coverage_bonus=COVERAGE_BONUS)
    from mpe2 import simple_spread_v3

    from truav.analysis.parallel_vec_env import ParallelVecEnv
    return ParallelVecEnv(lambda: simple_spread_v3.parallel_env(
        N=cfg.scenario.n_uavs, max_cycles=cfg.scenario.steps_per_episode, continuous_actions=False),
        list(range(envs)))


def timed(venv):
    """``venv`` wrapped so that the seconds spent in its reset() and step() are counted."""
    from stable_baselines3.common.vec_env import VecEnvWrapper

    class Timed(VecEnvWrapper):
        env_s, steps = 0.0, 0

        env_cpu_s = 0.0

        def _timed(self, call, *a):
            t, c = time.perf_counter(), time.process_time()
            out = call(*a)
            self.env_s += time.perf_counter() - t
            self.env_cpu_s += time.process_time() - c
            return out

        def reset(self):
            return self._timed(self.venv.reset)

        def step_async(self, actions):
            self._timed(self.venv.step_async, actions)

        def step_wait(self):
            self.steps += 1
            return self._timed(self.venv.step_wait)

    return Timed(venv)


def run(task: str, cfg: Config, envs: int, uav_steps: int, seed: int = 0) -> dict:
    """One learn() of ``uav_steps`` (rounded up to whole rollouts) on ``task``: its times and rates."""
    from truav.analysis.ppo_train import make_ppo
    env = timed(make_env(task, cfg, envs))
    model = make_ppo(env, lr=LR, n_steps=N_STEPS, seed=seed)
    t0, c0 = time.perf_counter(), time.process_time()
    model.learn(total_timesteps=uav_steps)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    env.close()
    env_steps = env.steps * envs
    return {"features": env.observation_space.shape[0], "actions": env.action_space.n, "wall_s": wall,
            "env_s": env.env_s, "env_steps": env_steps, "uav_steps": model.num_timesteps,
            "loop_rate": env_steps / wall, "env_rate": env_steps / env.env_s, "env_share": env.env_s / wall,
            "cpu_s": cpu, "cpu_env_share": env.env_cpu_s / cpu}


def line(name: str, r: dict) -> str:
    return (f"  {name:6s} {r['uav_steps']:>10,} UAV-steps in {r['wall_s']:7.1f} s: {r['loop_rate']:8,.0f} env-steps/s "
            f"({r['loop_rate'] * r['uav_steps'] / r['env_steps']:8,.0f} UAV-steps/s), environment alone "
            f"{r['env_rate']:8,.0f} env-steps/s, {100 * r['env_share']:4.1f}% of the time in the environment; CPU "
            f"{r['cpu_s']:.1f} s ({r['env_steps'] / r['cpu_s']:,.0f} env-steps per CPU-s, "
            f"{100 * r['cpu_env_share']:.1f}% in the environment)")


def median(runs: list[dict]) -> dict:
    return {k: statistics.median(r[k] for r in runs) for k in runs[0]}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--steps", type=int_in(1), default=SHIPPED_PPO_STEPS,
                    help="UAV-steps of PPO per run and task (default %(default)s, the shipped training's PPO budget)")
    ap.add_argument("--repeats", type=int_in(1), default=2, help="rounds of the two tasks, alternated (default 2)")
    ap.add_argument("--envs", type=int_in(1), default=16, help="environments per vector (default 16, as shipped)")
    ap.add_argument("--speed", type=positive_float, default=15.0, help="TRUAV's scenario.uav_speed_mps (default 15)")
    ap.add_argument("--threads", type=int_in(1), default=1, help="torch threads (default 1, as the shipped training)")
    ap.add_argument("--full", action="store_true", help="then run PPO for the paper's whole budget on TRUAV")
    ap.add_argument("--quick", action="store_true", help="a smoke run: 16,000 UAV-steps per task, one round")
    args = ap.parse_args()
    try:
        import mpe2  # noqa: F401
        import stable_baselines3  # noqa: F401
        import torch
    except ImportError as e:
        print(f"bench_ppo_training: needs the marl and peer extras: pip install -e '.[marl,peer]' ({e.name})",
              file=sys.stderr)
        return 2
    torch.set_num_threads(args.threads)
    cfg = truav_config(args.speed)
    uavs, per_episode = cfg.scenario.n_uavs, cfg.scenario.steps_per_episode
    steps, repeats = (2 * N_STEPS * args.envs * uavs, 1) if args.quick else (args.steps, args.repeats)
    budget = PAPER_SEEDS * cfg.learner.episodes * per_episode
    load = os.getloadavg()
    print(f"load: {load[0]:.2f} {load[1]:.2f} {load[2]:.2f} on {os.cpu_count()} cores; torch threads {args.threads}"
          + ("; a smoke run (--quick)" if args.quick else ""))
    print(f"{args.envs} environments x {uavs} agents = {args.envs * uavs} slots, episodes of {per_episode} steps, "
          f"{steps:,} UAV-steps per run")
    for task in ("truav", "peer"):  # warm-up: imports, compiled kernels, torch's first backward
        w = run(task, cfg, args.envs, N_STEPS * args.envs * uavs)
        print(f"  {task}: {w['features']} observation features, {w['actions']} actions (warm-up run: "
              f"{w['wall_s']:.1f} s, not counted)", flush=True)
    runs: dict[str, list[dict]] = {"truav": [], "peer": []}
    for k in range(repeats):
        for task in runs:
            runs[task].append(run(task, cfg, args.envs, steps))
            print(f"round {k + 1}/{repeats}" + line(task, runs[task][-1]), flush=True)
    t, p = median(runs["truav"]), median(runs["peer"])
    print(f"median of {repeats} (truav: TruavVecEnv, --preset paper at {args.speed:g} m/s; "
          f"peer: MPE simple_spread, N={uavs}):")
    print(line("truav", t))
    print(line("peer", p))
    print(f"  ratio truav / peer: {t['loop_rate'] / p['loop_rate']:.2f} of the whole loop's env-steps/s, "
          f"{t['env_rate'] / p['env_rate']:.2f} of the environment's alone, "
          f"{(t['env_steps'] / t['cpu_s']) / (p['env_steps'] / p['cpu_s']):.2f} per CPU-second of the loop")
    uav_rate = t["loop_rate"] * uavs
    print(f"paper budget: {PAPER_SEEDS} seeds x {cfg.learner.episodes} episodes x {per_episode} steps = "
          f"{budget:,} env-steps ({budget * uavs:,} UAV-steps); projected from the measured loop rate: "
          f"{budget * uavs / uav_rate / 60:.0f} min of PPO (target: at most 30 min); from its CPU time (a core of "
          f"its own): {budget / (t['env_steps'] / t['cpu_s']) / 60:.0f} min")
    if args.full:
        r = run("truav", cfg, args.envs, budget * uavs)
        print("paper budget, measured:" + line("truav", r))
        print(f"  {r['wall_s'] / 60:.1f} min of PPO for the paper's budget (target: at most 30 min)")
    return 0


if __name__ == "__main__":
    sys.exit(run_main("bench_ppo_training", main))
