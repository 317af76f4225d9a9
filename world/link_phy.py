"""Channel-driven beacon links (`links.model = "channel"`): the PHY abstraction that turns the distance
between two UAVs into the probability that one's beacon reaches the other, and the counter-based draw
that decides each beacon. Pure (numpy, numba), no I/O; docs/channel-models.md, "Beacon links".

PHY abstraction, per beacon from UAV j to UAV i at distance d (equal altitudes: d is horizontal):

- received power P_rx = P_tx G / L(d), P_tx = channel.uav_tx_w, G = channel.antenna_gain_dbi, L the
  channel model's UAV-UAV path loss: for ``paper`` its air-to-air two-state link (FSPL + eta_LoS with
  probability channel.a2a_los_probability, FSPL + eta_NLoS otherwise: 1 and FSPL + eta_LoS by default),
  for every other model free space (world/channel_models.py);
- SNR = P_rx / channel.noise_w;
- modulation: IEEE 802.11p, 10 MHz, 6 Mbit/s, QPSK with the rate-1/2 K=7 convolutional code. The packet
  success rate is the NIST OFDM error model of ns-3 (src/wifi/model/nist-error-rate-model.cc; G. Pei,
  T. Henderson, "Validation of OFDM error rate model in ns-3", 2010): uncoded QPSK bit error
  p = 0.5 erfc(sqrt(SNR / 2)); Viterbi first-event error bound P_e = 0.5 sum_k a_k D^k, D = sqrt(4 p (1 - p)),
  with the code's distance spectrum (d_free 10) of `CODE_SPECTRUM`, capped at 1; success (1 - P_e)^(8 bytes);
- for ``paper`` the delivery probability averages the two states' successes with the LoS probability, as
  that model averages rates;
- airtime (the beacon's delay on the link): the 802.11p 10 MHz frame, preamble and SIGNAL 40 us, then
  8 us OFDM symbols of 48 data bits carrying SERVICE (16 bits), the PSDU and the tail (6 bits).

The delivery probability depends on the distance only, so it is tabulated once per run (`link_params`,
every `TABLE_STEP_M`) and looked up with linear interpolation by the same compiled function in the
trainer's kernel and in an agent process: the same float, the same decision.

Draw: beacon k of episode e (k = 0 the episode's first observation, k = t + 1 the one after step t) from
UAV j to UAV i under run seed s is delivered iff u(s, e, k, j, i) < P_deliver(d), u a splitmix64 hash of
the five integers, in [0, 1): the same seed gives the same drops, in any process, in any order.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from truav import kernel_cache  # noqa: F401, I001 - numba's cache set up before numba loads a kernel
from numba import njit

from world.channel_models import fspl_db

BEACON_RATE_BPS = 6e6
"""802.11p, 10 MHz channel, QPSK rate 1/2 (the OFDM rate ns-3 names OfdmRate6MbpsBW10MHz)."""
PREAMBLE_S = 40e-6
"""802.11p 10 MHz: PLCP preamble 32 us and SIGNAL symbol 8 us."""
SYMBOL_S = 8e-6
BITS_PER_SYMBOL = 48
SERVICE_TAIL_BITS = 22
CODE_SPECTRUM = ((10, 36.0), (12, 211.0), (14, 1404.0), (16, 11633.0), (18, 77433.0), (20, 502690.0),
                 (22, 3322763.0), (24, 21292910.0), (26, 134365911.0))
"""(distance, bit-error weight) of the rate-1/2 K=7 code, as ns-3's NIST model uses them."""
TABLE_STEP_M = 1.0


class LinkParams(NamedTuple):
    """What the compiled draw needs: P_deliver every `step_m` from 0 m (the last value beyond the table)."""
    table: np.ndarray  # (n,) float64; size 0: ideal links (every beacon heard)
    step_m: float


IDEAL = LinkParams(np.zeros(0), 1.0)


def qpsk_ber(snr):
    """Uncoded QPSK (Gray) bit error rate at linear SNR."""
    erfc = np.vectorize(math.erfc, otypes=[float])
    return 0.5 * erfc(np.sqrt(np.asarray(snr, float) / 2.0))


def coded_ber(p):
    """Rate-1/2 K=7 convolutional code, hard Viterbi decoding: union bound on the bit error, capped at 1."""
    d = np.sqrt(4.0 * p * (1.0 - p))
    return np.minimum(0.5 * sum(a * d ** k for k, a in CODE_SPECTRUM), 1.0)


def packet_success(snr, n_bytes: int):
    """Probability that a frame of n_bytes is received without error at linear SNR."""
    return (1.0 - coded_ber(qpsk_ber(snr))) ** (8 * n_bytes)


