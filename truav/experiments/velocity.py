"""The paper's figure "Performance versus UAV velocity": schemes x speeds x
seeds, each trained for the paper's episodes, then evaluated greedily.
Schemes: truav, central, patrol (the paper's three), spread (the decentralized heuristic,
agents/spread_agent.py: the bar a learner must clear) and, on request,
patrol_ctrl (the patrol under the centralized control plane) and agent API
classes by name (pkg.module:Class, or a name an installed package registers).

Outputs under the run directory:

    velocity.csv      tidy: one row per (scheme, speed, seed, phase, episode window)
    summary.csv       per (scheme, speed): mean and 95% interval over seeds
    summary.md        the same, the main numbers, as a Markdown table
    velocity.png      the four panels (coverage, relay delay, energy, PDR) vs speed
    convergence.png   training curves per speed (sliding window)
    config.toml       the base configuration
    cells/            one .npz per finished cell (what a restart skips)
"""

from __future__ import annotations

from pathlib import Path

from truav.config import Config
from truav.experiments import report
from truav.stats import MIN_SEEDS_FOR_BAND
from truav.experiments.cells import BUILTIN_SCHEMES, Cell, CellResult
from truav.experiments.runner import seed_chunks

SCHEMES = ("truav", "central", "patrol", "spread")
"""spread: the decentralized heuristic (agents/spread_agent.py), the bar a learner must clear."""
CHOICES = BUILTIN_SCHEMES
"""patrol_ctrl: the patrol under the centralized control plane, what the control plane alone costs.
Besides these, an agents.api class by name (pkg.module:Class or a registered name)."""
SPEEDS = (5.0, 10.0, 15.0, 20.0, 25.0)
FILES = ("velocity.csv", "summary.csv", "summary.md", "velocity.png", "convergence.png", "config.toml")


def plan(schemes, speeds, seeds: list[int], episodes: dict[str, int], eval_episodes: int,
         seeds_per_cell: int) -> list[Cell]:
    return [Cell(s, float(v), chunk, episodes[s], eval_episodes)
            for s in schemes for v in speeds for chunk in seed_chunks(seeds, seeds_per_cell)]


def write_outputs(out: Path, base: Config, results: list[CellResult], window: int) -> list[Path]:
    out = Path(out)
    setting = ("speed_mps",)
    defaults = {"speed_mps": base.scenario.uav_speed_mps}
    report.write_tidy_csv(out / "velocity.csv", results, window, setting, defaults)
    rows = report.summary_rows(results, window)
    report.write_summary_csv(out / "summary.csv", rows)
    n_seeds = len({(r.cell.scheme, s) for r in results for s in r.cell.seeds}) // max(
        len({r.cell.scheme for r in results}), 1)
    ep = sorted({(r.cell.scheme, r.cell.episodes) for r in results})
    (out / "summary.md").write_text(
        "# Performance versus UAV velocity\n\n"
        f"Greedy evaluation of the trained policies on held-out traffic; mean ± 95% interval over "
        f"{n_seeds} seeds. Training episodes: {', '.join(f'{s} {e}' for s, e in ep)}.\n\n"
        + report.markdown_table(rows, setting) + "\n")
    report.versus_figure(rows, "speed_mps", "UAV velocity (m/s)", out / "velocity.png",
                         f"Performance versus UAV velocity (mean of {n_seeds} seeds, "
                         + ("95% bands)" if n_seeds >= MIN_SEEDS_FOR_BAND else "open markers: each seed)"))
    report.convergence_figure(results, out / "convergence.png", window,
                              f"Training convergence ({window}-episode sliding window)")
    return [out / f for f in FILES]
