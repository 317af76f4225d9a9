"""Fault plans: validation, and the link filter's behaviour per fault kind."""

import numpy as np
import pytest

from truav.bus.fault_filter import PlanFilter, uniform
from truav.faults import FaultPlan, PlanError, load_plan, plan_from_dict

RUN = "r"
T0 = 1_000_000_000_000


def filt(*faults, seed=0):
    f = PlanFilter(plan_from_dict({"seed": seed, "fault": list(faults)}), RUN)
    f.start(T0)
    return f


def at(seconds: float) -> int:
    return T0 + int(seconds * 1e9)


def test_example_plans_load():
    for name in ("beacon-loss", "crash-and-freeze", "partition-latency", "controller-crash", "controller-links"):
        plan = load_plan(f"deploy/plans/{name}.toml")
        assert plan.faults


@pytest.mark.parametrize("fault, fragment", [
    ({"kind": "meteor"}, "kind must be one of"),
    ({"kind": "loss", "start": 1.0}, "needs probability"),
    ({"kind": "loss", "probability": 1.5}, "probability"),
    ({"kind": "loss", "probability": 0.1, "p_good_to_bad": 0.1}, "either probability"),
    ({"kind": "latency", "fixed_ms": -3}, "fixed_ms"),
    ({"kind": "partition", "groups": [[0, 1]]}, "groups"),
    ({"kind": "partition", "groups": [[0, 1], [1, 2]]}, "two groups"),
    ({"kind": "crash", "start": 1.0}, "missing uav"),
    ({"kind": "freeze", "uav": 2, "colour": "red"}, "unknown key 'colour'"),
    ({"kind": "loss", "probability": 0.1, "duration": 0}, "duration"),
])
def test_bad_plans_name_the_fault_and_key(fault, fragment):
    with pytest.raises(PlanError, match=fragment) as err:
        plan_from_dict({"fault": [fault]})
    assert "fault #1" in str(err.value) or "kind" in str(err.value)


def test_counter_based_draws_are_reproducible():
    assert uniform(1, 0, "a>b|k", 5) == uniform(1, 0, "a>b|k", 5)
    assert uniform(1, 0, "a>b|k", 5) != uniform(2, 0, "a>b|k", 5)
    u = np.array([uniform(0, 0, "l", n) for n in range(4000)])
    assert 0.47 < u.mean() < 0.53 and u.min() >= 0 and u.max() < 1


def test_loss_rate_window_and_determinism():
    spec = {"kind": "loss", "start": 1.0, "duration": 2.0, "probability": 0.3, "keys": "uav/*/beacon"}
    key = f"truav/{RUN}/uav/1/beacon"
    a, b = filt(spec, seed=4), filt(spec, seed=4)
    got = [a.decide(key, "uav/1", "uav/2", at(1.5))[0] for _ in range(3000)]
    assert got == [b.decide(key, "uav/1", "uav/2", at(1.5))[0] for _ in range(3000)]
    assert 0.26 < 1 - np.mean(got) < 0.34
    assert a.decide(key, "uav/1", "uav/2", at(0.5)) == (True, 0.0)  # before the window
    assert a.decide(key, "uav/1", "uav/2", at(3.5)) == (True, 0.0)  # after it
    assert a.decide(f"truav/{RUN}/uav/1/action", "uav/1", "world", at(1.5)) == (True, 0.0)  # other keys


def test_gilbert_elliott_loss_comes_in_bursts():
    spec = {"kind": "loss", "p_good_to_bad": 0.05, "p_bad_to_good": 0.2, "loss_good": 0.0, "loss_bad": 1.0}
    f = filt(spec)
    lost = np.array([not f.decide(f"truav/{RUN}/uav/0/beacon", "uav/0", "uav/1", at(1))[0] for _ in range(5000)])
    rate = lost.mean()
    assert 0.12 < rate < 0.28  # stationary bad share 0.05 / 0.25 = 0.2
    runs = np.diff(np.flatnonzero(np.diff(np.r_[0, lost.astype(int), 0])))[::2]
    assert runs.mean() > 3.0  # mean burst 1 / 0.2 = 5 messages, not isolated losses


