"""SUMO traffic against the built-in model, in one run: the trace's build
time, and training env-steps/s on a trace against the grid's own mobility.

    python bench/bench_sumo.py                  # the paper's scenario: 200 vehicles, 5 UAVs, a 20-episode trace
    python bench/bench_sumo.py --episodes 20 --batch 5 --repeats 3

Build: a fresh cache directory, so netgenerate, randomTrips.py (with
duarouter's validation) and the libsumo run are all timed; the network and
routing part is reported apart. Training: one thread, a batch of seeds, the
fused TRUAV kernel, timed from the end of the first episode to the end of the
last (set-up, the trace's loading and the kernels' compilation excluded), the
best of --repeats runs for each mobility. The machine may be shared: quote
`uptime` with the figures. Needs the `sumo` extra.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from truav import jsonio  # noqa: E402
from truav.cli.args import int_in  # noqa: E402
from truav.config import Config  # noqa: E402


def train_rate(cfg: Config, batch: int, episodes: int) -> float:
    from agents.fused import set_threads
    from truav.analysis.trainer import run_chunk
    set_threads(1)
    stamps: list[float] = []
    run_chunk("truav", cfg.replace(learner={"episodes": episodes + 1}), list(range(batch)), episodes + 1,
              on_episode=lambda e, m: stamps.append(time.perf_counter()))
    return batch * episodes * cfg.scenario.steps_per_episode / (stamps[-1] - stamps[0])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--episodes", type=int_in(1), default=20, help="timed training episodes per run (default 20)")
    ap.add_argument("--batch", type=int_in(1), default=5, help="seeds trained as one batch (default 5)")
    ap.add_argument("--repeats", type=int_in(1), default=3, help="training runs per mobility, best kept (default 3)")
    ap.add_argument("--json", metavar="FILE", help="also write the figures as JSON")
    args = ap.parse_args()
    from truav.analysis import sumo_traffic
    cfg = Config().replace(scenario={"mobility": "sumo"}, roads={"warmup_steps": 0})
    with tempfile.TemporaryDirectory() as cache:
        os.environ["TRUAV_TRACE_CACHE"] = cache
        t0 = time.perf_counter()
        path, _ = sumo_traffic.build_trace(cfg)
        build_s = time.perf_counter() - t0
        meta = json.loads(str(np.load(path)["meta"]))
        rates = {}
        for mobility in ("builtin", "sumo"):
            run_cfg = cfg.replace(scenario={"mobility": mobility})
            rates[mobility] = max(train_rate(run_cfg, args.batch, args.episodes) for _ in range(args.repeats))
    n, rows = cfg.scenario.n_vehicles, cfg.sumo.trace_episodes * cfg.scenario.steps_per_episode + 1
    print(f"trace build ({n} vehicles, {cfg.sumo.warmup_s:g} s warm-up + {rows - 1} steps): {build_s:.1f} s "
          f"(network, trips and routes {meta['network_s']:.1f} s, SUMO {build_s - meta['network_s']:.1f} s)")
    print(f"training, batch {args.batch} on one thread, best of {args.repeats}: builtin {rates['builtin']:,.0f} "
          f"env-steps/s, sumo trace {rates['sumo']:,.0f} env-steps/s ({rates['sumo'] / rates['builtin']:.2f}x)")
    print(f"load average {os.getloadavg()[0]:.2f}")
    if args.json:
        Path(args.json).write_text(jsonio.dumps({"build_s": build_s, "network_s": meta["network_s"],
                                                 "env_steps_per_s": rates, "batch": args.batch,
                                                 "episodes": args.episodes, "load": os.getloadavg()[0]}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
