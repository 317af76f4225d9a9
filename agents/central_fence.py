"""The centralized baseline under an autopilot geofence (central.geofence).

The SAC's controller commands an action per UAV; the UAV's autopilot refuses
a move that would leave the area and flies the next allowed action instead
(agents.qlearning.fenced_actions, the rule TRUAV's exploratory draws follow).
The SAC learns from what it commanded: the fence is part of its environment.
A subclass, so the learner (agents/central.py, agents/sac.py) is unchanged.
"""

from __future__ import annotations

import numpy as np

from agents.central import CentralController
from agents.qlearning import Fence, fenced_actions
from world.uavs import ACTION_UNIT_VELOCITY


class FencedCentralController(CentralController):
    """CentralController whose executed actions stay inside the area."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        sc = self.cfg.scenario
        self.fence = Fence(float(sc.area_m), float(sc.uav_speed_mps * sc.step_s), ACTION_UNIT_VELOCITY)

    def act(self, t: int) -> np.ndarray:
        commanded = super().act(t)  # self.action stays the commanded one: the replay stores it
        return fenced_actions(np.ascontiguousarray(commanded, np.int64),
                              np.ascontiguousarray(self.pos, np.float64), self.fence)
