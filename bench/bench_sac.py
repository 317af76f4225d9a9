"""Training speed of the centralized SAC baseline (`truav train --scheme central`).

    python bench/bench_sac.py                        # this checkout: ~1 minute
    python bench/bench_sac.py --compare DIR          # and the checkout at DIR (e.g. main), in the same machine state
    python bench/bench_sac.py --config literal --compare DIR   # the literal config (Config()), e.g. against a
                                                     # checkout older than the presets (0cd7060)

Each run is a fresh process training 10 seeds of the paper preset (or,
with --config literal, the default Config(): the paper's Table read
literally) on one thread for 80 episodes (the first 50 are the random-action warm-up of
central.learning_starts = 5000 steps, without gradient steps); the figure is
the time per 10-seed episode of learning (episodes 51-80: world, acting,
replay and 25 gradient steps of every seed), from per-episode time stamps,
so start-up and warm-up are left out. Wall and CPU time are both printed:
on a shared machine CPU time is the steadier. Each figure is the best of
--repeats runs; quote `uptime` with them.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))
sys.path.insert(0, ROOT)

from truav.cli.args import int_in  # noqa: E402

BEFORE_S_PER_EPISODE = 0.32
"""Wall seconds per 10-seed episode of learning at commit d2daf94 (2026-12-01, load 0.7, before the
hand-written gradients): `truav train --scheme central --preset paper --seeds 10 --workers 1` took 14.7 s for
80 episodes and 69.1 s for 250, i.e. 54.4 s for 170 learning episodes. A recorded constant, measured
by whole runs (this bench's --compare measures another checkout the same way as this one)."""

_RUN = r"""
import json, sys, time
sys.path.insert(0, {root!r})
from truav.analysis.trainer import run_chunk
from truav.config import Config
import agents.sac as sac
spent = [0.0, 0]
update = sac.BatchedSAC.update
def timed_update(self):
    t0 = time.perf_counter(); update(self); spent[0] += time.perf_counter() - t0; spent[1] += 1
sac.BatchedSAC.update = timed_update
cfg = Config()
if {config!r} == "paper":
    from truav.presets import preset_overrides  # not in checkouts before the presets: use --config literal there
    cfg = cfg.replace(**preset_overrides("paper"))
warm = cfg.central.learning_starts // cfg.scenario.steps_per_episode
wall, cpu = [], []
def stamp(e, m):
    wall.append(time.perf_counter()); cpu.append(time.process_time())
    if e == warm:
        spent[:] = [0.0, 0]
run_chunk("central", cfg, list(range({seeds})), warm + 1 + {episodes}, on_episode=stamp)
print(json.dumps(dict(wall=(wall[-1] - wall[warm]) / {episodes}, cpu=(cpu[-1] - cpu[warm]) / {episodes},
                      update_ms=1e3 * spent[0] / spent[1], warmup_wall=(wall[warm - 1] - wall[0]) / (warm - 1),
                      steps=cfg.scenario.steps_per_episode)))
"""


def measure(root: str, seeds: int, episodes: int, config: str = "paper") -> dict:
    """One fresh process training `seeds` seeds for `episodes` learning episodes with the code at root,
    on the paper preset or the literal config (config "paper" or "literal")."""
    code = _RUN.format(root=root, seeds=seeds, episodes=episodes, config=config)
    out = subprocess.run([sys.executable, "-c", code], cwd=root, check=True, capture_output=True, text=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def best(root: str, seeds: int, episodes: int, repeats: int, config: str = "paper") -> dict:
    runs = [measure(root, seeds, episodes, config) for _ in range(repeats)]
    return {k: min(r[k] for r in runs) for k in runs[0]}


def line(name: str, r: dict, seeds: int) -> str:
    return (f"{name}: {r['wall']:.3f} s wall ({r['cpu']:.3f} s CPU) per {seeds}-seed episode of learning, "
            f"{seeds * r['steps'] / r['wall']:,.0f} env-steps/s; {r['update_ms']:.2f} ms per gradient step; "
            f"warm-up episodes {r['warmup_wall']:.3f} s")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--compare", metavar="DIR", help="also time the checkout at DIR (e.g. main's), alternating runs")
    ap.add_argument("--repeats", type=int_in(1), default=2, help="best of this many runs per figure (default 2)")
    ap.add_argument("--episodes", type=int_in(1), default=30, help="learning episodes per run (default 30)")
    ap.add_argument("--config", choices=("paper", "literal"), default="paper",
                    help="the paper preset (default) or the literal config, Config() (for checkouts without presets)")
    args = ap.parse_args()
    if args.compare and not os.path.isfile(os.path.join(args.compare, "truav", "trainer.py")):
        ap.error(f"--compare {args.compare}: not a checkout of this project (no truav/analysis/trainer.py there)")
    if args.compare and args.config == "paper" and not os.path.isfile(os.path.join(args.compare, "truav", "presets.py")):
        ap.error(f"--compare {args.compare}: that checkout has no presets (no truav/presets.py): use --config literal")
    seeds = 10
    load = os.getloadavg()
    print(f"config: {args.config}; load: {load[0]:.2f} {load[1]:.2f} {load[2]:.2f} on {os.cpu_count()} cores")
    if args.compare:  # alternate the two checkouts, so both see the same machine state
        mine, other = [], []
        for _ in range(args.repeats):
            mine.append(measure(ROOT, seeds, args.episodes, args.config))
            other.append(measure(os.path.abspath(args.compare), seeds, args.episodes, args.config))
        now = {k: min(r[k] for r in mine) for k in mine[0]}
        then = {k: min(r[k] for r in other) for k in other[0]}
        print(line(f"this checkout ({ROOT})", now, seeds))
        print(line(f"compared ({args.compare})", then, seeds))
        print(f"speed-up, same machine state: x{then['wall'] / now['wall']:.2f} wall, "
              f"x{then['cpu'] / now['cpu']:.2f} CPU per learning episode; "
              f"x{then['update_ms'] / now['update_ms']:.2f} per gradient step")
    else:
        now = best(ROOT, seeds, args.episodes, args.repeats, args.config)
        print(line("this checkout", now, seeds))
    if args.config == "paper":  # the recorded figure is the paper preset's
        print(f"vs the recorded {BEFORE_S_PER_EPISODE:.2f} s before (d2daf94, load 0.7): "
              f"x{BEFORE_S_PER_EPISODE / now['wall']:.2f} wall")


if __name__ == "__main__":
    main()
