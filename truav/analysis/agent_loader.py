"""Find and check an agent class (agents.api) named on the command line, before anything starts.

A name is ``pkg.module:Class``, or a name an installed package registers in the entry-point group
``truav.agents`` (TRUAV registers ``random`` and ``patrol``; pyproject.toml). Every problem (not importable,
no such class, a missing method, an API version this TRUAV does not drive, a trial step whose calls raise,
take too long or return an illegal action, a state_dict that cannot be saved or that load_state_dict refuses) is a UserError: one line naming the class and what is wrong, exit 2.
"""

from __future__ import annotations

import importlib
import importlib.metadata
import inspect
import io
import sys

import numpy as np

from truav.call_limit import CallTooLong, call_limited, limit_problem
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
    """Build one throwaway agent (UAV 0, its own generator), run it for one step of a trial view and take its
    state, save and read it back as an agent file would, and load it into a second throwaway agent: a class
    whose calls raise, take longer than its call_limit_s, return an illegal action, a state that is not named
    arrays of numbers, or refuse its own state fails here, before a run starts. (A trial step cannot show every failure: one
    during the run is handled where it happens.)"""
    from agents.api import action_problem, beacon_problem
    where = f"{flag} {name}"
    for owner in (cls, getattr(cls, "batched", None) or cls):
        problem = limit_problem(getattr(owner, "call_limit_s", 1.0))
        if problem:
            raise UserError(f"{where}: {owner.__name__}.{problem}")
    limit = float(getattr(cls, "call_limit_s", 1.0))

    def call(what: str, fn, *args):
        label = f"{cls.__name__}{what}"
        try:
            return call_limited(limit, fn, *args)
        except CallTooLong as exc:
            raise UserError(f"{where}: {label} {exc}") from None
        except Exception as exc:
            raise UserError(f"{where}: {label} raised {type(exc).__name__}: {_one_line(exc)}") from None

    agent = call("(cfg, uav, rng)", cls, cfg, 0, np.random.default_rng(0))
    view = trial_view(cfg)
    call(".begin_episode(0, True)", getattr(agent, "begin_episode", lambda *a: None), 0, True)
    problem = action_problem(call(".act(view)", agent.act, view))
    if problem:
        raise UserError(f"{where}: {cls.__name__}.{problem} (on a trial view)")
    if callable(getattr(agent, "beacon_fields", None)):
        problem = beacon_problem(call(".beacon_fields()", agent.beacon_fields))
        if problem:
            raise UserError(f"{where}: {cls.__name__}.{problem} (on a trial view)")
    call(".learn(view, 0.0, False)", agent.learn, view, 0.0, False)
    state = call(".state_dict()", agent.state_dict)
    if not isinstance(state, dict) or not all(isinstance(k, str) and k.isidentifier() for k in state):
        raise UserError(f"{where}: {cls.__name__}.state_dict() must return a dict of named arrays "
                        f"(identifier names), got {type(state).__name__}")
    problem = state_problem(state)
    if problem:
        raise UserError(f"{where}: {cls.__name__}.state_dict(){problem}")
    fresh = call("(cfg, uav, rng)", cls, cfg, 0, np.random.default_rng(0))
    call(".load_state_dict(its own state_dict())", fresh.load_state_dict, saved_and_read(state))
    batched = getattr(cls, "batched", None)
    if batched is not None and not (inspect.isclass(batched) and callable(getattr(batched, "act", None))):
        raise UserError(f"{where}: {cls.__name__}.batched must be a class with act (an agents.api.BatchedAgents)")


def state_problem(state: dict) -> str | None:
    """What keeps a state_dict() result from being saved as an agent file and its checkpoints are (numpy's
    .npz, read back without pickle), or None: each value must be an array (or a number) of numbers or
    booleans. The text follows ``state_dict()`` in a message."""
    for key, value in state.items():
        try:
            array = np.asarray(value)
        except Exception as exc:  # e.g. a ragged list
            return f"[{key!r}] is no array ({type(exc).__name__}: {_one_line(exc)})"
        if array.dtype.kind not in NUMERIC_KINDS:
            held = {"U": "str", "S": "bytes", "O": "object", "V": "structured", "M": "datetime",
                    "m": "timedelta"}.get(array.dtype.kind, str(array.dtype))
            return (f"[{key!r}] holds {held} values, not numbers (a state is saved as numpy arrays of numbers or "
                    f"booleans, read back without pickle)")
    return None


