"""An agent API class whose methods do nothing (agents.api): what the API itself costs per call.

    python bench/bench_trainer.py --agent bench.idle_agent:Idle

It hovers every step, learns nothing and keeps an empty state: its trainer's throughput against TRUAV's own
trainer is the handicap the API puts on a user's learner before it computes anything.
"""

from __future__ import annotations

from agents.api import HOVER, LocalView, UavAgent


class Idle(UavAgent):
    def act(self, view: LocalView) -> int:
        return HOVER

    def learn(self, view: LocalView, reward: float, done: bool) -> None:
        pass
