"""Per-episode random draws written straight into the batch's arrays.

numpy's `rng.poisson(lam, shape)` and `rng.random(shape)` cost about as much
per episode as a fifth of the episode's compiled steps, and the per-env
results were then stacked into (T, B, ...) copies. These compiled versions
consume each env's Generator exactly as numpy does (the same uniforms in the
same order: `Generator.random` is numpy's next_double, and Poisson with
lam < 10 is numpy's multiplication method, `random_poisson_mult`), fill the
(T, B, ...) arrays in place, and release the GIL, so the draw threads run in
parallel. tests/unit/test_world.py checks them against numpy, stream included.
"""

from __future__ import annotations

import math

import numpy as np
from llvmlite import ir
from truav import kernel_cache  # noqa: F401, I001 - numba's cache set up before numba loads a kernel
from numba import njit, types
from numba.extending import intrinsic

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
# tests/unit/test_world.py checks the stream against numpy's.
_MULT_HI = np.uint64(0x2360ED051FC65DA4)
_MULT_LO = np.uint64(0x4385DF649FCCF645)


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


RNG_WORDS = 6
"""Words of rng_words: PCG64 state (hi, lo), increment (hi, lo), has_uint32, uinteger."""


def rng_words(rng: np.random.Generator) -> np.ndarray:
    """rng's whole PCG64 state as RNG_WORDS uint64 (its buffered 32-bit half included), for a snapshot;
    ValueError if its bit generator is not PCG64."""
    st = rng.bit_generator.state
    if st.get("bit_generator") != "PCG64":
        raise ValueError(f"only PCG64 generators are captured, not {st.get('bit_generator')}")
    s, inc, m = st["state"]["state"], st["state"]["inc"], (1 << 64) - 1
    return np.array([s >> 64, s & m, inc >> 64, inc & m, st["has_uint32"], st["uinteger"]], np.uint64)


def rng_from_words(words: np.ndarray) -> np.random.Generator:
    """A PCG64 generator in the state rng_words captured."""
    hi, lo, inc_hi, inc_lo, has32, u32 = (int(w) for w in np.asarray(words, np.uint64).reshape(RNG_WORDS))
    bits = np.random.PCG64()
    bits.state = {"bit_generator": "PCG64", "state": {"state": hi << 64 | lo, "inc": inc_hi << 64 | inc_lo},
                  "has_uint32": has32, "uinteger": u32}
    return np.random.Generator(bits)


@intrinsic
def _mul_64x64(typingctx, a, b):
    """The full 128-bit product of two uint64, (hi, lo): one native multiply
    (LLVM i128), where four 32-bit ones would lengthen the generator's
    step-to-step dependency chain."""
    if a != types.uint64 or b != types.uint64:
        return None
    sig = types.UniTuple(types.uint64, 2)(a, b)

    def codegen(context, builder, signature, args):
        i128, i64 = ir.IntType(128), ir.IntType(64)
        prod = builder.mul(builder.zext(args[0], i128), builder.zext(args[1], i128))
        hi = builder.trunc(builder.lshr(prod, ir.Constant(i128, 64)), i64)
        lo = builder.trunc(prod, i64)
        return context.make_tuple(builder, signature.return_type, (hi, lo))

    return sig, codegen


@njit(inline="always")
def pcg64_next(s_hi, s_lo, inc_hi, inc_lo):
    """numpy's PCG64 step and next_double: (new state hi, lo, the double)."""
    hi, lo = _mul_64x64(s_lo, _MULT_LO)
    hi += s_hi * _MULT_LO + s_lo * _MULT_HI
    new_lo = lo + inc_lo
    hi += inc_hi + (np.uint64(1) if new_lo < lo else np.uint64(0))
    x = hi ^ new_lo
    rot = hi >> np.uint64(58)
    out = (x >> rot) | (x << ((np.uint64(64) - rot) & np.uint64(63)))
    return hi, new_lo, (out >> np.uint64(11)) * (1.0 / 9007199254740992.0)


@njit(nogil=True)
def pcg64_episode_draws(st, exp_neg_lam, arrivals, turns, moves):
    """One env's episode draws after its UAV start, in start_episode's order:
    arrivals (T, N) = poisson(lam) by numpy's multiplication method (all 0,
    drawing nothing, if exp_neg_lam is 1, i.e. lam = 0), turns (T, N, 2) and
    moves (K, 2) uniforms (K = 0: none drawn); st (4,) the PCG64 state words,
    advanced in place. The state lives in locals (registers) meanwhile."""
    hi, lo, inc_hi, inc_lo = st[0], st[1], st[2], st[3]
    for t in range(arrivals.shape[0]):
        for i in range(arrivals.shape[1]):
            x = 0
            if exp_neg_lam < 1.0:
                prod = 1.0
                while True:
                    hi, lo, u = pcg64_next(hi, lo, inc_hi, inc_lo)
                    prod *= u
                    if prod > exp_neg_lam:
                        x += 1
                    else:
                        break
            arrivals[t, i] = x
    for t in range(turns.shape[0]):
        for i in range(turns.shape[1]):
            for k in range(turns.shape[2]):
                hi, lo, u = pcg64_next(hi, lo, inc_hi, inc_lo)
                turns[t, i, k] = u
    for k in range(moves.shape[0]):
        for c in range(moves.shape[1]):
            hi, lo, u = pcg64_next(hi, lo, inc_hi, inc_lo)
            moves[k, c] = u
    st[0], st[1] = hi, lo
