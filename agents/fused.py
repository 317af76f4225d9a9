"""Fused episodes: one compiled kernel runs a whole episode of every
environment of the batch, parallel over environments (numba prange), with no
Python per step, vehicle or agent. For the TRUAV learners (`truav_episode`)
and the patrol baseline (`patrol_episode`).

Per env and step it does what the step-by-step driver does through
`World.step` and `TruavController.act/observe`, by calling the same compiled
functions: each agent's epsilon-greedy action (`qlearning.act_one`), the
world's `step.env_step`, each agent's neighbour features, state and reward
(`state.neighbour_one`, `state.nearest_sector_one`, `prediction.predict_one`, `state.encode_one`,
`reward.full_one`) and its Q
update (`qlearning.q_update_one`). Environments share nothing, so running
them on threads changes no number; tests/unit/test_fused.py checks the two paths
agree entry by entry. The world's per-episode draws after the UAV start
(arrivals, turns, hotspot moves) are made inside the kernel, each env from
its own generator's PCG64 state (World.start_episode(defer_draws=True)), so
they run in parallel with the episodes; the agents' exploration draws are
made in Python from the same generators, before the kernel runs.
"""

from __future__ import annotations

import os

from truav import kernel_cache  # noqa: F401, I001 - numba's cache set up before numba loads a kernel
import numba
import numpy as np
from numba import njit, prange

from agents.prediction import predict_one
from agents.qlearning import act_one, q_update_one
from agents.reward import full_one
from agents.state import encode_one, nearest_sector_one, neighbour_one
from world.link_phy import beacon_delivered
from world.draws import pcg64_episode_draws
from world.network import COVERED, DENSEST, EXCLUSIVE, IN_RANGE, QUEUED, RELAYED
from world.roads import mobility_scratch, move_hotspots_env
from world.step import env_step, pairwise_sum, replayed_row

if "NUMBA_THREADING_LAYER" not in os.environ:
    # The experiment and trainer pools fork worker processes; GNU OpenMP (the
    # default here) kills a child forked after the parent ran a parallel
    # kernel. numba's own workqueue layer is fork-safe; only this kernel runs
    # parallel, from one thread.
    os.environ["NUMBA_THREADING_LAYER"] = "workqueue"  # numba re-reads its config from the environment
    numba.config.THREADING_LAYER = "workqueue"


