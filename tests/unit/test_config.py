import tomllib

import pytest

from truav.config import Config, ConfigError, config_from_dict, load_config, to_toml


def test_defaults_are_the_papers_table():
    c = Config()
    assert (c.scenario.area_m, c.scenario.n_vehicles, c.scenario.n_uavs) == (5000.0, 200, 5)
    assert (c.scenario.uav_altitude_m, c.scenario.comm_range_m) == (100.0, 500.0)
    assert (c.energy.hover_w, c.energy.move_w) == (200.0, 250.0)
    assert (c.channel.bandwidth_hz, c.channel.noise_w) == (20e6, 1e-9)
    assert (c.channel.vehicle_tx_w, c.channel.uav_tx_w) == (0.1, 1.0)
    lc = c.learner
    assert (lc.learning_rate, lc.discount, lc.epsilon_start, lc.epsilon_end) == (0.1, 0.95, 1.0, 0.05)
    assert (lc.episodes, c.scenario.steps_per_episode) == (5000, 100)
    assert (lc.w_relay, lc.w_coverage, lc.w_energy, lc.w_overlap) == (1.0, 0.25, 0.15, 0.20)


def test_toml_roundtrip_is_exact():
    cfg = Config().replace(scenario={"n_uavs": 7}, roads={"major_intersections": [[1, 2], [3, 4]]})
    assert config_from_dict(tomllib.loads(to_toml(cfg))) == cfg


def test_load_file_and_overrides(tmp_path):
    f = tmp_path / "c.toml"
    f.write_text("[scenario]\nn_uavs = 3\nuav_speed_mps = 25\n")
    cfg = load_config(f, {"learner": {"episodes": 7}})
    assert cfg.scenario.n_uavs == 3 and cfg.scenario.uav_speed_mps == 25.0 and cfg.learner.episodes == 7


@pytest.mark.parametrize("data, fragment", [
    ({"scenario": {"n_uav": 3}}, "scenario.n_uav"),
    ({"scenario": {"n_uav": 3}}, "did you mean 'scenario.n_uavs'?"),  # a typo: the key meant
    ({"learner": {"gamma": 0.9}}, "known: learning_rate, discount,"),  # no near key: the section's keys
    ({"scenery": {}}, "scenery"),
    ({"scenario": {"n_uavs": 0}}, "scenario.n_uavs"),
    ({"scenario": {"n_uavs": 2.5}}, "scenario.n_uavs"),
    ({"channel": {"noise_w": -1.0}}, "channel.noise_w"),
    ({"roads": {"p_straight": 0.9}}, "p_straight"),
    ({"roads": {"major_intersections": [[99, 0]]}}, "major_intersections"),
    ({"learner": {"density_edges": [5.0, 1.0]}}, "learner.density_edges"),
    ({"scenario": {"uav_start": "moon"}}, "uav_start"),
])
def test_bad_values_are_rejected_naming_the_key(data, fragment):
    with pytest.raises(ConfigError) as err:
        config_from_dict(data)
    assert fragment in str(err.value)
    assert "\n" not in str(err.value)


def test_missing_or_invalid_file(tmp_path):
    with pytest.raises(ConfigError, match="not found"):
        load_config(tmp_path / "nope.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[scenario\n")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_config(bad)
