"""The API's example (agents.api): a UAV that flies a uniformly random action each step.

Registered as ``random`` (``truav train --agent random``). Its randomness is its own generator's, so
the same seed flies the same run. RandomAgentBatched is the same agent with the batched form.
"""

from __future__ import annotations

import numpy as np

from agents.api import BatchedAgents, LocalView, UavAgent, N_ACTIONS


class RandomAgent(UavAgent):
    def act(self, view: LocalView) -> int:
        return int(self.rng.integers(N_ACTIONS))


class _Batched(BatchedAgents):
    def act(self, views) -> np.ndarray:
        return np.array([[rng.integers(N_ACTIONS) for rng in row] for row in self.rngs], np.int64)


class RandomAgentBatched(RandomAgent):
    batched = _Batched
