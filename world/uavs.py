"""UAV kinematics and energy: the 16 discrete actions of the paper (8
headings at 45 degrees x half/full speed), plus HOVER for a missing action.

Energy per step (J) for a UAV moving at speed v:

    E = (P_hover + (P_move - P_hover) * v / v_ref) * dt + P_tx * t_tx

i.e. a hover base, propulsion above hover growing linearly with speed (the
paper reports energy rising roughly linearly with speed and gives one move
power; we attribute it to v_ref), plus transmit energy for the airtime the
UAV spends forwarding packets.
"""

from __future__ import annotations

import numpy as np

from truav.actions import HOVER, N_ACTIONS  # noqa: F401  (re-exported for the world model's users)
from truav.config import EnergyConfig

_ANGLES = np.deg2rad(45.0 * (np.arange(N_ACTIONS) % 8))
_FRACTION = np.where(np.arange(N_ACTIONS) < 8, 0.5, 1.0)
# Row N_ACTIONS is HOVER (index -1 wraps to it).
ACTION_UNIT_VELOCITY = np.concatenate(
    [np.stack([np.cos(_ANGLES), np.sin(_ANGLES)], axis=1) * _FRACTION[:, None], np.zeros((1, 2))])


def action_velocity(actions: np.ndarray, speed_max: float) -> np.ndarray:
    """Velocity (..., 2) in m/s for action indices (...) in [-1, 16); -1 hovers."""
    return ACTION_UNIT_VELOCITY[actions] * speed_max


def move(pos: np.ndarray, velocity: np.ndarray, dt: float, area_m: float) -> tuple[np.ndarray, np.ndarray]:
    """New positions (B, U, 2) clipped to the area, and the speed actually flown (B, U)."""
    new = np.clip(pos + velocity * dt, 0.0, area_m)
    step = new - pos
    return new, np.sqrt(step[..., 0] ** 2 + step[..., 1] ** 2) / dt


def flight_energy(speed: np.ndarray, dt: float, e: EnergyConfig) -> np.ndarray:
    """Hover plus propulsion energy (J) over dt at the given speeds."""
    return (e.hover_w + (e.move_w - e.hover_w) * speed / e.move_ref_speed_mps) * dt
