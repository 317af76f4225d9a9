"""docs/scripts/privileged_dagger.py: its --sectors reaches the view's sensing, for the student and the heuristics."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from agents.spread_agent import SENSE_RANGE_M

SCRIPT = Path(__file__).resolve().parents[2] / "docs" / "scripts" / "privileged_dagger.py"
sys.path.insert(0, str(SCRIPT.parent))
try:
    import privileged_dagger
finally:
    sys.path.pop(0)  # the scripts' folder is not left on the path of the other tests


def test_the_config_senses_over_the_sectors_asked_for() -> None:
    cfg = privileged_dagger.make_config(5.0, 16)
    assert cfg.learner.sense_sectors == 16
    assert cfg.learner.sense_range_m == SENSE_RANGE_M
    assert cfg.scenario.uav_speed_mps == 5.0
    assert privileged_dagger.make_config(5.0).learner.sense_sectors == 4


def test_sectors_outside_the_views_range_is_a_usage_error() -> None:
    got = subprocess.run([sys.executable, str(SCRIPT), "--sectors", "17"], capture_output=True, text=True,
                         timeout=120)
    assert got.returncode == 2
    assert "--sectors" in got.stderr and "Traceback" not in got.stderr
