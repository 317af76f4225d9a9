"""Deterministic re-simulation of a lock-step swarm run, in process, from its recorded seed and config.

A lock-step swarm is exact by protocol (docs/explanation/architecture.md, "Lock-step is exact by protocol"): each tick
the world publishes every observation, every agent sends its beacon, waits for its peers' beacons of the
same tick, learns and answers; the world steps once every action is in. :class:`Resimulation` runs that
same sequence without a bus: the world's ``World`` stepped as `world/process/world_process.py` steps it, one
agents.agent_decision.TruavDecision per UAV (the code an agent process runs), and the messages built by
the processes' own builders (truav.wire.world_messages, TruavDecision.beacon/act/acknowledge). So each
re-simulated observation, beacon and action is what the processes would have sent for it, field for
field; recorder.resim_verify compares them with the recording.

What a recording must hold (else :func:`load_run` raises UserError: one line, exit 2): the run config
(recorder.metadata CONFIG_METADATA) and the run's settings (RUN_METADATA, written by `truav-swarm up
--record`: seed, lock-step, scheme...), lock-step, scheme truav, not resumed, no outside agents; and not be one
part of a split recording (its parts merged first).
"""

from __future__ import annotations

import os
import tomllib
from dataclasses import dataclass, field
from typing import Any, Iterator

import numpy as np

from agents.agent_decision import TruavDecision, peer_arrays
from agents.api_decision import ApiDecision
from agents.decision_state import decision_state, restore_decision
from agents.qlearning import QLearners, geofence
from agents.reward import Reward
from agents.state import StateEncoder
from recorder.metadata import RECORDING_METADATA, read_config_toml, read_run_info
from recorder.reader import iter_messages, read_metadata
from recorder.record_modes import PARTS_INDEX_SUFFIX, PART_METADATA, REASON_END
from truav import seeding
from truav.analysis.agent_loader import AGENT_KIND_PREFIX
from truav.analysis.runio import read_qtables
from truav.call_limit import CallTooLong, call_limited
from truav.config import Config, ConfigError, config_from_dict
from truav.errors import UserError
from truav.wire import keys, schema
from truav.wire.world_messages import observation_messages
from world.env import World
from world.steer import apply_overrides
from world.uavs import N_ACTIONS
from world.world_state import restore_world, world_state


@dataclass(frozen=True)
class RecordedRun:
    """What a lock-step recording says about how to re-run it."""

    cfg: Config
    run: str
    """The run's name (its keys are under truav/<run>/)."""
    seed: int
    episodes: int
    greedy: bool
    qtable: str | None
    qtable_index: int
    info: dict = field(default_factory=dict)
    """The run settings as recorded (RUN_METADATA)."""
    agent: str | None = None
    """The agents.api class the run's agents flew (`up --agent NAME`), or None for TRUAV's own agents."""


