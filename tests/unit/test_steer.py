"""world.steer: the action that flies an overridden UAV toward its goal."""

import numpy as np
import pytest

from world.steer import apply_overrides, speed_tier, steer_action
from world.uavs import HOVER, action_velocity, move

SPEED, STEP, AREA = 15.0, 1.0, 5000.0


@pytest.mark.parametrize("goal,want", [((1100.0, 1000.0), 8), ((1000.0, 1100.0), 10), ((900.0, 1000.0), 12),
                                       ((1000.0, 900.0), 14), ((1100.0, 1100.0), 9), ((900.0, 900.0), 13)])
def test_full_speed_heading_toward_the_goal(goal, want):
    assert steer_action((1000.0, 1000.0), goal, 0.0, SPEED, STEP, AREA) == want


def test_hovers_within_one_step_and_half_speed_tier():
    assert steer_action((1000.0, 1000.0), (1010.0, 1005.0), 0.0, SPEED, STEP, AREA) == HOVER
    assert steer_action((1000.0, 1000.0), (1100.0, 1000.0), 7.0, SPEED, STEP, AREA) == 0  # half speed east
    assert steer_action((1000.0, 1000.0), (1005.0, 1000.0), 7.0, SPEED, STEP, AREA) == HOVER
    assert list(speed_tier(0.0, SPEED)) == list(range(8, 16)) and list(speed_tier(50.0, SPEED)) == list(range(8, 16))


def test_flying_the_actions_reaches_the_goal_and_stays():
    pos = np.array([[[100.0, 4000.0]]])
    goal = (3210.0, 777.0)
    for _ in range(400):
        a = apply_overrides(np.array([[3]]), pos, {0: (*goal, 0.0)}, SPEED, STEP, AREA)
        pos, _ = move(pos, action_velocity(a, SPEED), STEP, AREA)
    assert np.hypot(*(pos[0, 0] - goal)) <= SPEED * STEP


def test_goal_outside_the_area_is_clipped_and_others_untouched():
    actions = np.array([[5, 6]])
    out = apply_overrides(actions, np.array([[[4990.0, 10.0], [0.0, 0.0]]]), {0: (9000.0, 10.0, 0.0)}, SPEED, STEP,
                          AREA)
    assert out[0, 0] == HOVER and out[0, 1] == 6 and actions[0, 0] == 5
