"""The paper's local reward, eq. (1):

    r_i = alpha R_relay + beta R_cov - gamma R_eng - delta R_ov

with each term normalised to be O(1) (the paper gives the weights, not the
normalisation):

- R_relay = packets UAV i relayed this step / its fair share of the packets
  generated per step (packet_rate * n_vehicles * dt / n_uavs);
- R_cov = vehicles UAV i serves / its fair share (n_vehicles / n_uavs);
- R_eng = energy spent this step / the energy of cruising at P_move for the
  step (P_move dt): hovering costs P_hover/P_move = 0.8, cruising at v_ref 1;
- R_ov = sum over heard neighbours of the coverage-disc overlap fraction
  (see agents.state.neighbour_features).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from truav.config import Config


class RewardParams(NamedTuple):
    relay_norm: float
    cov_norm: float
    eng_norm: float
    w_relay: float
    w_coverage: float
    w_energy: float
    w_overlap: float


@njit(cache=True)
def reward_one(relayed, covered, energy_j, overlap, p):
    """One agent's r_i; the batch call and the fused trainer both use it."""
    return (p.w_relay * (relayed / p.relay_norm) + p.w_coverage * (covered / p.cov_norm)
            - p.w_energy * (energy_j / p.eng_norm) - p.w_overlap * overlap)


@njit(cache=True)
def _rewards(relayed, covered, energy_j, overlap, p):
    out = np.empty(relayed.size)
    for i in range(relayed.size):
        out[i] = reward_one(relayed[i], covered[i], energy_j[i], overlap[i], p)
    return out


class Reward:
    """Computes r_i (B, U) from a UAV's own step outcome and its overlap."""

    def __init__(self, cfg: Config):
        sc, lc, e = cfg.scenario, cfg.learner, cfg.energy
        self.relay_norm = max(cfg.traffic.packet_rate_hz * sc.n_vehicles * sc.step_s / sc.n_uavs, 1e-9)
        self.cov_norm = sc.n_vehicles / sc.n_uavs
        self.eng_norm = max(e.move_w * sc.step_s, 1e-9)
        self.w = (lc.w_relay, lc.w_coverage, lc.w_energy, lc.w_overlap)
        self.params = RewardParams(float(self.relay_norm), float(self.cov_norm), float(self.eng_norm),
                                   *(float(w) for w in self.w))

    def terms(self, relayed, covered, energy_j, overlap) -> tuple[np.ndarray, ...]:
        """The four normalised terms (R_relay, R_cov, R_eng, R_ov)."""
        return (relayed / self.relay_norm, covered / self.cov_norm,
                energy_j / self.eng_norm, overlap)

    def __call__(self, relayed, covered, energy_j, overlap) -> np.ndarray:
        arrays = np.broadcast_arrays(*(np.asarray(x, np.float64) for x in (relayed, covered, energy_j, overlap)))
        flat = [np.ascontiguousarray(x).ravel() for x in arrays]
        return _rewards(*flat, self.params).reshape(arrays[0].shape)
