"""Standard channel models for the world's links, each with its source (numpy only, any leading shape).

The world has three kinds of radio link, all at fixed heights (vehicles on the ground, UAVs at
scenario.uav_altitude_m, RSU antennas at scenario.rsu_height_m), so each link's rate is a function
of the horizontal distance alone, and the world tabulates it (world/network.py):

    uplink   vehicle -> UAV   air-to-ground
    backhaul UAV -> RSU       air-to-ground (the RSU is the ground station / base station)
    relay    UAV <-> UAV      air-to-air, equal altitudes

Models (`channel.model`):

- ``paper``: the paper's model as this project has always computed it (world/channel.py, numba, kept
  bit for bit): Al-Hourani's elevation-angle LoS probability with channel.los_a/los_b, LoS/NLoS
  excess losses channel.eta_los_db/eta_nlos_db on free space, and the *ergodic* rate
  R = P_LoS B log2(1 + SNR_LoS) + (1 - P_LoS) B log2(1 + SNR_NLoS); air-to-air links LoS with
  probability channel.a2a_los_probability (1 by default, so FSPL + eta_LoS).
- ``al-hourani``: A. Al-Hourani, S. Kandeepan, S. Lardner, "Optimal LAP Altitude for Maximum
  Coverage", IEEE Wireless Commun. Lett. 3(6):569-572, 2014: P_LoS(theta) = 1 / (1 + a exp(-b
  (theta - a))), theta the elevation angle in degrees, and the *mean* path loss
  PL = FSPL(d) + P_LoS eta_LoS + (1 - P_LoS) eta_NLoS (their Eq. 5), with the environment's
  (a, b, eta_LoS, eta_NLoS) of their Table I (`ENVIRONMENTS`, channel.environment). For the
  uplink and the backhaul; air-to-air links are free space (the letter covers air-to-ground only).
- ``3gpp-uma-av``, ``3gpp-umi-av``, ``3gpp-rma-av``: 3GPP TR 36.777 V15.0.0 (2017-12), "Study on
  Enhanced LTE Support for Aerial Vehicles", Annex B, Table B-1 (LoS probability by UAV height
  h_UT and horizontal distance d2D) and Table B-2 (LoS and NLoS path loss, f_c in GHz, distances in
  m), for the backhaul, the RSU standing for the base station. The TR models aerial UE <-> base
  station links only: the uplink from a vehicle uses Al-Hourani's air-to-ground model with
  channel.environment, and air-to-air links are free space. The aerial formulas hold for
  22.5 m < h_UT <= 300 m (UMa-AV, UMi-AV) and 10 m < h_UT <= 300 m (RMa-AV), `TR36777_HEIGHTS`
  (the config refuses an altitude outside); d2D beyond the TR's 4 km (10 km for RMa-AV) extends
  the same formulas. Shadow fading (Table B-3) and fast fading are not modelled: the mean.

The world uses a channel through one quantity, the link's rate in bit/s, as it does for the paper's
model: transmission time = bits / rate, per hop, for the relay delay and the UAVs' airtime.
Coverage stays the geometric scenario.comm_range_m the paper defines ("each UAV remains within a
communication range in which vehicles can form a reliable data link"). For the new models the rate
is B log2(1 + SNR) of the mean path loss, SNR = P_tx 10^((G - PL) / 10) / N with channel.
bandwidth_hz, antenna_gain_dbi, noise_w and the sender's power (vehicle_tx_w, uav_tx_w). Every
model here is deterministic (no LoS draw), so the trainer and a lock-step swarm see the same rates.
"""

from __future__ import annotations

import numpy as np

from truav.channel_catalog import ENVIRONMENTS, MODELS, TR36777_HEIGHTS  # noqa: F401 - the catalog, declared once

SPEED_OF_LIGHT = 299_792_458.0


def fspl_db(distance_m, carrier_hz):
    """Free-space path loss 20 log10(4 pi f d / c) (dB), distance clipped at 1 m as world/channel.py does."""
    return 20.0 * np.log10(4.0 * np.pi * carrier_hz * np.maximum(distance_m, 1.0) / SPEED_OF_LIGHT)


def elevation_deg(horizontal_m, height_m):
    """Elevation angle (degrees) of a sender height_m above the receiver at horizontal_m."""
    return np.degrees(np.arctan2(height_m, horizontal_m))


def al_hourani_los_probability(theta_deg, a, b):
    """P_LoS(theta) = 1 / (1 + a exp(-b (theta - a))), theta in degrees (Al-Hourani 2014, Eq. 3)."""
    return 1.0 / (1.0 + a * np.exp(-b * (theta_deg - a)))


def al_hourani_path_loss_db(horizontal_m, height_m, carrier_hz, environment: str):
    """Mean path loss FSPL + P_LoS eta_LoS + (1 - P_LoS) eta_NLoS (dB), Al-Hourani 2014 Eq. 5."""
    a, b, eta_los, eta_nlos = ENVIRONMENTS[environment]
    p = al_hourani_los_probability(elevation_deg(horizontal_m, height_m), a, b)
    distance = np.hypot(horizontal_m, height_m)
    return fspl_db(distance, carrier_hz) + p * eta_los + (1.0 - p) * eta_nlos


