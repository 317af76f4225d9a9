"""Train one PPO policy shared by every UAV with Stable-Baselines3 on TRUAV's vector environment, save it for
the agent processes, fly it: docs/how-to/train-with-sb3.md (needs the `marl` extra to train, not to fly).

    python examples/train_sb3.py --steps 200000         # train, write runs/sb3-ppo.npz
    PYTHONPATH=examples truav-swarm up --agent train_sb3:Sb3Agent --scenario paper-1500.toml --out runs/swarm-sb3
"""

from pathlib import Path

from agents.ppo_agent import PpoAgent

WEIGHTS = Path("runs/sb3-ppo.npz")  # relative to where you run it (the agent processes start there too)


class Sb3Agent(PpoAgent):
    """The `ppo` agent (numpy inference, no torch) flying the weights this script trained."""

    weights = WEIGHTS


if __name__ == "__main__":
    import argparse

    import numpy as np
    from stable_baselines3 import PPO
    from stable_baselines3.common.logger import Logger

    from truav.analysis.ppo_train import export
    from truav.analysis.ppo_vec_env import TruavVecEnv
    from truav.config import Config
    from truav.presets import preset_overrides

    ap = argparse.ArgumentParser(description="Train shared-parameter PPO on TruavVecEnv and save it for Sb3Agent.")
    ap.add_argument("--steps", type=int, default=200_000, help="UAV-steps of training (default 200000)")
    steps = ap.parse_args().steps

    # --- the few lines: the paper's scenario with 1.5 km sensing, 8 cities x 5 UAVs = 40 slots, one network
    cfg = Config().replace(**preset_overrides("paper")).replace(learner={"sense_range_m": 1500})
    env = TruavVecEnv(cfg, seeds=list(range(8)), coverage_bonus=5.0)  # local reward + 5 x the share covered
    model = PPO("MlpPolicy", env, n_steps=100, batch_size=1000, learning_rate=3e-4, seed=0, verbose=0)
    model.set_logger(Logger(folder=None, output_formats=[]))  # in memory: else SB3 leaves a dir in /tmp
    model.learn(total_timesteps=steps)
    WEIGHTS.parent.mkdir(parents=True, exist_ok=True)
    np.savez(WEIGHTS, **export(model, cfg, peers=4))  # numpy arrays: what the agent processes load
    print(f"trained {steps} UAV-steps; wrote {WEIGHTS}")
