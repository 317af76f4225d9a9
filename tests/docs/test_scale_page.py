"""docs/explanation/scale.md shows what docs/scripts/scale_model.py computes: its table and its limits, line for
line (the page is reproducible), and the script's inputs are the code's (the wire codec's beacon, its key space)."""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_the_scale_page_is_the_scale_models_output() -> None:
    out = subprocess.run([sys.executable, str(ROOT / "docs" / "scripts" / "scale_model.py")], capture_output=True,
                         text=True, timeout=60, check=True).stdout
    page = (ROOT / "docs" / "explanation" / "scale.md").read_text()
    missing = [line for line in out.splitlines() if line.strip() and line not in page.splitlines()]
    assert missing == [], missing
    assert "10,000 UAVs, all-to-all (9,999 hear each beacon): UAV ids (at most 1,024" in out


def test_the_model_grows_with_the_square_of_an_all_to_all_swarm() -> None:
    sys.path.insert(0, str(ROOT / "docs" / "scripts"))
    try:
        import scale_model
    finally:
        sys.path.pop(0)
    a = argparse.Namespace(rate=10.0, us_per_reception=12.6, cores_per_node=2.0, usable_share=0.65, per_process=10,
                           process_msgs_per_s=111_000, beacon_bytes=100)
    small, big = scale_model.model(100, 99, "all-to-all", a), scale_model.model(1000, 999, "all-to-all", a)
    assert small.receptions_per_s == 100 * 10 * 99 + 2 * 100 * 10
    assert 95 < big.receptions_per_s / small.receptions_per_s < 105
    assert small.nodes == 1 and big.nodes == -(-big.cores // 1.3)
    assert big.link_in_bytes_s == (1000 - 1000 / big.nodes) * 10 * 100
    assert scale_model.beacon_bytes() > 100