def test_latency_fixed_plus_jitter():
    f = filt({"kind": "latency", "fixed_ms": 100.0, "jitter_ms": 50.0})
    delays = [f.decide(f"truav/{RUN}/uav/0/beacon", "uav/0", "uav/3", at(0.1))[1] for _ in range(500)]
    assert min(delays) >= 0.1 and max(delays) < 0.15 and np.std(delays) > 0.005


def test_partition_blocks_only_across_groups():
    f = filt({"kind": "partition", "start": 0.0, "duration": 5.0, "groups": [[0, 1], [2, 3]]})
    key = f"truav/{RUN}/uav/0/beacon"
    assert f.decide(key, "uav/0", "uav/2", at(1))[0] is False
    assert f.decide(key, "uav/0", "uav/1", at(1))[0] is True
    assert f.decide(key, "uav/0", "world", at(1))[0] is True  # the world still hears everyone
    assert f.decide(key, "uav/0", "uav/2", at(6))[0] is True


def test_observation_loss_hits_only_world_to_agent_obs():
    f = filt({"kind": "obs_loss", "probability": 1.0, "uavs": [2]})
    assert f.decide(f"truav/{RUN}/uav/2/obs", "world", "uav/2", at(1))[0] is False
    assert f.decide(f"truav/{RUN}/uav/1/obs", "world", "uav/1", at(1))[0] is True
    assert f.decide(f"truav/{RUN}/uav/1/beacon", "uav/1", "uav/2", at(1))[0] is True


def test_no_faults_before_the_run_starts_and_plans_can_change():
    f = PlanFilter(plan_from_dict({"fault": [{"kind": "loss", "probability": 1.0}]}), RUN)
    assert f.decide(f"truav/{RUN}/uav/0/beacon", "uav/0", "uav/1", at(1)) == (True, 0.0)
    f.start(T0)
    assert f.decide(f"truav/{RUN}/uav/0/beacon", "uav/0", "uav/1", at(1))[0] is False
    f.set_plan(FaultPlan())
    assert f.decide(f"truav/{RUN}/uav/0/beacon", "uav/0", "uav/1", at(1)) == (True, 0.0)
    assert plan_from_dict(plan_from_dict({"fault": [{"kind": "crash", "uav": 1, "start": 2}]}).to_dict()).faults


def test_a_plan_without_link_faults_lets_the_bus_skip_the_filter():
    f = PlanFilter(FaultPlan(), RUN)
    assert f.passes_everything  # the swarm's default: inboxes keep their fast path
    f.set_plan(plan_from_dict({"fault": [{"kind": "crash", "uav": 1, "start": 2}]}))
    assert f.passes_everything  # process faults are the supervisor's business, not the link's
    f.set_plan(plan_from_dict({"fault": [{"kind": "latency", "fixed_ms": 100}]}))
    assert not f.passes_everything


def test_controller_faults_need_the_central_scheme_and_cut_its_links():
    from truav.faults import check_plan_for
    plan = plan_from_dict({"fault": [{"kind": "crash", "start": 1.0, "target": "controller"}]})
    assert check_plan_for(plan, 5, scheme="central") is plan
    with pytest.raises(PlanError, match="names the controller, but --scheme truav has none"):
        check_plan_for(plan, 5, scheme="truav")
    f = filt({"kind": "partition", "start": 0.0, "groups": [[0, 1], ["controller", 2]]})
    up, down = "truav/r/uav/0/state", "truav/r/controller/cmd/0"
    assert f.decide(up, "uav/0", "controller", at(1))[0] is False  # uplink of a cut-off UAV
    assert f.decide(down, "controller", "uav/0", at(1))[0] is False  # and its downlink
    assert f.decide("truav/r/uav/2/state", "uav/2", "controller", at(1))[0] is True
    assert f.decide("truav/r/uav/1/beacon", "uav/1", "uav/0", at(1))[0] is True  # within a group
    loss = filt({"kind": "loss", "start": 0.0, "probability": 1.0, "keys": "uav/*/state", "dst": "controller"})
    assert loss.decide(up, "uav/0", "controller", at(1))[0] is False
    assert loss.decide("truav/r/uav/0/beacon", "uav/0", "uav/1", at(1))[0] is True
