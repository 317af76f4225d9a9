"""Env-steps/s of the TRUAV trainer with ideal and with channel-driven beacon links (links.model), runs
alternated (the machine may be shared: they see the same load), one thread, the default scenario.

    python bench/bench_links.py                 # 6 rounds of batch-10, 30-episode runs of each variant
    python bench/bench_links.py --rounds 10 --batch 10 --episodes 50

Three variants: ``ideal``; ``channel-all``, channel links whose table says every beacon is delivered
(P_deliver = 1 at every distance, patched in), so the agents learn what ideal links teach them (checked)
and the difference is the cost of the links' draws alone; ``channel``, the default channel (noise 1e-9 W:
beacons reach ~60 m), where the UAVs also fly differently, which changes the world's own cost per step.
Each figure times from the end of the
first episode to the end of the last (start-up excluded), as bench/bench_trainer.py's batch figures do;
the ratios are of the medians. Time is this process's CPU time (one thread), not wall time: on a shared
machine (load 5-8 on 2 cores while this was written) wall-clock rates of the same run varied 3x.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

import numpy as np  # noqa: E402

from agents import controller  # noqa: E402
from truav.analysis.trainer import run_chunk  # noqa: E402
from truav.cli.args import int_in  # noqa: E402
from truav.config import Config  # noqa: E402
from world import link_phy  # noqa: E402


VARIANTS = {"ideal": {"links": {"model": "ideal"}},
            "channel-all": {"links": {"model": "channel"}},
            "channel": {"links": {"model": "channel"}}}


def all_delivered(cfg) -> link_phy.LinkParams:
    """The channel's table with every beacon delivered: the draws' cost, the ideal links' outcome."""
    table = link_phy.link_params(cfg).table
    return link_phy.LinkParams(np.ones_like(table), link_phy.TABLE_STEP_M)


def rate(variant: str, batch: int, episodes: int):
    """(env-steps per CPU second, final Q-tables) of one run."""
    cfg = Config().replace(learner={"episodes": episodes}, roads={"warmup_steps": 0}, **VARIANTS[variant])
    controller.link_params = all_delivered if variant == "channel-all" else link_phy.link_params
    stamps: list[float] = []
    res = run_chunk("truav", cfg, list(range(batch)), episodes + 1,
                    on_episode=lambda e, m: stamps.append(time.process_time()))
    return batch * episodes * cfg.scenario.steps_per_episode / (stamps[-1] - stamps[0]), res.q


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int_in(1), default=6)
    ap.add_argument("--batch", type=int_in(1), default=10)
    ap.add_argument("--episodes", type=int_in(2), default=30)
    args = ap.parse_args()
    from agents.fused import set_threads
    set_threads(1)
    for v in VARIANTS:
        rate(v, 1, 2)  # compile (or load) every path first
    got: dict[str, list[float]] = {v: [] for v in VARIANTS}
    names = list(VARIANTS)
    for i in range(args.rounds):
        q = {}
        for v in names[i % 3:] + names[:i % 3]:  # rotated: no variant always first after a pause
            r, q[v] = rate(v, args.batch, args.episodes)
            got[v].append(r)
        assert (q["ideal"] == q["channel-all"]).all(), "channel-all must learn what ideal links teach"
        print(f"round {i}: " + "  ".join(f"{v} {got[v][-1]:,.0f}" for v in names)
              + f" env-steps/s; load {os.getloadavg()[0]:.2f}", flush=True)
    med = {k: statistics.median(v) for k, v in got.items()}
    print("medians: " + ", ".join(f"{v} {med[v]:,.0f}" for v in names) + " env-steps/s; "
          f"channel-all / ideal = {med['channel-all'] / med['ideal']:.3f}, "
          f"channel / ideal = {med['channel'] / med['ideal']:.3f}")


if __name__ == "__main__":
    main()
