"""Small statistics helpers: mean with a two-sided 95% Student-t interval, the paper's sliding-window
smoothing, and paired effects (a change measured on the same seeds or episodes with and without it) with
their interval and the number of pairs it would take to resolve them. Pure: no I/O."""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

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


def nan_mean(values, axis: int = 0) -> np.ndarray:
    """Mean over `axis` ignoring NaNs; an all-NaN column (no packet delivered, say) is NaN without a warning."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.nanmean(np.asarray(values, dtype=np.float64), axis=axis)


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


# -- paired effects ---------------------------------------------------------------------
@dataclass(frozen=True)
class Effect:
    """The mean of paired differences b - a (the same seeds or episodes with and without a change) and its
    two-sided 95% Student-t half-width."""

    diff: float
    half: float
    """NaN with fewer than 2 pairs."""
    n: int
    sd: float
    """Standard deviation of the differences (NaN with fewer than 2 pairs)."""

    @property
    def lo(self) -> float:
        return self.diff - self.half

    @property
    def hi(self) -> float:
        return self.diff + self.half

    @property
    def identical(self) -> bool:
        """Every pair equal: no difference at all (not merely none detectable)."""
        return self.n >= 2 and self.sd == 0.0 and self.diff == 0.0

    @property
    def resolved(self) -> bool:
        """The interval excludes zero."""
        return self.n >= 2 and math.isfinite(self.half) and abs(self.diff) > self.half


def paired_effect(a, b) -> Effect:
    """The effect b - a over the pairs where both values are finite (a NaN metric drops its pair)."""
    a, b = np.asarray(a, dtype=np.float64).ravel(), np.asarray(b, dtype=np.float64).ravel()
    if a.shape != b.shape:
        raise ValueError(f"paired values need equal lengths, got {a.size} and {b.size}")
    d = (b - a)[np.isfinite(a) & np.isfinite(b)]
    n = int(d.size)
    if n == 0:
        return Effect(math.nan, math.nan, 0, math.nan)
    diff = float(d.mean())
    if n == 1:
        return Effect(diff, math.nan, 1, math.nan)
    sd = float(d.std(ddof=1))
    return Effect(diff, t95(n - 1) * sd / math.sqrt(n), n, sd)


def pairs_to_resolve(sd: float, size: float, limit: int = 100_000) -> int | None:
    """Roughly how many pairs make the 95% half-width smaller than ``size`` at this spread of differences
    (an effect of that size would then show as an interval that excludes zero, about half the time:
    twice as many make it likely); None when it cannot be said (no spread known, no size, past ``limit``)."""
    if not (math.isfinite(sd) and math.isfinite(size)) or size == 0.0:
        return None
    if sd == 0.0:
        return 2
    # the normal approximation first, then the t correction by a short walk up
    n = max(2, math.ceil((1.96 * sd / abs(size)) ** 2))
    while n <= limit and t95(n - 1) * sd / math.sqrt(n) >= abs(size):
        n += 1
    return n if n <= limit else None


def effect_text(e: Effect, digits: int = 2, noun: str = "pairs", size: float | None = None) -> str:
    """One cell of a comparison: the difference with its 95% interval, or why there is none. When the
    interval covers zero: "no effect detectable at this size (±X)" and about how many ``noun`` would
    resolve a difference of the observed size (or of ``size``, when given), unless that size prints as
    zero at ``digits``: a difference of "0.00" is not one more pairs would resolve, the interval says it all."""
    f = f"{{:+.{digits}f}}"
    if e.n == 0:
        return "n/a (no pair with both values)"
    if e.n == 1:
        return f"{f.format(e.diff)} (1 pair: no interval; more {noun} give one)"
    if e.identical:
        return f"{f.format(0.0)}: identical in all {e.n} {noun}"
    if e.resolved:
        return f"{f.format(e.diff)} ±{e.half:.{digits}f} (95% CI, {e.n} {noun})"
    target = abs(e.diff) if size is None else abs(size)
    # a difference that prints as zero at these digits is no size to aim at: no count of pairs is asked for
    shown_target = round(target, digits)
    need = pairs_to_resolve(e.sd, target) if shown_target > 0 else None
    more = f"; ~{need} {noun} would resolve a difference of {target:.{digits}f}" if need else ""
    return f"{f.format(e.diff)}: no effect detectable at this size (±{e.half:.{digits}f}, {e.n} {noun}){more}"


NO_DATA = "no data"


def shown(value: float, spec: str, unit: str = "") -> str:
    """``value`` formatted by ``spec`` followed by ``unit`` (e.g. "%", " J"), or "no data" (right-aligned to the
    spec's width, without the unit) for a metric that had nothing to measure (a PDR without packets is NaN,
    which would print as ``nan``)."""
    if value is not None and math.isfinite(value):
        return format(value, spec) + unit
    width = "".join(ch for ch in spec.split(".")[0] if ch.isdigit())
    return NO_DATA.rjust(int(width) + len(unit)) if width else NO_DATA
