"""The in-process driver: steps a batched World with any controller.

A controller decides the actions of all UAVs of all B environments; TRUAV's
independent Q-learners are one (`agents.controller.TruavController`), fixed
policies (`agents.policies`) and the baselines are others. Pure computation:
no files, no progress bars (callbacks report episodes).
"""

from __future__ import annotations

import gc
import os
from concurrent.futures import ThreadPoolExecutor
from typing import Callable, Protocol

import numpy as np

from truav import seeding
from truav.analysis.sumo_traffic import make_world
from truav.config import Config
from world.env import EPISODE_FIELDS, LocalObs, World

EpisodeCallback = Callable[[int, dict[str, np.ndarray]], None]
"""Called after each episode with (episode index, metrics each of shape (B,))."""


class Controller(Protocol):
    def begin_episode(self, episode: int, obs: LocalObs) -> None:
        """A new episode starts with these observations."""

    def act(self, t: int) -> np.ndarray:
        """Actions (B, U) for step t."""

    def observe(self, obs: LocalObs, done: bool) -> None:
        """Outcome of the last actions (learners update here)."""

    def episode_stats(self) -> dict[str, np.ndarray]:
        """Extra per-episode metrics, each (B,) (e.g. mean reward, epsilon)."""


class ControlPlane(Protocol):
    """Optional extra of a controller with a control plane (e.g. the centralized
    baseline): if a controller has `control`, the driver calls it right after
    `act(t)` and passes its effects to World.step."""

    def control(self, t: int) -> tuple[np.ndarray | None, np.ndarray | float]:
        """(airtime_s (B, U) or None, action_delay_s scalar or (B, U)) of step t."""


class FusedEpisode(Protocol):
    """Optional extra of a controller without a control plane: if it has
    `run_episode` and `fused` is true, the driver hands it each whole episode
    (after begin_episode) instead of stepping act/observe."""

    fused: bool
    draws_in_kernel: bool
    """Optional: run_episode makes the world's deferred draws (World.start_episode(defer_draws=True))."""

    def run_episode(self, world: World) -> None:
        """Run steps 0..T-1 of the world's current episode."""


def run_episodes(cfg: Config, seeds: list[int], controller: Controller, episodes: int,
                 on_episode: EpisodeCallback | None = None, start_pos: np.ndarray | None = None,
                 end_pos: np.ndarray | None = None, world: World | None = None, first_episode: int = 0,
                 after_episode: Callable[[int], bool] | None = None) -> dict[str, np.ndarray]:
    """Run `episodes` episodes of one World per seed; returns {metric: (E, B)}.

    start_pos (B, U, 2): under scenario.uav_start = "persist", the swarm starts
    deployed there (World.reset); end_pos, if given, receives the UAV
    positions at the end, so an evaluation can continue a trained swarm.
    world: run in this World instead of a new one: reset here if it never
    was, otherwise gone on with (e.g. the one training ran in; every episode
    then starts with start_episode).

    first_episode: go on with episodes first_episode..episodes-1 of a run whose earlier ones this
    world and controller ran (a resumed training: the exploration schedule follows the episode).
    after_episode(episode): called at each episode's end, with everything of it done (a checkpoint
    taken there continues exactly); True stops the run there (the metrics then end with it)."""
    world = make_world(cfg, len(seeds)) if world is None else world
    with ThreadPoolExecutor(max_workers=max(1, min(len(seeds), os.cpu_count() or 1))) as pool:
        if len(seeds) > 1:
            world.draw_map = pool.map  # each env's draws from its own generator, on threads
        try:
            return _run(cfg, seeds, controller, episodes, on_episode, world, start_pos, end_pos, first_episode,
                        after_episode)
        finally:
            world.draw_map = map  # the pool ends here; a world gone on with later draws without it


def _run(cfg, seeds, controller, episodes, on_episode, world, start_pos, end_pos, first_episode=0,
         after_episode=None) -> dict[str, np.ndarray]:
    fresh = world.episode < 0
    control = getattr(controller, "control", None)  # see ControlPlane
    fused = getattr(controller, "run_episode", None) if control is None and getattr(controller, "fused", False) \
        else None  # see FusedEpisode
    defer = fused is not None and getattr(controller, "draws_in_kernel", False)
    history: dict[str, list[np.ndarray]] = {}
    if fresh:
        obs = world.reset([seeding.world_rng(s) for s in seeds], start_pos, defer_draws=defer)
    for episode in range(first_episode, episodes):
        if episode or not fresh:
            obs = world.start_episode(defer_draws=defer)
        controller.begin_episode(episode, obs)
        if fused is not None:
            fused(world)
        else:
            _step_episode(world, controller, control)
        summary = {**world.episode_summary(), **controller.episode_stats()}
        for key, value in summary.items():
            history.setdefault(key, []).append(value)
        if on_episode is not None:
            on_episode(episode, summary)
        if after_episode is not None and after_episode(episode):
            break
        if episode == first_episode:
            # Everything alive now (numba's compiled kernels and their type objects:
            # a large graph) lives to the end; frozen, the cyclic collector no longer
            # walks it on every full collection between episodes.
            gc.freeze()
    if end_pos is not None:
        end_pos[...] = world.uav_pos
    return {k: np.stack(v) for k, v in history.items()} if history else {}


def _step_episode(world: World, controller: Controller, control) -> None:
    done, t = False, 0
    while not done:
        if control is None:
            obs, _, done = world.step(controller.act(t))
        else:
            actions = controller.act(t)
            airtime, delay = control(t)
            obs, _, done = world.step(actions, control_airtime_s=airtime, action_delay_s=delay)
        controller.observe(obs, done)
        t += 1


__all__ = ["Controller", "ControlPlane", "FusedEpisode", "EpisodeCallback", "EPISODE_FIELDS", "run_episodes"]
