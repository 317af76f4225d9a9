"""The densest sensed disc (learner.sense_disc): what the world computes, what the wire and the agent API carry,
what a learner observes; off by default, and changing nothing else when on."""

from __future__ import annotations

import dataclasses

import msgpack
import numpy as np
import pytest

from agents.api import UavAgent
from agents.api_controller import ApiController
from agents.api_decision import ApiDecision
from agents.view_features import ViewEncoder
from truav import seeding
from truav.config import Config
from truav.wire import schema
from truav.wire.codec import decode, encode
from truav.wire.guard import Bounds, Guard
from world import network
from world.env import World
from world.world_state import restore_world, world_state

SMALL = Config().replace(scenario={"n_vehicles": 60, "steps_per_episode": 6}, roads={"warmup_steps": 5},
                         learner={"sense_range_m": 1500.0})
DISC = SMALL.replace(learner={"sense_disc": True})


def reference(xy: np.ndarray, pos: np.ndarray, sense_m: float, r: float) -> tuple[np.ndarray, np.ndarray]:
    """The disc by brute force, for one env: (U, 2) offsets and (U,) counts (the definition, vectorised)."""
    ok = ~np.isnan(xy).any(axis=1)
    idx = np.flatnonzero(ok)
    p = xy[ok]
    count = (((p[:, None] - p[None]) ** 2).sum(-1) <= r * r).sum(1)
    off, n = np.zeros((len(pos), 2)), np.zeros(len(pos), np.int64)
    for u, q in enumerate(pos):
        near = ((p - q) ** 2).sum(-1) <= sense_m * sense_m
        if near.any():
            best = int(np.argmax(np.where(near, count, -1)))
            off[u], n[u] = xy[idx[best]] - q, count[best]
    return off, n


def test_the_disc_is_the_sensed_vehicle_with_the_most_vehicles_in_range():
    cluster = np.array([[1000.0, 0.0]] * 4 + [[1200.0, 0.0]] * 2)
    far = np.array([[4000.0, 4000.0]] * 30)  # denser, but beyond the sensing range
    lone = np.array([[0.0, 600.0]])
    xy = np.ascontiguousarray(np.concatenate([lone, cluster, far, [[np.nan, np.nan]]]))
    pos = np.array([[0.0, 0.0], [2500.0, 2500.0]])
    out = np.zeros((2, network.UAV_COLUMNS))
    network._densest_discs(xy, pos, 500.0 ** 2, 1500.0 ** 2, out)
    # UAV 0: the cluster's first vehicle (at 1000 m) has all 6 of it in range; UAV 1 senses nothing
    np.testing.assert_array_equal(out[0, network.DISC_DX:], [1000.0, 0.0, 6.0])
    np.testing.assert_array_equal(out[1, network.DISC_DX:], [0.0, 0.0, 0.0])


