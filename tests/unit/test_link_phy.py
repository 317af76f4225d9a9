"""Channel-driven beacon links (links.model = "channel", world/link_phy.py): the PHY abstraction, the
counter-based draws, the trainer's two paths under it, and the default (ideal links) unchanged."""

import math

import numpy as np
import pytest

import truav.cli.main
from agents.agent_decision import TruavDecision
from agents.controller import TruavController
from agents.qlearning import QLearners
from truav.analysis.driver import run_episodes
from truav.analysis.trainer import run_chunk
from truav.config import Config
from truav.wire import schema
from world import link_phy
from world.channel_models import fspl_db

CHANNEL = Config().replace(links={"model": "channel"})


def test_delivery_falls_with_distance_from_one_to_zero():
    d = np.arange(0.0, 2000.0, 0.5)
    for model in ("paper", "al-hourani", "3gpp-uma-av"):
        p = link_phy.delivery_probability(d, CHANNEL.replace(channel={"model": model}))
        assert np.all(np.diff(p) <= 0.0), model  # monotone in distance
        assert p[0] == 1.0 and p[d == 20.0] == 1.0  # no loss at short range
        assert p[-1] < 1e-12  # lost far away
    # a lower noise floor carries a beacon farther, as free space says: 20 dB less noise, 10x the range
    base = link_phy.threshold_distance_m(CHANNEL)
    quieter = link_phy.threshold_distance_m(CHANNEL.replace(channel={"noise_w": 1e-11}))
    assert quieter == pytest.approx(10.0 * base, rel=1e-3)


def test_documented_threshold_distances():
    """docs/channel-models.md, "Beacon links": the 50% distances under the default channel (noise 1e-9 W)."""
    assert link_phy.threshold_distance_m(CHANNEL) == pytest.approx(59.51, abs=0.01)
    free_space = CHANNEL.replace(channel={"model": "al-hourani"})
    assert link_phy.threshold_distance_m(free_space) == pytest.approx(66.77, abs=0.01)
    assert link_phy.threshold_distance_m(CHANNEL.replace(channel={"noise_w": 1e-11})) == pytest.approx(595.02, abs=0.05)


def test_packet_error_rate_by_hand():
    """The NIST OFDM error model for QPSK 1/2 at 5 dB, 100 bytes, evaluated step by step."""
    snr = 10.0 ** 0.5
    p = 0.5 * math.erfc(math.sqrt(snr / 2.0))
    dd = math.sqrt(4.0 * p * (1.0 - p))
    pe = 0.5 * (36 * dd**10 + 211 * dd**12 + 1404 * dd**14 + 11633 * dd**16 + 77433 * dd**18 + 502690 * dd**20
                + 3322763 * dd**22 + 21292910 * dd**24 + 134365911 * dd**26)
    assert float(link_phy.packet_success(snr, 100)) == pytest.approx((1.0 - pe) ** 800, rel=1e-12)
    # received power: P_tx minus the paper's air-to-air loss (FSPL + eta_LoS), over the noise
    ch = CHANNEL.channel
    d = 59.51
    snr_d = ch.uav_tx_w * 10.0 ** (-(fspl_db(d, ch.carrier_hz) + ch.eta_los_db) / 10.0) / ch.noise_w
    assert float(link_phy.delivery_probability(d, CHANNEL)) == pytest.approx(float(link_phy.packet_success(snr_d, 100)))


def test_airtime_is_preamble_plus_symbols():
    assert link_phy.airtime_s(100) == pytest.approx(40e-6 + 18 * 8e-6)  # (16 + 800 + 6) bits / 48 per symbol
    assert link_phy.airtime_s(1) == pytest.approx(40e-6 + 8e-6)


