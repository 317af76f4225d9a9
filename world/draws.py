"""Per-episode random draws written straight into the batch's arrays.

numpy's `rng.poisson(lam, shape)` and `rng.random(shape)` cost about as much
per episode as a fifth of the episode's compiled steps, and the per-env
results were then stacked into (T, B, ...) copies. These compiled versions
consume each env's Generator exactly as numpy does (the same uniforms in the
same order: `Generator.random` is numpy's next_double, and Poisson with
lam < 10 is numpy's multiplication method, `random_poisson_mult`), fill the
(T, B, ...) arrays in place, and release the GIL, so the draw threads run in
parallel. tests/test_world.py checks them against numpy, stream included.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

POISSON_MULT_MAX_LAM = 10.0
"""numpy draws Poisson by multiplying uniforms below this mean (and by PTRS
rejection at or above it, which is left to numpy)."""


@njit(cache=True, nogil=True)
def _poisson_mult(rng, exp_neg_lam, out):
    # numpy's random_poisson_mult, element by element in C order of `out` (2-D).
    for t in range(out.shape[0]):
        for i in range(out.shape[1]):
            x = 0
            prod = 1.0
            while True:
                prod *= rng.random()
                if prod > exp_neg_lam:
                    x += 1
                else:
                    break
            out[t, i] = x


@njit(cache=True, nogil=True)
def _uniform(rng, out):
    for t in range(out.shape[0]):
        for i in range(out.shape[1]):
            for k in range(out.shape[2]):
                out[t, i, k] = rng.random()


def poisson_into(rng: np.random.Generator, lam: float, out: np.ndarray) -> None:
    """out[...] = rng.poisson(lam, out.shape), out 2-D int64 (any strides)."""
    if lam >= POISSON_MULT_MAX_LAM:
        out[...] = rng.poisson(lam, out.shape)
    elif lam == 0.0:  # numpy returns 0 without drawing
        out[...] = 0
    else:
        _poisson_mult(rng, math.exp(-lam), out)  # numpy's C exp(), i.e. the C library's


def uniform_into(rng: np.random.Generator, out: np.ndarray) -> None:
    """out[...] = rng.random(out.shape), out 3-D float64 (any strides)."""
    _uniform(rng, out)
