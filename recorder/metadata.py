"""Names and shapes of the MCAP metadata records TRUAV writes, shared by the recorder
(which writes them) and the report (which reads them), without importing Zenoh."""

from __future__ import annotations

import json
import os
import tomllib
from typing import Any, Optional

from recorder.reader import Source, read_metadata

CONFIG_METADATA = "truav.config"  # {"toml": <text>, "<section>.<key>": <JSON value>, ...}
CONFIG_TOML_KEY = "toml"
RECORDING_METADATA = "truav.recording"  # run name, start time, host, recorder version
SUMMARY_METADATA = "truav.recorder_summary"  # written when the recorder stops cleanly


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
            out[prefix] = json.dumps(value, default=str)

    walk("", tomllib.loads(toml_text))
    return out


def read_config_toml(source: Source | os.PathLike[str]) -> Optional[str]:
    """The run config TOML stored in a recording, or None."""
    meta = read_metadata(source).get(CONFIG_METADATA)
    return None if not meta else meta.get(CONFIG_TOML_KEY)
