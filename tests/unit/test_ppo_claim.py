"""The claim features (agents/view_features.py, ``claim``: the climbing heuristic's state) and the network cloned
with them (agents.ppo_agent.PpoClaimAgent): the default observation unchanged, and the batched form flying the
per-UAV form action for action on the same seed."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("numba")

from agents.claim_agent import CLAIM_FEATURES  # noqa: E402
from agents.ppo_agent import CLAIM_WEIGHTS, PpoClaimAgent, load_policy  # noqa: E402
from agents.spread_agent import SENSE_RANGE_M  # noqa: E402
from agents.view_features import ViewEncoder, observation_features  # noqa: E402
from truav.config import Config  # noqa: E402
from tests.support.batched_forms import assert_batched_flies_per_uav  # noqa: E402
from truav.presets import preset_overrides  # noqa: E402

CFG = Config().replace(**preset_overrides("paper")).replace(scenario={"uav_speed_mps": 15.0},
                                                            learner={"sense_range_m": SENSE_RANGE_M})


def test_the_claim_features_are_appended_and_the_default_observation_is_unchanged():
    default = observation_features(CFG)
    assert observation_features(CFG, claim=False) == default
    with_claim = observation_features(CFG, claim=True)
    assert with_claim[: len(default)] == default
    assert [f.name for f in with_claim[len(default):]] == [f"claim_{n}" for n, _ in CLAIM_FEATURES]
    assert ViewEncoder(CFG).size == len(default)


def test_an_encoder_with_the_claim_features_needs_them():
    enc = ViewEncoder(CFG, claim=True)
    with pytest.raises(ValueError, match="claim"):
        enc._claim(None)


def test_the_shipped_claim_weights_observe_the_claim_features():
    policy = load_policy(str(CLAIM_WEIGHTS))
    assert policy.claim and not policy.memory
    assert policy.n_features == ViewEncoder(CFG, policy.peers, False, True).size


def test_the_batched_form_flies_the_per_uav_form_on_the_same_seed():
    cfg = CFG.replace(scenario={"n_vehicles": 80, "steps_per_episode": 25}, roads={"warmup_steps": 10})
    assert_batched_flies_per_uav("ppo-claim", PpoClaimAgent, cfg)


def test_dagger_labels_come_from_the_rule_the_claim_features_come_from():
    # Where the features say the climb replaced a hover, the label is the climb's heading at full speed; in every
    # round (a second, fresh heuristic labelled later rounds from another climb heading than the features').
    from agents.claim_agent import ClaimBatched
    from truav.analysis.ppo_train import teacher_data
    from truav.analysis.ppo_vec_env import HOVER_INDEX, TruavVecEnv

    cfg = CFG.replace(scenario={"n_vehicles": 80, "steps_per_episode": 25}, roads={"warmup_steps": 10})
    env = TruavVecEnv(cfg, [3, 4], claim=True)
    first = env.encoder.index("claim_climb_x")
    for flier in (None, lambda o: np.full(len(o), HOVER_INDEX)):
        obs, labels, _ = teacher_data(env, 2, 0.9, flier, teacher_cls=ClaimBatched)
        climbing = obs[:, env.encoder.index("claim_climbing")] == 1.0
        sector = np.round(np.arctan2(obs[:, first + 1], obs[:, first]) / (np.pi / 4)).astype(np.int64) % 8
        assert climbing.sum() > 10
        assert np.array_equal(labels[climbing], sector[climbing] + 8)
