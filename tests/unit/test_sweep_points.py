"""Which sweep points a re-run keeps: only a run that ended by itself, ok, with every episode asked for."""

import json

from truav.swarm.fault_sweep import finished_point, is_finished


def _summary(result="ok", episodes=3, interrupted=False) -> str:
    return json.dumps({"interrupted": interrupted, "outcome": {"result": result},
                       "world": {"episodes": [{"coverage_pct": 1.0}] * episodes}})


def test_only_a_finished_point_is_kept(tmp_path):
    assert is_finished(_summary(), 3)
    assert not is_finished(_summary("interrupted", 0, True), 3)  # what Ctrl-C leaves: once taken as done
    assert not is_finished(_summary("interrupted", 3, True), 3)
    assert not is_finished(_summary("failed"), 3)
    assert not is_finished(_summary(episodes=2), 3)
    assert not is_finished("{", 3) and not is_finished("[]", 3)
    assert finished_point(tmp_path / "missing.json", 3) is None
    (tmp_path / "s.json").write_text(_summary())
    assert finished_point(tmp_path / "s.json", 3) == _summary()
