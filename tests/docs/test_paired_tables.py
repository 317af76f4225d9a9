"""docs/scripts/paired.py: the results pages' Markdown tables over seeds and their speed figure."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from truav.stats import effect_text, mean_ci, paired_effect

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "docs" / "scripts"))
try:
    import paired
finally:
    sys.path.pop(0)  # the scripts' folder is not left on the path of the other tests


def test_a_table_is_a_header_a_rule_and_rows_of_means_and_paired_differences() -> None:
    assert paired.head("speed (m/s)", ["a", "b"]) == ["| speed (m/s) | a | b |", "|---|---|---|"]
    assert paired.row("5", ["1", "2"]) == "| 5 | 1 | 2 |"
    base, other = np.array([40.0, 42.0, 45.0, 41.0]), np.array([44.0, 47.0, 48.0, 43.0])
    m, h = mean_ci(base)
    assert paired.ci(base) == f"{m:.1f} ± {h:.1f}"
    assert paired.diff(base, other) == effect_text(paired_effect(base, other), digits=1, noun="seeds")
    assert paired.diff(base, other).startswith("+3.5")


def test_the_speed_figure_is_written(tmp_path) -> None:
    cov = {(k, v): np.array([10.0 + v, 12.0 + v, 11.0 + v]) for k in ("a", "b") for v in (5.0, 10.0)}
    marked = []
    paired.speed_figure(cov, [5.0, 10.0], (("a", "A"), ("b", "B")), {"a": ("C0", "o", "-"), "b": ("C1", "s", "--")},
                        tmp_path / "f.png", "title", 70, mark=marked.append)
    assert (tmp_path / "f.png").stat().st_size > 0 and len(marked) == 1