def load_run(path: str | os.PathLike[str]) -> RecordedRun:
    """The config and run settings of the lock-step TRUAV recording at ``path``; UserError (one line) when it
    is not one, or cannot be re-run."""
    name = os.fspath(path)
    part = read_metadata(path).get(PART_METADATA)
    if part is not None and (part.get("part") != "1" or part.get("reason") != REASON_END):  # more parts follow
        raise UserError(f"{name}: part {part.get('part')} of a split recording; `truav log merge ALL.mcap "
                        f"<stem>{PARTS_INDEX_SUFFIX}` joins its parts, then re-simulate ALL.mcap")
    toml_text = read_config_toml(path)
    info = read_run_info(path)
    if toml_text is None or info is None:
        missing = "run config" if toml_text is None else "run settings (seed, lock-step)"
        raise UserError(f"{name}: not a lock-step TRUAV run recording: it holds no {missing} (record one with "
                        f"`truav-swarm up --lockstep --record FILE`)")
    if not info.get("lockstep"):
        raise UserError(f"{name}: a real-time run (not --lockstep): its timing decided which actions and beacons "
                        f"counted, so it cannot be re-simulated")
    scheme = info.get("scheme", "truav")
    agent = scheme[len(AGENT_KIND_PREFIX):] if isinstance(scheme, str) and scheme.startswith(AGENT_KIND_PREFIX) \
        else None
    if scheme != "truav" and not agent:
        raise UserError(f"{name}: a --scheme {str(scheme)[:60]} run; only TRUAV's agents and agent API classes "
                        f"are re-simulated")
    if info.get("resume"):
        raise UserError(f"{name}: a --resume run: its agents started from checkpoints the recording does not hold")
    if info.get("external"):
        raise UserError(f"{name}: UAV(s) {str(info['external'])[:60]} were flown by outside agents (--external): their "
                        f"decisions cannot be re-run")
    try:
        cfg = config_from_dict(tomllib.loads(toml_text))
    except (tomllib.TOMLDecodeError, ConfigError, RecursionError, TypeError, ValueError) as exc:
        raise UserError(f"{name}: its recorded run config is unreadable or out of bounds ({_short(exc)})") from None
    seed = _setting(name, info, "seed", int, 0, 2**63 - 1)
    episodes = _setting(name, info, "episodes", int, 1, _max_episodes())
    qtable = _setting(name, info, "qtable", str, None, None, default=None) or None
    qtable_index = _setting(name, info, "qtable_index", int, 0, 10**6, default=0)
    run = read_metadata(path).get(RECORDING_METADATA, {}).get("run")
    if not run:
        raise UserError(f"{name}: not a TRUAV recording: it names no run")
    try:
        keys.validate_run(run)
    except ValueError as exc:
        raise UserError(f"{name}: recorded run name {run[:80]!r}: {exc}") from None
    table_bytes = 0 if agent else cfg.scenario.n_uavs * StateEncoder(cfg).n_states * N_ACTIONS * 8
    if table_bytes > MAX_RESIM_TABLE_BYTES:
        raise UserError(f"{name}: its recorded config (learner.grid_cells {cfg.learner.grid_cells}, "
                        f"{cfg.scenario.n_uavs} UAVs) needs {table_bytes / 2**30:.1f} GiB of Q-tables; resim "
                        f"allocates at most {MAX_RESIM_TABLE_BYTES / 2**30:.0f} GiB")
    return RecordedRun(cfg=cfg, run=run, seed=seed, episodes=episodes, greedy=info.get("greedy") is True,
                       qtable=qtable, qtable_index=qtable_index, info=info, agent=agent)


MAX_RESIM_TABLE_BYTES = 2**30
"""Q-tables a re-simulation allocates at most: a recording from elsewhere may name any legal config
(grid_cells 1000 asks for GiBs); refused in one line above this."""


def _max_episodes() -> int:
    from truav.config import LearnerConfig
    return int(LearnerConfig.__dataclass_fields__["episodes"].metadata["range"][1])


def _short(exc: BaseException) -> str:
    return str(exc)[:200] or type(exc).__name__


_MISSING = object()


def _setting(name: str, info: dict, key: str, kind: type, lo, hi, default: Any = _MISSING) -> Any:
    """One recorded run setting, type- and range-checked; UserError (one line naming it) otherwise."""
    value = info.get(key, default)
    if value is _MISSING:
        raise UserError(f"{name}: its recorded run settings have no {key}")
    if value is default:
        return value
    if type(value) is not kind or (lo is not None and not lo <= value <= hi):
        shown = repr(value)[:60]
        want = kind.__name__ + ("" if lo is None else f" in {lo}..{hi}")
        raise UserError(f"{name}: recorded run setting {key} = {shown}: not a {want}")
    return value


