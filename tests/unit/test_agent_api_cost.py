"""The agent API's price per call (issue 55): the in-process trainer's per-UAV form runs one call timer per
sweep over the UAVs, not one per call, builds the very views the dataclasses build, and still refuses every
result the API does not allow, naming the UAV."""

from __future__ import annotations

import dataclasses
import pickle
import signal

import numpy as np
import pytest

from agents.api import HeardBeacon, LocalView, UavAgent
from agents.api_controller import AgentFailure, ApiController
from bench.idle_agent import Idle
from truav.analysis.driver import run_episodes
from truav.config import Config

SMALL = Config().replace(scenario={"n_vehicles": 60, "steps_per_episode": 10}, roads={"warmup_steps": 10})
SEEDS = [0, 1]


def test_one_call_timer_per_sweep_over_the_uavs_not_one_per_call(monkeypatch):
    """Setting a timer (and installing its handler) per call cost more than a call that does nothing: now
    begin_episode's calls and two sweeps per step (act, learn) set it, whatever the number of UAVs."""
    arms = []
    real = signal.setitimer

    def counting(which, seconds, *interval):
        if which == signal.ITIMER_REAL and seconds > 0:
            arms.append(seconds)
        return real(which, seconds, *interval)

    ctl = ApiController("idle", Idle, SMALL, SEEDS)
    monkeypatch.setattr(signal, "setitimer", counting)
    run_episodes(SMALL, SEEDS, ctl, 1)
    uavs, steps = len(SEEDS) * SMALL.scenario.n_uavs, SMALL.scenario.steps_per_episode
    # begin_episode: one bounded call per UAV; then 2 sweeps per step (slack: a timer re-armed on a busy host)
    assert len(arms) <= uavs + 3 * steps


class Seer(UavAgent):
    """Flies its generator's actions, hovering too, and beacons a field."""

    def act(self, view):
        return int(self.rng.integers(-1, 16))

    def beacon_fields(self):
        return {"k": int(self.rng.integers(5))}


@pytest.mark.parametrize("cls", [Seer, Idle])
def test_the_views_are_the_dataclasses_own(cls):
    """Built without the frozen dataclass's per-field __init__, every view and beacon is what LocalView(...) and
    HeardBeacon(...) build from the same fields: equal, the same repr and attributes, frozen, pickled alike."""
    ctl = ApiController("seer", cls, SMALL, SEEDS)
    run_episodes(SMALL, SEEDS, ctl, 1)
    views = [v for row in ctl.views for v in row]
    assert len(views) == len(SEEDS) * SMALL.scenario.n_uavs and views[0].step == SMALL.scenario.steps_per_episode
    for view in views:
        for made in [view, *view.beacons]:
            own = type(made)(**{f.name: getattr(made, f.name) for f in dataclasses.fields(made)})
            assert made == own and repr(made) == repr(own) and vars(made) == vars(own)
            assert pickle.loads(pickle.dumps(made)) == own
            with pytest.raises(dataclasses.FrozenInstanceError):
                made.uav = 9
    assert type(views[0]) is LocalView and type(views[0].beacons[0]) is HeardBeacon
    fields = {b.fields.get("k") for v in views for b in v.beacons}
    assert (fields <= set(range(5))) if cls is Seer else fields == {None}


@pytest.mark.parametrize("act, fields, says", [
    (lambda: True, dict, "act returned True (bool), not an int action in 0..15 or HOVER"),
    (lambda: 16, dict, "act returned 16, not an action in 0..15 or HOVER (-1)"),
    (lambda: -2, dict, "act returned -2, not an action in 0..15 or HOVER (-1)"),
    (lambda: 3.0, dict, "act returned 3.0 (float), not an int action"),
    (lambda: np.int64(99), dict, "act returned 99, not an action"),
    (lambda: 1 // 0, dict, "act raised ZeroDivisionError"),
    (lambda: 0, lambda: [], "beacon_fields returned list, not a dict"),
    (lambda: 0, lambda: {"x": float("nan")}, "beacon_fields['x']=nan is not finite"),
    (lambda: 0, lambda: {"x": "text"}, "beacon_fields['x'] must be a bool, int or float, got str"),
])
def test_a_result_the_api_does_not_allow_still_stops_the_run_naming_the_uav(act, fields, says):
    seeds = [0, 1]
    ctl = ApiController("breaking", _by_seed(act, fields, seeds), SMALL, seeds)
    with pytest.raises(AgentFailure) as exc:
        run_episodes(SMALL, seeds, ctl, 1)
    assert str(exc.value).startswith("agent breaking (UAV 3 of seed 1): ") and says in str(exc.value)


def _by_seed(act, fields, seeds):
    """A class breaking at UAV 3 of the second seed (the controller builds its instances seed by seed)."""
    made = []

    class Breaking(UavAgent):
        def __init__(self, cfg, uav, rng):
            super().__init__(cfg, uav, rng)
            self.bad = (len(made) // cfg.scenario.n_uavs, uav) == (1, 3)
            made.append(self)

        def act(self, view):
            return act() if self.bad else 0

        def beacon_fields(self):
            return fields() if self.bad else {}
    return Breaking


def test_numpy_integer_actions_and_hover_are_still_actions():
    class Numpy(UavAgent):
        def act(self, view):
            return np.int32(view.step % 17 - 1)  # -1 (HOVER) .. 15

    ctl = ApiController("numpy", Numpy, SMALL, SEEDS)
    run_episodes(SMALL, SEEDS, ctl, 1)
    assert ctl.action.dtype == np.int64 and (ctl.action == (SMALL.scenario.steps_per_episode - 1) % 17 - 1).all()
