import numpy as np
import pytest

from agents.qlearning import NO_FENCE, QLearners, epsilon_at, geofence
from agents.reward import Reward
from agents.state import StateEncoder, all_peers, neighbour_features
from truav.config import Config


def test_q_update_by_hand():
    lc = Config().learner
    q = np.zeros((1, 1, 3, 16))
    q[0, 0, 2, 5] = 2.0
    learners = QLearners(lc, 3, [np.random.default_rng(0)], 1, 1, q=q)
    learners.update(np.array([[0]]), np.array([[4]]), np.array([[1.0]]), np.array([[2]]), False)
    assert learners.q[0, 0, 0, 4] == pytest.approx(0.1 * (1.0 + 0.95 * 2.0))
    learners.update(np.array([[1]]), np.array([[0]]), np.array([[1.0]]), np.array([[2]]), True)
    assert learners.q[0, 0, 1, 0] == pytest.approx(0.1)


def test_epsilon_schedule():
    lc = Config().learner
    assert epsilon_at(0, lc) == 1.0
    assert epsilon_at(int(0.8 * lc.episodes), lc) == pytest.approx(0.05)
    assert epsilon_at(lc.episodes - 1, lc) == 0.05
    assert epsilon_at(100, lc) > epsilon_at(200, lc)


def test_geofence_keeps_a_cornered_agent_inside_the_area():
    """At the corner (0, 0) only actions with no negative x or y component are
    allowed: the greedy pick skips a better action into the corner, and an
    exploratory draw that would leave goes to the next allowed action."""
    cfg = Config().replace(learner={"geofence": True})
    lc = cfg.learner
    assert geofence(Config()) is NO_FENCE  # off by default: the literal preset's results stay as they were
    q = np.zeros((1, 1, 1, 16))
    q[0, 0, 0, 5] = 9.0  # 225 degrees at half speed: into the corner
    q[0, 0, 0, 1] = 1.0  # 45 degrees at half speed: away from it
    learners = QLearners(lc, 1, [np.random.default_rng(0)], 1, 1, q=q, fence=geofence(cfg))
    corner, middle = np.zeros((1, 1, 2)), np.full((1, 1, 2), 2500.0)
    state = np.zeros((1, 1), np.int64)
    assert learners.greedy(state, middle)[0, 0] == 5
    assert learners.greedy(state, corner)[0, 0] == 1
    learners._explore_u = np.zeros((1, 1, 1))  # explore
    learners._random_a = np.full((1, 1, 1), 4)  # 180 degrees, half speed: out of the area from x = 0
    learners.epsilon = 1.0
    assert learners.act(state, 0, corner)[0, 0] == 8  # 4..7 leave it (180, 225, 270 degrees; 315 dips below y = 0)
    assert learners.act(state, 0, middle)[0, 0] == 4
    with pytest.raises(ValueError):
        learners.act(state, 0)  # a fenced learner needs positions


def test_greedy_without_exploration():
    lc = Config().learner
    q = np.zeros((2, 1, 1, 16))
    q[0, 0, 0, 3] = 1.0
    q[1, 0, 0, 9] = 1.0
    rngs = [np.random.default_rng(i) for i in range(2)]
    learners = QLearners(lc, 1, rngs, 2, 1, q=q)
    learners.begin_episode(0, 5, greedy=True)
    assert learners.act(np.zeros((2, 1), np.int64), 0).ravel().tolist() == [3, 9]


def test_state_indices_are_in_range_and_distinct():
    cfg = Config()
    enc = StateEncoder(cfg)
    rng = np.random.default_rng(0)
    pos = rng.random((50, 5, 2)) * 5000
    idx = enc.encode(pos, rng.integers(0, 40, (50, 5)), rng.integers(0, 60, (50, 5)), rng.random((50, 5)) * 5000)
    assert idx.min() >= 0 and idx.max() < enc.n_states
    assert enc.n_states == 100 * 4 * 4 * 3 * 3
    # different cells give different states
    a = enc.encode(np.array([[[100.0, 100.0]]]), np.array([[3]]), np.array([[0]]), np.array([[5000.0]]))
    b = enc.encode(np.array([[[4900.0, 100.0]]]), np.array([[3]]), np.array([[0]]), np.array([[5000.0]]))
    assert a[0, 0] != b[0, 0]


def test_overlap_of_coverage_discs():
    pos = np.array([[[0.0, 0.0], [0.0, 0.0], [2000.0, 0.0]]])
    nearest, overlap = neighbour_features(pos, *all_peers(pos), 500.0)
    assert overlap[0, 0] == pytest.approx(1.0)  # co-located twin, the far one adds nothing
    assert nearest[0, 2] == pytest.approx(2000.0) and overlap[0, 2] == 0.0
    # half a radius apart: lens area / disc area by formula
    pos = np.array([[[0.0, 0.0], [250.0, 0.0]]])
    _, ov = neighbour_features(pos, *all_peers(pos), 500.0)
    x = 0.25
    assert ov[0, 0] == pytest.approx(2 / np.pi * (np.arccos(x) - x * np.sqrt(1 - x * x)))


def test_reward_weights():
    cfg = Config()
    r = Reward(cfg)
    relay, cov, eng, ov = r.terms(np.array([8.0]), np.array([40.0]), np.array([250.0]), np.array([0.5]))
    assert relay[0] == pytest.approx(1.0) and cov[0] == pytest.approx(1.0)
    assert eng[0] == pytest.approx(1.0) and ov[0] == 0.5
    assert r(np.array([8.0]), np.array([40.0]), np.array([250.0]), np.array([0.5]))[0] == pytest.approx(
        1.0 + 0.25 - 0.15 - 0.20 * 0.5)
