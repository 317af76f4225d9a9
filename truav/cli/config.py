"""The config options every command line shares: --preset, --config, --set, and the
UsageError a user's mistake on the command line raises.

    defaults < --preset < a command's base (e.g. --quick) < --config file < --set < dedicated flags

Used by `truav`, `truav experiment ...` and `truav-swarm`.
"""

from __future__ import annotations

import argparse
import tomllib
from typing import Any

from truav.config import Config, load_config
from truav.errors import UserError


class UsageError(UserError):
    """A user mistake on the command line."""


def parse_sets(items: list[str]) -> dict[str, dict[str, Any]]:
    """--set section.key=value (value in TOML syntax; bare words are strings)."""
    out: dict[str, dict[str, Any]] = {}
    for item in items:
        if "=" not in item or "." not in item.split("=", 1)[0]:
            raise UsageError(f"--set expects section.key=value, got {item!r}")
        dotted, raw = item.split("=", 1)
        section, key = dotted.strip().split(".", 1)
        try:
            value = tomllib.loads(f"v = {raw}")["v"]
        except tomllib.TOMLDecodeError:
            value = raw
        except RecursionError:
            raise UsageError(f"--set {dotted}: the value is nested too deeply") from None
        out.setdefault(section, {})[key] = value
    return out


def add_preset_arg(p: argparse.ArgumentParser, help_text: str | None = None) -> None:
    from truav.presets import PRESETS
    p.add_argument("--preset", metavar="NAME", help=help_text or (
        f"scenario preset applied before --config and --set: {' or '.join(PRESETS)} (default literal: "
        "the paper's Table read literally); `truav config show --preset paper` lists each choice and its source"))


def preset_from(args) -> dict[str, dict[str, Any]]:
    """The overrides of --preset ({} if not given); an unknown name is a UsageError."""
    from truav.presets import preset_overrides
    name = getattr(args, "preset", None)
    if name is None:
        return {}
    try:
        return preset_overrides(name)
    except KeyError as exc:
        raise UsageError(f"--preset: {exc.args[0]}") from None


def add_config_args(p: argparse.ArgumentParser) -> None:
    add_preset_arg(p)
    p.add_argument("--config", "-c", metavar="FILE", help="TOML file overriding the defaults (or the preset)")
    p.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="override one config value (repeatable), e.g. --set scenario.n_uavs=8")


def config_from(args, extra: dict[str, dict[str, Any]] | None = None,
                base: dict[str, dict[str, Any]] | None = None) -> Config:
    """Defaults < --preset < ``base`` (e.g. --quick) < --config file < --set < ``extra`` (dedicated flags)."""
    overrides = parse_sets(args.set)
    for section, values in (extra or {}).items():
        for key, value in values.items():
            if key in overrides.get(section, {}) and overrides[section][key] != value:
                raise UsageError(f"--set {section}.{key}={overrides[section][key]} contradicts the flag that sets "
                                 f"it to {value}; give one of them")
        overrides.setdefault(section, {}).update(values)
    layered = preset_from(args)
    for section, values in (base or {}).items():
        layered[section] = {**layered.get(section, {}), **values}
    return load_config(args.config, overrides, layered)
