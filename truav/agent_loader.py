"""Find and check an agent class (agents.api) named on the command line, before anything starts.

A name is ``pkg.module:Class``, or a name an installed package registers in the entry-point group
``truav.agents`` (TRUAV registers ``random`` and ``patrol``; pyproject.toml). Every problem (not importable,
no such class, a missing method, an API version this TRUAV does not drive, an __init__ or state_dict that
raises) is a UserError: one line naming the class and what is wrong, exit 2.
"""

from __future__ import annotations

import importlib
import importlib.metadata
import inspect

import numpy as np

from truav.config import Config
from truav.errors import UserError

ENTRY_POINT_GROUP = "truav.agents"
AGENT_KIND_PREFIX = "agent:"
"""The trainer's controller kind of an API class: this prefix and the name as given (trainer.make_controller)."""


def registered() -> dict[str, str]:
    """{name: "module:Class"} of the installed entry points."""
    return {ep.name: ep.value for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP)}


def resolve(name: str, flag: str = "--agent") -> type:
    """The class ``name`` names, checked against the API (see the module docstring)."""
    from agents.api import REQUIRED_METHODS, SUPPORTED_API_VERSIONS
    spec = name
    if ":" not in name:
        names = registered()
        if name not in names:
            raise UserError(f"{flag} {name}: no agent registered under that name (registered: "
                            f"{', '.join(sorted(names)) or 'none'}); give pkg.module:Class")
        spec = names[name]
    module_name, _, attr = spec.partition(":")
    if not module_name or not attr:
        raise UserError(f"{flag} {name}: expected pkg.module:Class")
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        raise UserError(f"{flag} {name}: cannot import {module_name} (no module named {exc.name!r}; is it on "
                        f"PYTHONPATH or installed?)") from None
    except Exception as exc:  # the module's own code failed: its error, on one line
        raise UserError(f"{flag} {name}: importing {module_name} raised {type(exc).__name__}: "
                        f"{_one_line(exc)}") from None
    cls = module
    for part in attr.split("."):
        cls = getattr(cls, part, None)
        if cls is None:
            raise UserError(f"{flag} {name}: {module_name} has no {attr}")
    if not inspect.isclass(cls):
        raise UserError(f"{flag} {name}: {attr} is a {type(cls).__name__}, not a class")
    missing = [m for m in REQUIRED_METHODS if not callable(getattr(cls, m, None))]
    if missing:
        raise UserError(f"{flag} {name}: {attr} lacks the method{'s' if len(missing) > 1 else ''} "
                        f"{', '.join(missing)} (subclass agents.api.UavAgent)")
    version = getattr(cls, "api_version", None)
    if version is None:
        raise UserError(f"{flag} {name}: {attr} declares no api_version (subclass agents.api.UavAgent, or set "
                        f"api_version = {SUPPORTED_API_VERSIONS[-1]})")
    if version not in SUPPORTED_API_VERSIONS:
        raise UserError(f"{flag} {name}: {attr} is written for agent API version {version!r}; this TRUAV drives "
                        f"version{'s' if len(SUPPORTED_API_VERSIONS) > 1 else ''} "
                        f"{', '.join(map(str, SUPPORTED_API_VERSIONS))}")
    return cls


def check_instance(name: str, cls: type, cfg: Config, flag: str = "--agent") -> None:
    """Build one agent (UAV 0, a throwaway generator) and take its state: a class whose __init__ or state_dict
    raises, or whose state is not named arrays, fails here, before a run starts."""
    where = f"{flag} {name}"
    try:
        agent = cls(cfg, 0, np.random.default_rng(0))
    except Exception as exc:
        raise UserError(f"{where}: {cls.__name__}(cfg, uav, rng) raised {type(exc).__name__}: "
                        f"{_one_line(exc)}") from None
    try:
        state = agent.state_dict()
    except Exception as exc:
        raise UserError(f"{where}: {cls.__name__}.state_dict() raised {type(exc).__name__}: "
                        f"{_one_line(exc)}") from None
    if not isinstance(state, dict) or not all(isinstance(k, str) and k.isidentifier() for k in state):
        raise UserError(f"{where}: {cls.__name__}.state_dict() must return a dict of named arrays "
                        f"(identifier names), got {type(state).__name__}")
    batched = getattr(cls, "batched", None)
    if batched is not None and not (inspect.isclass(batched) and callable(getattr(batched, "act", None))):
        raise UserError(f"{where}: {cls.__name__}.batched must be a class with act (an agents.api.BatchedAgents)")


def load(name: str, cfg: Config, flag: str = "--agent") -> type:
    """resolve + check_instance: the class, ready for a run."""
    cls = resolve(name, flag)
    check_instance(name, cls, cfg, flag)
    return cls


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or "(no message)"


__all__ = ["AGENT_KIND_PREFIX", "ENTRY_POINT_GROUP", "check_instance", "load", "registered", "resolve"]
