"""docs/scripts/velocity_schemes.py: a second run's schemes merged into the page's per-seed CSV, pairing checked."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "docs" / "scripts"))
try:
    import velocity_schemes as vs
finally:
    sys.path.pop(0)  # the scripts' folder is not left on the path of the other tests


def _cell(run: Path, stem: str, seeds: list[int], cov: list[float]) -> None:
    (run / "cells").mkdir(parents=True, exist_ok=True)
    np.savez(run / "cells" / f"{stem}.npz", seeds=np.array(seeds), **{"eval/coverage_pct": np.array([cov, cov])})


def test_a_class_path_cell_is_read_under_its_registered_name(tmp_path) -> None:
    _cell(tmp_path, "agents.ppo_agent-PpoClaimAgent_v15_u5_n200_s0-1_e1_abc", [0, 1], [60.0, 65.0])
    assert vs.per_seed(tmp_path) == {("ppo-claim", 15.0): {0: 60.0, 1: 65.0}}


def test_a_merge_adds_new_schemes_and_refuses_a_run_on_other_draws() -> None:
    cov = {("spread", 15.0): {0: 47.0, 1: 48.0}}
    assert vs.merge(cov, {("spread", 15.0): {0: 47.00001, 1: 48.0}, ("claim", 15.0): {0: 64.0, 1: 66.0}}) == ""
    assert cov[("claim", 15.0)] == {0: 64.0, 1: 66.0}
    assert "spread 15 m/s seed 1" in vs.merge(cov, {("spread", 15.0): {1: 50.0}})


def test_the_tables_pair_the_clone_with_spread_and_claim() -> None:
    keys = ("truav", "spread", "ppo", "patrol", "claim", "ppo-claim")
    cov = {(k, 15.0): {s: 40.0 + i * 3 + s for s in range(4)} for i, k in enumerate(keys)}
    assert "| speed (m/s) | ppo-claim - spread | ppo-claim - claim | claim - spread |" in vs.tables(cov)


def test_the_tables_pair_ppo_disc_with_the_heuristics_and_ppo_claim() -> None:
    keys = ("truav", "spread", "ppo", "patrol", "claim", "ppo-claim", "ppo-disc")
    cov = {(k, 5.0): {s: 40.0 + i * 3 + s for s in range(4)} for i, k in enumerate(keys)}
    out = vs.tables(cov)
    assert "| speed (m/s) | ppo-disc - spread | ppo-disc - claim | ppo-disc - ppo-claim |" in out
    assert "ppo-disc (learned, senses the disc)" in out.splitlines()[0]
    without = vs.tables({k: v for k, v in cov.items() if k[0] != "ppo-disc"})  # an older CSV: no such column
    assert "ppo-disc" not in without
