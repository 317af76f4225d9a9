"""Do federated tables make UAVs fly alike? Trains TRUAV without and with sharing, then measures the swarm.

    python docs/scripts/federated_spread.py [--seeds 3] [--episodes 1000] [--eval-episodes 20] \
        [--set learner.grid_cells=1 --set learner.sense_range_m=1500] [--every 1] [--max-weight 0.5]

Under `--preset paper` at 15 m/s, for federated.every = 0 and the given sharing: trains the seeds in
process (truav.analysis.trainer.run_chunk), then flies the trained tables greedily on held-out traffic from where
training left the swarm (seeds + 1000), stepping the driver to record every UAV's position, and prints
per design: greedy coverage, how often the agents' greedy actions agree in the states two agents both
learned in (pairs of the 5 agents, per seed), the mean distance between two UAVs, and the share of
(step, pair) with the two UAVs within comm range of each other (their coverage discs overlap).
"""
from __future__ import annotations

import argparse
import itertools

import numpy as np

from agents.controller import TruavController
from agents.qlearning import states_visited  # noqa: F401  (the ablation's "rows known", for reference)
from truav import seeding
from truav.analysis.driver import run_episodes
from truav.analysis.trainer import run_chunk
from truav.config import Config
from truav.presets import preset_overrides


def _parse_set(items: list[str]) -> dict:
    out: dict = {}
    for item in items:
        key, value = item.split("=", 1)
        section, name = key.split(".", 1)
        out.setdefault(section, {})[name] = float(value) if "." in value else int(value)
    return out


def measure(cfg: Config, seeds: list[int], episodes: int, eval_episodes: int) -> dict:
    trained = run_chunk("truav", cfg, seeds, episodes)
    q = trained.q
    init_rngs = [seeding.agent_rng(s, i) for s in seeds for i in range(cfg.scenario.n_uavs)]
    init = np.empty(q.shape)
    for k, rng in enumerate(init_rngs):  # the tables as drawn, to tell learned rows from untouched ones
        b, u = divmod(k, cfg.scenario.n_uavs)
        rng.random(out=init[b, u])
        init[b, u] *= cfg.learner.q_init_scale
    learned = (q != init).any(axis=3)
    agree = []
    for b in range(len(seeds)):
        for i, j in itertools.combinations(range(cfg.scenario.n_uavs), 2):
            both = learned[b, i] & learned[b, j]
            if both.any():
                agree.append(float(np.mean(q[b, i, both].argmax(1) == q[b, j, both].argmax(1))))
    held_out = [s + 1000 for s in seeds]
    ctrl = TruavController(cfg, held_out, train=False, q=q)
    ctrl.fused = False  # step by step, to see every position
    positions: list[np.ndarray] = []
    observe = ctrl.observe

    def recording(obs, done):
        positions.append(obs.pos.copy())
        observe(obs, done)

    ctrl.observe = recording
    metrics = run_episodes(cfg, held_out, ctrl, eval_episodes, start_pos=trained.uav_pos)
    pos = np.stack(positions)  # (steps, B, U, 2)
    d = np.linalg.norm(pos[:, :, :, None] - pos[:, :, None, :], axis=-1)
    iu = np.triu_indices(cfg.scenario.n_uavs, 1)
    pair_d = d[:, :, iu[0], iu[1]]
    return {"coverage_pct": float(np.mean(metrics["coverage_pct"])), "greedy_agree": float(np.mean(agree)),
            "pair_distance_m": float(pair_d.mean()),
            "pairs_in_range": float(np.mean(pair_d < cfg.scenario.comm_range_m))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--episodes", type=int, default=1000)
    ap.add_argument("--eval-episodes", type=int, default=20)
    ap.add_argument("--every", type=int, default=1)
    ap.add_argument("--max-weight", type=float, default=0.5)
    ap.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE")
    args = ap.parse_args()
    base = Config().replace(**preset_overrides("paper")).replace(scenario={"uav_speed_mps": 15.0},
                                                                 learner={"episodes": args.episodes})
    extra = _parse_set(args.set)
    if extra:
        base = base.replace(**extra)
    seeds = list(range(args.seeds))
    print("| federated | greedy coverage % | greedy actions agreeing (pairs of agents) | mean distance between two "
          "UAVs m | (step, pair) within comm range |")
    print("|---|---|---|---|---|")
    for every, weight in ((0, 0.5), (args.every, args.max_weight)):
        cfg = base.replace(federated={"every": every, "max_weight": weight})
        m = measure(cfg, seeds, args.episodes, args.eval_episodes)
        name = "off" if every == 0 else f"every {every}, max_weight {weight:g}"
        print(f"| {name} | {m['coverage_pct']:.1f} | {m['greedy_agree']:.2f} | {m['pair_distance_m']:.0f} | "
              f"{m['pairs_in_range']:.2f} |", flush=True)


if __name__ == "__main__":
    main()
