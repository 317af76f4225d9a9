"""A World's whole state as named arrays, and a World restored from them: the snapshots of a lock-step
recording (`truav log resim --from TICK` starts from the latest one instead of tick 0). Pure, no I/O.

What is captured: the vehicles, the packet queues, the UAVs' positions and velocities, the episode's
running totals, the traffic hotspots, the step kernel's last outputs (the next observation is made of
them), the step t and episode, and each env's generator twice: now, and before this episode's draws.
The episode's draws themselves (arrivals and turn uniforms of every step, ~T x N x 3 numbers) are not
captured: a restore redraws them from the second generator state (World.episode_blocks), and checks
that this lands the generator exactly on the first.

The next observation is rebuilt from the kernel's outputs and ``obs_energy``, the energy the pending
observation reports (zero at an episode's start, the last step's otherwise).
"""

from __future__ import annotations

import numpy as np

from truav.config import Config
from world.draws import RNG_WORDS, rng_from_words, rng_words
from world.env import LocalObs, World, _EpisodeDraws
from world.network import ENV_COLUMNS, OLD_UAV_COLUMNS, UAV_COLUMNS
from world.roads import Vehicles
from world.step import TOTAL_COLUMNS

_VEHICLE_DTYPES = {"heading": np.int64, "road": np.int64, "s": np.float64, "v": np.float64, "home": np.int64,
                   "next_turn": np.int64, "cluster": np.int64, "lane_order": np.int64}


def world_state_spec(cfg: Config, batch: int = 1) -> dict[str, tuple[np.dtype, tuple[int, ...]]]:
    """Every array of a World's state for ``cfg``: name -> (dtype, shape)."""
    sc = cfg.scenario
    B, N, U = batch, sc.n_vehicles, sc.n_uavs
    f8, i8 = np.dtype(np.float64), np.dtype(np.int64)
    spec = {"t": (i8, ()), "episode": (i8, ()),
            "rng": (np.dtype(np.uint64), (B, RNG_WORDS)), "episode_rng": (np.dtype(np.uint64), (B, RNG_WORDS))}
    spec.update({f"vehicles.{name}": (np.dtype(dt), (B, N)) for name, dt in _VEHICLE_DTYPES.items()})
    spec.update({
        "queue_slots": (i8, (B, N, cfg.traffic.deadline_steps)), "queue_total": (i8, (B, N)),
        "uav_pos": (f8, (B, U, 2)), "velocity": (f8, (B, U, 2)), "uav_start": (f8, (B, U, 2)),
        "totals": (f8, (B, TOTAL_COLUMNS)), "hotspots": (i8, (B, -1, 2)),
        "out_uav": (f8, (B, U, UAV_COLUMNS)), "out_env": (f8, (B, ENV_COLUMNS)),
        "energy": (f8, (B, U)), "above_hover": (f8, (B, U)), "obs_energy": (f8, (B, U)),
    })
    return spec


def world_state(world: World, obs: LocalObs) -> dict[str, np.ndarray]:
    """Copies of every array of ``world``'s state, ``obs`` being the observation it last returned (the one
    the next tick publishes). Only between ticks of an episode whose draws were made (not deferred)."""
    if world.vehicles is None or world._draws is None or world.episode_rng_words is None:
        raise ValueError("a world is captured once reset, with PCG64 generators")
    if world._rng_state is not None:
        raise ValueError("a world whose episode draws are deferred to a kernel cannot be captured")
    state = {"t": np.array(world.t, np.int64), "episode": np.array(world.episode, np.int64),
             "rng": np.stack([rng_words(rng) for rng in world.rngs]), "episode_rng": world.episode_rng_words.copy()}
    state.update({f"vehicles.{name}": np.array(getattr(world.vehicles, name), dt)
                  for name, dt in _VEHICLE_DTYPES.items()})
    state.update({
        "queue_slots": world.queues.slots.copy(), "queue_total": world.queues.total.copy(),
        "uav_pos": world.uav_pos.copy(), "velocity": world._velocity.copy(), "uav_start": world._draws.uav_start.copy(),
        "totals": world._totals.copy(), "hotspots": np.array(world.hotspots, np.int64),
        "out_uav": world._out_uav.copy(), "out_env": world._out_env.copy(), "energy": world._energy.copy(),
        "above_hover": world._above_hover.copy(), "obs_energy": np.array(obs.energy_j, np.float64),
    })
    return state


