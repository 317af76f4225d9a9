"""Federated TRUAV: the merge rule of shared Q rows (pure: no I/O, no bus).

Every ``federated.every`` episodes each UAV shares the Q rows of the states it
visited since its last share, with its visit counts (how many updates it made
in each state, ever), and merges what its peers shared by visit-weighted
averaging::

    Q_i(s) += sum_j w_j (Q_j(s) - Q_i(s)),   w_j = min(n_j(s) / (n_i(s) + sum_k n_k(s)), max_weight)

over the peers j whose share holds s (k as well), Q_i taken as it was before
the merge (the share a UAV sends is its table before it merges the others').
Bounded: a peer touches only the rows it shares, moves an entry at most
``max_weight`` of the way to its own value, and a share with a NaN, an
infinite or an out-of-range value, a state outside the table, a count no
run could have made, or of another share round is refused whole
(:func:`check_share`). A UAV's own counts are never changed by a merge, so
nothing is counted twice.

The in-process trainer (agents.controller.TruavController, :func:`federate`)
and a swarm agent (agents.agent_federated, rows from the bus) call the same
functions with the same arrays, in UAV-id order, so they give the same
tables entry for entry.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from truav.config import FederatedConfig

R_SHAPE = "bad_shape"
R_STATE = "bad_state"
R_COUNT = "bad_count"
R_VALUE = "bad_value"
R_ROUND = "stale_round"
R_AHEAD = "bad_round"
"""Not a share round, or further ahead than the rounds a receiver keeps (:func:`rounds_to_keep`)."""
REFUSAL_REASONS = (R_SHAPE, R_STATE, R_COUNT, R_VALUE, R_ROUND, R_AHEAD)


class Share(NamedTuple):
    """What one UAV shares after an episode: rows ``q`` (n, 16) of ``states`` (n,), visited ``counts`` (n,) times."""

    uav: int
    episode: int
    """The episode it was made after (its share round: (episode + 1) % every == 0)."""
    states: np.ndarray
    counts: np.ndarray
    q: np.ndarray


def share_due(episode: int, fc: FederatedConfig) -> bool:
    """Whether the UAVs share after ``episode`` (0-based)."""
    return fc.every > 0 and (episode + 1) % fc.every == 0


def max_parts(fc: FederatedConfig, rows_per_part: int) -> int:
    """The most messages a share of at most ``fc.max_rows`` rows is split over (:func:`split_share`)."""
    return max(1, -(-fc.max_rows // rows_per_part))


def rounds_to_keep(rounds: set[int], oldest: int, fc: FederatedConfig, most: int) -> set[int]:
    """Of the share ``rounds`` a receiver holds parts of, those it keeps: share rounds not older than ``oldest``,
    the ``most`` nearest (a hostile peer's rounds far ahead are dropped, never the present one)."""
    return set(sorted(r for r in rounds if r >= oldest and share_due(r, fc))[:most])


def make_share(uav: int, episode: int, q: np.ndarray, visits: np.ndarray, since: np.ndarray,
               max_rows: int) -> Share:
    """UAV ``uav``'s share of its table q (S, 16): the rows whose visits (S,) grew since ``since`` (S,), the
    most visited first (ties: lower state first), at most ``max_rows``."""
    visited = np.flatnonzero(visits > since)
    order = np.lexsort((visited, -visits[visited]))[:max_rows]
    states = visited[order].astype(np.int64)
    return Share(uav, episode, states, visits[states].astype(np.int64), q[states].astype(np.float64))


def max_count(episode: int, steps_per_episode: int) -> int:
    """The most updates a UAV can have made in one state by the end of ``episode``."""
    return (episode + 1) * steps_per_episode


def check_share(share: Share, n_states: int, n_actions: int, episode: int, most: int, q_bound: float) -> str | None:
    """Why ``share`` must be refused (one of REFUSAL_REASONS, with a detail), or None: it is of round ``episode``,
    its rows fit a table (n_states, n_actions), its states are distinct, its counts in [1, most], its values
    finite and within +-q_bound."""
    states, counts, q = share.states, share.counts, share.q
    if share.episode != episode:
        return f"{R_ROUND}: share of episode {share.episode}, this round is episode {episode}"
    if states.ndim != 1 or counts.shape != states.shape or q.shape != (len(states), n_actions):
        return f"{R_SHAPE}: {len(states)} states, {counts.shape} counts, {q.shape} rows"
    if len(states) and (states.min() < 0 or states.max() >= n_states or len(np.unique(states)) != len(states)):
        return f"{R_STATE}: states must be distinct and in [0, {n_states})"
    if len(counts) and (counts.min() < 1 or counts.max() > most):
        return f"{R_COUNT}: counts must be in [1, {most}]"
    if not np.isfinite(q).all() or (len(q) and np.abs(q).max() > q_bound):
        return f"{R_VALUE}: values must be finite and within +-{q_bound:g}"
    return None


def merge(q: np.ndarray, visits: np.ndarray, shares: list[Share], max_weight: float) -> int:
    """Merge peers' ``shares`` (checked, in UAV-id order) into table q (S, 16) in place, weighting by the
    receiver's own visits (S,); returns the number of rows changed."""
    if not shares:
        return 0
    total = np.zeros(q.shape[0])
    touched = np.zeros(q.shape[0], np.bool_)
    for sh in shares:
        total[sh.states] += sh.counts
        touched[sh.states] = True
    rows = np.flatnonzero(touched)
    total[rows] += visits[rows]
    before = q[rows].copy()
    delta = np.zeros_like(before)
    where = np.full(q.shape[0], -1, np.int64)
    where[rows] = np.arange(len(rows))
    for sh in shares:
        k = where[sh.states]
        w = np.minimum(sh.counts / total[sh.states], max_weight)
        delta[k] += w[:, None] * (sh.q - before[k])
    q[rows] = before + delta
    return len(rows)


def federate(q: np.ndarray, visits: np.ndarray, since: np.ndarray, episode: int, fc: FederatedConfig,
             steps_per_episode: int, heard: np.ndarray | None = None) -> None:
    """The in-process round after ``episode``: in each environment b, every UAV shares (tables q (B, U, S, 16),
    visits and since (B, U, S)), then every UAV merges all the others' shares (all-to-all) that
    :func:`check_share` passes, as a swarm agent does (a row beyond ``fc.q_bound`` refuses its share in
    both); since := visits. ``heard`` (B, U, U), if given: which peers' shares reach each UAV (channel-driven
    links, world.link_phy); None: all."""
    batch, n_uavs, n_states, n_actions = q.shape
    most = max_count(episode, steps_per_episode)
    for b in range(batch):
        shares = [make_share(u, episode, q[b, u], visits[b, u], since[b, u], fc.max_rows) for u in range(n_uavs)]
        shares = [sh for sh in shares if check_share(sh, n_states, n_actions, episode, most, fc.q_bound) is None]
        for u in range(n_uavs):
            reaching = [sh for sh in shares if sh.uav != u and (heard is None or heard[b, u, sh.uav])]
            merge(q[b, u], visits[b, u], reaching, fc.max_weight)
    since[...] = visits


def split_share(share: Share, rows_per_part: int) -> list[Share]:
    """``share`` in parts of at most ``rows_per_part`` rows, in order (one, empty, if it has none)."""
    n = len(share.states)
    bounds = list(range(0, n, rows_per_part)) or [0]
    return [share._replace(states=share.states[a:a + rows_per_part], counts=share.counts[a:a + rows_per_part],
                           q=share.q[a:a + rows_per_part]) for a in bounds]


def join_parts(parts: list[Share]) -> Share:
    """The share whose :func:`split_share` parts these are, in order."""
    first = parts[0]
    return first._replace(states=np.concatenate([p.states for p in parts]),
                          counts=np.concatenate([p.counts for p in parts]),
                          q=np.concatenate([p.q for p in parts]).reshape(-1, first.q.shape[1]))