def tr36777_los_probability(scenario: str, d2d_m, h_ut_m: float):
    """Table B-1 for an aerial UE at h_UT (inside `TR36777_HEIGHTS`), d2D in m."""
    lg = np.log10(h_ut_m)
    if scenario == "3gpp-uma-av":
        if h_ut_m > 100.0:
            return np.ones_like(np.asarray(d2d_m, dtype=float))
        p1, d1 = 4300.0 * lg - 3800.0, max(460.0 * lg - 700.0, 18.0)
    elif scenario == "3gpp-umi-av":
        p1, d1 = 233.98 * lg - 0.95, max(294.05 * lg - 432.94, 18.0)
    elif scenario == "3gpp-rma-av":
        if h_ut_m > 40.0:
            return np.ones_like(np.asarray(d2d_m, dtype=float))
        p1, d1 = max(15021.0 * lg - 16053.0, 1000.0), max(1350.8 * lg - 1602.0, 18.0)
    else:
        raise KeyError(scenario)
    d = np.maximum(np.asarray(d2d_m, dtype=float), d1)  # d <= d1: the formula gives exactly 1
    return np.where(np.asarray(d2d_m) <= d1, 1.0, d1 / d + np.exp(-d / p1) * (1.0 - d1 / d))


def tr36777_path_loss_db(scenario: str, d2d_m, h_ut_m: float, h_bs_m: float, carrier_hz: float):
    """Table B-2: (LoS, NLoS) path loss (dB) of an aerial UE at h_UT, base station at h_BS."""
    fc = carrier_hz / 1e9
    d3d = np.hypot(np.asarray(d2d_m, dtype=float), h_ut_m - h_bs_m)
    lg_d, lg_h = np.log10(d3d), np.log10(h_ut_m)
    free = 20.0 * np.log10(40.0 * np.pi * d3d * fc / 3.0)  # PL' of Note 3 (free space)
    if scenario == "3gpp-uma-av":
        los = 28.0 + 22.0 * lg_d + 20.0 * np.log10(fc)
        nlos = -17.5 + (46.0 - 7.0 * lg_h) * lg_d + 20.0 * np.log10(40.0 * np.pi * fc / 3.0)
    elif scenario == "3gpp-umi-av":
        los = np.maximum(free, 30.9 + (22.25 - 0.5 * lg_h) * lg_d + 20.0 * np.log10(fc))
        nlos = np.maximum(los, 32.4 + (43.2 - 7.6 * lg_h) * lg_d + 20.0 * np.log10(fc))
    elif scenario == "3gpp-rma-av":
        los = max(23.9 - 1.8 * lg_h, 20.0) * lg_d + 20.0 * np.log10(40.0 * np.pi * fc / 3.0)
        nlos = np.maximum(los, -12.0 + (35.0 - 5.3 * lg_h) * lg_d + 20.0 * np.log10(40.0 * np.pi * fc / 3.0))
    else:
        raise KeyError(scenario)
    return los, nlos


def tr36777_mean_path_loss_db(scenario: str, d2d_m, h_ut_m: float, h_bs_m: float, carrier_hz: float):
    """P_LoS PL_LoS + (1 - P_LoS) PL_NLoS (dB): Tables B-1 and B-2 averaged as Al-Hourani averages."""
    p = tr36777_los_probability(scenario, d2d_m, h_ut_m)
    los, nlos = tr36777_path_loss_db(scenario, d2d_m, h_ut_m, h_bs_m, carrier_hz)
    return p * los + (1.0 - p) * nlos


def paper_rate(horizontal_m, height_m, tx_w, carrier_hz, bandwidth_hz, noise_w, gain_dbi, los_a, los_b,
               eta_los_db, eta_nlos_db, los_probability=None):
    """The paper model's ergodic two-state rate (bit/s), as world/channel.py computes it (there in
    numba, which the world runs); los_probability overrides the elevation model (air-to-air)."""
    distance = np.hypot(horizontal_m, height_m)
    p = al_hourani_los_probability(elevation_deg(horizontal_m, height_m), los_a, los_b) \
        if los_probability is None else los_probability
    loss = fspl_db(distance, carrier_hz)
    r_los = shannon_rate(tx_w, loss + eta_los_db, gain_dbi, noise_w, bandwidth_hz)
    r_nlos = shannon_rate(tx_w, loss + eta_nlos_db, gain_dbi, noise_w, bandwidth_hz)
    return p * r_los + (1.0 - p) * r_nlos


def shannon_rate(tx_w, loss_db, gain_dbi, noise_w, bandwidth_hz):
    """B log2(1 + P_tx 10^((G - PL) / 10) / N) in bit/s."""
    return bandwidth_hz * np.log2(1.0 + tx_w * 10.0 ** ((gain_dbi - loss_db) / 10.0) / noise_w)


def uplink_loss_db(model: str, environment: str, horizontal_m, uav_altitude_m: float, carrier_hz: float):
    """Vehicle -> UAV mean path loss (dB) of a non-paper model."""
    return al_hourani_path_loss_db(horizontal_m, uav_altitude_m, carrier_hz, environment)


def backhaul_loss_db(model: str, environment: str, horizontal_m, uav_altitude_m: float, rsu_height_m: float,
                     carrier_hz: float):
    """UAV -> RSU mean path loss (dB) of a non-paper model."""
    if model in TR36777_HEIGHTS:
        return tr36777_mean_path_loss_db(model, horizontal_m, uav_altitude_m, rsu_height_m, carrier_hz)
    return al_hourani_path_loss_db(horizontal_m, uav_altitude_m - rsu_height_m, carrier_hz, environment)


def relay_loss_db(model: str, distance_m, carrier_hz: float):
    """UAV <-> UAV path loss (dB) of a non-paper model: free space."""
    return fspl_db(distance_m, carrier_hz)
