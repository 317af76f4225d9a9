"""One agent's decision state as named arrays, and restored from them: the agent half of a lock-step
recording's snapshots (the world's: world.world_state). Pure, no I/O.

The Q-table is captured sparsely: only the rows the agent updated (TruavDecision.touched) with their
indices. A restore starts from the table the run started with (fresh from the agent's generator, or a
trained run's) and writes those rows back, so a 14,400 x 16 table of a UAV that visited a few hundred
states costs a few hundred rows. The rest: the exploration generator, this episode's exploration draws
(one uniform and one random action per step, drawn at its start), epsilon, and the decision's
episode, step, last state, last action and velocity, its density map (prediction) and its last count of
vehicles in range (shaping).
"""

from __future__ import annotations

import numpy as np

from agents.agent_decision import TruavDecision
from world.draws import RNG_WORDS, rng_from_words, rng_words
from world.uavs import N_ACTIONS
from world.world_state import check_state


def decision_state(d: TruavDecision) -> dict[str, np.ndarray]:
    """Copies of every array of ``d``'s state (a TruavDecision of one agent, B = U = 1)."""
    lr = d.learners
    rows = np.array(sorted(d.touched), np.int64)
    return {
        "episode": np.array(d.episode, np.int64), "t": np.array(d.t, np.int64),
        "state": np.array(d.state, np.int64), "action": np.array(d.action, np.int64),
        "velocity": np.array(d.velocity, np.float64), "epsilon": np.array(lr.epsilon, np.float64),
        "rng": rng_words(lr.rngs[0]), "explore_u": np.array(lr._explore_u[:, 0, 0], np.float64),
        "random_a": np.array(lr._random_a[:, 0, 0], np.int64),
        "q_rows": rows, "q_values": lr.q[0, 0, rows].copy(),
        "density_map": d.density_map[0, 0].copy(), "prev_in_range": np.array(d.prev_in_range, np.float64),
    }


def decision_state_spec(n_states: int) -> dict[str, tuple[np.dtype, tuple[int, ...]]]:
    """Every array of a decision state: name -> (dtype, shape), -1 any length."""
    f8, i8 = np.dtype(np.float64), np.dtype(np.int64)
    return {"episode": (i8, ()), "t": (i8, ()), "state": (i8, ()), "action": (i8, ()), "velocity": (f8, (2,)),
            "epsilon": (f8, ()), "rng": (np.dtype(np.uint64), (RNG_WORDS,)), "explore_u": (f8, (-1,)),
            "random_a": (i8, (-1,)), "q_rows": (i8, (-1,)), "q_values": (f8, (-1, N_ACTIONS)),
            "density_map": (f8, (-1,)), "prev_in_range": (f8, ())}


def restore_decision(d: TruavDecision, state: dict[str, np.ndarray]) -> None:
    """Put ``state`` into ``d``, whose learners hold the table the run started with; ValueError when the
    state does not fit it (shapes, dtypes, rows or actions out of range)."""
    lr = d.learners
    check_state(state, decision_state_spec(lr.n_states))
    rows, values = state["q_rows"], state["q_values"]
    steps = state["explore_u"].shape[0]
    if rows.shape[0] != values.shape[0] or (rows.size and (rows.min() < 0 or rows.max() >= lr.n_states)) \
            or len(np.unique(rows)) != rows.size:
        raise ValueError(f"q_rows must be {values.shape[0]} distinct states below {lr.n_states}")
    if state["random_a"].shape[0] != steps or (steps and (state["random_a"].min() < 0
                                                         or state["random_a"].max() >= N_ACTIONS)):
        raise ValueError("random_a must be one action per exploration draw")
    if not 0 <= int(state["state"]) < lr.n_states or not 0 <= int(state["action"]) < N_ACTIONS:
        raise ValueError("state or action out of range")
    if not np.all(np.isfinite(values)) or not np.all(np.isfinite(state["velocity"])):
        raise ValueError("q_values and velocity must be finite")
    if state["density_map"].shape != d.density_map.shape[2:] or not np.all(np.isfinite(state["density_map"])) \
            or not np.isfinite(state["prev_in_range"]):
        raise ValueError(f"density_map must be {d.density_map.shape[2:]} finite values (the run's prediction "
                         "settings), prev_in_range finite")
    lr.q[0, 0, rows] = values
    lr.rngs[0] = rng_from_words(state["rng"])
    lr.epsilon = float(state["epsilon"])
    lr._explore_u = state["explore_u"].reshape(steps, 1, 1).copy()
    lr._random_a = state["random_a"].reshape(steps, 1, 1).copy()
    d.episode, d.t = int(state["episode"]), int(state["t"])
    d.state, d.action = int(state["state"]), int(state["action"])
    d.velocity = tuple(float(v) for v in state["velocity"])
    d._encoded = np.array([[d.state]], np.int64)
    d.touched = set(int(r) for r in rows)
    d.density_map[0, 0] = state["density_map"]
    d.prev_in_range = float(state["prev_in_range"])


__all__ = ["decision_state", "decision_state_spec", "restore_decision"]