def check_state(state: dict[str, np.ndarray], spec: dict[str, tuple[np.dtype, tuple[int, ...]]]) -> None:
    """ValueError naming the first array of ``state`` that is missing, extra, or of another dtype or shape
    than ``spec`` says (-1: any length)."""
    extra = sorted(set(state) - set(spec))
    if extra:
        raise ValueError(f"unknown state array(s) {', '.join(extra)}")
    for name, (dtype, shape) in spec.items():
        a = state.get(name)
        if a is None:
            raise ValueError(f"state array {name} missing")
        if a.dtype != dtype or a.ndim != len(shape) or any(n >= 0 and n != m for n, m in zip(shape, a.shape)):
            raise ValueError(f"state array {name}: {a.dtype}{list(a.shape)}, expected {dtype}{list(shape)}")


def upgraded(state: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """``state`` as this version captures it: a snapshot from before the disc columns (world.network.
    OLD_UAV_COLUMNS per UAV, recorded before learner.sense_disc existed, so they were 0) gets them as 0."""
    out_uav = state.get("out_uav")
    if isinstance(out_uav, np.ndarray) and out_uav.ndim == 3 and out_uav.shape[-1] == OLD_UAV_COLUMNS:
        pad = np.zeros((*out_uav.shape[:2], UAV_COLUMNS - OLD_UAV_COLUMNS), out_uav.dtype)
        return {**state, "out_uav": np.concatenate([out_uav, pad], axis=-1)}
    return state


def restore_world(cfg: Config, state: dict[str, np.ndarray], batch: int = 1) -> tuple[World, LocalObs]:
    """A World in the captured ``state`` and the observation it would publish next; ValueError when the
    state is not one of a World of ``cfg`` (shapes, dtypes, or generators that do not replay the
    episode's draws)."""
    state = upgraded(state)
    check_state(state, world_state_spec(cfg, batch))
    world = World(cfg, batch)
    sc = cfg.scenario
    T, N, U = sc.steps_per_episode, sc.n_vehicles, sc.n_uavs
    t, episode = int(state["t"]), int(state["episode"])
    if not 0 <= t <= T or episode < 0:
        raise ValueError(f"state step {t} / episode {episode} out of range")
    world.vehicles = Vehicles(**{name: state[f"vehicles.{name}"].copy() for name in _VEHICLE_DTYPES})
    world.queues.slots[...] = state["queue_slots"]
    world.queues.total[...] = state["queue_total"]
    world.uav_pos = state["uav_pos"].copy()
    world._velocity = state["velocity"].copy()
    world._totals[...] = state["totals"]
    world.hotspots = state["hotspots"].copy()
    world._out_uav[...] = state["out_uav"]
    world._out_env[...] = state["out_env"]
    world._energy[...] = state["energy"]
    world._above_hover[...] = state["above_hover"]
    world.t, world.episode = t, episode
    world._draws = _EpisodeDraws(np.empty((T, batch, N), np.int64), np.empty((T, batch, N, 2)),
                                 state["uav_start"].copy())
    world.episode_rng_words = state["episode_rng"].copy()
    world.rngs = []
    for b in range(batch):
        rng = rng_from_words(state["episode_rng"][b])
        rng.random((U, 2))  # the UAV start, drawn first every episode (restored above)
        world.episode_blocks(rng, b)
        if not np.array_equal(rng_words(rng), state["rng"][b]):
            raise ValueError(f"env {b}'s generators do not replay its episode's draws")
        world.rngs.append(rng)
    return world, world._observe(state["obs_energy"].copy())


__all__ = ["check_state", "restore_world", "upgraded", "world_state", "world_state_spec"]