@njit(parallel=True, nogil=True, cache=True)
def truav_episode(q, state, explore_u, random_a, epsilon, fence, train, lr, discount, others, links, link_step,
                  link_seeds, episode, comm_range, sp, rp_reward, maps, prev_in_range, pp, draw, rng_state, exp_neg_lam, moves, apply_moves, hp, hotspots, cluster,
                  pos, velocity, heading, road, s, v, home, next_turn, lane_order, turn_u, xy, trace, row0, slots,
                  total, arrivals, up, mp, rp, ch, out_uav, out_env, energy, above_hover, totals, reward_sum, visits,
                  last_action):
    """Run steps 0..T-1 of the current episode for every env b, in place.

    draw: first make env b's deferred draws of the episode (World.deferred_draws:
    rng_state .. hp) into turn_u and arrivals, and move its hotspots
    (B, K, 2) and re-home its vehicles (cluster (B, N)), as
    World.start_episode would have before step 0.

    q (B, U, S, 16); state (B, U) the agents' states at the episode start,
    left at the last step's; explore_u, random_a (T, B, U) exploration draws;
    fence the agents' geofence (qlearning.Fence); maps (B, U, C) the agents'
    density maps and pp their agents.prediction.PredictParams; prev_in_range (B, U)
    the vehicles in range at each agent's last observation (the shaping's phi), both
    left as the last step leaves them;
    others (U, U) which peers each UAV hears (all but itself); links, link_step the channel-driven beacon
    links' table (world.link_phy.LinkParams; size 0: ideal links, others alone), link_seeds (B,) the envs'
    run seeds and episode the episode's number for their draws (the beacons after step t are number t + 1);
    turn_u
    (T, B, N, 2) and arrivals (T, B, N) the world's draws; the world arrays
    as in `step.env_step`, with a leading B (trace and row0 as in
    `step.world_step`); reward_sum (B,) adds each step's
    mean reward over UAVs; visits (B, U, S) counts each agent's updates per
    state (federated TRUAV weighs shared rows by them, agents.federated); last_action (B, U) is left
    holding each agent's action of the last step (the controller's `action`, as act/observe leave it)."""
    n_env, n_uav = state.shape
    n_steps = turn_u.shape[0]
    for b in prange(n_env):
        if draw:
            pcg64_episode_draws(rng_state[b], exp_neg_lam, arrivals[:, b], turn_u[:, b], moves[b])
            if apply_moves and moves.shape[1] > 0:
                move_hotspots_env(hotspots[b], moves[b], hp, home[b], cluster[b])
        actions = np.empty(n_uav, np.int64)
        rewards = np.empty(n_uav)
        no_delay = np.zeros(n_uav)
        heard_u = np.zeros(n_uav, np.bool_)
        work_f, work_i, work_b = mobility_scratch(s.shape[1], mp.n_roads)  # the steps' scratch, per env
        # Env b's views, once per episode rather than per step: each view of a
        # batch array counts a reference on that array, shared by all threads.
        q_b, pos_b, vel_b, heading_b, road_b, s_b, v_b = q[b], pos[b], velocity[b], heading[b], road[b], s[b], v[b]
        home_b, next_turn_b, lane_order_b, slots_b, total_b = home[b], next_turn[b], lane_order[b], slots[b], total[b]
        o, out_env_b, energy_b, above_hover_b, totals_b = out_uav[b], out_env[b], energy[b], above_hover[b], totals[b]
        xy_b, row0_b = xy[b], row0[b]
        for t in range(n_steps):
            for u in range(n_uav):
                actions[u] = act_one(q_b[u, state[b, u]], explore_u[t, b, u], random_a[t, b, u], epsilon,
                                     pos_b[u, 0], pos_b[u, 1], fence)
            env_step(actions, False, no_delay, no_delay, pos_b, vel_b, heading_b, road_b, s_b, v_b,
                     home_b, next_turn_b, lane_order_b, turn_u[t, b], xy_b, replayed_row(trace, row0_b, t), slots_b,
                     total_b, arrivals[t, b], t,
                     up, mp, rp, ch, o, out_env_b, energy_b, above_hover_b, totals_b, work_f, work_i, work_b)
            for u in range(n_uav):
                x, y = pos_b[u, 0], pos_b[u, 1]
                heard = others[u]
                if links.size > 0:  # channel-driven beacons: as world.link_phy.heard_masks decides them
                    for m in range(n_uav):
                        heard_u[m] = others[u, m] and beacon_delivered(links, link_step, x, y, pos_b[m, 0],
                                                                       pos_b[m, 1], link_seeds[b], episode, t + 1, m, u)
                    heard = heard_u
                nearest, overlap = neighbour_one(x, y, pos_b, heard, comm_range)
                nb_sector = nearest_sector_one(x, y, pos_b, heard, sp.neighbour_sectors) \
                    if sp.neighbour_sectors > 0 else 0
                predicted = predict_one(maps[b, u], x, y, o[u, IN_RANGE], pp)
                s_next = encode_one(x, y, o[u, IN_RANGE], o[u, QUEUED], nearest, nb_sector, int(o[u, DENSEST]),
                                    predicted, sp)
                rewards[u] = full_one(o[u, RELAYED], o[u, COVERED], energy_b[u], overlap, o[u, EXCLUSIVE],
                                      o[u, IN_RANGE], prev_in_range[b, u], rp_reward)
                prev_in_range[b, u] = o[u, IN_RANGE]
                if train:
                    q_update_one(q_b[u], state[b, u], actions[u], rewards[u], s_next, False, lr, discount)
                    visits[b, u, state[b, u]] += 1
                state[b, u] = s_next
            reward_sum[b] += pairwise_sum(rewards, 0, n_uav) / n_uav
        if n_steps > 0:
            for u in range(n_uav):
                last_action[b, u] = actions[u]


