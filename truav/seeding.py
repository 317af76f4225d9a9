"""Seed streams: every random number of a run derives from (seed, role, id).

The world of seed s draws from SeedSequence(s, spawn_key=(0,)); agent i from
SeedSequence(s, spawn_key=(1, i)). The in-process trainer and the swarm's
separate processes therefore draw identical numbers for the same seed.
"""

from __future__ import annotations

import numpy as np

WORLD_ROLE = 0
AGENT_ROLE = 1
BASELINE_ROLE = 2

EVAL_SEED_OFFSET = 10_000
"""Evaluation runs on held-out traffic: world seed = training seed + this (`truav evaluate`, experiment cells)."""


def world_rng(seed: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(WORLD_ROLE,)))


def agent_rng(seed: int, agent: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(AGENT_ROLE, agent)))


def baseline_rng(seed: int, index: int = 0) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(BASELINE_ROLE, index)))
