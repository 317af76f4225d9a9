"""Air-to-ground and air-to-air link model, for scalars or arrays.

Al-Hourani, Kandeepan & Lardner, "Optimal LAP Altitude for Maximum Coverage",
IEEE WCL 2014: LoS probability from the elevation angle theta (degrees),

    P_LoS(theta) = 1 / (1 + a exp(-b (theta - a))),

and path loss FSPL(d) + eta_LoS or FSPL(d) + eta_NLoS (dB). A link's rate is
the ergodic Shannon rate over the two states,

    R = P_LoS B log2(1 + SNR_LoS) + (1 - P_LoS) B log2(1 + SNR_NLoS),
    SNR = P_tx G / (PL N).

Averaging the rate rather than the dB loss keeps a rarely-LoS link useful in
expectation, as an ergodic capacity does. The functions are compiled with
numba so the world's step kernels call the very same code; `ChannelParams`
carries the config into them.

This is the paper's model (channel.model = "paper"). The other models of
world/channel_models.py reach the kernels as `RateTables` (rates over
horizontal distance, built by world.network.relay_params) in its place:
`backhaul_rate` and `relay_rate` pick the formula by the type of the
parameters at compile time, so the paper's kernels are the code they were.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from truav import kernel_cache  # noqa: F401, I001 - numba's cache set up before numba loads a kernel
from numba import njit, types
from numba.extending import overload

from truav.config import ChannelConfig

SPEED_OF_LIGHT = 299_792_458.0


class ChannelParams(NamedTuple):
    carrier_hz: float
    bandwidth_hz: float
    noise_w: float
    gain_dbi: float
    los_a: float
    los_b: float
    eta_los_db: float
    eta_nlos_db: float
    a2a_los_probability: float

    @classmethod
    def from_config(cls, ch: ChannelConfig) -> "ChannelParams":
        """The paper model's parameters."""
        return cls(ch.carrier_hz, ch.bandwidth_hz, ch.noise_w, ch.antenna_gain_dbi, ch.los_a, ch.los_b,
                   ch.eta_los_db, ch.eta_nlos_db, ch.a2a_los_probability)


class RateTables(NamedTuple):
    """A model other than the paper's, for the kernels: rates (bit/s) sampled every step_m of horizontal distance."""
    step_m: float
    backhaul: np.ndarray  # UAV -> RSU
    relay: np.ndarray  # UAV <-> UAV


@njit(cache=True)
def fspl_db(distance_m, carrier_hz):
    """Free-space path loss 20 log10(4 pi f d / c) in dB (distance clipped at 1 m)."""
    return 20.0 * np.log10(4.0 * np.pi * carrier_hz * np.maximum(distance_m, 1.0) / SPEED_OF_LIGHT)


@njit(cache=True)
def los_probability(elevation_deg, a, b):
    """Al-Hourani's elevation-angle LoS probability."""
    return 1.0 / (1.0 + a * np.exp(-b * (elevation_deg - a)))


@njit(cache=True)
def shannon_rate(snr, bandwidth_hz):
    """B log2(1 + SNR) in bit/s."""
    return bandwidth_hz * np.log2(1.0 + snr)


@njit(cache=True)
def rx_snr(tx_w, loss_db, gain_dbi, noise_w):
    """Linear SNR from transmit power, path loss and antenna gains."""
    return tx_w * 10.0 ** ((gain_dbi - loss_db) / 10.0) / noise_w


@njit(cache=True)
def _two_state_rate(p_los, fspl, tx_w, p):
    r_los = shannon_rate(rx_snr(tx_w, fspl + p.eta_los_db, p.gain_dbi, p.noise_w), p.bandwidth_hz)
    r_nlos = shannon_rate(rx_snr(tx_w, fspl + p.eta_nlos_db, p.gain_dbi, p.noise_w), p.bandwidth_hz)
    return p_los * r_los + (1.0 - p_los) * r_nlos


@njit(cache=True)
def a2g_rate(horizontal_m, height_diff_m, tx_w, p):
    """Expected rate (bit/s) of an air-to-ground link (vehicle<->UAV, UAV<->RSU)."""
    distance = np.sqrt(horizontal_m * horizontal_m + height_diff_m * height_diff_m)
    elevation = np.degrees(np.arctan2(height_diff_m, horizontal_m))
    return _two_state_rate(los_probability(elevation, p.los_a, p.los_b), fspl_db(distance, p.carrier_hz), tx_w, p)


@njit(cache=True)
def a2a_rate(distance_m, tx_w, p):
    """Expected rate (bit/s) of a UAV-to-UAV link at equal altitude; its LoS
    probability is the configured air-to-air value, not the elevation model."""
    return _two_state_rate(p.a2a_los_probability, fspl_db(distance_m, p.carrier_hz), tx_w, p)


@njit(cache=True)
def table_rate(table, step_m, horizontal_m):
    """A rate table sampled every step_m, linearly interpolated (held beyond its end)."""
    x = min(horizontal_m / step_m, table.size - 2.0)
    i = int(x)
    frac = x - i
    return table[i] * (1.0 - frac) + table[i + 1] * frac


def _tabulated(ch) -> bool:
    return isinstance(ch, types.BaseNamedTuple) and ch.instance_class is RateTables


def backhaul_rate(horizontal_m, height_diff_m, tx_w, ch):
    """UAV -> RSU rate (bit/s) under ch, ChannelParams or RateTables (compiled code only)."""
    raise NotImplementedError("called from numba kernels only")


def relay_rate(distance_m, tx_w, ch):
    """UAV <-> UAV rate (bit/s) under ch, ChannelParams or RateTables (compiled code only)."""
    raise NotImplementedError("called from numba kernels only")


@overload(backhaul_rate)
def _backhaul_rate(horizontal_m, height_diff_m, tx_w, ch):
    if _tabulated(ch):
        return lambda horizontal_m, height_diff_m, tx_w, ch: table_rate(ch.backhaul, ch.step_m, horizontal_m)
    return lambda horizontal_m, height_diff_m, tx_w, ch: a2g_rate(horizontal_m, height_diff_m, tx_w, ch)


@overload(relay_rate)
def _relay_rate(distance_m, tx_w, ch):
    if _tabulated(ch):
        return lambda distance_m, tx_w, ch: table_rate(ch.relay, ch.step_m, distance_m)
    return lambda distance_m, tx_w, ch: a2a_rate(distance_m, tx_w, ch)
