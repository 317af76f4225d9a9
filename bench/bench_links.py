"""Env-steps/s of the TRUAV trainer with ideal and with channel-driven beacon links (links.model), runs
alternated (the machine may be shared: the two see the same load), one thread, the default scenario.

    python bench/bench_links.py                 # 6 pairs of batch-10, 30-episode runs
    python bench/bench_links.py --pairs 10 --batch 10 --episodes 50

Each figure times from the end of the first episode to the end of the last (start-up excluded), as
bench/bench_trainer.py's batch figures do; the ratio is channel / ideal of the medians.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from truav.cli_args import int_in  # noqa: E402
from truav.config import Config  # noqa: E402
from truav.trainer import run_chunk  # noqa: E402


def rate(links: str, batch: int, episodes: int) -> float:
    cfg = Config().replace(learner={"episodes": episodes}, roads={"warmup_steps": 0}, links={"model": links})
    stamps: list[float] = []
    run_chunk("truav", cfg, list(range(batch)), episodes + 1, on_episode=lambda e, m: stamps.append(time.perf_counter()))
    return batch * episodes * cfg.scenario.steps_per_episode / (stamps[-1] - stamps[0])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", type=int_in(1), default=6)
    ap.add_argument("--batch", type=int_in(1), default=10)
    ap.add_argument("--episodes", type=int_in(2), default=30)
    args = ap.parse_args()
    from agents.fused import set_threads
    set_threads(1)
    rate("ideal", 1, 2), rate("channel", 1, 2)  # compile (or load) both kernels' paths first
    got: dict[str, list[float]] = {"ideal": [], "channel": []}
    for i in range(args.pairs):
        for links in (("ideal", "channel") if i % 2 == 0 else ("channel", "ideal")):
            got[links].append(rate(links, args.batch, args.episodes))
        print(f"pair {i}: ideal {got['ideal'][-1]:,.0f}  channel {got['channel'][-1]:,.0f} env-steps/s", flush=True)
    med = {k: statistics.median(v) for k, v in got.items()}
    print(f"medians: ideal {med['ideal']:,.0f}, channel {med['channel']:,.0f} env-steps/s; "
          f"channel / ideal = {med['channel'] / med['ideal']:.3f}; load {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
