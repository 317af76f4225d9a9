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


# -- PCG64 in the kernels ------------------------------------------------------
# numba reaches a Generator only as a function argument, so a parallel kernel
# cannot draw from one Generator per env. It can run numpy's PCG64 itself on
# each env's state copied into an array: the same 128-bit LCG step and XSL-RR
# output as numpy's pcg64_next64, and next_double = (next64 >> 11) * 2^-53,
# so the kernel draws the very numbers numpy would, and its state goes back
# into the Generator afterwards (`pcg64_state`, `set_pcg64_state`).
# tests/test_world.py checks the stream against numpy's.
_MULT_HI = np.uint64(0x2360ED051FC65DA4)
_MULT_LO = np.uint64(0x4385DF649FCCF645)
_M32 = np.uint64(0xFFFFFFFF)
_S32 = np.uint64(32)


def pcg64_state(rng: np.random.Generator) -> np.ndarray | None:
    """rng's PCG64 state as uint64 (state_hi, state_lo, inc_hi, inc_lo), or
    None if its bit generator is not PCG64."""
    st = rng.bit_generator.state
    if st.get("bit_generator") != "PCG64":
        return None
    s, inc, m = st["state"]["state"], st["state"]["inc"], (1 << 64) - 1
    return np.array([s >> 64, s & m, inc >> 64, inc & m], np.uint64)


def set_pcg64_state(rng: np.random.Generator, words: np.ndarray) -> None:
    """Put the state a kernel advanced (pcg64_state's layout) back into rng;
    its buffered 32-bit half (unused by doubles) is kept."""
    st = rng.bit_generator.state
    hi, lo, inc_hi, inc_lo = (int(w) for w in words)
    st["state"] = {"state": hi << 64 | lo, "inc": inc_hi << 64 | inc_lo}
    rng.bit_generator.state = st


@njit(inline="always")
def _mul_64x64(a, b):
    """The full 128-bit product of two uint64: (hi, lo)."""
    a_lo, a_hi = a & _M32, a >> _S32
    b_lo, b_hi = b & _M32, b >> _S32
    p0, p1, p2, p3 = a_lo * b_lo, a_lo * b_hi, a_hi * b_lo, a_hi * b_hi
    mid = (p0 >> _S32) + (p1 & _M32) + (p2 & _M32)
    return p3 + (p1 >> _S32) + (p2 >> _S32) + (mid >> _S32), (p0 & _M32) | (mid << _S32)


@njit(inline="always")
def pcg64_double(st):
    """numpy's PCG64 next_double on the state words st (4,) uint64, in place."""
    hi, lo = _mul_64x64(st[1], _MULT_LO)
    hi += st[0] * _MULT_LO + st[1] * _MULT_HI
    new_lo = lo + st[3]
    hi += st[2] + (np.uint64(1) if new_lo < lo else np.uint64(0))
    st[0], st[1] = hi, new_lo
    x = hi ^ new_lo
    rot = hi >> np.uint64(58)
    out = (x >> rot) | (x << ((np.uint64(64) - rot) & np.uint64(63)))
    return (out >> np.uint64(11)) * (1.0 / 9007199254740992.0)


@njit(nogil=True)
def pcg64_episode_draws(st, exp_neg_lam, arrivals, turns, moves):
    """One env's episode draws after its UAV start, in start_episode's order:
    arrivals (T, N) = poisson(lam) by numpy's multiplication method (all 0,
    drawing nothing, if exp_neg_lam is 1, i.e. lam = 0), turns (T, N, 2) and
    moves (K, 2) uniforms (K = 0: none drawn)."""
    for t in range(arrivals.shape[0]):
        for i in range(arrivals.shape[1]):
            x = 0
            if exp_neg_lam < 1.0:
                prod = 1.0
                while True:
                    prod *= pcg64_double(st)
                    if prod > exp_neg_lam:
                        x += 1
                    else:
                        break
            arrivals[t, i] = x
    for t in range(turns.shape[0]):
        for i in range(turns.shape[1]):
            for k in range(turns.shape[2]):
                turns[t, i, k] = pcg64_double(st)
    for k in range(moves.shape[0]):
        for c in range(moves.shape[1]):
            moves[k, c] = pcg64_double(st)
