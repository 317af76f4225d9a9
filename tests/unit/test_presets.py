"""Scenario presets and moving traffic hotspots."""

import numpy as np

from truav import seeding
from truav.cli.main import main
from truav.config import Config, load_config
from truav.presets import PRESETS, preset_overrides
from world.env import World

SMALL = {"scenario": {"n_vehicles": 60, "steps_per_episode": 20}, "roads": {"warmup_steps": 20}}


def test_config_show_lists_every_choice_of_the_paper_preset_and_applies_it(capsys, tmp_path):
    assert main(["config", "show", "--preset", "paper"]) == 0
    text = capsys.readouterr().out
    for choice in PRESETS["paper"]:
        assert f"# {choice.key} = " in text  # shown with its source
    path = tmp_path / "paper.toml"
    path.write_text(text)
    cfg = load_config(path)  # the comments do not get in the way
    assert cfg.scenario.uav_start == "persist" and cfg.roads.hotspot_move_prob > 0
    assert Config().replace(**preset_overrides("literal")) == Config()


def test_set_overrides_the_preset_and_an_unknown_preset_is_one_line(capsys):
    assert main(["config", "show", "--preset", "paper", "--set", "scenario.uav_start=random"]) == 0
    assert 'uav_start = "random"' in capsys.readouterr().out
    assert main(["config", "show", "--preset", "nope"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--preset" in err[0] and "literal" in err[0]


def _world(cfg, seeds):
    w = World(cfg, len(seeds))
    w.reset([seeding.world_rng(s) for s in seeds])
    return w


def test_hotspots_move_inside_the_major_box_and_their_vehicles_follow():
    cfg = Config().replace(scenario=SMALL["scenario"], roads={"warmup_steps": 20, "hotspot_move_prob": 1.0})
    w = _world(cfg, [0, 1])
    majors = w.grid.majors
    hover = np.full((2, cfg.scenario.n_uavs), -1)
    for _ in range(3):
        w.start_episode()
        for _ in range(cfg.scenario.steps_per_episode):
            w.step(hover)
    assert not np.array_equal(w.hotspots, np.repeat(majors[None], 2, axis=0))
    assert (w.hotspots >= majors.min(axis=0)).all() and (w.hotspots <= majors.max(axis=0)).all()
    n = w.grid.n_roads
    for b in range(2):
        site_index = w.hotspots[b, :, 0] * n + w.hotspots[b, :, 1]
        np.testing.assert_array_equal(w.vehicles.home[b], site_index[w.vehicles.cluster[b]])


def test_moving_hotspots_keep_a_batch_equal_to_its_seeds_alone():
    cfg = Config().replace(scenario=SMALL["scenario"], roads={"warmup_steps": 20, "hotspot_move_prob": 0.5})
    rng = np.random.default_rng(3)
    batch = _world(cfg, [4, 5])
    alone = [_world(cfg, [4]), _world(cfg, [5])]
    for _ in range(3):
        batch.start_episode()
        for w in alone:
            w.start_episode()
        for _ in range(cfg.scenario.steps_per_episode):
            a = rng.integers(0, 16, (2, cfg.scenario.n_uavs))
            batch.step(a)
            for b, w in enumerate(alone):
                w.step(a[b:b + 1])
    for b, w in enumerate(alone):
        np.testing.assert_array_equal(batch.hotspots[b], w.hotspots[0])
        np.testing.assert_array_equal(batch.vehicle_xy()[b], w.vehicle_xy()[0])
        for key, value in w.episode_summary().items():
            np.testing.assert_array_equal(batch.episode_summary()[key][b], value[0])


def test_train_with_the_paper_preset_saves_the_swarm_and_evaluate_starts_it_there(tmp_path, capsys):
    run = tmp_path / "run"
    small = ["--set", "scenario.n_vehicles=30", "--set", "scenario.steps_per_episode=10", "--set", "roads.warmup_steps=5"]
    assert main(["train", "--preset", "paper", "--seeds", "2", "--episodes", "2", "--workers", "1", "--quiet",
                 "--out", str(run), *small]) == 0
    cfg = load_config(run / "config.toml")
    assert cfg.scenario.uav_start == "persist" and cfg.roads.hotspot_move_prob == 0.5
    with np.load(run / "qtables.npz") as data:
        assert data["uav_pos"].shape == (2, cfg.scenario.n_uavs, 2)
    capsys.readouterr()
    assert main(["evaluate", str(run), "--episodes", "1", "--workers", "1", "--quiet"]) == 0
    assert "the swarm starts where training left it" in capsys.readouterr().out
    assert main(["evaluate", str(run), "--preset", "nope", "--quiet"]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1
