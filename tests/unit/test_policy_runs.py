"""The policy benchmarks' sampling (bench/policy_runs.py): which pids.json entries are agent processes and how
many UAVs each hosts, memory read from /proc, totals only from samples that read every agent process."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))

import policy_runs  # noqa: E402


def test_agent_process_names_and_the_uavs_they_host():
    assert policy_runs.uavs_of("agent7") == 1
    assert policy_runs.uavs_of("agents0-9") == 10
    assert policy_runs.uavs_of("agents0,1,3") == 3
    assert [policy_runs.uavs_of(n) for n in ("world", "router", "controller", "agent")] == [0, 0, 0, 0]


def test_schemes_are_flown_by_their_own_flags():
    assert policy_runs.scheme_args("truav") == ["--scheme", "truav"]  # explicit: up's default may be another
    assert policy_runs.scheme_args("ppo") == ["--agent", "ppo"]
    assert (policy_runs.flown_as("truav"), policy_runs.flown_as("ppo")) == ("truav", "agent:ppo")


def test_this_process_memory_from_proc():
    mem = policy_runs.memory_kb(os.getpid())
    assert mem is not None and mem["rss_kb"] > 0 and mem["hwm_kb"] >= mem["rss_kb"] > 0
    assert 0 < mem["uss_kb"] <= mem["pss_kb"] <= mem["rss_kb"]
    assert policy_runs.memory_kb(2 ** 22 + 1) is None  # above pid_max's default: no such process


def test_a_total_counts_only_samples_that_read_every_agent_process(tmp_path):
    me = os.getpid()
    (tmp_path / "pids.json").write_text(json.dumps({"router": me, "world": me, "agent0": me, "agents1-4": me}))
    sampler = policy_runs.AgentSampler(tmp_path, period_s=3600.0)  # samples once at start, then on demand
    sampler.sample()
    sampler.stop()
    assert sampler.uavs == {"agent0": 1, "agents1-4": 4} and "router" not in sampler.peak
    assert {"world", "agent0", "agents1-4"} <= set(sampler.peak)
    assert sampler.total_pss_kb(2) >= 2 * policy_runs.memory_kb(me)["pss_kb"] * 0.5
    assert sampler.total_pss_kb(3) != sampler.total_pss_kb(3)  # NaN: no sample read three agent processes
