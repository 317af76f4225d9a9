"""Tests for agents.beacon_schedule: slots anchored to the world's tick, robust to late stamps."""

from __future__ import annotations

import numpy as np
import pytest

from agents.beacon_schedule import BeaconSchedule

PERIOD = 0.1
ORIGIN = 1_000.0  # world clock, s


def schedule(uav: int = 0, n: int = 20, **kw) -> BeaconSchedule:
    return BeaconSchedule(PERIOD, phase=0.3, spread=0.6, uav=uav, n_uavs=n, **kw)


def test_one_slot_per_uav_spreads_them_evenly_by_id_within_the_tick() -> None:
    slots = []
    for uav in range(20):
        s = schedule(uav, slots=20)
        s.observe(7, ORIGIN + 7 * PERIOD)
        slots.append(s.due(7) - (ORIGIN + 7 * PERIOD))
    np.testing.assert_allclose(np.diff(slots), 0.6 * PERIOD / 20)
    assert slots[0] == pytest.approx(0.3 * PERIOD) and slots[-1] < PERIOD


@pytest.mark.parametrize("n_slots", [1, 3, 4])
def test_uavs_share_a_few_slots_by_id_modulo(n_slots) -> None:
    offsets = []
    for uav in range(20):
        s = schedule(uav, slots=n_slots)
        s.observe(7, ORIGIN + 7 * PERIOD)
        offsets.append(round(s.due(7) - (ORIGIN + 7 * PERIOD), 9))
    assert len(set(offsets)) == n_slots  # the beacons of a slot go out together: a receiver wakes once for them
    assert offsets[:n_slots] == sorted(offsets[:n_slots]) and offsets[n_slots:] == offsets[:20 - n_slots]
    assert min(offsets) == pytest.approx(0.3 * PERIOD) and max(offsets) < 0.9 * PERIOD + 1e-9


def test_the_default_is_one_slot_for_every_uav() -> None:
    assert len({schedule(uav).offset_s for uav in range(20)}) == 1


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
                                dict(window=0), dict(slots=0)])
def test_bad_settings_are_rejected(kw) -> None:
    args = dict(period_s=PERIOD, phase=0.3, spread=0.6, uav=0, n_uavs=20) | kw
    with pytest.raises(ValueError):
        BeaconSchedule(**args)


def test_due_needs_an_observation_first() -> None:
    with pytest.raises(RuntimeError):
        schedule().due(0)
