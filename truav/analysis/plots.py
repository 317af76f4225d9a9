"""Figures: training convergence (the paper's 500-episode sliding window)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only; no display needed
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from truav.stats import MIN_SEEDS_FOR_BAND, mean_ci, sliding_mean  # noqa: E402

UNSMOOTHED = ("epsilon",)  # schedules, not noisy measurements
# (metric, axis label, scale applied to the raw value, the scaled value's possible range)
CONVERGENCE_PANELS = (
    ("coverage_pct", "coverage (%)", 1.0, (0.0, 100.0)),
    ("pdr", "packet delivery ratio (%)", 100.0, (0.0, 100.0)),
    ("delay_ms", "avg relay delay (ms)", 1.0, (0.0, np.inf)),
    ("energy_j", "energy per UAV (kJ/episode)", 1e-3, (0.0, np.inf)),
    ("reward", "mean reward per step", 1.0, (-np.inf, np.inf)),
    ("epsilon", "exploration rate", 1.0, (0.0, 1.0)),
)

MIN_RELATIVE_SPAN = {"energy_j": 0.05, "delay_ms": 0.05}
"""A panel's y axis spans at least this share of the curve's mean (energy moves by tenths of a percent:
autoscaled, a flat line looked like a wild swing)."""


def spanned_limits(values: np.ndarray, min_span: float, lo_bound: float = -np.inf) -> tuple[float, float] | None:
    """y limits showing ``values`` over at least ``min_span`` (centred, not below ``lo_bound``),
    or None if the values already span that much (matplotlib's own limits then)."""
    finite = np.asarray(values, float)[np.isfinite(values)]
    if not finite.size or finite.max() - finite.min() >= min_span:
        return None
    mid = (finite.max() + finite.min()) / 2
    lo = max(mid - min_span / 2, lo_bound)
    return lo, lo + min_span


def window_text(window: int, episodes: int) -> str:
    """What the curves average, in words that hold for short runs too."""
    if window >= episodes:
        return "running mean from the first episode"
    return f"trailing mean of the last {window} episodes (fewer in the first {window - 1})"


def convergence_figure(metrics: dict[str, np.ndarray], path: Path, window: int = 500,
                       title: str = "TRUAV training") -> Path:
    """Sliding-window means over episodes, mean over seeds with a 95% band."""
    panels = [p for p in CONVERGENCE_PANELS if p[0] in metrics]
    cols = 3
    rows = (len(panels) + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.0 * rows), squeeze=False)
    for ax, (name, label, scale, (lo, hi)) in zip(axes.ravel(), panels):
        raw = metrics[name] * scale
        smooth = raw if name in UNSMOOTHED else sliding_mean(raw, window, axis=0)  # (E, B)
        mean, half = mean_ci(smooth, axis=1)
        x = np.arange(1, len(mean) + 1)
        if smooth.shape[1] < MIN_SEEDS_FOR_BAND:
            if smooth.shape[1] > 1:  # too few seeds for a band: each seed, thin
                ax.plot(x, smooth, color="C0", lw=0.7, alpha=0.45)
        elif np.isfinite(half).any():
            # a t-interval of few seeds is wide: never draw it past what the metric can be
            ax.fill_between(x, np.clip(mean - half, lo, hi), np.clip(mean + half, lo, hi), color="C0", alpha=0.25,
                            lw=0)
        ax.plot(x, mean, color="C0", lw=1.5)
        if name in MIN_RELATIVE_SPAN and np.isfinite(mean).any():
            limits = spanned_limits(smooth, MIN_RELATIVE_SPAN[name] * abs(float(np.nanmean(mean))), lo)
            if limits is not None:
                ax.set_ylim(*limits)
        ax.set_xlabel("episode")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    for ax in axes.ravel()[len(panels):]:
        ax.axis("off")
    episodes, n_seeds = next(iter(metrics.values())).shape[:2]
    seeds = (f"mean of {n_seeds} seeds, 95% band" if n_seeds >= MIN_SEEDS_FOR_BAND
             else f"mean of {n_seeds} seeds (thin: each seed; no band below {MIN_SEEDS_FOR_BAND})" if n_seeds > 1
             else "1 seed, no band")
    fig.suptitle(f"{title}: {window_text(window, episodes)}; {seeds}")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
