"""The numpy core of the deep independent learner (agents.deep_iql): N independent small MLP Q-networks,
each with its own target network, Adam state, replay buffer and generator, stepped as one.

One UAV's agent is the core with N = 1; the batched form is the core with N = B x U. Every array has
the network axis first and every operation acts on each network's slice alone (batched matmuls,
elementwise arithmetic, per-network draws from that network's own generator), so network i of a core
of N computes, bit for bit, what a core of one computes for it: the API's promise that the batched
form equals the per-UAV form (tests/unit/test_deep_iql.py checks it).

The biases are folded into the weights (a constant-1 input column per layer), so every product of the
forward and backward pass is a matmul, with no axis reductions whose summation order could depend on N.
"""

from __future__ import annotations

import numpy as np

from agents.api import HOVER, N_ACTIONS

_PCG_FIELDS = 6  # state hi/lo, inc hi/lo, has_uint32, uinteger: a PCG64 generator as uint64 words
_MASK64 = (1 << 64) - 1


def rng_words(rng: np.random.Generator) -> np.ndarray:
    """A PCG64 generator's whole state as 6 uint64 words (a state_dict holds arrays only)."""
    st = rng.bit_generator.state
    if st["bit_generator"] not in ("PCG64", "PCG64DXSM"):
        raise ValueError(f"cannot save a {st['bit_generator']} generator (PCG64 only)")
    s, inc = st["state"]["state"], st["state"]["inc"]
    return np.array([s >> 64, s & _MASK64, inc >> 64, inc & _MASK64, st["has_uint32"], st["uinteger"]], np.uint64)


def set_rng_words(rng: np.random.Generator, words: np.ndarray) -> None:
    """Restore in place what rng_words saved (the caller's generator object goes on from there)."""
    w = [int(x) for x in np.asarray(words, np.uint64)]
    st = rng.bit_generator.state
    st["state"] = {"state": (w[0] << 64) | w[1], "inc": (w[2] << 64) | w[3]}
    st["has_uint32"], st["uinteger"] = w[4], w[5]
    rng.bit_generator.state = st


def epsilon_at(episode: int, start: float, end: float, fraction: float, episodes: int) -> float:
    """The project's exploration schedule (LearnerConfig.epsilon_*): exponential decay from start to end
    over fraction x episodes, then end; linear when an end point is 0 (exponential cannot reach it)."""
    horizon = max(fraction * episodes, 1.0)
    if episode >= horizon:
        return end
    if end <= 0.0 or start <= 0.0:
        return start + (end - start) * episode / horizon
    return float(start * (end / start) ** (episode / horizon))


class QNets:
    """N MLPs sizes[0] -> ... -> sizes[-1] (ReLU between), parameters flat (N, P) per network."""

    def __init__(self, sizes: tuple[int, ...], rngs: list[np.random.Generator]):
        self.sizes = sizes
        self.layout = []  # (start, stop, fan_in, fan_out) of each layer's (fan_in + 1, fan_out) block
        start = 0
        for fin, fout in zip(sizes[:-1], sizes[1:]):
            self.layout.append((start, start + (fin + 1) * fout, fin, fout))
            start += (fin + 1) * fout
        self.n_params = start
        self.params = np.zeros((len(rngs), start))
        for i, rng in enumerate(rngs):  # network i from its own generator alone: the same in any N
            for k, (lo, hi, fin, fout) in enumerate(self.layout):
                # He-uniform for the ReLU layers; the output layer 10x smaller so initial Q are near 0
                lim = np.sqrt(6.0 / fin) * (0.1 if k == len(self.layout) - 1 else 1.0)
                w = np.zeros((fin + 1, fout))
                w[:fin] = rng.uniform(-lim, lim, size=(fin, fout))  # biases (last row) start at 0
                self.params[i, lo:hi] = w.ravel()

    def weights(self, flat: np.ndarray, k: int) -> np.ndarray:
        lo, hi, fin, fout = self.layout[k]
        return flat[:, lo:hi].reshape(len(flat), fin + 1, fout)

    def forward(self, flat: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
        """Q (N, M, A) of inputs x (N, M, F), and each layer's input with its 1-column (for backward)."""
        inputs, h = [], x
        for k in range(len(self.layout)):
            a = np.concatenate([h, np.ones(h.shape[:-1] + (1,))], axis=-1)
            inputs.append(a)
            h = a @ self.weights(flat, k)
            if k < len(self.layout) - 1:
                h = np.maximum(h, 0.0)
        return h, inputs

    def backward(self, flat: np.ndarray, inputs: list[np.ndarray], dout: np.ndarray) -> np.ndarray:
        """d loss / d params (N, P) from d loss / d Q (N, M, A)."""
        grad = np.empty_like(flat)
        d = dout
        for k in reversed(range(len(self.layout))):
            lo, hi, fin, fout = self.layout[k]
            a = inputs[k]
            grad[:, lo:hi] = (a.transpose(0, 2, 1) @ d).reshape(len(flat), -1)
            if k:  # through this layer's weights (not the bias row) and the ReLU before it
                d = (d @ self.weights(flat, k)[:, :fin, :].transpose(0, 2, 1)) * (a[..., :fin] > 0.0)
        return grad


def first_allowed(start: np.ndarray, allowed: np.ndarray) -> np.ndarray:
    """Per row, the first allowed action cyclically from start (N,) (HOVER if none is): the project's
    rule for an exploratory draw that the geofence forbids."""
    order = (start[:, None] + np.arange(N_ACTIONS)) % N_ACTIONS
    ok = np.take_along_axis(allowed, order, axis=1)
    return np.where(ok.any(axis=1), order[np.arange(len(start)), ok.argmax(axis=1)], HOVER)


def greedy(q: np.ndarray, allowed: np.ndarray) -> np.ndarray:
    """argmax over the allowed actions (first on ties; HOVER if none is allowed)."""
    return np.where(allowed.any(axis=-1), np.where(allowed, q, -np.inf).argmax(axis=-1), HOVER)
