"""An API agent class (agents.api) as a controller of the in-process driver (truav.analysis.driver.Controller).

Its batched form when the class offers one (``batched``), else one instance per seed and UAV, looped.
Each step builds every UAV's LocalView from the world's LocalObs, as TRUAV's trainer does: every UAV hears
every other's beacon (position, the velocity of its last action, its beacon_fields), and its reward is
the paper's local reward (agents.reward, with the same overlap term TRUAV's controller uses). A class
that raises or breaks a promise (an illegal action, a bad beacon or state) stops the run with an
AgentFailure naming the class, the UAV and the error.
"""

from __future__ import annotations

import dataclasses
import functools
import operator
from typing import Mapping

import numpy as np

from agents.api import BatchedViews, HeardBeacon, LocalView, UavAgent, action_problem, beacon_problem, sensing
from agents.reward import Reward
from agents.state import all_peers, neighbour_features
from truav import seeding
from truav.call_limit import CallBound, CallTooLong, call_limited
from truav.actions import HOVER, N_ACTIONS
from truav.config import Config
from world.env import LocalObs
from world.network import rsu_positions
from world.uavs import action_velocity


def nearest_rsu_m(pos: np.ndarray, rsu: np.ndarray) -> np.ndarray:
    """Distance (m) from each position (..., 2) to the nearest RSU of rsu (K, 2) (inf without RSUs): one
    arithmetic for the in-process views and the agent process's (agents.api_decision)."""
    if not len(rsu):
        return np.full(pos.shape[:-1], np.inf)
    return np.sqrt(((pos[..., None, :] - rsu) ** 2).sum(-1)).min(-1)


def _frozen_maker(cls: type):
    """A constructor of the frozen dataclass ``cls`` taking every field by position that fills the instance's
    __dict__ at once, not field by field through object.__setattr__ as its __init__ does: the same object
    (fields, equality, repr, pickle), at about half the price. ``cls`` itself where that would skip code of
    its own (a __post_init__) or it has no __dict__ (slots)."""
    if hasattr(cls, "__post_init__") or "__slots__" in vars(cls):
        return cls
    names, new = tuple(f.name for f in dataclasses.fields(cls)), object.__new__

    def make(*values):
        if len(values) != len(names):  # defaults to fill: the class's own __init__
            return cls(*values)
        obj = new(cls)
        obj.__dict__.update(zip(names, values))
        return obj
    return make


_make_view, _make_beacon = _frozen_maker(LocalView), _frozen_maker(HeardBeacon)


@functools.lru_cache(maxsize=8)
def _others(n: int) -> tuple:
    """For each of n UAVs, a function of a list of n items giving the tuple of the others', in order."""
    def pick(keep: list[int]):
        if len(keep) == 1:
            return lambda items: (items[keep[0]],)
        return operator.itemgetter(*keep) if keep else lambda items: ()
    return tuple(pick([m for m in range(n) if m != u]) for u in range(n))


def _python(column, kind: type) -> list:
    """A (B, U) array as rows of Python ``kind`` numbers (int() or float() of each, as a view holds them)."""
    a = np.asarray(column)
    if a.dtype.kind == ("i" if kind is int else "f"):
        return a.tolist()
    return [[kind(v) for v in row] for row in a.tolist()]


class AgentFailure(RuntimeError):
    """An API agent raised or broke the API during a run: the message is one line for the user."""


