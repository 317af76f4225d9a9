"""The agent file of `truav train --agent NAME` (truav.analysis.agent_run) read as a file from elsewhere: what it
declares is bounded before anything is inflated, and a start state that does not fit is one named line."""

from __future__ import annotations

import zipfile

import numpy as np
import pytest

from truav.analysis import agent_run, policy_scenario
from truav.config import Config
from truav.errors import UserError
from truav.analysis.runio import RunDirError

CFG = Config()


def _write(tmp_path, name="truav", uavs=5, seeds=(0, 1)):
    state = {"q": np.arange(len(seeds) * uavs * 6, dtype=np.float64).reshape(len(seeds), uavs, 3, 2)}
    agent_run.write_agent_state(tmp_path, name, 1, list(seeds), state, None, CFG)
    return tmp_path / agent_run.AGENT_FILE


def test_start_states_are_each_uavs_slice_of_the_chosen_seed(tmp_path):
    _write(tmp_path)
    starts = agent_run.agent_start_states(tmp_path, "truav", 5, index=1)
    assert len(starts) == 5
    assert np.array_equal(starts[3]["q"], np.arange(60, dtype=np.float64).reshape(2, 5, 3, 2)[1, 3])


def test_the_file_records_the_scenario_it_was_trained_in(tmp_path):
    path = _write(tmp_path)
    assert policy_scenario.read_record(path) == policy_scenario.record(CFG)
    assert policy_scenario.check("--qtable", str(tmp_path), path, CFG).line() is None
    faster = CFG.replace(scenario={"uav_speed_mps": 25.0})
    with pytest.raises(UserError, match="was trained at 15 m/s; this run flies at 25 m/s"):
        policy_scenario.check("--qtable", str(tmp_path), path, faster)


@pytest.mark.parametrize("kwargs, words", [
    ({"name": "random"}, "trained by agent 'truav', not 'random'"),
    ({"n_uavs": 3}, "holds 5 UAV(s), this swarm flies 3"),
    ({"index": 2}, "holds 2 seed(s); index 2"),
])
def test_a_start_state_that_does_not_fit_is_named(tmp_path, kwargs, words):
    _write(tmp_path)
    args = {"name": "truav", "n_uavs": 5, "index": 0, **kwargs}
    with pytest.raises(RunDirError) as exc:
        agent_run.agent_start_states(tmp_path, args["name"], args["n_uavs"], args["index"])
    assert words in str(exc.value)


def test_a_file_declaring_more_than_the_bound_is_not_inflated(tmp_path):
    """A few hundred bytes whose zip directory declares ~8 GiB: refused from the directory, nothing inflated."""
    path = tmp_path / agent_run.AGENT_FILE
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("agent.npy", b"x")
        z.writestr("seeds.npy", b"y")
    raw = bytearray(path.read_bytes())
    at = 0
    while (at := raw.find(b"PK\x01\x02", at)) >= 0:  # each central-directory entry: forge its declared size
        raw[at + 24:at + 28] = (0xFFFFFFF0).to_bytes(4, "little")
        at += 4
    path.write_bytes(bytes(raw))
    assert path.stat().st_size < 1000
    with pytest.raises(RunDirError, match="declares 8.0 GiB of arrays"):
        agent_run.read_agent_state(path)


@pytest.mark.parametrize("content", [b"", b"not a zip at all", b"PK\x03\x04broken"])
def test_a_damaged_file_is_one_named_error(tmp_path, content):
    path = tmp_path / agent_run.AGENT_FILE
    path.write_bytes(content)
    with pytest.raises(RunDirError, match="agent.npz"):
        agent_run.read_agent_state(path)


def test_a_missing_file_is_named(tmp_path):
    with pytest.raises(RunDirError, match="no such agent file"):
        agent_run.read_agent_state(tmp_path)