def start_tables(qtable: str | None, index: int, n_uavs: int) -> list[np.ndarray | None]:
    """Each UAV's starting Q-table: none (fresh, from its generator) or table ``index`` of a trained run, as
    the agent process loads it (AgentNode._make_learners); UserError when the run cannot give them."""
    if qtable is None:
        return [None] * n_uavs
    _, tables = read_qtables(qtable)  # RunDirError (a UserError) names the file
    if index >= tables.shape[0] or tables.shape[1] < n_uavs:
        raise UserError(f"{qtable}: holds {tables.shape[0]} seed(s) x {tables.shape[1]} UAV(s); table {index} "
                        f"for {n_uavs} UAVs is not there")
    return [tables[index, i][None, None] for i in range(n_uavs)]


Goal = tuple[float, float, float]
"""An override's goal: (x, y, speed), as world.steer takes it."""
OverrideEvents = dict[int, list[tuple[int, Goal | None]]]
"""Tick -> the overrides that start (a goal) or end (None) there, in the order the world applied them:
[(uav, goal or None), ...]."""


def recorded_overrides(path: str | os.PathLike[str], run: str, n_uavs: int) -> OverrideEvents:
    """The world's fault/override events in the recording (UAVs steered from outside, control/override/<i>), by the
    tick the world applied them from; an event that does not decode or names no valid tick, UAV or goal is left
    out (the re-simulation then diverges there, and says so)."""
    events: list[tuple[int, int, int, Goal | None]] = []
    for _, payload, _, _ in iter_messages(path, include=[keys.fault(run, schema.FAULT_OVERRIDE)]):
        try:
            msg = schema.decode(payload, schema.KIND_FAULT)
        except schema.SchemaError:
            continue
        event = _override_event(msg, n_uavs)
        if event is not None:
            events.append((event[0], msg.seq, *event[1:]))
    out: OverrideEvents = {}
    for tick, _, uav, goal in sorted(events, key=lambda e: e[:2]):
        out.setdefault(tick, []).append((uav, goal))
    return out


def _override_event(msg: schema.Fault, n_uavs: int) -> tuple[int, int, Goal | None] | None:
    if msg.src != keys.SRC_WORLD or msg.fault != schema.FAULT_OVERRIDE:
        return None
    p, uav = msg.params, keys.parse_uav_identity(msg.target)
    tick = p.get("tick")
    if uav is None or uav >= n_uavs or type(tick) is not int or tick < 0:
        return None
    if msg.phase == schema.PHASE_END:
        return tick, uav, None
    x, y, speed = p.get("x"), p.get("y"), p.get("speed")
    if not all(isinstance(v, (int, float)) and np.isfinite(v) for v in (x, y, speed)) or speed < 0:
        return None
    return tick, uav, (float(x), float(y), float(speed))


def overridden_before(events: OverrideEvents, tick: int) -> dict[int, Goal]:
    """The UAVs steered from outside when ``tick`` begins (every event of an earlier tick applied)."""
    active: dict[int, Goal] = {}
    for t in sorted(t for t in events if t < tick):
        for uav, goal in events[t]:
            if goal is None:
                active.pop(uav, None)
            else:
                active[uav] = goal
    return active


@dataclass
class Round:
    """One tick as the processes would have sent it."""

    tick: int
    episode: int
    done: bool
    obs: list[schema.Obs]
    beacons: list[schema.Beacon]
    actions: list[schema.Action]
    """The actions (for a `done` tick: the acknowledgements), in UAV order."""
    summary: dict[str, float] | None = None
    """At a `done` tick: the episode's metrics, as the world publishes them (metrics/episode)."""