def test_draws_are_counter_based_and_uniform():
    u = np.array([link_phy.link_uniform(3, e, k, j, i) for e in range(20) for k in range(20)
                  for j in range(3) for i in range(3)])
    again = np.array([link_phy.link_uniform(3, e, k, j, i) for e in range(20) for k in range(20)
                      for j in range(3) for i in range(3)])
    assert np.array_equal(u, again)
    assert 0.0 <= u.min() and u.max() < 1.0 and abs(u.mean() - 0.5) < 0.02
    assert len(np.unique(u)) == u.size  # each (episode, k, src, dst) its own number
    other_seed = np.array([link_phy.link_uniform(4, e, 0, 0, 1) for e in range(400)])
    assert not np.array_equal(other_seed, u[:400])


def test_agent_decision_hears_what_the_trainer_hears():
    """TruavDecision.hear (an agent process, a re-simulation) and heard_masks (the trainer) decide alike."""
    cfg = CHANNEL.replace(channel={"noise_w": 1e-11}, scenario={"n_uavs": 3})
    params = link_phy.link_params(cfg)
    rng = np.random.default_rng(0)
    pos = rng.uniform(0.0, 1200.0, (40, 3, 2))
    decisions = [TruavDecision(cfg, i, QLearners(cfg.learner, 16, [np.random.default_rng(i)], 1, 1), seed=7)
                 for i in range(3)]
    for d in decisions:
        d.episode, d.t = 2, 4  # the episode's 6th observation: beacon k = 5
    masks = link_phy.heard_masks(params.table, params.step_m, pos, np.full(40, 7, np.int64), 2, 5)
    assert 0 < masks.sum() < 40 * 6  # some heard, some lost
    for b in range(40):
        beacons = {j: schema.Beacon(uav=j, tick=0, pos=tuple(pos[b, j]), vel=(0.0, 0.0)) for j in range(3)}
        for i, d in enumerate(decisions):
            obs = schema.Obs(uav=i, tick=0, episode=2, pos=tuple(pos[b, i]), vehicles_in_range=0, queued_packets=0,
                             relayed=0, covered=0, energy_j=0.0, speed_max=20.0, done=False)
            heard = d.hear(obs, {j: v for j, v in beacons.items() if j != i})
            assert sorted(heard) == [j for j in range(3) if masks[b, i, j]]
    assert sum(c[1] for d in decisions for c in d.link_counts.values()) == 40 * 6 - masks.sum()


def _run(cfg, seeds, fused):
    ctrl = TruavController(cfg, seeds)
    ctrl.fused = fused
    return run_episodes(cfg, seeds, ctrl, 3), ctrl.learners.q


def test_fused_kernel_equals_the_step_path_with_channel_links(small_cfg):
    cfg = small_cfg.replace(links={"model": "channel"}, channel={"noise_w": 1e-11}, scenario={"n_uavs": 4})
    ref, q_ref = _run(cfg, [0, 5], fused=False)
    got, q_got = _run(cfg, [0, 5], fused=True)
    for k in ref:
        np.testing.assert_array_equal(got[k], ref[k], err_msg=k)
    np.testing.assert_array_equal(q_got, q_ref)
    _, q_ideal = _run(cfg.replace(links={"model": "ideal"}), [0, 5], fused=True)
    assert not np.array_equal(q_got, q_ideal)  # the channel lost beacons the ideal links deliver


def test_ideal_links_are_todays_numbers():
    """links.model "ideal" (the default) is bit for bit the run of before channel-driven links: the same
    digests as tests/unit/test_channel_models.py's golden run, recorded before either existed."""
    from tests.support.golden import GOLDEN, SMALL, digest
    assert Config().links.model == "ideal"
    result = run_chunk("truav", Config().replace(**SMALL, links={"model": "ideal"}), [0, 7], 3)
    assert digest(result) == GOLDEN["truav"]


def test_a_bad_link_model_is_one_line(capsys):
    assert truav.cli.main.main(["train", "--set", "links.model=radio", "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "links.model" in err and "ideal, channel" in err


def test_config_show_lists_the_link_models(capsys):
    truav.cli.main.main(["config", "show"])
    out = capsys.readouterr().out
    assert "links.model choices" in out and "#   channel:" in out and '[links]\nmodel = "ideal"' in out
