"""docs/how-to/train-with-sb3.md: its few lines are examples/train_sb3.py's, and that file trains (a tiny budget),
saves the weights where its agent class reads them, and a lock-step swarm flies them with `--agent` (issue 56)."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("stable_baselines3", reason="training needs the optional extra 'marl'")

REPO = Path(__file__).resolve().parents[2]
PAGE = REPO / "docs" / "how-to" / "train-with-sb3.md"
SCRIPT = REPO / "examples" / "train_sb3.py"


def test_the_pages_python_lines_are_the_scripts():
    blocks = re.findall(r"^```python\n(.*?)^```", PAGE.read_text(), re.M | re.S)
    assert blocks, "the page shows the training in a python block"
    script = SCRIPT.read_text().splitlines()
    for block in blocks:
        lines = [ln for ln in block.splitlines() if ln.strip()]
        assert 5 <= len(lines) <= 20, "a few lines"
        at = 0
        for ln in lines:  # each line of the page in the script, in the page's order (dedented the same)
            found = next((i for i in range(at, len(script)) if script[i].strip() == ln.strip()), None)
            assert found is not None, f"not in {SCRIPT.name} (or not in this order): {ln!r}"
            at = found + 1


@pytest.mark.timeout(900)  # torch's import and a rollout, then a swarm: minutes on a loaded 2-core host
def test_the_script_trains_saves_and_a_swarm_flies_it(tmp_path):
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO / "examples"), str(REPO)])}
    trained = subprocess.run([sys.executable, str(SCRIPT), "--steps", "1"], cwd=tmp_path, env=env,
                             capture_output=True, text=True, timeout=600)
    assert trained.returncode == 0, trained.stdout + trained.stderr
    assert (tmp_path / "runs" / "sb3-ppo.npz").is_file()
    scenario = subprocess.run([sys.executable, "-m", "truav.cli", "config", "show", "--preset", "paper", "--set",
                               "learner.sense_range_m=1500"], cwd=tmp_path, env=env, capture_output=True, text=True,
                              check=True).stdout
    (tmp_path / "paper-1500.toml").write_text(scenario)
    out = tmp_path / "runs" / "swarm-sb3"
    flown = subprocess.run([sys.executable, "-m", "truav.cli.swarm", "up", "--agent", "train_sb3:Sb3Agent",
                            "--scenario", "paper-1500.toml", "--out", str(out), "--lockstep", "--agents", "2",
                            "--episodes", "1", "--steps", "4", "--set", "scenario.n_vehicles=40", "--set",
                            "roads.warmup_steps=5", "--no-plot", "--quiet", "--no-references"],
                           cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600,
                           start_new_session=True)
    assert flown.returncode == 0, flown.stdout[-3000:] + flown.stderr[-3000:]
    world = json.loads((out / "world.json").read_text())
    assert world["ticks"] >= 4 and world["deadline_misses"] == 0
    assert all(u["missed"] == 0 and u["applied"] > 0 for u in world["per_uav"])
