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

Selectable terms (off by default, r_i then exactly eq. (1)):

- difference reward: + w_difference x (vehicles in range that no other UAV
  covers) / the fair share: the coverage the swarm loses without UAV i;
- potential-based shaping: + discount phi(s') - phi(s), phi = w_shaping x
  vehicles in range / the fair share (policy-invariant, Ng et al. 1999).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from truav import kernel_cache  # noqa: F401, I001 - numba's cache set up before numba loads a kernel
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
    w_difference: float
    w_shaping: float
    discount: float


@njit(cache=True)
def reward_one(relayed, covered, energy_j, overlap, p):
    """One agent's r_i; the batch call and the fused trainer both use it."""
    return (p.w_relay * (relayed / p.relay_norm) + p.w_coverage * (covered / p.cov_norm)
            - p.w_energy * (energy_j / p.eng_norm) - p.w_overlap * overlap)


@njit(cache=True)
def extra_one(exclusive, in_range, prev_in_range, p):
    """One agent's selectable terms: the difference reward's coverage term and
    the shaping F = discount phi(s') - phi(s) (0 when both are off)."""
    extra = 0.0
    if p.w_difference != 0.0:
        extra += p.w_difference * (exclusive / p.cov_norm)
    if p.w_shaping != 0.0:
        extra += p.discount * (p.w_shaping * in_range / p.cov_norm) - p.w_shaping * prev_in_range / p.cov_norm
    return extra


@njit(cache=True)
def full_one(relayed, covered, energy_j, overlap, exclusive, in_range, prev_in_range, p):
    """r_i with the selectable terms; exactly reward_one when they are off."""
    r = reward_one(relayed, covered, energy_j, overlap, p)
    if p.w_difference != 0.0 or p.w_shaping != 0.0:
        r += extra_one(exclusive, in_range, prev_in_range, p)
    return r


@njit(cache=True)
def _rewards(relayed, covered, energy_j, overlap, exclusive, in_range, prev_in_range, p):
    out = np.empty(relayed.size)
    for i in range(relayed.size):
        out[i] = full_one(relayed[i], covered[i], energy_j[i], overlap[i], exclusive[i], in_range[i],
                          prev_in_range[i], p)
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
                                   *(float(w) for w in self.w), float(lc.w_difference), float(lc.w_shaping),
                                   float(lc.discount))
        self.extra = lc.w_difference != 0.0 or lc.w_shaping != 0.0
        """Whether a selectable term is on (then the callers pass exclusive and the vehicles in range)."""

    def terms(self, relayed, covered, energy_j, overlap) -> tuple[np.ndarray, ...]:
        """The four normalised terms (R_relay, R_cov, R_eng, R_ov)."""
        return (relayed / self.relay_norm, covered / self.cov_norm,
                energy_j / self.eng_norm, overlap)

    def __call__(self, relayed, covered, energy_j, overlap, exclusive=0.0, in_range=0.0,
                 prev_in_range=0.0) -> np.ndarray:
        """r_i (B, U); exclusive (world.network.EXCLUSIVE), in_range (vehicles in range now) and
        prev_in_range (at the previous observation) matter only with the selectable terms on."""
        arrays = np.broadcast_arrays(*(np.asarray(x, np.float64) for x in (relayed, covered, energy_j, overlap,
                                                                           exclusive, in_range, prev_in_range)))
        flat = [np.ascontiguousarray(x).ravel() for x in arrays]
        return _rewards(*flat, self.params).reshape(arrays[0].shape)