class Resimulation:
    """The world and every agent of a lock-step run, stepped in process (see the module docstring)."""

    def __init__(self, cfg: Config, seed: int, episodes: int, tables: list | None = None,
                 train: bool = True, agent_cls: type | None = None, overrides: OverrideEvents | None = None):
        """``overrides``: the run's UAVs steered from outside (:func:`recorded_overrides`), applied at the ticks the
        world applied them (world.process.world_process.WorldNode._steer). ``agent_cls``: the agents.api class the run's agents flew (its recording's ``agent``), run through
        agents.api_decision.ApiDecision as agents.process.api_process runs it; else TRUAV's own agents. ``tables``: each
        UAV's start, a Q-table (S, 16) for TRUAV's agents or a state_dict for a class's, or None (fresh)."""
        self.cfg, self.seed, self.episodes = cfg, seed, episodes
        n = cfg.scenario.n_uavs
        tables = tables if tables is not None else [None] * n
        self.world = World(cfg, 1)
        encoder = StateEncoder(cfg)
        self.api = agent_cls is not None
        self.agents = [self._api_agent(agent_cls, cfg, i, seed, train, tables[i]) for i in range(n)] if self.api \
            else [TruavDecision(cfg, i, QLearners(cfg.learner, encoder.n_states, [seeding.agent_rng(seed, i)], 1, 1,
                                                  q=tables[i], fence=geofence(cfg)), train, encoder, Reward(cfg),
                                seed=seed)
                  for i in range(n)]
        self.tick = 0
        self.episode = 0
        self.override_events: OverrideEvents = overrides or {}
        self.overridden: dict[int, Goal] = {}
        self._obs = self.world.reset([seeding.world_rng(seed)])
        self._done = False  # the next round is the episode's `done` observation

    @staticmethod
    def _api_agent(cls: type, cfg: Config, uav: int, seed: int, train: bool, start) -> "ApiResimAgent":
        """``start``: the state_dict its agent process loaded (`up --agent NAME --qtable RUN`), or None."""
        decision = ApiDecision(cls, cfg, uav, seed, train)
        if start is not None:
            try:
                call_limited(decision.limit_s, decision.agent.load_state_dict, start)
            except (Exception, CallTooLong) as exc:
                raise UserError(f"{cls.__name__}.load_state_dict refused UAV {uav}'s start state: "
                                f"{type(exc).__name__}: {' '.join(str(exc).split())[:300]}") from None
        return ApiResimAgent(decision)

    @property
    def total_ticks(self) -> int:
        """Ticks of the whole run: every step of every episode and each episode's `done` tick."""
        return self.episodes * (self.cfg.scenario.steps_per_episode + 1)

    def rounds(self) -> Iterator[Round]:
        """Every tick from the current one to the run's end, each stepped once its round is taken."""
        while self.episode < self.episodes:
            yield self.step()

    def step(self) -> Round:
        """The next tick: the world's observations, every agent's beacon and answer, then the world's step (or,
        at a `done` tick, the episode's end and the next episode's start), as world_process.WorldNode.run."""
        tick, episode, done = self.tick, self.episode, self._done
        obs = observation_messages(self.cfg, tick, episode, self._obs, done)
        beacons = [agent.beacon(o) for agent, o in zip(self.agents, obs)]
        by_uav = {b.uav: b for b in beacons}
        actions = []
        for agent, o in zip(self.agents, obs):
            heard = agent.hear(o, {j: b for j, b in by_uav.items() if j != agent.uav})
            if self.api:
                actions.append(agent.answer(o, heard))
                continue
            agent.learn(o, *peer_arrays(heard))
            actions.append(agent.acknowledge(o) if done else agent.act(o))
        summary = None
        self.tick += 1
        if done:
            summary = {k: float(v[0]) for k, v in self.world.episode_summary().items()}
            self._done = False
            self.episode += 1
            if self.episode < self.episodes:
                self._obs = self.world.start_episode()
        else:
            chosen = np.array([[a.action for a in actions]], np.int64)
            for uav, goal in self.override_events.get(tick, ()):
                if goal is None:
                    self.overridden.pop(uav, None)
                else:
                    self.overridden[uav] = goal
            if self.overridden:
                sc = self.cfg.scenario
                chosen = apply_overrides(chosen, self._obs.pos, self.overridden, sc.uav_speed_mps, sc.step_s, sc.area_m)
            self._obs, _, self._done = self.world.step(chosen)
        return Round(tick, episode, done, obs, beacons, actions, summary)

    # -- snapshots ----------------------------------------------------------------------------------------
    def snapshot(self) -> tuple[int, dict[str, np.ndarray], list[dict[str, np.ndarray]]]:
        """The state before the next tick, as a lock-step run's snapshot holds it: (tick, the world's state,
        each agent's state)."""
        if self.api:
            raise UserError("state snapshots and what-if branches are TRUAV's: an agent API class's state is its own")
        return self.tick, world_state(self.world, self._obs), [decision_state(a) for a in self.agents]

    def restore(self, tick: int, world: dict[str, np.ndarray], agents: list[dict[str, np.ndarray]]) -> None:
        """Continue from a snapshot (see :meth:`snapshot`) of this run: the agents' learners must hold the
        tables the run started with (only the rows they updated are in a snapshot). ValueError when the
        snapshot does not fit this run."""
        if len(agents) != len(self.agents):
            raise ValueError(f"a snapshot of {len(agents)} agent(s), the run has {len(self.agents)}")
        self.world, self._obs = restore_world(self.cfg, world)
        self.episode = self.world.episode
        self._done = self.world.t >= self.cfg.scenario.steps_per_episode
        for agent, state in zip(self.agents, agents):
            restore_decision(agent, state)
        self.tick = tick
        self.overridden = overridden_before(self.override_events, tick)

    # -- what a branch changes ------------------------------------------------------------------------
    def set_tables(self, tables: list[np.ndarray]) -> None:
        """Replace every agent's Q-table (a branch flying another run's tables)."""
        for agent, q in zip(self.agents, tables):
            agent.learners.q[...] = q

    def set_greedy(self) -> None:
        """From now on every agent acts greedily and learns nothing (exploration off at once, not only from the
        next episode as QLearners.begin_episode would)."""
        for agent in self.agents:
            agent.train = False
            agent.learners.epsilon = 0.0

    def set_learner(self, cfg: Config) -> None:
        """Use ``cfg``'s learner settings (rates, reward weights, geofence) from now on, its exploration schedule
        from the next episode (an episode's exploration is drawn at its start); the state encoding stays
        (recorder.resim_branch refuses settings that change it)."""
        self.cfg = cfg
        for agent in self.agents:
            agent.cfg = cfg
            agent.reward = Reward(cfg)
            agent.learners.lc = cfg.learner
            agent.learners.fence = geofence(cfg)


