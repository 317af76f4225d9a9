"""The learned policy's network in numpy: the inference an agent process and the in-process evaluation share.

A multilayer perceptron (tanh hidden layers, then the action logits) exported from the trained PPO policy
(truav/analysis/ppo_train.py, Stable-Baselines3's MlpPolicy: its policy branch and action head), stored as a
small .npz: arrays ``w0, b0, w1, b1, ...`` (the last pair gives the logits) and the metadata it was trained
with (``peers``: heard-peer slots of the observation; ``n_features``; ``sense_sectors``; ``speed_mps``;
``memory``: 1 if the observation holds the memory features, agents.view_features; ``claim``: 1 if it holds the
climbing heuristic's features; ``disc``: 1 if it holds the densest sensed disc's (flown with learner.sense_disc
on); absent: 0).
Greedy: the action with the largest logit (the first on ties); logit N_ACTIONS is HOVER. No torch at run
time: numpy only. Pure computation: the file is read by the caller (agents.ppo_agent).
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

from truav.actions import HOVER, N_ACTIONS


class NumpyPolicy:
    """The exported network (see the module's docstring)."""

    def __init__(self, arrays: Mapping[str, np.ndarray]):
        n = sum(1 for k in arrays if k.startswith("w"))
        if n < 1:
            raise ValueError("the weights hold no layer (w0, b0, ...)")
        self.layers = [(np.asarray(arrays[f"w{i}"], np.float64), np.asarray(arrays[f"b{i}"], np.float64))
                       for i in range(n)]
        for i, (w, b) in enumerate(self.layers):
            if w.ndim != 2 or b.shape != (w.shape[1],) or (i and w.shape[0] != self.layers[i - 1][0].shape[1]):
                raise ValueError(f"layer {i} is shaped {w.shape} + {b.shape}: the layers do not chain")
        if self.layers[-1][0].shape[1] != N_ACTIONS + 1:
            raise ValueError(f"the last layer gives {self.layers[-1][0].shape[1]} logits, not {N_ACTIONS + 1}")
        self.n_features = self.layers[0][0].shape[0]
        self.peers = int(arrays["peers"]) if "peers" in arrays else None
        self.sense_sectors = int(arrays["sense_sectors"]) if "sense_sectors" in arrays else None
        self.memory = bool(int(arrays["memory"])) if "memory" in arrays else False
        self.claim = bool(int(arrays["claim"])) if "claim" in arrays else False
        self.disc = bool(int(arrays["disc"])) if "disc" in arrays else False
        self.speed_mps = float(arrays["speed_mps"]) if "speed_mps" in arrays else None

    def logits(self, obs: np.ndarray) -> np.ndarray:
        """(N, N_ACTIONS + 1) logits of N observations (N, n_features)."""
        x = np.asarray(obs, np.float64)
        for w, b in self.layers[:-1]:
            x = np.tanh(x @ w + b)
        w, b = self.layers[-1]
        return x @ w + b

    def greedy(self, obs: np.ndarray) -> np.ndarray:
        """The greedy actions (N,) of N observations: 0..N_ACTIONS-1, or HOVER."""
        best = np.argmax(self.logits(obs), axis=-1)
        return np.where(best == N_ACTIONS, HOVER, best).astype(np.int64)


__all__ = ["NumpyPolicy"]