def test_the_world_senses_the_disc_only_when_asked_and_changes_nothing_else():
    sc = DISC.scenario
    on, off = World(DISC, 2), World(SMALL, 2)
    got = [w.reset([seeding.world_rng(s) for s in (0, 1)]) for w in (on, off)]
    rng = np.random.default_rng(5)
    for t in range(sc.steps_per_episode):
        a, b = got
        for name in ("pos", "vehicles_in_range", "queued", "relayed", "covered", "energy_j", "densest_sector",
                     "exclusive"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
        assert not b.disc_offset.any() and not b.disc_vehicles.any()
        for env in range(2):
            off_ref, n_ref = reference(on.vehicle_xy()[env], a.pos[env], 1500.0, sc.comm_range_m)
            np.testing.assert_allclose(a.disc_offset[env], off_ref, atol=1e-9)
            np.testing.assert_array_equal(a.disc_vehicles[env], n_ref)
        assert a.disc_vehicles.any()
        actions = rng.integers(0, 16, (2, sc.n_uavs))
        steps = [w.step(actions) for w in (on, off)]
        for name, v in vars(steps[0][1]).items():
            np.testing.assert_array_equal(v, vars(steps[1][1])[name], err_msg=name)
        got = [s[0] for s in steps]


class Recorder(UavAgent):
    views: list = []

    def act(self, view):
        Recorder.views.append(view)
        return 0


def test_the_view_carries_the_disc_in_process_and_over_the_wire():
    world = World(DISC, 1)
    obs = world.reset([seeding.world_rng(3)])
    ctl = ApiController("rec", Recorder, DISC, [3])
    ctl.begin_episode(0, obs)
    views = ctl.views[0]
    assert [v.disc_offset for v in views] == [tuple(map(float, p)) for p in obs.disc_offset[0]]
    assert [v.disc_vehicles for v in views] == obs.disc_vehicles[0].tolist()
    from truav.wire.world_messages import observation_messages
    msgs = observation_messages(DISC, 0, 0, obs, False)
    for u, msg in enumerate(msgs):
        back = decode(encode(dataclasses.replace(msg, src="world")))
        decision = ApiDecision(Recorder, DISC, u, seed=3)  # an agent process builds its view from the message
        decision.learn(back, {})
        assert (decision.view.disc_offset, decision.view.disc_vehicles) == (views[u].disc_offset,
                                                                           views[u].disc_vehicles)
    enc = ViewEncoder(DISC, disc=True)
    batched = np.stack([enc(v) for v in views])
    assert np.abs(batched[:, enc.index("disc_vehicles")]).sum() > 0
    assert batched[:, enc.index("disc_dx")].tolist() == pytest.approx(
        [v.disc_offset[0] / 1500.0 for v in views], abs=1e-6)


def test_an_older_senders_observation_decodes_with_no_disc():
    msg = schema.Obs(src="world", tick=1, episode=0, uav=0, pos=(1.0, 2.0), vehicles_in_range=1, queued_packets=0,
                     relayed=0, covered=1, energy_j=0.0, speed_max=15.0, done=False, disc_offset=(3.0, -4.0),
                     disc_vehicles=7)
    assert decode(encode(msg)) == msg
    assert decode(encode(msg), expect="obs") == msg  # a receiver's limits for the kind its key carries
    old = msgpack.unpackb(encode(msg))
    del old["disc_offset"], old["disc_vehicles"]
    back = decode(msgpack.packb(old))
    assert (back.disc_offset, back.disc_vehicles) == ((0.0, 0.0), 0)


@pytest.mark.parametrize("change", [{"disc_vehicles": 61}, {"disc_offset": (1e7, 0.0)}])
def test_the_guard_refuses_a_disc_the_world_cannot_produce(change):
    guard = Guard(Bounds.from_config(SMALL))
    base = schema.Obs(src="world", tick=0, episode=0, uav=0, pos=(1.0, 2.0), vehicles_in_range=1, queued_packets=0,
                      relayed=0, covered=1, energy_j=0.0, speed_max=15.0, done=False)
    bad = dataclasses.replace(base, **change)
    for check in (guard.check, guard._check_any):  # the fast path per kind and the general one say the same
        assert check("k", base) is None
        refused = check("k", bad)
        assert refused is not None and refused[0] == "implausible", refused


def test_a_snapshot_from_before_the_disc_restores():
    world = World(SMALL, 1)
    obs = world.reset([seeding.world_rng(0)])
    obs, _, _ = world.step(np.zeros((1, SMALL.scenario.n_uavs), np.int64))
    state = world_state(world, obs)
    old = {**state, "out_uav": state["out_uav"][..., :network.OLD_UAV_COLUMNS].copy()}
    restored, robs = restore_world(SMALL, old)
    np.testing.assert_array_equal(restored._out_uav, state["out_uav"])
    assert not robs.disc_vehicles.any()


def test_disc_weights_refuse_a_run_without_the_disc():
    from agents.ppo_agent import DISC_WEIGHTS, PpoDiscAgent
    if not DISC_WEIGHTS.exists():
        pytest.fail(f"{DISC_WEIGHTS} is not shipped")
    slow = Config().replace(scenario={"uav_speed_mps": 5.0}, learner={"sense_range_m": 1500.0})
    with pytest.raises(ValueError, match="learner.sense_disc"):
        PpoDiscAgent(slow, 0, np.random.default_rng(0))
    agent = PpoDiscAgent(slow.replace(learner={"sense_disc": True}), 0, np.random.default_rng(0))
    assert agent.weights == DISC_WEIGHTS and agent.policy.disc
    fast = PpoDiscAgent(slow.replace(scenario={"uav_speed_mps": 15.0}), 0, np.random.default_rng(0))
    assert not fast.policy.disc  # from DISC_BELOW_MPS on: ppo-claim's weights


def test_a_swarm_or_a_comparison_of_ppo_disc_senses_the_disc_unasked():
    from agents.spread_agent import with_sensing
    from truav.swarm.swarm_options import with_agent_sensing
    for cfg in (with_sensing("ppo-disc", Config()), with_agent_sensing("agent:ppo-disc", Config())):
        assert cfg.learner.sense_disc and cfg.learner.sense_range_m == 1500.0
    assert not with_agent_sensing("agent:ppo-claim", Config()).learner.sense_disc
    assert not with_sensing("claim", Config()).learner.sense_disc
