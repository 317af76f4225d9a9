"""Figures: training convergence (the paper's 500-episode sliding window)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only; no display needed
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from truav.stats import mean_ci, sliding_mean  # noqa: E402

UNSMOOTHED = ("epsilon",)  # schedules, not noisy measurements
# (metric, axis label, scale applied to the raw value)
CONVERGENCE_PANELS = (
    ("coverage_pct", "coverage (%)", 1.0),
    ("pdr", "packet delivery ratio (%)", 100.0),
    ("delay_ms", "avg relay delay (ms)", 1.0),
    ("energy_j", "energy per UAV (kJ/episode)", 1e-3),
    ("reward", "mean reward per step", 1.0),
    ("epsilon", "exploration rate", 1.0),
)


def convergence_figure(metrics: dict[str, np.ndarray], path: Path, window: int = 500,
                       title: str = "TRUAV training") -> Path:
    """Sliding-window means over episodes, mean over seeds with a 95% band."""
    panels = [p for p in CONVERGENCE_PANELS if p[0] in metrics]
    cols = 3
    rows = (len(panels) + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.0 * rows), squeeze=False)
    for ax, (name, label, scale) in zip(axes.ravel(), panels):
        raw = metrics[name] * scale
        smooth = raw if name in UNSMOOTHED else sliding_mean(raw, window, axis=0)  # (E, B)
        mean, half = mean_ci(smooth, axis=1)
        x = np.arange(1, len(mean) + 1)
        ax.plot(x, mean, color="C0", lw=1.5)
        if np.isfinite(half).any():
            ax.fill_between(x, mean - half, mean + half, color="C0", alpha=0.25, lw=0)
        ax.set_xlabel("episode")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    for ax in axes.ravel()[len(panels):]:
        ax.axis("off")
    n_seeds = next(iter(metrics.values())).shape[1]
    fig.suptitle(f"{title} — {window}-episode sliding window, mean of {n_seeds} seeds, 95% band")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
