"""The chaos checker has three states, held, violated and not checked; what was not checked never counts as held."""

from __future__ import annotations

import json

from truav.faults import plan_from_dict
from truav.swarm import invariants
from truav.swarm.invariants import Invariant


def test_not_checked_rows_are_named_and_left_out_of_the_count(tmp_path):
    rows = [Invariant("a", True, "ok"), Invariant("b", True, "ok"),
            invariants._log_check(None, []), invariants._memory([])]
    assert [r.status for r in rows] == ["held", "held", "not checked", "not checked"]
    table = invariants.table(rows)
    assert table.splitlines()[-1] == ("2 of 2 checked held; 2 not checked: the recording passes truav log check, "
                                      "memory growth at most 100 MB per process")
    assert "4 of 4" not in table
    assert invariants.sound(rows)  # nothing violated: chaos exits 0, and says what it did not check
    invariants.write(tmp_path, rows)
    got = json.loads((tmp_path / "invariants.json").read_text())
    assert (got["sound"], got["held"], got["violated"], got["not_checked"]) == (True, 2, 0, 2)
    assert [r["status"] for r in got["invariants"]] == ["held", "held", "not checked", "not checked"]


def test_a_violation_is_counted_and_makes_the_run_unsound_whatever_was_not_checked():
    rows = [Invariant("a", True, "ok"), Invariant("b", False, "broken"), invariants._log_check(None, [])]
    assert not invariants.sound(rows)
    assert invariants.table(rows).splitlines()[-1] == ("1 of 2 checked held: the run is NOT sound; "
                                                       "1 not checked: the recording passes truav log check")
    assert "VIOLATED" in invariants.table(rows)


def test_a_plan_that_faults_to_the_end_leaves_the_quiet_tail_not_checked():
    plan = plan_from_dict({"fault": [{"kind": "loss", "start": 5.0, "probability": 0.5}]})  # never ends
    hovering = [[t, 1.0] for t in range(600)]
    row = invariants._quiet_tail({"timeline": {"hovering": hovering}}, plan, 10.0)
    assert row.held is None and row.status == "not checked" and "last to the end" in row.detail, row