def airtime_s(n_bytes: int) -> float:
    """802.11p 10 MHz 6 Mbit/s frame duration: preamble + ceil((service + 8 bytes + tail) / 48) symbols."""
    return PREAMBLE_S + SYMBOL_S * math.ceil((SERVICE_TAIL_BITS + 8 * n_bytes) / BITS_PER_SYMBOL)


def snr_at(loss_db, channel) -> np.ndarray:
    return channel.uav_tx_w * 10.0 ** ((channel.antenna_gain_dbi - loss_db) / 10.0) / channel.noise_w


def delivery_probability(distance_m, cfg) -> np.ndarray:
    """P(beacon delivered) between two UAVs distance_m apart under cfg's channel and links settings."""
    ch, n = cfg.channel, cfg.links.beacon_bytes
    free = fspl_db(np.asarray(distance_m, float), ch.carrier_hz)
    if ch.model == "paper":
        p = ch.a2a_los_probability
        return p * packet_success(snr_at(free + ch.eta_los_db, ch), n) \
            + (1.0 - p) * packet_success(snr_at(free + ch.eta_nlos_db, ch), n)
    return packet_success(snr_at(free, ch), n)


def threshold_distance_m(cfg, probability: float = 0.5) -> float:
    """The distance at which P_deliver falls to `probability` (1 cm resolution; the table's range at most)."""
    d = np.arange(0.0, max_distance_m(cfg), 0.01)
    below = np.flatnonzero(delivery_probability(d, cfg) < probability)
    return float(d[below[0]]) if below.size else math.inf


def max_distance_m(cfg) -> float:
    """The farthest two UAVs can be apart (the area's diagonal), plus a step."""
    return cfg.scenario.area_m * math.sqrt(2.0) + 2.0 * TABLE_STEP_M


def link_params(cfg) -> LinkParams:
    """The run's link model: IDEAL for links.model "ideal", else the tabulated delivery probability."""
    if cfg.links.model != "channel":
        return IDEAL
    d = np.arange(0.0, max_distance_m(cfg), TABLE_STEP_M)
    return LinkParams(np.ascontiguousarray(delivery_probability(d, cfg), np.float64), TABLE_STEP_M)


@njit(cache=True)
def _mix(z):
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


@njit(cache=True)
def link_uniform(seed, episode, k, src, dst):
    """Counter-based uniform in [0, 1) of beacon k of `episode` from UAV src to UAV dst under `seed`."""
    golden = np.uint64(0x9E3779B97F4A7C15)
    h = _mix(np.uint64(seed & 0xFFFFFFFFFFFF) + golden)
    h = _mix(h ^ (np.uint64(episode & 0xFFFFFFFF) + golden))
    h = _mix(h ^ (np.uint64(k & 0xFFFFFFFF) + golden))
    h = _mix(h ^ ((np.uint64(src & 0xFFFF) << np.uint64(16)) | np.uint64(dst & 0xFFFF)))
    return np.float64(h >> np.uint64(11)) / 9007199254740992.0


@njit(cache=True)
def deliver_probability_at(table, step_m, distance):
    x = distance / step_m
    i = int(x)
    if i >= table.size - 1:
        return table[table.size - 1]
    f = x - i
    return table[i] * (1.0 - f) + table[i + 1] * f


@njit(cache=True)
def link_probability(table, step_m, x, y, px, py):
    """P_deliver between UAVs at (x, y) and (px, py)."""
    return deliver_probability_at(table, step_m, np.sqrt((px - x) ** 2 + (py - y) ** 2))


@njit(cache=True)
def beacon_delivered(table, step_m, x, y, px, py, seed, episode, k, src, dst):
    """Whether beacon k of `episode` from UAV src at (px, py) reaches UAV dst at (x, y)."""
    return link_uniform(seed, episode, k, src, dst) < link_probability(table, step_m, x, y, px, py)


@njit(cache=True)
def heard_masks(table, step_m, pos, seeds, episode, k):
    """(B, U, U) which peers each UAV hears at beacon k: pos (B, U, 2), seeds (B,) the envs' run seeds."""
    n_env, n_uav = pos.shape[0], pos.shape[1]
    out = np.zeros((n_env, n_uav, n_uav), np.bool_)
    for b in range(n_env):
        for u in range(n_uav):
            for m in range(n_uav):
                if m != u:
                    out[b, u, m] = beacon_delivered(table, step_m, pos[b, u, 0], pos[b, u, 1], pos[b, m, 0],
                                                    pos[b, m, 1], seeds[b], episode, k, m, u)
    return out
