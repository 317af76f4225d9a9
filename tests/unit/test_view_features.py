"""An agent's LocalView as a fixed-size feature vector (agents.view_features, issue 56): every feature named,
with its unit and scale, in its declared bounds; the K nearest heard peers sorted, padded and masked."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agents.api import HeardBeacon, LocalView
from agents.view_features import DEFAULT_PEERS, ViewEncoder, observation_features
from truav.config import Config

CFG = Config()
SENSING = CFG.replace(learner={"sense_range_m": 1500.0, "sense_sectors": 8})


def _view(cfg: Config, beacons=(), densest=0, step=0, rsu_m=1200.0, energy=230.0) -> LocalView:
    return LocalView(uav=0, episode=0, step=step, pos=(1000.0, 2500.0), vehicles_in_range=40, queued_packets=8,
                     relayed=3, covered=30, energy_j=energy, speed_max=float(cfg.scenario.uav_speed_mps),
                     densest_sector=densest, exclusive=20, nearest_rsu_m=rsu_m, beacons=tuple(beacons),
                     sense_range_m=cfg.learner.sense_range_m, sense_sectors=cfg.learner.sense_sectors)


def _named(enc: ViewEncoder, vec: np.ndarray) -> dict[str, float]:
    return {f.name: float(v) for f, v in zip(enc.features, vec)}


def test_every_feature_has_a_name_unit_scale_and_bounds_and_the_size_follows_the_options():
    feats = observation_features(CFG)
    names = [f.name for f in feats]
    assert len(names) == len(set(names))
    assert all(f.unit and f.scale > 0 and f.scale_of and f.low < f.high and f.meaning for f in feats)
    sectors, k = CFG.learner.sense_sectors, DEFAULT_PEERS
    onehot = [n for n in names if n.startswith("densest_sector_")]
    assert onehot == [f"densest_sector_{s}" for s in range(1, sectors + 1)]
    assert [n for n in names if n.startswith("peer1_")] == ["peer1_dx", "peer1_dy", "peer1_vx", "peer1_vy",
                                                           "peer1_distance", "peer1_mask"]
    assert len(observation_features(SENSING, peers=2)) == len(feats) + (8 - sectors) + 6 * (2 - k)
    enc = ViewEncoder(SENSING, peers=2)
    assert enc.size == len(enc.features) == enc.low.shape[0] == enc.high.shape[0]
    assert enc.low.dtype == enc.high.dtype == np.float32


def test_own_features_are_the_view_scaled_to_order_one():
    enc = ViewEncoder(CFG)
    sc = CFG.scenario
    share = sc.n_vehicles / sc.n_uavs
    f = _named(enc, enc(_view(CFG, step=25)))
    assert f["x"] == pytest.approx(1000 / sc.area_m) and f["y"] == pytest.approx(2500 / sc.area_m)
    assert f["vehicles_in_range"] == pytest.approx(40 / share) and f["covered"] == pytest.approx(30 / share)
    assert f["exclusive"] == pytest.approx(20 / share)
    packets = CFG.traffic.packet_rate_hz * sc.n_vehicles * sc.step_s / sc.n_uavs
    assert f["queued"] == pytest.approx(8 / packets) and f["relayed"] == pytest.approx(3 / packets)
    assert f["energy"] == pytest.approx(230 / (CFG.energy.move_w * sc.step_s))
    assert f["nearest_rsu"] == pytest.approx(1200 / sc.area_m)
    assert f["progress"] == pytest.approx(25 / sc.steps_per_episode)
    assert f["heard_peers"] == 0.0


def test_densest_sector_is_one_hot_and_all_zero_when_nothing_is_sensed_or_sensing_is_off():
    enc = ViewEncoder(SENSING)
    onehot = lambda v: [x for n, x in _named(enc, v).items() if n.startswith("densest_sector_")]  # noqa: E731
    assert onehot(enc(_view(SENSING, densest=3))) == [0, 0, 1, 0, 0, 0, 0, 0]
    assert onehot(enc(_view(SENSING, densest=0))) == [0] * 8
    off = ViewEncoder(CFG)
    assert [x for n, x in _named(off, off(_view(CFG))).items() if n.startswith("densest_sector_")] == [0] * 4


def test_nearest_heard_peers_sorted_by_distance_padded_and_masked():
    enc = ViewEncoder(CFG, peers=3)
    area, v = CFG.scenario.area_m, CFG.scenario.uav_speed_mps
    far = HeardBeacon(4, (4000.0, 2500.0), (0.0, 0.0))
    near = HeardBeacon(2, (1300.0, 2100.0), (v, 0.0))  # 500 m away
    f = _named(enc, enc(_view(CFG, beacons=(far, near))))
    assert (f["peer1_dx"], f["peer1_dy"]) == pytest.approx((300 / area, -400 / area))
    assert (f["peer1_vx"], f["peer1_vy"], f["peer1_distance"], f["peer1_mask"]) == pytest.approx((1, 0, 500 / area, 1))
    assert (f["peer2_dx"], f["peer2_distance"], f["peer2_mask"]) == pytest.approx((3000 / area, 3000 / area, 1))
    # the third slot is padding: the documented fill, mask 0
    fill = {ft.name: ft.fill_value for ft in enc.features if ft.name.startswith("peer3_")}
    assert {n: f[n] for n in fill} == pytest.approx(fill)
    assert fill["peer3_mask"] == 0.0 and fill["peer3_distance"] == pytest.approx(math.sqrt(2))
    assert f["heard_peers"] == pytest.approx(2 / (CFG.scenario.n_uavs - 1))
    # more peers heard than slots: only the K nearest
    many = [HeardBeacon(m, (1000.0 + 100 * m, 2500.0), (0.0, 0.0)) for m in (4, 3, 2, 1)]
    g = _named(enc, enc(_view(CFG, beacons=many)))
    assert [g[f"peer{k}_dx"] * area for k in (1, 2, 3)] == pytest.approx([100, 200, 300])


def test_open_ended_values_are_capped_into_the_declared_bounds():
    enc = ViewEncoder(CFG)
    vec = enc(_view(CFG, rsu_m=math.inf, energy=1e9))
    assert np.isfinite(vec).all() and (vec >= enc.low).all() and (vec <= enc.high).all()
    f = _named(enc, vec)
    assert f["nearest_rsu"] == pytest.approx(math.sqrt(2)) and f["energy"] == enc.high[enc.index("energy")]
