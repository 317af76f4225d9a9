"""Names and shapes of the MCAP metadata records TRUAV writes, shared by the recorder
(which writes them) and the report (which reads them), without importing Zenoh."""

from __future__ import annotations

import json
import os
import tomllib
from typing import Any, Optional

from recorder.reader import Source, read_metadata
from truav import jsonio

CONFIG_METADATA = "truav.config"  # {"toml": <text>, "<section>.<key>": <JSON value>, ...}
CONFIG_TOML_KEY = "toml"
RECORDING_METADATA = "truav.recording"  # run name, start time, host, recorder version
SUMMARY_METADATA = "truav.recorder_summary"  # written when the recorder stops cleanly
RUN_METADATA = "truav.run"
"""How the swarm was run beyond its config (seed, lock-step, scheme, episodes, the agents' starting tables and
whether they learn): {"<name>": <JSON value>, ...}. `truav-swarm up --record` writes it; the re-simulation of a
recording (recorder.resim) needs it."""


def config_metadata(toml_text: str) -> dict[str, str]:
    """The run config as an MCAP metadata map: the TOML verbatim (for tools) plus one
    ``section.key`` entry per value (for people browsing the metadata in Foxglove).
    Raises tomllib.TOMLDecodeError for text that is not TOML."""
    out: dict[str, str] = {CONFIG_TOML_KEY: toml_text}

    def walk(prefix: str, value: Any) -> None:
        if isinstance(value, dict):
            for k, v in value.items():
                walk(f"{prefix}.{k}" if prefix else str(k), v)
        else:
            out[prefix] = jsonio.dumps(value, default=str)

    walk("", tomllib.loads(toml_text))
    return out


def read_config_toml(source: Source | os.PathLike[str]) -> Optional[str]:
    """The run config TOML stored in a recording, or None."""
    meta = read_metadata(source).get(CONFIG_METADATA)
    return None if not meta else meta.get(CONFIG_TOML_KEY)


def run_info_metadata(info: dict[str, Any]) -> dict[str, str]:
    """A run's settings as an MCAP metadata map (every value JSON-encoded)."""
    return {str(k): jsonio.dumps(v) for k, v in info.items()}


def read_run_info(source: Source | os.PathLike[str]) -> Optional[dict[str, Any]]:
    """The run settings stored in a recording (RUN_METADATA), or None (a recording made without them)."""
    meta = read_metadata(source).get(RUN_METADATA)
    if not meta:
        return None
    try:
        return {k: json.loads(v) for k, v in meta.items()}
    except ValueError:
        return None
