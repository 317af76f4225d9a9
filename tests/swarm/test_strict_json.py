"""Every JSON file the project writes loads with a strict parser: a non-finite number is null, never a bare NaN."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from truav import jsonio
from truav.config import Config
from world.world_stats import WorldStats, write_stats


def strict_load(path: Path):
    def refuse(name: str):
        raise AssertionError(f"{path.name}: bare {name}")
    return json.loads(path.read_text(), parse_constant=refuse)


def test_non_finite_values_at_any_depth_become_null():
    value = {"a": math.nan, "b": [1.0, math.inf, {"c": -math.inf}], "d": np.float32("nan"),
             "e": np.array([0.5, np.nan]), "f": (np.int64(3), "x"), "g": None}
    text = jsonio.dumps(value)
    assert "NaN" not in text and "Infinity" not in text
    assert jsonio.loads_strict(text) == {"a": None, "b": [1.0, None, {"c": None}], "d": None,
                                         "e": [0.5, None], "f": [3, "x"], "g": None}
    assert jsonio.num(None) != jsonio.num(None)  # NaN again for arithmetic
    assert jsonio.num(2) == 2.0


def test_the_strict_loader_refuses_what_other_parsers_refuse():
    with pytest.raises(ValueError, match="NaN"):
        jsonio.loads_strict('{"pdr": NaN}')


def test_world_stats_with_an_episode_without_packets_are_strict_json(tmp_path):
    # pdr and delay_ms are NaN when nothing was generated or delivered (world.env)
    stats = WorldStats(episodes=[{"coverage_pct": 3.0, "pdr": math.nan, "delay_ms": math.nan}],
                       tick_lateness_ms=[0.5, 1.0])
    write_stats(tmp_path / "world.json", stats)
    got = strict_load(tmp_path / "world.json")
    assert got["episodes"][0] == {"coverage_pct": 3.0, "pdr": None, "delay_ms": None}


def test_every_json_a_swarm_run_writes_is_strict(tmp_path):
    from tests.support.runs import up_to_end

    # 1 vehicle: hardly any packet, so the episode's delay (and likely PDR) is NaN in memory
    cfg = Config().replace(scenario={"n_vehicles": 1, "steps_per_episode": 6, "n_uavs": 2},
                           roads={"warmup_steps": 2})
    out = up_to_end(tmp_path, "strict", cfg, "--episodes", "1", "--lockstep")
    files = sorted(out.rglob("*.json"))
    assert any(f.name == "summary.json" for f in files), files
    for f in files:
        strict_load(f)
    summary = strict_load(out / "summary.json")
    assert summary["world"]["episodes"], summary["world"]
