"""The agent API's view says whether sensing is on (issue 55): densest_sector's 0 is no longer silent; the
sectors are oriented as docs/reference/agent-api.md says; every field of the view is documented."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from agents import api
from agents.api import UavAgent
from agents.api_controller import ApiController
from agents.api_decision import ApiDecision
from truav import seeding
from truav.analysis.agent_loader import trial_view
from truav.cli.reference import field_docs
from truav.config import Config
from truav.wire import schema
from world.network import sector

SENSING = Config().replace(scenario={"n_vehicles": 60, "steps_per_episode": 5}, roads={"warmup_steps": 5},
                           learner={"sense_range_m": 1500.0, "sense_sectors": 8})


class Recorder(UavAgent):
    views: list = []

    def act(self, view):
        Recorder.views.append(view)
        return 0


def _obs(cfg: Config) -> schema.Obs:
    return schema.Obs(tick=0, episode=0, uav=1, pos=(100.0, 200.0), vehicles_in_range=3, queued_packets=2,
                      relayed=0, covered=3, energy_j=0.0, speed_max=float(cfg.scenario.uav_speed_mps), done=False,
                      densest_sector=0, exclusive=1)


@pytest.mark.parametrize("cfg, on", [(Config(), (0.0, 4)), (SENSING, (1500.0, 8))])
def test_every_view_says_whether_sensing_is_on_and_in_how_many_sectors(cfg, on):
    decision = ApiDecision(Recorder, cfg, 1, seed=0)  # the swarm's agent process
    decision.learn(_obs(cfg), {})
    assert (decision.view.sense_range_m, decision.view.sense_sectors) == on
    view = trial_view(cfg)  # the trial step before a run
    assert (view.sense_range_m, view.sense_sectors) == on
    from agents.random_agent import RandomAgentBatched as RandomAgent
    from world.env import World
    small = cfg.replace(scenario={"n_vehicles": 60, "steps_per_episode": 5}, roads={"warmup_steps": 5})
    world = World(small, 1)
    obs = world.reset([seeding.world_rng(0)])
    per_uav = ApiController("rec", Recorder, small, [0])  # the in-process trainer, per-UAV form
    per_uav.begin_episode(0, obs)
    assert {(v.sense_range_m, v.sense_sectors) for row in per_uav.views for v in row} == {on}
    batched = ApiController("random", RandomAgent, small, [0])  # and batched
    assert RandomAgent.batched is not None
    batched.begin_episode(0, obs)
    assert (batched.views.sense_range_m, batched.views.sense_sectors) == on


def test_a_view_built_without_the_sensing_fields_has_the_config_defaults():
    """Adding the fields broke no user who builds a LocalView by position (e.g. in a test of their class)."""
    view = api.LocalView(0, 0, 0, (0.0, 0.0), 0, 0, 0, 0, 0.0, 15.0, 0, 0, 10.0, ())
    learner = Config().learner
    assert (view.sense_range_m, view.sense_sectors) == (learner.sense_range_m, learner.sense_sectors)


@pytest.mark.parametrize("degrees, expected", [(10, 0), (80, 0), (100, 1), (190, 2), (280, 3), (350, 3)])
def test_sectors_run_counter_clockwise_from_east(degrees, expected):
    """As documented: with 4 sectors, densest_sector 1 is east to north, 2 north to west, 3 west to south."""
    a = np.radians(degrees)
    assert sector(np.cos(a), np.sin(a), 4) == expected


def test_every_field_of_the_view_has_a_documented_unit_or_range():
    docs = field_docs(open(api.__file__).read())
    for cls in (api.LocalView, api.HeardBeacon):
        for f in dataclasses.fields(cls):
            assert docs[cls.__name__].get(f.name, "").strip(), f"{cls.__name__}.{f.name} has no docstring"


def test_an_api_agent_loads_its_step_kernels_before_it_joins():
    """A swarm's API agent warms up (agents.process.api_process) as TRUAV's does: the reward's and the overlap's
    compiled kernels are loaded before the first tick (else a busy host misses its first ticks), and nothing of
    the class is called."""
    from agents.reward import _rewards
    from agents.state import neighbour_features

    class Untouchable(UavAgent):
        def act(self, view):
            raise AssertionError("called")

        def learn(self, view, reward, done):
            raise AssertionError("called")

    decision = ApiDecision(Untouchable, Config(), 0, seed=0)
    decision.warm_up()
    assert _rewards.signatures and neighbour_features.signatures
    assert decision.view is None and decision.episode == -1
