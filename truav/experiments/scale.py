"""Scalability, measured: the four metrics and control-plane traffic of the
distributed (TRUAV) and centralized (MA-SAC) schemes as the swarm grows
(5 -> 10 -> 20 UAVs) and traffic grows (200 -> 1000 vehicles), at one speed.

Control-plane traffic per second of simulated time:

- centralized: the counted uploads and commands (messages, bytes) and the
  radio airtime they take from each UAV;
- TRUAV: no controller traffic. Its agents read neighbours' positions from
  the aerial identification broadcasts UAVs send anyway (ASTM F3411 Remote
  ID: one 25-byte message at least once per second); that reference load is
  listed too, not charged (the broadcasts exist whatever the scheme).

Outputs: scale.csv (tidy), summary.csv, summary.md, scale.png, config.toml.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from truav.config import Config
from truav.experiments import report
from truav.experiments.cells import Cell, CellResult
from truav.experiments.runner import seed_chunks

SCHEMES = ("truav", "central", "spread")
UAVS = (5, 10, 20)
VEHICLES = (200, 1000)
REMOTE_ID_BYTES = 25
"""ASTM F3411-22a broadcast Remote ID message size (bytes)."""
REMOTE_ID_HZ = 1.0
"""Minimum broadcast rate of Remote ID messages (per second)."""
FILES = ("scale.csv", "summary.csv", "summary.md", "scale.png", "config.toml")


def plan(schemes, uavs, vehicles, speed: float, seeds: list[int], episodes: dict[str, int], eval_episodes: int,
         seeds_per_cell: int) -> list[Cell]:
    return [Cell(s, float(speed), chunk, episodes[s], eval_episodes,
                 (("scenario", "n_uavs", int(u)), ("scenario", "n_vehicles", int(n))))
            for s in schemes for n in vehicles for u in uavs for chunk in seed_chunks(seeds, seeds_per_cell)]


def traffic_table(rows: list[dict[str, object]], base: Config) -> str:
    """Markdown table of control-plane traffic per second of simulated time."""
    episode_s = base.scenario.steps_per_episode * base.scenario.step_s
    lines = ["| scheme | UAVs | vehicles | controller msgs/s | controller kB/s | control airtime % of radio time "
             "| action delay ms | Remote ID beacons msgs/s (reference) | beacon kB/s |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        u = int(r["n_uavs"])
        msgs = (r.get("eval_ctrl_up_msgs_mean", 0.0) + r.get("eval_ctrl_down_msgs_mean", 0.0)) / episode_s
        kbs = (r.get("eval_ctrl_up_bytes_mean", 0.0) + r.get("eval_ctrl_down_bytes_mean", 0.0)) / episode_s / 1e3
        air = 100.0 * r.get("eval_ctrl_airtime_s_mean", 0.0) / episode_s
        delay = r.get("eval_ctrl_delay_ms_mean", np.nan)
        delay_s = f"{delay:.1f}" if np.isfinite(delay) else "0"
        lines.append(f"| {r['scheme']} | {u} | {int(r['n_vehicles'])} | {msgs:.1f} | {kbs:.2f} | {air:.2f} | "
                     f"{delay_s} | {u * REMOTE_ID_HZ:.1f} | {u * REMOTE_ID_HZ * REMOTE_ID_BYTES / 1e3:.3f} |")
    return "\n".join(lines)


def write_outputs(out: Path, base: Config, results: list[CellResult], window: int) -> list[Path]:
    out = Path(out)
    setting = ("n_uavs", "n_vehicles")
    defaults = {"n_uavs": base.scenario.n_uavs, "n_vehicles": base.scenario.n_vehicles}
    report.write_tidy_csv(out / "scale.csv", results, window, setting, defaults)
    rows = report.summary_rows(results, window)
    report.write_summary_csv(out / "summary.csv", rows)
    speeds = sorted({r.cell.speed for r in results})
    wall = {}
    for r in results:
        key = (r.cell.scheme, dict((k, v) for _, k, v in r.cell.overrides)["n_uavs"])
        wall.setdefault(key, []).append(r.meta.get("train_env_steps_per_s", np.nan))
    speed_lines = "\n".join(f"| {s} | {u} | {np.nanmean(v):,.0f} |" for (s, u), v in sorted(wall.items()))
    (out / "summary.md").write_text(
        f"# Scalability at {', '.join(f'{s:g}' for s in speeds)} m/s\n\n"
        "Greedy evaluation on held-out traffic; mean ± 95% interval over seeds.\n\n"
        + report.markdown_table(rows, setting) + "\n\n## Control-plane traffic per second\n\n"
        + traffic_table(rows, base)
        + "\n\n## Training throughput (env-steps/s per worker process)\n\n| scheme | UAVs | env-steps/s |\n"
          "|---|---|---|\n" + speed_lines + "\n")
    report.versus_figure(rows, "n_uavs", "number of UAVs", out / "scale.png",
                         "Scalability: metrics versus swarm size (solid/dashed: fewer/more vehicles)",
                         group="n_vehicles")
    return [out / f for f in FILES]
