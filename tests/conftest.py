"""Shared fixtures: small, fast configurations of the paper's scenario."""

from __future__ import annotations

import pytest

from truav.config import Config


@pytest.fixture
def small_cfg() -> Config:
    """A reduced city (fewer vehicles, short episodes) that runs in milliseconds."""
    return Config().replace(
        scenario={"n_vehicles": 60, "steps_per_episode": 20},
        roads={"warmup_steps": 20},
        learner={"episodes": 3},
    )
