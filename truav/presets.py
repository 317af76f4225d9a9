"""Scenario presets: named sets of config overrides, each choice with its source.

`literal` is the defaults: the paper's Table read literally, with a random
redeployment every episode and traffic hotspots fixed at the major
intersections. `paper` is the scenario the paper's results and wording imply
(docs/results/reproduction.md, "Scenario presets"). A preset is applied first; a
--config file and --set overrides come on top of it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class Choice:
    """One key a preset sets, and why."""

    key: str
    """section.key, as --set takes it."""
    value: Any
    """The value (TOML-compatible)."""
    why: str
    """The source: the paper's words (section) or a measurement, in one line."""


PRESETS: dict[str, tuple[Choice, ...]] = {
    "literal": (),
    "paper": (
        Choice("scenario.uav_start", "persist",
               "Evaluation, Fig. 'Performance versus UAV velocity': ~94% coverage at 15 m/s needs a swarm on "
               "station; 5 discs of 500 m cover 16% of the city and a random redeployment each 100 s episode "
               "spends it in transit (measured: patrol 42% from random starts, 80-88% continuing)"),
        Choice("roads.hotspot_move_prob", 0.5,
               "Related work: static deployment 'fails to cope with spatio-temporal hotspot dynamics' (Cho et al.); "
               "Evaluation: UAVs 'follow moving vehicle clusters', 'fixed patrol paths cannot adapt to spatial "
               "traffic variations'. No rate is given: 0.5 per 100 s episode, a hotspot dwells 200 s on average"),
        Choice("learner.geofence", True,
               "Not in the paper (silent on boundaries): a greedy UAV that pushes into a wall keeps its state "
               "and stays there; the fence removes that corner trap (docs/results/reproduction.md, greedy collapse)"),
        Choice("central.geofence", True,
               "Not in the paper: the same boundary rule for the centralized baseline (its UAVs' autopilot "
               "refuses moves out of the area); without it a persistent swarm under the SAC ends pinned to "
               "the borders (measured: 2.8% training coverage after 1000 episodes at 15 m/s)"),
        Choice("roads.hotspot_step_blocks", 4,
               "System model: clusters gather at intersections; a move of 4 blocks (1 km, two comm ranges) takes a "
               "cluster out of the coverage of a UAV parked on its old site"),
    ),
}
"""Preset name -> its choices."""

DEFAULT_PRESET = "literal"


def preset_overrides(name: str) -> dict[str, dict[str, Any]]:
    """{section: {key: value}} of a preset; KeyError names the known presets."""
    if name not in PRESETS:
        raise KeyError(f"unknown preset {name!r} (known: {', '.join(PRESETS)})")
    out: dict[str, dict[str, Any]] = {}
    for c in PRESETS[name]:
        section, key = c.key.split(".", 1)
        out.setdefault(section, {})[key] = c.value
    return out


def preset_header(name: str) -> str:
    """TOML comment lines naming the preset and, for each of its choices, why."""
    lines = [f"# preset: {name}" + ("" if PRESETS.get(name) else " (the defaults)")]
    for c in PRESETS.get(name, ()):
        lines.append(f"# {c.key} = {c.value!r}: {c.why}")
    return "\n".join(lines) + "\n\n"
