"""Training the learned policy writes nothing to the temporary directory: Stable-Baselines3 makes a
``SB3-<date>`` directory there for its default logger unless the model has one set
(truav.analysis.ppo_train sets an in-memory logger on every PPO model it makes)."""

from __future__ import annotations

import os
import tempfile

import pytest

pytest.importorskip("stable_baselines3")

from truav.analysis.ppo_train import make_ppo, train  # noqa: E402
from truav.analysis.ppo_vec_env import TruavVecEnv  # noqa: E402
from truav.config import Config  # noqa: E402

CFG = Config().replace(scenario={"n_vehicles": 40, "steps_per_episode": 6, "n_uavs": 2},
                       roads={"warmup_steps": 5}, learner={"sense_range_m": 1500.0})


def _left(tmp: str) -> list[str]:
    """What is in ``tmp``, less torch's own compiler cache (``torchinductor_<user>``, made once when
    torch._dynamo is first imported, by the optimizer's construction; reused, not one per run)."""
    return sorted(n for n in os.listdir(tmp) if not n.startswith("torchinductor_"))


@pytest.fixture
def tmpdir_is(tmp_path, monkeypatch):
    """tempfile.gettempdir() is an empty tmp_path for the test."""
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    monkeypatch.delenv("SB3_LOGDIR", raising=False)
    monkeypatch.setattr(tempfile, "tempdir", None)  # gettempdir() caches its first answer
    assert tempfile.gettempdir() == str(tmp_path)
    return tmp_path


def test_training_with_ppo_writes_nothing_to_the_temporary_directory(tmpdir_is):
    model, times = train(CFG, [3], bc_episodes=1, bc_epochs=1, ppo_steps=24, n_steps=6, say=lambda s: None)
    assert model.num_timesteps >= 24 and times["ppo_s"] > 0
    assert _left(tmpdir_is) == []


def test_a_model_made_for_training_logs_in_memory(tmpdir_is):
    model = make_ppo(TruavVecEnv(CFG, [1]), n_steps=6)
    model.learn(total_timesteps=12)
    assert model.logger.dir is None and model.logger.output_formats == []
    assert _left(tmpdir_is) == []
