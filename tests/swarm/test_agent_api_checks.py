"""Mistakes in an agent class's state, and the names of a class, caught before anything runs (issue 55): a
state_dict that cannot be saved fails the trial step (not the training's end); a state the class refuses is
exit 2 in train, evaluate, up and resim alike; `log resim --agent` takes any name of the recorded class."""

from __future__ import annotations

import argparse
import sys
import textwrap

import pytest

from truav.analysis import agent_loader
from truav.cli import main as cli
from truav.cli.log_resim import _agent_class
from truav.config import Config
from truav.errors import UserError

TINY = ["--seeds", "1", "--episodes", "2", "--set", "scenario.n_vehicles=60", "--set",
        "scenario.steps_per_episode=10", "--set", "roads.warmup_steps=10", "--quiet"]

STATES = textwrap.dedent('''
    import numpy as np
    from agents.api import UavAgent


    class Base(UavAgent):
        def act(self, view):
            return 0


    class HoldsObject(Base):
        def state_dict(self):
            return {"table": np.array([object(), object()])}


    class HoldsLambda(Base):
        def state_dict(self):
            return {"policy": lambda view: 0}


    class HoldsStrings(Base):
        def state_dict(self):
            return {"labels": np.array(["north", "south"])}


    class HoldsNested(Base):
        def state_dict(self):
            return {"table": {"a": np.zeros(3)}}


    class RefusesOwn(Base):
        def state_dict(self):
            return {"table": np.zeros(3)}

        def load_state_dict(self, state):
            raise KeyError("weights")


    class Sized(Base):
        """Its state's shape is a class attribute: a user who changes it after training has a class that
        refuses the trained state."""
        SIZE = 3

        def state_dict(self):
            return {"table": np.zeros(self.SIZE)}

        def load_state_dict(self, state):
            if state["table"].shape != (self.SIZE,):
                raise ValueError(f"table must hold {self.SIZE} values")
''')


@pytest.fixture
def states_module(tmp_path, monkeypatch):
    (tmp_path / "statesagents.py").write_text(STATES)
    monkeypatch.syspath_prepend(str(tmp_path))
    yield sys.modules.get
    sys.modules.pop("statesagents", None)


@pytest.mark.parametrize("agent, says", [
    ("statesagents:HoldsObject", "HoldsObject.state_dict()['table'] holds object values, not numbers"),
    ("statesagents:HoldsLambda", "HoldsLambda.state_dict()['policy'] holds object values, not numbers"),
    ("statesagents:HoldsStrings", "HoldsStrings.state_dict()['labels'] holds str values, not numbers"),
    ("statesagents:HoldsNested", "HoldsNested.state_dict()['table'] holds object values, not numbers"),
    ("statesagents:RefusesOwn", "RefusesOwn.load_state_dict(its own state_dict()) raised KeyError: 'weights'"),
])
def test_a_state_that_cannot_be_saved_or_loaded_fails_the_trial_step(states_module, tmp_path, capsys, agent, says):
    out = tmp_path / "run"
    assert cli.main(["train", "--agent", agent, *TINY, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and agent in err and says in err, err
    assert not out.exists()


def test_a_refused_trained_state_is_exit_2_in_evaluate_and_up(states_module, tmp_path, capsys):
    run = tmp_path / "run"
    assert cli.main(["train", "--agent", "statesagents:Sized", *TINY, "--out", str(run)]) == 0
    capsys.readouterr()
    states_module("statesagents").Sized.SIZE = 4  # the class changed after its training
    assert cli.main(["evaluate", str(run), "--episodes", "1", "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "Sized.load_state_dict refused UAV 0's state" in err, err
    assert "table must hold 4 values" in err, err
    from truav.swarm.checks import check_agent_start
    cfg = Config().replace(scenario={"n_vehicles": 60, "steps_per_episode": 10}, roads={"warmup_steps": 10})
    with pytest.raises(UserError, match="Sized.load_state_dict refused UAV 0's state"):
        check_agent_start("--qtable", str(run), "statesagents:Sized", cfg)


def _resim_args(agent: str | None) -> argparse.Namespace:
    return argparse.Namespace(agent=agent, file="run.mcap")


def test_resim_takes_any_name_of_the_recorded_class():
    rec = argparse.Namespace(agent="random", cfg=Config())
    assert _agent_class(_resim_args("agents.random_agent:RandomAgent"), rec, False) is \
        agent_loader.resolve("random")
    rec = argparse.Namespace(agent="agents.random_agent:RandomAgent", cfg=Config())
    assert _agent_class(_resim_args("random"), rec, False) is agent_loader.resolve("random")
    with pytest.raises(UserError) as refused:
        _agent_class(_resim_args("patrol"), rec, False)
    line = str(refused.value)
    assert "\n" not in line and "was flown by 'agents.random_agent:RandomAgent' (as recorded)" in line, line
    assert "--agent patrol" in line and "agents.patrol_agent:PatrolAgent" in line, line


def test_resim_does_not_import_the_recorded_module_to_compare():
    """A recording from elsewhere never picks code that runs: its module path is compared, not imported."""
    rec = argparse.Namespace(agent="nosuchmodule_from_elsewhere:Agent", cfg=Config())
    with pytest.raises(UserError, match="was flown by 'nosuchmodule_from_elsewhere:Agent'"):
        _agent_class(_resim_args("random"), rec, False)
    assert "nosuchmodule_from_elsewhere" not in sys.modules
