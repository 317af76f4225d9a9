"""What the deep learner's networks have learned, measured on their own replay buffers
(docs/results/deep-learner.md, "what stops it").

    python docs/scripts/deep_learner_probe.py RUN

RUN is a `truav train --agent agents.deep_iql:DeepIql` run (its agent.npz holds every UAV's state_dict:
network, replay buffer, cursor). For each UAV, on the transitions its buffer holds at the end (the last
episodes of its training, in the order they were stored): the discounted return G actually obtained
after each (state, action) within its episode, beside the network's Q(s, a); how far Q is above G
(over-estimation), how well Q ranks the transitions by G (Pearson r), and how varied its greedy
actions are over the stored states (the share of the most frequent one).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from agents.api import N_ACTIONS
from agents.deep_iql import DeepIqlConfig
from agents.deep_iql_net import QNets


def returns(reward: np.ndarray, done: np.ndarray, discount: float) -> np.ndarray:
    """Discounted return after each transition, within its episode (chronological arrays; the last is done)."""
    g, out = 0.0, np.empty_like(reward)
    for t in range(len(reward) - 1, -1, -1):
        g = reward[t] + (0.0 if done[t] else discount * g)
        out[t] = g
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run", type=Path)
    ap.add_argument("--discount", type=float, default=0.95, help="learner.discount of the run")
    a = ap.parse_args()
    with np.load(a.run / "agent.npz") as d:
        st = {k[len("state."):]: d[k] for k in d.files if k.startswith("state.")}
    B, U, F = st["replay_x"].shape[0], st["replay_x"].shape[1], st["replay_x"].shape[-1]
    nets = QNets((F, *DeepIqlConfig().hidden, N_ACTIONS), [np.random.default_rng(0)])  # only its layout is used
    if nets.n_params != st["params"].shape[-1]:
        raise SystemExit(f"{a.run}: its networks are not DeepIqlConfig's default widths")
    print("| seed | UAV | transitions | mean G | mean Q(s,a) | Q - G | Pearson r(Q, G) | most frequent greedy action's share |")
    print("|---|---|---|---|---|---|---|---|")
    rows = []
    for b in range(B):
        for u in range(U):
            filled, cursor = int(st["filled"][b, u]), int(st["cursor"][b, u])
            order = np.roll(np.arange(filled), -cursor) if filled == st["replay_x"].shape[2] else np.arange(filled)
            x = st["replay_x"][b, u, order].astype(np.float64)
            act, r, done = st["replay_a"][b, u, order], st["replay_r"][b, u, order], st["replay_done"][b, u, order]
            g = returns(r, done, a.discount)
            q, _ = nets.forward(st["params"][b, u][None], x[None])
            q = q[0]
            qa = q[np.arange(len(act)), act]
            share = np.bincount(q.argmax(axis=1), minlength=N_ACTIONS).max() / len(q)
            r_qg = float(np.corrcoef(qa, g)[0, 1])
            rows.append((g.mean(), qa.mean(), qa.mean() - g.mean(), r_qg, share))
            print(f"| {b} | {u} | {filled} | {g.mean():.2f} | {qa.mean():.2f} | {qa.mean() - g.mean():+.2f} | "
                  f"{r_qg:.2f} | {share:.2f} |")
    m = np.array(rows).mean(axis=0)
    print(f"| all | mean | | {m[0]:.2f} | {m[1]:.2f} | {m[2]:+.2f} | {m[3]:.2f} | {m[4]:.2f} |")


if __name__ == "__main__":
    main()
