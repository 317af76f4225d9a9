"""Tests for agents.beacon_schedule: slots anchored to the world's tick, robust to late stamps."""

from __future__ import annotations

import numpy as np
import pytest

from agents.beacon_schedule import BeaconSchedule

PERIOD = 0.1
ORIGIN = 1_000.0  # world clock, s


def schedule(uav: int = 0, n: int = 20, **kw) -> BeaconSchedule:
    return BeaconSchedule(PERIOD, phase=0.3, spread=0.6, uav=uav, n_uavs=n, **kw)


def test_slots_are_evenly_spread_by_uav_id_within_the_tick() -> None:
    slots = []
    for uav in range(20):
        s = schedule(uav)
        s.observe(7, ORIGIN + 7 * PERIOD)
        slots.append(s.due(7) - (ORIGIN + 7 * PERIOD))
    np.testing.assert_allclose(np.diff(slots), 0.6 * PERIOD / 20)
    assert slots[0] == pytest.approx(0.3 * PERIOD) and slots[-1] < PERIOD


def test_late_stamps_do_not_move_the_slot() -> None:
    rng = np.random.default_rng(0)
    s = schedule(3)
    for tick in range(100):  # stamps up to 30 ms late, the earliest 1 ms late
        s.observe(tick, ORIGIN + tick * PERIOD + 0.001 + rng.uniform(0, 0.03))
    assert s.tick_start(100) == pytest.approx(ORIGIN + 100 * PERIOD, abs=0.0015)
    assert s.due(100) == pytest.approx(ORIGIN + 100 * PERIOD + s.offset_s, abs=0.0015)


def test_an_earlier_tick_start_is_followed_at_once() -> None:
    s = schedule()
    for tick in range(10):
        s.observe(tick, ORIGIN + tick * PERIOD)
    # a world that sends tick 10 right after tick 9, without a period of its own, shifts every later tick
    s.observe(10, ORIGIN + 9 * PERIOD + 0.002)
    assert s.tick_start(11) == pytest.approx(ORIGIN + 10 * PERIOD, abs=0.003)


def test_a_stalled_or_new_world_restarts_the_estimate() -> None:
    s = schedule()
    for tick in range(10):
        s.observe(tick, ORIGIN + tick * PERIOD)
    restart = ORIGIN + 500.0
    s.observe(0, restart)  # a new world, from tick 0, later
    assert s.tick_start(1) == pytest.approx(restart + PERIOD)
    s.observe(1, restart + PERIOD + 0.05)  # late, but within a period: the estimate keeps its minimum
    assert s.tick_start(2) == pytest.approx(restart + 2 * PERIOD)


def test_the_window_forgets_old_stamps() -> None:
    s = schedule(window=5)
    s.observe(0, ORIGIN - 0.05)  # an early stamp (clock step) ages out after 5 more ticks
    for tick in range(1, 6):
        s.observe(tick, ORIGIN + tick * PERIOD)
    assert s.tick_start(6) == pytest.approx(ORIGIN + 6 * PERIOD)


@pytest.mark.parametrize("kw", [dict(phase=0.6, spread=0.5), dict(phase=-0.1, spread=0.5), dict(uav=20),
                                dict(window=0)])
def test_bad_settings_are_rejected(kw) -> None:
    args = dict(period_s=PERIOD, phase=0.3, spread=0.6, uav=0, n_uavs=20) | kw
    with pytest.raises(ValueError):
        BeaconSchedule(**args)


def test_due_needs_an_observation_first() -> None:
    with pytest.raises(RuntimeError):
        schedule().due(0)
