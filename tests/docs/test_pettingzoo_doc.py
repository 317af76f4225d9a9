"""The PettingZoo environment's example in docs/tutorials/train-and-compare.md runs as shown, and its feature
table (docs/reference/pettingzoo-observation.md) lists every feature the environment observes (issue 56)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

pytest.importorskip("pettingzoo", reason="the PettingZoo adapter is the optional extra 'pettingzoo'")

from truav.analysis.pettingzoo_env import parallel_env  # noqa: E402

DOCS = Path(__file__).resolve().parents[2] / "docs"


def test_the_tutorials_example_runs_as_shown(capsys):
    page = (DOCS / "tutorials" / "train-and-compare.md").read_text()
    code = re.search(r"## Other learners: the PettingZoo environment.*?```python\n(.*?)```", page, re.S).group(1)
    exec(compile(code, "train-and-compare.md", "exec"), {})
    assert 0.0 <= float(capsys.readouterr().out.split()[-1]) <= 100.0


def test_the_feature_table_names_every_feature_of_the_default_environment():
    table = (DOCS / "reference" / "pettingzoo-observation.md").read_text()
    rows = {m.group(1): m.group(2) for m in re.finditer(r"^\| ([\d, ]+) \| `([^`]+)`", table, re.M)}
    env = parallel_env()
    listed = {}
    for index, group in rows.items():
        for i in map(int, index.split(", ")):
            listed[i] = group
    feats = env.observation_features()
    assert sorted(listed) == list(range(len(feats)))
    assert all(listed[i] == f.group for i, f in enumerate(feats))
