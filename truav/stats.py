"""Small statistics helpers: mean with a two-sided 95% Student-t interval,
and the paper's sliding-window smoothing."""

from __future__ import annotations

import warnings

import numpy as np

# Two-sided 95% Student-t critical values for 1..30 degrees of freedom.
_T95 = (12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179, 2.160, 2.145,
        2.131, 2.120, 2.110, 2.101, 2.093, 2.086, 2.080, 2.074, 2.069, 2.064, 2.060, 2.056, 2.052, 2.048,
        2.045, 2.042)


MIN_SEEDS_FOR_BAND = 3
"""Fewer seeds than this get no confidence band in a figure (a t-interval of 2 seeds is 12.7 standard
errors wide, clipped it reads 0-100%): the figure draws each seed instead."""


def t95(dof: int) -> float:
    """Two-sided 95% t critical value (normal 1.96 beyond 30 dof)."""
    if dof < 1:
        return float("nan")
    return _T95[dof - 1] if dof <= len(_T95) else 1.96


def mean_ci(values, axis: int = -1) -> tuple[np.ndarray, np.ndarray]:
    """Mean and 95% half-width over `axis`, ignoring NaNs."""
    v = np.asarray(values, dtype=np.float64)
    n = np.sum(np.isfinite(v), axis=axis)
    # One seed (or an all-NaN column) has no spread: the half-width is NaN, not a warning to the user.
    with np.errstate(invalid="ignore", divide="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        mean = np.nanmean(v, axis=axis) if v.size else np.nan
        sd = np.nanstd(v, axis=axis, ddof=1) if v.size else np.nan
        half = np.vectorize(t95)(np.maximum(n - 1, 0)) * sd / np.sqrt(n)
    return mean, np.where(n > 1, half, np.nan)


def sliding_mean(x: np.ndarray, window: int, axis: int = 0) -> np.ndarray:
    """Trailing moving average over `axis` (shorter windows at the start), NaN-aware."""
    x = np.moveaxis(np.asarray(x, dtype=np.float64), axis, 0)
    finite = np.isfinite(x)
    c = np.concatenate([np.zeros((1,) + x.shape[1:]), np.cumsum(np.where(finite, x, 0.0), axis=0)])
    k = np.concatenate([np.zeros((1,) + x.shape[1:]), np.cumsum(finite, axis=0)])
    idx = np.arange(1, x.shape[0] + 1)
    lo = np.maximum(idx - window, 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = (c[idx] - c[lo]) / (k[idx] - k[lo])
    return np.moveaxis(out, 0, axis)
