"""The channel models of world/channel_models.py against their published sources, and the
config section that selects them (channel.model).

Sources:
- A. Al-Hourani, S. Kandeepan, S. Lardner, "Optimal LAP Altitude for Maximum Coverage", IEEE WCL
  3(6):569-572, 2014: Table I (a, b, eta_LoS, eta_NLoS per environment) and the optimal elevation
  angles it reports (suburban 20.34, urban 42.44, dense urban 54.62, high-rise urban 75.52 degrees).
- 3GPP TR 36.777 V15.0.0, Annex B: Table B-1 (LoS probability) and Table B-2 (path loss). The TR
  publishes formulas, not values: the expected numbers below are those formulas evaluated by hand
  (f_c = 2 GHz; base station heights of the TR's Note 1: 25 m UMa-AV, 10 m UMi-AV, 35 m RMa-AV).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from tests.support.golden import GOLDEN, SMALL, digest

from truav.config import ChannelConfig, Config, ConfigError
from world import channel_models as cm
from world.channel import ChannelParams, a2a_rate, a2g_rate

FC = 2e9


def test_al_hourani_environments_are_table_one():
    assert cm.ENVIRONMENTS == {"suburban": (4.88, 0.43, 0.1, 21.0), "urban": (9.61, 0.16, 1.0, 20.0),
                               "dense-urban": (12.08, 0.11, 1.6, 23.0), "highrise-urban": (27.23, 0.08, 2.3, 34.0)}


def _radius(h: float, env: str, pl_max: float) -> float:
    """Ground radius where the mean path loss from height h reaches pl_max (bisection)."""
    lo, hi = 0.0, 1e7
    for _ in range(100):
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if cm.al_hourani_path_loss_db(mid, h, FC, env) < pl_max else (lo, mid)
    return lo


@pytest.mark.parametrize("env, published_deg", [("suburban", 20.34), ("urban", 42.44), ("dense-urban", 54.62),
                                                ("highrise-urban", 75.52)])
def test_al_hourani_optimal_elevation_angle(env, published_deg):
    # The altitude of largest coverage radius for a path-loss budget sits at an elevation angle that
    # depends only on the environment (Al-Hourani 2014, Sec. III); found here from the mean path loss.
    pl_max = 125.0
    # up to where even straight down (LoS, eta_LoS) the budget is spent: the radius is unimodal there
    lo, hi = 10.0, 0.99 * 299_792_458.0 / (4 * math.pi * FC) * 10 ** ((pl_max - cm.ENVIRONMENTS[env][2]) / 20)
    g = (math.sqrt(5) - 1) / 2
    for _ in range(80):  # golden-section search of the altitude maximising the radius
        a, b = hi - g * (hi - lo), lo + g * (hi - lo)
        lo, hi = (lo, b) if _radius(a, env, pl_max) > _radius(b, env, pl_max) else (a, hi)
    h = (lo + hi) / 2
    assert math.degrees(math.atan2(h, _radius(h, env, pl_max))) == pytest.approx(published_deg, abs=0.01)


def test_al_hourani_mean_path_loss_by_hand():
    # urban, 100 m up, 300 m away: FSPL + P eta_LoS + (1 - P) eta_NLoS (Eq. 5)
    theta = math.degrees(math.atan2(100, 300))
    p = 1 / (1 + 9.61 * math.exp(-0.16 * (theta - 9.61)))
    fspl = 20 * math.log10(4 * math.pi * FC * math.hypot(100, 300) / 299_792_458.0)
    assert cm.al_hourani_path_loss_db(300.0, 100.0, FC, "urban") == pytest.approx(fspl + p + (1 - p) * 20, abs=1e-9)
    assert fspl + p + (1 - p) * 20 == pytest.approx(102.78, abs=0.01)  # 88.47 + 0.30 x 1 + 0.70 x 20


@pytest.mark.parametrize("model, h_ut, h_bs, d2d, los_db, nlos_db, p_los", [
    ("3gpp-uma-av", 100.0, 25.0, 100.0, 80.153, None, 1.0),  # d1 220 m, p1 4800 m (100 m: still the formula)
    ("3gpp-uma-av", 100.0, 25.0, 1000.0, 100.047, None, 0.85331),
    ("3gpp-uma-av", 100.0, 25.0, 3000.0, 110.520, None, 0.56934),
    ("3gpp-uma-av", 150.0, 25.0, 3000.0, 110.526, None, 1.0),  # above 100 m: LoS 100%
    ("3gpp-uma-av", 50.0, 25.0, 100.0, None, 89.626, 0.99480),  # d1 81.5 m, p1 3506 m
    ("3gpp-uma-av", 50.0, 25.0, 1000.0, None, 123.289, 0.77205),
    ("3gpp-umi-av", 50.0, 10.0, 100.0, 80.411, 99.972, 0.92565),  # d1 66.6 m, p1 396.6 m
    ("3gpp-umi-av", 50.0, 10.0, 1000.0, 101.130, 129.295, 0.14162),
    ("3gpp-rma-av", 30.0, 35.0, 100.0, 80.956, 80.956, 1.0),  # d <= d1 = 393.3 m; NLoS = max(LoS, .)
    ("3gpp-rma-av", 30.0, 35.0, 2000.0, 108.580, 116.156, 0.77651),
    ("3gpp-rma-av", 60.0, 35.0, 2000.0, None, None, 1.0),  # above 40 m: LoS 100%
])
def test_tr36777_tables_b1_b2(model, h_ut, h_bs, d2d, los_db, nlos_db, p_los):
    los, nlos = cm.tr36777_path_loss_db(model, np.array([d2d]), h_ut, h_bs, FC)
    if los_db is not None:
        assert los[0] == pytest.approx(los_db, abs=0.01)
    if nlos_db is not None:
        assert nlos[0] == pytest.approx(nlos_db, abs=0.01)
    assert cm.tr36777_los_probability(model, np.array([d2d]), h_ut)[0] == pytest.approx(p_los, abs=1e-5)


def test_tr36777_los_probability_is_one_within_d1_and_falls_beyond():
    d = np.linspace(0.0, 4000.0, 801)
    for model, h in (("3gpp-uma-av", 60.0), ("3gpp-umi-av", 120.0), ("3gpp-rma-av", 25.0)):
        p = cm.tr36777_los_probability(model, d, h)
        assert p[0] == 1.0 and np.all(np.diff(p) <= 1e-12) and p[-1] < 1.0
        assert np.all((p >= 0.0) & (p <= 1.0))


def test_paper_model_numpy_equals_the_worlds_kernel():
    ch = ChannelConfig()
    params = ChannelParams.from_config(ch)
    h = np.linspace(0.0, 3000.0, 301)
    common = (ch.carrier_hz, ch.bandwidth_hz, ch.noise_w, ch.antenna_gain_dbi, ch.los_a, ch.los_b, ch.eta_los_db,
              ch.eta_nlos_db)
    np.testing.assert_allclose(cm.paper_rate(h, 100.0, 0.1, *common), a2g_rate(h, 100.0, 0.1, params), rtol=1e-12)
    np.testing.assert_allclose(cm.paper_rate(h[1:], 0.0, 1.0, *common, los_probability=1.0),
                               a2a_rate(h[1:], 1.0, params), rtol=1e-12)


# -- the config section ---------------------------------------------------------------------------------

@pytest.mark.parametrize("channel, scenario, key", [
    ({"model": "ns3"}, {}, "channel.model"),
    ({"model": "al-hourani", "environment": "rural"}, {}, "channel.environment"),
    ({"environment": "suburban"}, {}, "channel.environment"),  # the paper model takes los_a/los_b/eta_*
    ({"model": "3gpp-uma-av", "los_a": 4.88}, {}, "channel.los_a"),
    ({"model": "3gpp-uma-av"}, {"uav_altitude_m": 20.0}, "scenario.uav_altitude_m"),
    ({"model": "3gpp-rma-av"}, {"uav_altitude_m": 301.0}, "scenario.uav_altitude_m"),
])
def test_config_mistakes_name_the_key(channel, scenario, key):
    with pytest.raises(ConfigError) as err:
        Config().replace(channel=channel, scenario=scenario)
    assert str(err.value).startswith(key) and "\n" not in str(err.value)


def test_every_model_is_accepted_and_listed(capsys):
    from truav.cli.main import main
    for model in cm.MODELS:
        assert Config().replace(channel={"model": model}).channel.model == model
    assert main(["config", "show"]) == 0
    out = capsys.readouterr().out
    for model, m in cm.MODELS.items():
        assert f"#   {model}: " in out and m.source in out
    assert 'model = "paper"' in out


def _run_dir(tmp_path):
    """A `truav train` run directory (config and Q-tables of the right shape) to evaluate."""
    from agents.state import StateEncoder
    from truav.analysis import runio
    from world.uavs import N_ACTIONS
    cfg = Config()
    run = tmp_path / "run"
    run.mkdir()
    runio.write_config(run, cfg)
    runio.write_qtables(run, [0], np.zeros((1, cfg.scenario.n_uavs, StateEncoder(cfg).n_states, N_ACTIONS)))
    return run


@pytest.mark.parametrize("argv", [
    ["train", "--set", "channel.model=ns3"],
    ["evaluate", "run", "--set", "channel.model=ns3"],
    ["experiment", "velocity", "--quick", "--set", "channel.model=ns3"],
])
def test_set_channel_model_reaches_the_commands(argv, capsys, monkeypatch, tmp_path):
    import truav.experiments.runner
    import truav.analysis.trainer

    def trap(*_a, **_k):
        raise AssertionError("work started before the mistake was caught")
    _run_dir(tmp_path)
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(truav.analysis.trainer, "run_parallel", trap)
    monkeypatch.setattr(truav.experiments.runner, "run_cells", trap)
    from truav.cli.main import main
    try:
        rc = main(argv)
    except SystemExit as exc:
        rc = exc.code
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "channel.model" in err[0], err


def test_set_channel_model_reaches_swarm_up(capsys, monkeypatch, tmp_path):
    import truav.swarm.supervisor

    def trap(*_a, **_k):
        raise AssertionError("the swarm started before the mistake was caught")
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(truav.swarm.supervisor, "run_swarm", trap)
    from truav.cli.swarm import main
    try:
        rc = main(["up", "--set", "channel.model=3gpp-umi-av", "--set", "scenario.uav_altitude_m=15"])
    except SystemExit as exc:
        rc = exc.code
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "scenario.uav_altitude_m" in err[0], err


def test_evaluate_runs_a_policy_under_another_channel(tmp_path, monkeypatch, capsys):
    import truav.cli.main
    seen = []

    def fake_run(kind, cfg, *_a, **_k):
        seen.append(cfg.channel.model)
        raise SystemExit(0)
    run = _run_dir(tmp_path)
    monkeypatch.setattr(truav.cli.main, "run_with_progress", fake_run)
    with pytest.raises(SystemExit):
        truav.cli.main.main(["evaluate", str(run), "--set", "channel.model=3gpp-rma-av", "--quiet"])
    assert seen == ["3gpp-rma-av"]


# -- the world under each model ------------------------------------------------------------------------

@pytest.mark.parametrize("kind", ["truav", "patrol"])
def test_paper_model_reproduces_the_numbers_of_before(kind):
    from truav.analysis.trainer import run_chunk
    default = run_chunk(kind, Config().replace(**SMALL), [0, 7], 3)
    explicit = run_chunk(kind, Config().replace(**SMALL, channel={"model": "paper"}), [0, 7], 3)
    assert digest(default) == digest(explicit) == GOLDEN[kind]


def test_other_models_change_the_rates_and_stay_deterministic():
    from truav.analysis.trainer import run_chunk
    paper = run_chunk("truav", Config().replace(**SMALL), [0, 7], 2)
    for model in ("al-hourani", "3gpp-uma-av"):
        cfg = Config().replace(**SMALL, channel={"model": model})
        batch, again = run_chunk("truav", cfg, [0, 7], 2), run_chunk("truav", cfg, [0, 7], 2)
        alone = run_chunk("truav", cfg, [7], 2)
        np.testing.assert_array_equal(batch.q, again.q)
        np.testing.assert_array_equal(batch.q[1], alone.q[0])
        assert not np.array_equal(batch.metrics["delay_ms"], paper.metrics["delay_ms"])


def test_world_rates_follow_the_model():
    from world.network import relay_params, routes, uplink_rate
    cfg = Config().replace(channel={"model": "3gpp-uma-av"})
    ch, p = relay_params(cfg)
    sc = cfg.scenario
    for h in (0.0, 123.4, 499.0):
        loss = cm.al_hourani_path_loss_db(h, sc.uav_altitude_m, cfg.channel.carrier_hz, "urban")
        assert uplink_rate(p, h) == pytest.approx(cm.shannon_rate(0.1, loss, 0.0, 1e-9, 20e6), rel=1e-4)
    uav = np.array([[p.rsu[0, 0] + 300.0, p.rsu[0, 1]], [p.rsu[0, 0] + 1300.0, p.rsu[0, 1]]])
    best, next_hop, hop = routes(uav, p, ch)
    loss = cm.tr36777_mean_path_loss_db("3gpp-uma-av", 300.0, sc.uav_altitude_m, sc.rsu_height_m, 5.9e9)
    direct = p.bits / cm.shannon_rate(1.0, loss, 0.0, 1e-9, 20e6) + math.hypot(300.0, 90.0) / cm.SPEED_OF_LIGHT
    assert next_hop[0] == -1 and best[0] == pytest.approx(direct, rel=1e-4)
    # UAV 1, 1300 m from the RSU: straight there (TR 36.777) or over UAV 0 (free space), whichever is faster
    relay = p.bits / cm.shannon_rate(1.0, cm.fspl_db(1000.0, 5.9e9), 0.0, 1e-9, 20e6) + 1000.0 / cm.SPEED_OF_LIGHT
    loss = cm.tr36777_mean_path_loss_db("3gpp-uma-av", 1300.0, sc.uav_altitude_m, sc.rsu_height_m, 5.9e9)
    far = p.bits / cm.shannon_rate(1.0, loss, 0.0, 1e-9, 20e6) + math.hypot(1300.0, 90.0) / cm.SPEED_OF_LIGHT
    assert best[1] == pytest.approx(min(far, relay + direct), rel=1e-4)
    assert next_hop[1] == (0 if relay + direct < far else -1)
