"""The patrol baseline (agents.patrol) written through the agent API (agents.api), registered as ``patrol``.

Each UAV plans, at an episode's first step, the whole swarm's orbits from its own start and the starts
its peers' beacons tell (agents.patrol.assign_slots and plan_trajectories, as PatrolController does for
all UAVs at once), keeps its own, and each step flies the action landing closest to its next planned
position (PatrolController.act_one's arithmetic): the same numbers as ``truav evaluate --against patrol``
when every beacon is heard, as in the in-process trainer.
"""

from __future__ import annotations

import numpy as np

from agents.api import HOVER, LocalView, N_ACTIONS, UavAgent
from agents.patrol import TRACKABLE, assign_slots, orbit_slots, plan_trajectories
from world.uavs import ACTION_UNIT_VELOCITY


class PatrolAgent(UavAgent):
    def __init__(self, cfg, uav, rng):
        super().__init__(cfg, uav, rng)
        sc = cfg.scenario
        self.speed = sc.uav_speed_mps * cfg.patrol.speed_fraction * TRACKABLE
        self.centre, self.phase = orbit_slots(cfg)
        self.cand = np.concatenate([ACTION_UNIT_VELOCITY[:N_ACTIONS], ACTION_UNIT_VELOCITY[-1:]]) * sc.uav_speed_mps
        self.cand_action = np.concatenate([np.arange(N_ACTIONS), [HOVER]])
        self.plan = np.zeros((sc.steps_per_episode + 1, 2))

    def act(self, view: LocalView) -> int:
        sc, pc = self.cfg.scenario, self.cfg.patrol
        if view.step == 0:  # deployment: the swarm's starts, in UAV-id order
            known = {b.uav: b.pos for b in view.beacons} | {self.uav: view.pos}
            ids = sorted(known)
            start = np.array([known[i] for i in ids], np.float64)
            slot = assign_slots(start, self.centre[:len(ids)], pc.radius_m, pc.assignment)
            plan, _ = plan_trajectories(start, self.centre[slot], self.phase[slot], pc.radius_m, self.speed,
                                        sc.step_s, sc.steps_per_episode)
            self.plan = plan[:, ids.index(self.uav)]
        land = np.clip(np.asarray(view.pos, np.float64)[None, :] + self.cand * sc.step_s, 0.0, sc.area_m)
        miss = np.sum((land - self.plan[view.step + 1][None, :]) ** 2, axis=-1)
        return int(self.cand_action[np.argmin(miss)])
