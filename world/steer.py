"""Steering a UAV from outside (an override, control/override/<i>): the action that flies it toward a goal.

Pure computation: a function of positions, goals and the scenario's speed and step, used by the world
process while a UAV is overridden and by the re-simulation of a recording with overrides, so that both fly
the same actions.
"""

from __future__ import annotations

import numpy as np

from world.uavs import ACTION_UNIT_VELOCITY, HOVER

_HALF = np.arange(8)
_FULL = np.arange(8, 16)


def speed_tier(speed_mps: float, speed_max: float) -> np.ndarray:
    """The 8 actions flown for a requested speed: half speed (0-7) when it is nearer half the UAV's speed
    than full, else full speed (8-15); 0 means full speed."""
    if speed_mps <= 0.0 or abs(speed_mps - 0.5 * speed_max) >= abs(speed_mps - speed_max):
        return _FULL
    return _HALF


def steer_action(pos: tuple[float, float], goal: tuple[float, float], speed_mps: float, speed_max: float,
                 step_s: float, area_m: float) -> int:
    """The action (one of the 16, or HOVER) that takes a UAV at ``pos`` toward ``goal`` (clipped to the area):
    HOVER once within one step of it, else the one of its speed tier's 8 headings that ends the step nearest
    to the goal (ties: the lowest action number)."""
    tier = speed_tier(speed_mps, speed_max)
    p = np.asarray(pos, np.float64)
    g = np.clip(np.asarray(goal, np.float64), 0.0, area_m)
    step = float(np.hypot(*ACTION_UNIT_VELOCITY[tier[0]])) * speed_max * step_s
    if float(np.hypot(*(g - p))) <= step:
        return HOVER
    ends = np.clip(p + ACTION_UNIT_VELOCITY[tier] * speed_max * step_s, 0.0, area_m)
    return int(tier[int(np.argmin(np.hypot(*(ends - g).T)))])


def apply_overrides(actions: np.ndarray, pos: np.ndarray, goals: dict[int, tuple[float, float, float]],
                    speed_max: float, step_s: float, area_m: float) -> np.ndarray:
    """``actions`` (1, U) with each overridden UAV's replaced by :func:`steer_action` toward its goal;
    ``goals``: {uav: (x, y, speed)}, ``pos`` (1, U, 2). A new array; the input is left as it is."""
    out = np.array(actions, np.int64, copy=True)
    for uav, (x, y, speed) in goals.items():
        out[0, uav] = steer_action(tuple(pos[0, uav]), (x, y), speed, speed_max, step_s, area_m)
    return out
