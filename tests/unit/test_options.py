"""Options declared once (truav/options.py): the flag a declaration adds parses back what to_argv wrote."""

import argparse
import dataclasses

import pytest

from agents.process.agent_process import AgentOptions
from agents.process.central_process import ControllerOptions
from truav import options
from truav.cli.args import add_options, options_from
from world.process.world_process import WorldOptions

EXAMPLES = {
    AgentOptions: {"checkpoint": "a.npz", "checkpoint_every": 7, "qtable": "runs/t", "qtable_index": 2,
                   "stats_out": "a.json", "command_hold_s": 0.5, "beacon_every": 10, "beacon_cell_m": 250.0,
                   "beacon_slots": 4, "snapshot_every": 0},
    WorldOptions: {"episodes": 3, "rate_hz": 20.0, "wait_agents_s": 5.0, "stats_out": "w.json", "max_missed_share": 0.25,
                   "snapshot_every": 7},
    ControllerOptions: {"policy": "runs/c", "policy_index": 1, "stats_out": "c.json"},
}


@pytest.mark.parametrize("cls", list(EXAMPLES), ids=lambda c: c.__name__)
def test_to_argv_parses_back(cls):
    parser = argparse.ArgumentParser()
    add_options(parser, cls)
    given = cls(**EXAMPLES[cls])
    names = [name for name, _, _ in options.declared(cls)]
    assert set(names) == set(EXAMPLES[cls])  # every declared flag is exercised here
    back = options_from(cls, parser.parse_args(options.to_argv(given, names)))
    assert {n: getattr(back, n) for n in names} == EXAMPLES[cls]


@pytest.mark.parametrize("cls", list(EXAMPLES), ids=lambda c: c.__name__)
def test_defaults_are_the_dataclass_defaults(cls):
    parser = argparse.ArgumentParser()
    add_options(parser, cls)
    assert options_from(cls, parser.parse_args([])) == cls()


def test_undeclared_field_has_no_flag():
    with pytest.raises(KeyError):
        options.flag_of(AgentOptions, "uav")
    assert all(f.name != "uav" for f in dataclasses.fields(AgentOptions) if options.FLAG in f.metadata)