NUMERIC_KINDS = "biufc"
"""The dtype kinds a state array may have: booleans, integers, floats, complex numbers."""


def saved_and_read(state: dict) -> dict[str, np.ndarray]:
    """``state`` written as an agent file's arrays are (np.savez_compressed) and read back without pickle: what
    a later load_state_dict gets."""
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **{k: np.asarray(v) for k, v in state.items()})
    buffer.seek(0)
    with np.load(buffer, allow_pickle=False) as data:
        return {k: data[k] for k in data.files}


def check_state(where: str, cls: type, cfg: Config, states: dict[str, dict]) -> None:
    """States the class must load (a trained run's, read from its file; ``states``: {whose, e.g. "UAV 0's
    state": the arrays}): each tried on one throwaway instance of UAV 0 within its call_limit_s; a UserError
    (exit 2) at the first it refuses, the same in every command."""
    limit = float(getattr(cls, "call_limit_s", 1.0))
    whose = "its constructor"
    try:
        agent = call_limited(limit, cls, cfg, 0, np.random.default_rng(0))
        for whose, state in states.items():
            call_limited(limit, agent.load_state_dict, state)
    except (Exception, CallTooLong) as exc:
        raise UserError(f"{where}: {cls.__name__}.load_state_dict refused {whose}: "
                        f"{type(exc).__name__}: {_one_line(exc)[:300]}") from None


def same_class(name: str, cls: type) -> bool:
    """Whether ``name`` (an entry-point name or pkg.module:Class) names ``cls``, without importing anything: a
    name from a recording made elsewhere must not pick code that runs. A module path is looked up only among
    the modules already imported (``cls``'s own, and what importing it imported)."""
    spec = name if ":" in name else registered().get(name)
    if spec is None:
        return False
    module_name, _, attr = spec.partition(":")
    obj = sys.modules.get(module_name)
    for part in attr.split("."):
        obj = getattr(obj, part, None) if obj is not None else None
    return obj is cls


def class_path(cls: type) -> str:
    """``cls`` as pkg.module:Class."""
    return f"{cls.__module__}:{cls.__qualname__}"


def checkpoint_problem(cls: type, cfg: Config) -> str | None:
    """Why a training of ``cls`` cannot be checkpointed (its instance does not pickle), or None. The trainer
    checkpoints an API class by pickling its instances: their attributes, and the class by its import path."""
    import pickle
    try:
        agent = call_limited(float(getattr(cls, "call_limit_s", 1.0)), cls, cfg, 0, np.random.default_rng(0))
        pickle.dumps(agent, protocol=pickle.HIGHEST_PROTOCOL)
    except (Exception, CallTooLong) as exc:
        return f"its instances cannot be pickled ({type(exc).__name__}: {_one_line(exc)})"
    return None


def trial_view(cfg: Config):
    """The view of UAV 0 hovering at the area's centre at the first step, nothing around it: the trial step."""
    from agents.api import LocalView, sensing
    centre = cfg.scenario.area_m / 2.0
    sense_m, sectors = sensing(cfg)
    return LocalView(uav=0, episode=0, step=0, pos=(centre, centre), vehicles_in_range=0, queued_packets=0,
                     relayed=0, covered=0, energy_j=0.0, speed_max=float(cfg.scenario.uav_speed_mps),
                     densest_sector=0, exclusive=0, nearest_rsu_m=centre, beacons=(), sense_range_m=sense_m,
                     sense_sectors=sectors)


def load(name: str, cfg: Config, flag: str = "--agent") -> type:
    """resolve + check_instance: the class, ready for a run."""
    cls = resolve(name, flag)
    check_instance(name, cls, cfg, flag)
    return cls


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or "(no message)"


__all__ = ["AGENT_KIND_PREFIX", "ENTRY_POINT_GROUP", "check_instance", "check_state", "checkpoint_problem", "class_path",
           "load", "registered", "resolve", "same_class", "saved_and_read", "state_problem"]
