"""Shared command line of the greedy-collapse diagnostics: SEEDS EPISODES TAG [JSON overrides]."""
import json
import os

from truav.config import load_config


def diag_setup(argv):
    """(cfg, seeds, episodes, tag): persist starts at 15 m/s, ``learner.episodes`` = EPISODES, then the
    JSON overrides ({"section": {"key": value}}); makes runs/diag for the outputs."""
    os.makedirs("runs/diag", exist_ok=True)
    seeds, episodes, tag = list(range(int(argv[1]))), int(argv[2]), argv[3]
    overrides = {"scenario": {"uav_start": "persist", "uav_speed_mps": 15.0}, "learner": {"episodes": episodes}}
    for section, values in (json.loads(argv[4]) if len(argv) > 4 else {}).items():
        overrides.setdefault(section, {}).update(values)
    return load_config(None, overrides), seeds, episodes, tag
