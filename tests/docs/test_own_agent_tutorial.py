"""The class tutorial (docs/tutorials/own-agent.md) shows the class the repository ships, examples/cell_agent.py,
as it is; that class passes TRUAV's checks and its state round-trips (the commands themselves run in
tests/docs/test_readme_commands.py, in the order a reader meets them)."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import numpy as np
import pytest

from truav.analysis import agent_loader
from truav.config import Config

REPO = Path(__file__).resolve().parents[2]
TUTORIAL = REPO / "docs" / "tutorials" / "own-agent.md"
EXAMPLE = REPO / "examples" / "cell_agent.py"


def test_the_tutorial_shows_the_shipped_class_as_it_is():
    blocks = re.findall(r"```python\n(.*?)```", TUTORIAL.read_text(), re.S)
    assert blocks == [EXAMPLE.read_text()], "docs/tutorials/own-agent.md: copy examples/cell_agent.py into its block"


def test_every_command_of_the_tutorial_names_its_own_output():
    """After the quick start and the earlier tutorials, in one directory: no --out of another page."""
    text = TUTORIAL.read_text()
    outs = re.findall(r"--out (\S+)", text)
    assert outs and all("cell-agent" in o for o in outs), outs
    for page in (REPO / "docs" / "tutorials").glob("*.md"):
        if page != TUTORIAL:
            assert not set(outs) & set(re.findall(r"--out (\S+)", page.read_text())), page.name


@pytest.fixture
def cell_agent(monkeypatch):
    monkeypatch.syspath_prepend(str(EXAMPLE.parent))
    yield
    sys.modules.pop("cell_agent", None)


def test_the_shipped_class_passes_the_checks_and_its_state_round_trips(cell_agent):
    cfg = Config()
    cls = agent_loader.load("cell_agent:CellAgent", cfg)
    a, b = cls(cfg, 0, np.random.default_rng(1)), cls(cfg, 0, np.random.default_rng(2))
    a.q[3, 4] = 1.5
    b.load_state_dict(agent_loader.saved_and_read(a.state_dict()))
    assert np.array_equal(a.q, b.q)
    with pytest.raises(ValueError, match="q must be shaped"):
        b.load_state_dict({"q": np.zeros(3)})