class ApiController:
    """Drives an agents.api class for B seeds x U UAVs (see the module's docstring)."""

    def __init__(self, name: str, cls: type, cfg: Config, seeds: list[int], train: bool = True,
                 state: Mapping[str, np.ndarray] | None = None):
        self.name, self.cls, self.cfg, self.seeds, self.train = name, cls, cfg, list(seeds), train
        B, U = len(seeds), cfg.scenario.n_uavs
        self.shape = (B, U)
        self.reward = Reward(cfg)
        self.rsu = rsu_positions(cfg)
        rngs = [[seeding.agent_rng(s, u) for u in range(U)] for s in seeds]
        self.batched = getattr(cls, "batched", None)
        if self.batched is not None:
            self.group = self._call(None, None, "batched __init__", self.batched, cfg, rngs)
            if state is not None:
                self._call(None, None, "load_state_dict", self.group.load_state_dict, dict(state))
        else:
            self.agents = [[self._call(b, u, "__init__", cls, cfg, u, rngs[b][u]) for u in range(U)]
                           for b in range(B)]
            if state is not None:
                for b, row in enumerate(self.agents):
                    for u, agent in enumerate(row):
                        self._call(b, u, "load_state_dict", agent.load_state_dict,
                                   {k: np.array(v[b, u]) for k, v in state.items()})
        self.fused = self.batched is not None and callable(getattr(self.group, "run_episode", None))
        """The batched form runs whole episodes (BatchedAgents.run_episode): the driver hands them to it."""
        self.draws_in_kernel = self.fused and bool(getattr(self.group, "draws_in_kernel", False))
        self._first_obs: LocalObs | None = None
        self.episode, self.t = 0, 0
        self.views = None
        self.action = np.zeros(self.shape, np.int64)
        self.fields = [[{} for _ in range(U)] for _ in range(B)]
        self.prev_in_range = np.zeros(self.shape)
        self._reward_sum = np.zeros(B)
        self._steps = 0

    # -- failures ---------------------------------------------------------------------------
    def _where(self, b, u) -> str:
        return "" if b is None else f" (UAV {u} of seed {self.seeds[b]})"

    def _call(self, b, u, what, fn, *args):
        limit = getattr(self.batched if b is None and self.batched is not None else self.cls, "call_limit_s", 1.0)
        try:
            return call_limited(limit, fn, *args)
        except (CallTooLong, Exception) as exc:
            raise self._failure(b, u, what, exc) from None

    def _failure(self, b, u, what, exc: BaseException) -> AgentFailure:
        if isinstance(exc, CallTooLong):
            return AgentFailure(f"agent {self.name}{self._where(b, u)}: {what} {exc}")
        return AgentFailure(f"agent {self.name}{self._where(b, u)}: {what} raised "
                            f"{type(exc).__name__}: {exc}".replace("\n", " "))

    def _fail(self, b, u, problem: str):
        raise AgentFailure(f"agent {self.name}{self._where(b, u)}: {problem}")

    # -- the driver's calls -----------------------------------------------------------------
    def begin_episode(self, episode: int, obs: LocalObs) -> None:
        self.episode, self.t = episode, 0
        self.action[:] = HOVER  # no action yet: beacons carry velocity (0, 0)
        self.prev_in_range = np.asarray(obs.vehicles_in_range, np.float64).copy()
        self._reward_sum[:], self._steps = 0.0, 0
        if self.batched is not None:
            self._call(None, None, "begin_episode", self.group.begin_episode, episode, self.train)
            if self.fused:  # views only if a driver steps it after all (act): run_episode starts from obs
                self._first_obs, self.views = obs, None
                return
        else:
            for b, row in enumerate(self.agents):
                for u, agent in enumerate(row):
                    self._call(b, u, "begin_episode", agent.begin_episode, episode, self.train)
                    self.fields[b][u] = {}
        self.views = self._views(obs)

    def run_episode(self, world) -> None:
        """The driver's whole-episode call (truav.analysis.driver.FusedEpisode): the batched form's run_episode."""
        B = self.shape[0]
        got = self._call(None, None, "run_episode", self.group.run_episode, world, self._first_obs)
        r = np.asarray(got, np.float64) if isinstance(got, np.ndarray) and got.dtype.kind in "fiu" else None
        if r is None or r.shape != (B,) or not np.isfinite(r).all():
            shape = f" shaped {got.shape}" if isinstance(got, np.ndarray) else ""
            self._fail(None, None, f"run_episode returned {type(got).__name__}{shape}, not each seed's mean reward "
                                   f"per step, finite, shaped ({B},)")
        steps = self.cfg.scenario.steps_per_episode
        self._reward_sum, self._steps, self.t = r * steps, steps, steps

    def act(self, t: int) -> np.ndarray:
        if self.views is None:  # a whole-episode form stepped by a driver that records each step
            self.views = self._views(self._first_obs)
        if self.batched is not None:
            a = self._call(None, None, "act", self.group.act, self.views)
            if not (isinstance(a, np.ndarray) and a.shape == self.shape and np.issubdtype(a.dtype, np.integer)):
                self._fail(None, None, f"batched act returned {type(a).__name__} "
                                       f"{getattr(a, 'shape', '')}, not an int array shaped {self.shape}")
            bad = np.argwhere((a < HOVER) | (a >= N_ACTIONS))
            if len(bad):
                b, u = bad[0]
                self._fail(b, u, action_problem(int(a[b, u])))
            self.action = a.astype(np.int64)
            return self.action
        # One call timer for the sweep (truav.call_limit.CallBound), the common results checked inline, and
        # the base class's beacon_fields (always {}) not called: the API's price per UAV and step stays small.
        plain_fields = getattr(self.cls, "beacon_fields", None) is UavAgent.beacon_fields
        actions = []
        with CallBound(float(getattr(self.cls, "call_limit_s", 1.0))) as call:
            for b, row in enumerate(self.agents):
                views, fields = self.views[b], self.fields[b]
                for u, agent in enumerate(row):
                    try:
                        a = call(agent.act, views[u])
                    except (CallTooLong, Exception) as exc:
                        raise self._failure(b, u, "act", exc) from None
                    if type(a) is not int or not HOVER <= a < N_ACTIONS:
                        problem = action_problem(a)
                        if problem:
                            self._fail(b, u, problem)
                    actions.append(a)
                    if plain_fields:
                        fields[u] = {}
                        continue
                    try:
                        got = call(agent.beacon_fields)
                    except (CallTooLong, Exception) as exc:
                        raise self._failure(b, u, "beacon_fields", exc) from None
                    if type(got) is not dict or got:
                        problem = beacon_problem(got)
                        if problem:
                            self._fail(b, u, problem)
                    fields[u] = dict(got)
        self.action[...] = np.array(actions, np.int64).reshape(self.shape)
        return self.action.copy()

    def observe(self, obs: LocalObs, done: bool) -> None:
        self.t += 1
        overlap = neighbour_features(obs.pos, *all_peers(obs.pos), self.cfg.scenario.comm_range_m)[1]
        r = self.reward(obs.relayed, obs.covered, obs.energy_j, overlap, obs.exclusive, obs.vehicles_in_range,
                        self.prev_in_range)
        self.prev_in_range = np.asarray(obs.vehicles_in_range, np.float64).copy()
        self.views = self._views(obs)
        if self.batched is not None:
            self._call(None, None, "learn", self.group.learn, self.views, r, done)
        else:
            rows = r.tolist()
            if getattr(self.cls, "learn", None) is not UavAgent.learn:  # the base's learns nothing: not called
                with CallBound(float(getattr(self.cls, "call_limit_s", 1.0))) as call:
                    for b, row in enumerate(self.agents):
                        views, rewards = self.views[b], rows[b]
                        for u, agent in enumerate(row):
                            try:
                                call(agent.learn, views[u], rewards[u], done)
                            except (CallTooLong, Exception) as exc:
                                raise self._failure(b, u, "learn", exc) from None
        self._reward_sum += r.mean(axis=1)
        self._steps += 1

    def episode_stats(self) -> dict[str, np.ndarray]:
        return {"reward": self._reward_sum / max(self._steps, 1)}

    # -- views and state ------------------------------------------------------------------------
    def _views(self, obs: LocalObs):
        sc = self.cfg.scenario
        pos = np.asarray(obs.pos, np.float64)
        vel = action_velocity(self.action, sc.uav_speed_mps)  # HOVER's row is (0, 0)
        rsu_m = nearest_rsu_m(pos, self.rsu)
        densest = obs.densest_sector if obs.densest_sector is not None else np.zeros(self.shape, np.int64)
        exclusive = obs.exclusive if obs.exclusive is not None else np.zeros(self.shape, np.int64)
        sense = sensing(self.cfg)
        if self.batched is not None:
            peers, heard = all_peers(pos)
            return BatchedViews(self.episode, self.t, pos.copy(), np.asarray(obs.vehicles_in_range).copy(),
                                np.asarray(obs.queued).copy(), np.asarray(obs.relayed).copy(),
                                np.asarray(obs.covered).copy(), np.asarray(obs.energy_j, np.float64).copy(),
                                float(sc.uav_speed_mps), np.asarray(densest).copy(), np.asarray(exclusive).copy(),
                                rsu_m, peers, np.repeat(vel[:, None], self.shape[1], axis=1), heard, *sense,
                                None if obs.disc_offset is None else np.asarray(obs.disc_offset, np.float64).copy(),
                                None if obs.disc_vehicles is None else np.asarray(obs.disc_vehicles).copy())
        # Each column converted once to Python numbers (lists of rows), each view built without the frozen
        # dataclass's per-field __setattr__ (_frozen_maker): what a view costs per UAV and step stays small.
        P, V = pos.tolist(), vel.tolist()
        n_in, queued, relayed, covered, densest, exclusive = (
            _python(x, int) for x in (obs.vehicles_in_range, obs.queued, obs.relayed, obs.covered, densest, exclusive))
        energy, rsu_m = _python(obs.energy_j, float), _python(rsu_m, float)
        no_disc = obs.disc_offset is None
        disc = [[(0.0, 0.0)] * self.shape[1]] * self.shape[0] if no_disc else [
            list(map(tuple, row)) for row in np.asarray(obs.disc_offset, np.float64).tolist()]
        disc_n = _python(np.zeros(self.shape, np.int64) if no_disc else obs.disc_vehicles, int)
        speed, episode, t, U = float(sc.uav_speed_mps), self.episode, self.t, self.shape[1]
        others = _others(U)
        views = []
        for b, fields in enumerate(self.fields):
            own = list(map(tuple, P[b]))
            heard = list(map(_make_beacon, range(U), own, map(tuple, V[b]), fields))
            views.append([_make_view(u, episode, t, p, n, q, r, c, e, speed, d, x, m, peers_of(heard), *sense, o, k)
                          for u, peers_of, p, n, q, r, c, e, d, x, m, o, k in zip(
                              range(U), others, own, n_in[b], queued[b], relayed[b], covered[b], energy[b],
                              densest[b], exclusive[b], rsu_m[b], disc[b], disc_n[b])])
        return views

    def state_arrays(self) -> dict[str, np.ndarray]:
        """Every agent's state_dict, each array stacked to (B, U, ...) (the batched form's own layout)."""
        if self.batched is not None:
            state = self._call(None, None, "state_dict", self.group.state_dict)
            return {k: np.asarray(v) for k, v in self._checked_state(None, None, state).items()}
        dicts = [[self._checked_state(b, u, self._call(b, u, "state_dict", agent.state_dict))
                  for u, agent in enumerate(row)] for b, row in enumerate(self.agents)]
        first = dicts[0][0]
        out = {}
        for k, v in first.items():
            for b, row in enumerate(dicts):
                for u, d in enumerate(row):
                    if set(d) != set(first):
                        self._fail(b, u, f"state_dict has keys {sorted(d)}, UAV 0 of seed {self.seeds[0]} "
                                         f"{sorted(first)} (every UAV must use the same names)")
                    if np.shape(d[k]) != np.shape(v):
                        self._fail(b, u, f"state_dict[{k!r}] is shaped {np.shape(d[k])}, UAV 0 of seed "
                                         f"{self.seeds[0]}'s {np.shape(v)} (every UAV must use the same shapes)")
            out[k] = np.stack([np.stack([np.asarray(d[k]) for d in row]) for row in dicts])
        return out

    def _checked_state(self, b, u, state) -> dict[str, np.ndarray]:
        if not isinstance(state, dict):
            self._fail(b, u, f"state_dict returned {type(state).__name__}, not a dict of arrays")
        for k, v in state.items():
            if not isinstance(k, str) or not k.isidentifier():
                self._fail(b, u, f"state_dict: the name {k!r} is not a Python identifier")
            if np.asarray(v).dtype == object:
                self._fail(b, u, f"state_dict[{k!r}] is not a numeric array")
        return state


__all__ = ["AgentFailure", "ApiController", "nearest_rsu_m"]