class ApiResimAgent:
    """One UAV of an agent API class's run, answering as agents.process.api_process.ApiAgentNode.handle does in
    lock-step: a call that raises, runs past its limit or returns an illegal action costs that tick's action
    (the UAV hovers), and the run goes on; ``errors`` counts them."""

    def __init__(self, decision: ApiDecision):
        self.decision, self.uav = decision, decision.uav
        self.errors = 0

    def beacon(self, obs: schema.Obs) -> schema.Beacon:
        return self.decision.beacon(obs)

    def hear(self, obs: schema.Obs, beacons: dict[int, schema.Beacon]) -> dict[int, schema.Beacon]:
        return beacons  # the agent process hears every beacon of its tick (no channel-driven links for a class)

    def answer(self, obs: schema.Obs, beacons: dict[int, schema.Beacon]) -> schema.Action:
        d = self.decision
        try:
            d.learn(obs, beacons)
        except (Exception, CallTooLong):
            self.errors += 1
        if obs.done:
            return d.acknowledge(obs)
        try:
            return d.act(obs)
        except (Exception, CallTooLong):
            self.errors += 1
            return d.hover(obs)


def payload_fields(msg: Any) -> dict[str, Any]:
    """A message's payload fields: everything but the envelope (sender, sequence, time stamp, incarnation)."""
    return {name: getattr(msg, name) for name in type(msg).__dataclass_fields__ if name not in _ENVELOPE}


_ENVELOPE = frozenset(schema.Envelope.__dataclass_fields__)


__all__ = ["ApiResimAgent", "RecordedRun", "Resimulation", "Round", "load_run", "overridden_before", "payload_fields",
           "recorded_overrides", "start_tables"]