@njit(parallel=True, nogil=True, cache=True)
def patrol_episode(plan, cand, cand_action, draw, rng_state, exp_neg_lam, moves, apply_moves, hp, hotspots, cluster,
                   pos, velocity, heading, road, s, v, home, next_turn, lane_order, turn_u, xy, trace, row0,
                   slots, total, arrivals, up, mp, rp, ch, out_uav, out_env, energy, above_hover, totals, err_sum):
    """The patrol baseline's episode, as PatrolController.act/observe step it:
    each UAV takes the candidate action (cand (17, 2) velocities) landing
    closest to its planned position plan (T + 1, B, U, 2) of the next step;
    err_sum (B,) adds each step's mean distance to the plan; draw .. cluster
    as in truav_episode."""
    n_env, n_uav = pos.shape[0], pos.shape[1]
    n_steps = turn_u.shape[0]
    dt, area = up.dt, up.area
    for b in prange(n_env):
        if draw:
            pcg64_episode_draws(rng_state[b], exp_neg_lam, arrivals[:, b], turn_u[:, b], moves[b])
            if apply_moves and moves.shape[1] > 0:
                move_hotspots_env(hotspots[b], moves[b], hp, home[b], cluster[b])
        actions = np.empty(n_uav, np.int64)
        err = np.empty(n_uav)
        no_delay = np.zeros(n_uav)
        work_f, work_i, work_b = mobility_scratch(s.shape[1], mp.n_roads)
        for t in range(n_steps):
            for u in range(n_uav):
                best, best_c = np.inf, 0
                for c in range(cand.shape[0]):
                    # np.clip(pos + cand * dt, 0, area), then the squared miss summed over x, y.
                    lx, ly = pos[b, u, 0] + cand[c, 0] * dt, pos[b, u, 1] + cand[c, 1] * dt
                    lx = lx if lx > 0.0 else 0.0
                    ly = ly if ly > 0.0 else 0.0
                    lx = lx if lx < area else area
                    ly = ly if ly < area else area
                    dx, dy = lx - plan[t + 1, b, u, 0], ly - plan[t + 1, b, u, 1]
                    miss = dx * dx + dy * dy
                    if miss < best:  # np.argmin: the first of equal misses
                        best, best_c = miss, c
                actions[u] = cand_action[best_c]
            env_step(actions, False, no_delay, no_delay, pos[b], velocity[b], heading[b], road[b], s[b], v[b],
                     home[b], next_turn[b], lane_order[b], turn_u[t, b], xy[b], replayed_row(trace, row0[b], t),
                     slots[b], total[b], arrivals[t, b], t,
                     up, mp, rp, ch, out_uav[b], out_env[b], energy[b], above_hover[b], totals[b],
                     work_f, work_i, work_b)
            for u in range(n_uav):
                ex, ey = pos[b, u, 0] - plan[t + 1, b, u, 0], pos[b, u, 1] - plan[t + 1, b, u, 1]
                err[u] = np.sqrt(ex * ex + ey * ey)
            err_sum[b] += pairwise_sum(err, 0, n_uav) / n_uav


def _world_args(world):
    veh, queues, draws = world.vehicles, world.queues, world._draws
    return (world.uav_pos, world._velocity, veh.heading, veh.road, veh.s, veh.v, veh.home, veh.next_turn,
            veh.lane_order, draws.turn_u, world._xy, world._trace, world._row0, queues.slots, queues.total,
            draws.arrivals, world.uav, world.grid.params,
            world.relay, world.channel, world._out_uav, world._out_env, world._energy, world._above_hover, world._totals)


def _draw_args(world, deferred):
    """draw .. cluster of the kernels: the world's deferred draws, or none if start_episode made them."""
    if deferred is None:
        return (False, np.zeros((world.batch, 4), np.uint64), 1.0, np.zeros((world.batch, 0, 2)), False,
                world.grid.hotspot_params(), world.hotspots, world.vehicles.cluster)
    return (True, *deferred, world.hotspots, world.vehicles.cluster)


def run_patrol_episode(world, controller) -> None:
    """The current episode (from step 0) under the PatrolController `controller`."""
    if world.t != 0:
        raise RuntimeError("the fused episode starts at step 0")
    deferred = world.deferred_draws()
    patrol_episode(controller.plan, controller._cand, controller._cand_action.astype(np.int64),
                   *_draw_args(world, deferred), *_world_args(world), controller._err_sum)
    if deferred is not None:
        world.end_deferred_draws()
    steps = world._draws.turn_u.shape[0]
    world.t = steps
    controller._err_n = steps
    controller.pos = world.uav_pos.copy()


def set_threads(n: int) -> None:
    """Run the fused kernel on n threads (at most the cores numba found)."""
    numba.set_num_threads(max(1, min(n, numba.config.NUMBA_NUM_THREADS)))


def run_episode(world, controller) -> None:
    """The rest of the current episode (from step 0) of `world` under the
    TruavController `controller`, as the driver's step loop would run it."""
    if world.t != 0:
        raise RuntimeError("the fused episode starts at step 0")
    cfg, lc, ln = world.cfg, controller.cfg.learner, controller.learners
    others = ~np.eye(world.n_uavs, dtype=np.bool_)
    action = controller.action
    if not (isinstance(action, np.ndarray) and action.dtype == np.int64 and action.flags.c_contiguous
            and action.shape == controller.state.shape):  # act() may have left another array: the kernel writes it
        controller.action = np.zeros(controller.state.shape, np.int64)
    deferred = world.deferred_draws()
    truav_episode(ln.q, controller.state, ln._explore_u, ln._random_a, float(ln.epsilon), ln.fence,
                  bool(controller.train),
                  float(lc.learning_rate), float(lc.discount), others, controller.links.table,
                  float(controller.links.step_m), controller.link_seeds, int(controller._episode),
                  float(cfg.scenario.comm_range_m),
                  controller.encoder.params, controller.reward.params, controller.maps, controller.prev_in_range,
                  controller.predict,
                  *_draw_args(world, deferred), *_world_args(world), controller._reward_sum, controller.visits,
                  controller.action)
    if deferred is not None:
        world.end_deferred_draws()
    steps = world._draws.turn_u.shape[0]
    world.t = steps
    controller._steps = steps
    controller.pos = world.uav_pos.copy()  # the episode's last positions (channel-driven federated shares)
