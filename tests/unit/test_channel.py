"""Channel formulas against hand computations."""

import math

import numpy as np
import pytest

from truav.config import ChannelConfig
from world.channel import ChannelParams, a2a_rate, a2g_rate, fspl_db, los_probability, rx_snr, shannon_rate

P = ChannelParams.from_config(ChannelConfig())


def test_free_space_path_loss():
    # 20 log10(4 pi f d / c) at 5.9 GHz, 1 km
    expected = 20 * math.log10(4 * math.pi * 5.9e9 * 1000 / 299_792_458.0)
    assert fspl_db(1000.0, 5.9e9) == pytest.approx(expected, abs=1e-9)
    assert expected == pytest.approx(107.87, abs=0.01)


def test_al_hourani_urban_los_probability():
    assert los_probability(90.0, 9.61, 0.16) == pytest.approx(1 / (1 + 9.61 * math.exp(-0.16 * 80.39)))
    assert los_probability(9.61, 9.61, 0.16) == pytest.approx(1 / (1 + 9.61))
    theta = np.linspace(1, 90, 50)
    assert np.all(np.diff(los_probability(theta, 9.61, 0.16)) > 0)  # higher angle, more LoS


def test_shannon_and_snr():
    assert shannon_rate(1.0, 20e6) == pytest.approx(20e6)
    # 0.1 W through 90 dB with 0 dBi into 1e-9 W noise: SNR = 0.1 * 1e-9 / 1e-9
    assert rx_snr(0.1, 90.0, 0.0, 1e-9) == pytest.approx(0.1)


def test_a2g_rate_by_hand():
    h, alt = 300.0, 100.0
    d = math.hypot(h, alt)
    theta = math.degrees(math.atan2(alt, h))
    p_los = 1 / (1 + 9.61 * math.exp(-0.16 * (theta - 9.61)))
    fspl = 20 * math.log10(4 * math.pi * 5.9e9 * d / 299_792_458.0)
    snr = lambda eta: 0.1 * 10 ** (-(fspl + eta) / 10) / 1e-9  # noqa: E731
    expected = p_los * 20e6 * math.log2(1 + snr(1.0)) + (1 - p_los) * 20e6 * math.log2(1 + snr(20.0))
    assert a2g_rate(h, alt, 0.1, P) == pytest.approx(expected, rel=1e-12)


def test_a2a_links_are_los_and_faster_than_a2g():
    d = 800.0
    fspl = 20 * math.log10(4 * math.pi * 5.9e9 * d / 299_792_458.0)
    expected = 20e6 * math.log2(1 + 1.0 * 10 ** (-(fspl + 1.0) / 10) / 1e-9)
    assert a2a_rate(d, 1.0, P) == pytest.approx(expected, rel=1e-12)
    assert a2a_rate(d, 1.0, P) > a2g_rate(d, 90.0, 1.0, P)


def test_rate_falls_with_distance():
    h = np.linspace(0, 500, 101)
    assert np.all(np.diff(a2g_rate(h, 100.0, 0.1, P)) < 0)
