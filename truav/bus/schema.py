"""TRUAV wire schema: the one module that encodes and decodes bus messages.

Every message on the bus is a msgpack map.  Six envelope entries come first:

``v``     schema version (:data:`SCHEMA_VERSION`)
``kind``  one of :data:`KINDS`
``src``   sender id: ``world``, ``uav/<i>``, ``recorder``, ``fault``, ``replay``
``seq``   per-sender, per-kind counter (0, 1, 2, ...)
``t``     sender wall clock when stamped, int nanoseconds
``inc``   the sender's incarnation: a random 63-bit id drawn once per :class:`Sequencer`
          (one per process start), so a restarted sender, whose ``seq`` starts from 0
          again, is a new stream (``(src, inc, kind)``) and not a run of duplicates;
          0 = unknown (a payload from before incarnations, which still decodes)

followed by the fields of that kind; one frozen dataclass per kind below
(:class:`Tick`, :class:`Obs`, :class:`Beacon`, :class:`Action`,
:class:`Metrics`, :class:`Fault`, :class:`Control`, :class:`Positions`, and
the centralized scheme's :class:`State` upload and :class:`Command`, and an
agent's :class:`Health` report).  The
envelope fields ``src``/``seq``/``t``/``inc`` are keyword-only with "unstamped"
defaults; a :class:`Sequencer` (or :class:`truav.bus.transport.Bus`, which owns
one) stamps them just before sending.

Messages validate themselves on construction and :func:`decode` builds them
from untrusted bytes, so any message object that exists is valid.  ``decode``
raises only :class:`SchemaError` (a ``ValueError``) for hostile input: not
msgpack, not a map, wrong/missing version, unknown kind, missing or extra
fields, wrong types, out-of-range values (negative counts, NaN/inf, an action
outside ``[-1, 16)`` (-1: hover), a UAV id outside ``[0, 1024)``) and oversized payloads.
``SchemaError.reason`` is one of the short ``R_*`` codes, handy as a counter
key.

Lenient in, strict out: constructors accept numpy scalars/arrays and ints for
float fields, and store plain Python ``int``/``float``/``tuple`` values.
Floats go on the wire as float64, so a decode/encode round-trip is exact.

Size (measured, pinned by ``tests/test_schema.py``): a stamped beacon from
``uav/3`` at tick 1234 with a 19-digit ns timestamp is 114 bytes: map header
1 B, envelope with its keys 54 B (13 of them the incarnation), body 59 B (of
which the four float64 of pos/vel are 36 B).  The worst case (``uav/1023``,
64-bit seq/tick/t) is :data:`BEACON_MAX_BYTES` = 133 bytes.  Zenoh adds its own framing on top.
Every kind but ``positions`` and ``control`` must fit in
:data:`MAX_SMALL_PAYLOAD_BYTES`.
"""

from __future__ import annotations

import copy
import math
import os
import re
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, fields
from math import isfinite
from types import MappingProxyType
from typing import Any, ClassVar, TypeVar, Union

import msgpack
import numpy as np

from truav.bus import keys
from truav.bus.keys import MAX_UAVS
from world.uavs import HOVER, N_ACTIONS  # noqa: F401  (re-exported: an action is an int in [0, N_ACTIONS), or
# HOVER, an agent's explicit hover: the central scheme's autopilot without commands)

SCHEMA_VERSION = 1

# --- kinds ----------------------------------------------------------------
KIND_TICK = "tick"
KIND_OBS = "obs"
KIND_BEACON = "beacon"
KIND_ACTION = "action"
KIND_METRICS = "metrics"
KIND_FAULT = "fault"
KIND_CONTROL = "control"
KIND_POSITIONS = "positions"
KIND_STATE = "state"
KIND_COMMAND = "command"
KIND_HEALTH = "health"

# --- enumerated string values ------------------------------------------------
SCOPE_STEP = "step"
SCOPE_EPISODE = "episode"
SCOPES = (SCOPE_STEP, SCOPE_EPISODE)

PHASE_START = "start"
PHASE_END = "end"
PHASES = (PHASE_START, PHASE_END)

FAULT_LOSS = "loss"
FAULT_LATENCY = "latency"
FAULT_PARTITION = "partition"
FAULT_CRASH = "crash"
FAULT_FREEZE = "freeze"
FAULT_KINDS = (FAULT_LOSS, FAULT_LATENCY, FAULT_PARTITION, FAULT_CRASH, FAULT_FREEZE)

# --- limits -------------------------------------------------------------------
MAX_PAYLOAD_BYTES = 1 << 20  # 1 MiB: the largest payload of any kind (positions)
MAX_CONTROL_PAYLOAD_BYTES = 256 << 10  # control messages may carry plans
MAX_SMALL_PAYLOAD_BYTES = 16 << 10  # everything else
BEACON_MAX_BYTES = 133  # worst case of a stamped beacon, see module docstring
MAX_VEHICLE_POSITIONS = 32_768  # positions.vehicles cap (x,y float64 each: ~19 B)
MAX_SRC_LEN = 64
MAX_NAME_LEN = 64  # metric names, param names, fault kinds, control commands
MAX_TARGET_LEN = 128
MAX_PARAM_STR_LEN = 256
MAX_METRIC_VALUES = 128
MAX_FAULT_PARAMS = 32
MAX_ARGS_DEPTH = 16
MAX_ARGS_NODES = 65_536
MAX_ARGS_STR_LEN = 64 << 10
MAX_HEALTH_REASONS = 32  # rejection reasons in a health message (there are about 20)
MAX_HEALTH_SENDERS = 8  # the senders most refused, in a health message
INT64_MAX = (1 << 63) - 1
UINT64_MAX = (1 << 64) - 1

# --- SchemaError reasons --------------------------------------------------------
R_NOT_BYTES = "not_bytes"
R_TOO_LARGE = "too_large"
R_NOT_MSGPACK = "not_msgpack"
R_NOT_MAP = "not_map"
R_VERSION = "bad_version"
R_UNKNOWN_KIND = "unknown_kind"
R_MISSING_FIELD = "missing_field"
R_EXTRA_FIELD = "extra_field"
R_BAD_TYPE = "bad_type"
R_OUT_OF_RANGE = "out_of_range"
R_UNSTAMPED = "unstamped"

_SRC_RE = re.compile(r"[A-Za-z0-9_-]+(?:/[A-Za-z0-9_-]+)*")
_NAME_RE = re.compile(r"[A-Za-z0-9_.-]+")
_ENVELOPE_KEYS = ("v", "kind", "src", "seq", "t", "inc")


class SchemaError(ValueError):
    """A message that does not follow the schema.

    ``reason`` is one of the ``R_*`` constants; ``src`` is the sender id when it
    could be read from the offending payload (for log lines), else None.
    """

    def __init__(self, reason: str, detail: str = "", *, src: str | None = None) -> None:
        super().__init__(f"{reason}: {detail}" if detail else reason)
        self.reason = reason
        self.detail = detail
        self.src = src


# --- field checks: (field path, value) -> normalised value, or SchemaError --------
Check = Callable[[str, Any], Any]

_INT_TYPES = (int, np.integer)
_REAL_TYPES = (int, float, np.integer, np.floating)
_BOOL_TYPES = (bool, np.bool_)


def _int(lo: int, hi: int) -> Check:
    """An int in ``[lo, hi]`` (bools rejected)."""

    def check(name: str, v: Any) -> int:
        if type(v) is int and lo <= v <= hi:  # the common case first: a plain int (never a bool) in range
            return v
        if isinstance(v, _BOOL_TYPES) or not isinstance(v, _INT_TYPES):
            raise SchemaError(R_BAD_TYPE, f"{name} must be an int, got {type(v).__name__}")
        v = int(v)
        if not lo <= v <= hi:
            raise SchemaError(R_OUT_OF_RANGE, f"{name}={v} outside [{lo}, {hi}]")
        return v

    return check


def _real(lo: float | None = None, *, lo_open: bool = False) -> Check:
    """A finite float (ints accepted), optionally ``>= lo`` (``> lo`` if lo_open)."""

    def check(name: str, v: Any) -> float:
        if type(v) is float and isfinite(v) and (lo is None or (v > lo if lo_open else v >= lo)):  # common case
            return v
        if isinstance(v, _BOOL_TYPES) or not isinstance(v, _REAL_TYPES):
            raise SchemaError(R_BAD_TYPE, f"{name} must be a number, got {type(v).__name__}")
        v = float(v)
        if not math.isfinite(v):
            raise SchemaError(R_OUT_OF_RANGE, f"{name}={v} is not finite")
        if lo is not None and (v <= lo if lo_open else v < lo):
            raise SchemaError(R_OUT_OF_RANGE, f"{name}={v} must be {'>' if lo_open else '>='} {lo}")
        return v

    return check


def _bool(name: str, v: Any) -> bool:
    if not isinstance(v, _BOOL_TYPES):
        raise SchemaError(R_BAD_TYPE, f"{name} must be a bool, got {type(v).__name__}")
    return bool(v)


def _text(max_len: int, pattern: re.Pattern[str] | None = None, *, allow_empty: bool = False) -> Check:
    def check(name: str, v: Any) -> str:
        if not isinstance(v, str):
            raise SchemaError(R_BAD_TYPE, f"{name} must be a str, got {type(v).__name__}")
        if (not v and not allow_empty) or len(v) > max_len:
            raise SchemaError(R_OUT_OF_RANGE, f"{name} must have 1..{max_len} characters")
        if v and pattern is not None and not pattern.fullmatch(v):
            raise SchemaError(R_OUT_OF_RANGE, f"{name}={v[:max_len]!r} has invalid characters")
        return v

    return check


def _choice(options: tuple[str, ...]) -> Check:
    def check(name: str, v: Any) -> str:
        if not isinstance(v, str):
            raise SchemaError(R_BAD_TYPE, f"{name} must be a str, got {type(v).__name__}")
        if v not in options:
            raise SchemaError(R_OUT_OF_RANGE, f"{name}={v[:32]!r} not one of {options}")
        return v

    return check


_finite = _real()
_nonneg = _real(0.0)
_positive = _real(0.0, lo_open=True)
_uint63 = _int(0, INT64_MAX)
_uint64 = _int(0, UINT64_MAX)
_int64 = _int(-INT64_MAX - 1, INT64_MAX)
_uav_id = _int(0, MAX_UAVS - 1)
_n_uavs = _int(0, MAX_UAVS)
_action = _int(0, N_ACTIONS - 1)
_action_or_hover = _int(HOVER, N_ACTIONS - 1)
_sector = _int(0, 16)  # learner.sense_sectors is at most 16; 0 = none sensed
_name = _text(MAX_NAME_LEN, _NAME_RE)
_src = _text(MAX_SRC_LEN, _SRC_RE, allow_empty=True)


def _pad(name: str, v: Any) -> bytes:
    """Opaque padding bytes (the rest of a fixed-size report), at most a small payload."""
    if not isinstance(v, (bytes, bytearray)):
        raise SchemaError(R_BAD_TYPE, f"{name} must be bytes, got {type(v).__name__}")
    if len(v) > MAX_SMALL_PAYLOAD_BYTES:
        raise SchemaError(R_OUT_OF_RANGE, f"{name} has {len(v)} bytes, cap is {MAX_SMALL_PAYLOAD_BYTES}")
    return bytes(v)


def _vec2(name: str, v: Any) -> tuple[float, float]:
    if (type(v) is list or type(v) is tuple) and len(v) == 2:  # the common case: two finite floats
        x, y = v
        if type(x) is float and type(y) is float and isfinite(x) and isfinite(y):
            return (x, y)
    if isinstance(v, np.ndarray):
        v = v.tolist()
    if not isinstance(v, (list, tuple)) or len(v) != 2:
        raise SchemaError(R_BAD_TYPE, f"{name} must be a pair of numbers")
    return (_finite(f"{name}[0]", v[0]), _finite(f"{name}[1]", v[1]))


def _points(max_n: int) -> Check:
    """A list of (x, y) pairs, at most ``max_n``; numpy (n, 2) arrays accepted."""

    def check(name: str, v: Any) -> tuple[tuple[float, float], ...]:
        if isinstance(v, np.ndarray):
            if v.ndim != 2 or (v.size and v.shape[1] != 2) or v.dtype.kind not in "iuf":
                raise SchemaError(R_BAD_TYPE, f"{name} must be an (n, 2) numeric array")
            if len(v) > max_n:
                raise SchemaError(R_OUT_OF_RANGE, f"{name} has {len(v)} points, cap is {max_n}")
            if not np.isfinite(v).all():
                raise SchemaError(R_OUT_OF_RANGE, f"{name} has non-finite coordinates")
            return tuple((float(x), float(y)) for x, y in v.reshape(-1, 2).tolist())
        if not isinstance(v, (list, tuple)):
            raise SchemaError(R_BAD_TYPE, f"{name} must be a list of [x, y]")
        if len(v) > max_n:
            raise SchemaError(R_OUT_OF_RANGE, f"{name} has {len(v)} points, cap is {max_n}")
        return tuple(_vec2(f"{name}[{k}]", p) for k, p in enumerate(v))

    return check


def _str_map(max_entries: int, value_check: Check) -> Check:
    """A map of names to checked values, at most ``max_entries``."""

    def check(name: str, v: Any) -> dict[str, Any]:
        if not isinstance(v, Mapping):
            raise SchemaError(R_BAD_TYPE, f"{name} must be a map")
        if len(v) > max_entries:
            raise SchemaError(R_OUT_OF_RANGE, f"{name} has {len(v)} entries, cap is {max_entries}")
        out: dict[str, Any] = {}
        for k, x in v.items():
            out[_name(f"{name} key", k)] = value_check(f"{name}[{k!r}]", x)
        return out

    return check


_param_text = _text(MAX_PARAM_STR_LEN, allow_empty=True)


_printable_src = _text(MAX_SRC_LEN, re.compile(r"[ -~]+"))  # a sender as a receiver names it: "?", "(other senders)"


def _count_map(max_entries: int, key_check: Check) -> Check:
    """A map of checked keys to counts (ints >= 0), at most ``max_entries``."""

    def check(name: str, v: Any) -> dict[str, int]:
        if not isinstance(v, Mapping):
            raise SchemaError(R_BAD_TYPE, f"{name} must be a map")
        if len(v) > max_entries:
            raise SchemaError(R_OUT_OF_RANGE, f"{name} has {len(v)} entries, cap is {max_entries}")
        return {key_check(f"{name} key", k): _uint63(f"{name}[{k!r}]", x) for k, x in v.items()}

    return check


def _param_value(name: str, v: Any) -> float | int | str:
    if isinstance(v, str):
        return _param_text(name, v)
    if isinstance(v, _INT_TYPES) and not isinstance(v, _BOOL_TYPES):
        return _int64(name, v)
    if isinstance(v, (float, np.floating)):
        return _finite(name, v)
    raise SchemaError(R_BAD_TYPE, f"{name} must be a float, int or str, got {type(v).__name__}")


def _json_like(name: str, v: Any) -> dict[str, Any]:
    """Control ``args``: a map of JSON-like values (None, bool, int, float, str, list, map)."""
    budget = [MAX_ARGS_NODES]

    def walk(path: str, x: Any, depth: int) -> Any:
        budget[0] -= 1
        if budget[0] < 0:
            raise SchemaError(R_OUT_OF_RANGE, f"{name} has more than {MAX_ARGS_NODES} values")
        if depth > MAX_ARGS_DEPTH:
            raise SchemaError(R_OUT_OF_RANGE, f"{path} nests deeper than {MAX_ARGS_DEPTH}")
        if x is None or isinstance(x, bool):
            return x
        if isinstance(x, np.bool_):
            return bool(x)
        if isinstance(x, _INT_TYPES):
            return _int64(path, x)
        if isinstance(x, (float, np.floating)):
            return _finite(path, x)
        if isinstance(x, str):
            if len(x) > MAX_ARGS_STR_LEN:
                raise SchemaError(R_OUT_OF_RANGE, f"{path} is longer than {MAX_ARGS_STR_LEN}")
            return x
        if isinstance(x, (list, tuple)):
            return [walk(f"{path}[{k}]", y, depth + 1) for k, y in enumerate(x)]
        if isinstance(x, Mapping):
            out = {}
            for k, y in x.items():
                if not isinstance(k, str) or len(k) > MAX_NAME_LEN:
                    raise SchemaError(R_BAD_TYPE, f"{path} keys must be str of <= {MAX_NAME_LEN} chars")
                out[k] = walk(f"{path}.{k}", y, depth + 1)
            return out
        raise SchemaError(R_BAD_TYPE, f"{path} has unsupported type {type(x).__name__}")

    if not isinstance(v, Mapping):
        raise SchemaError(R_BAD_TYPE, f"{name} must be a map")
    return walk(name, v, 0)


# --- message classes ------------------------------------------------------------------
@dataclass(frozen=True, kw_only=True)
class Envelope:
    """Envelope fields shared by every kind; ``src=""`` means "not stamped yet"."""

    KIND: ClassVar[str] = ""
    PLACE: ClassVar[tuple[str, ...]] = ()
    """The key it is published on, after ``truav/<run>/``: its first chunks, named in :mod:`truav.bus.keys`
    (a ``uav`` key: ``uav``, then the UAV id, then its last chunk; see :mod:`truav.bus.placement`)."""
    CHECKS: ClassVar[Mapping[str, Check]] = MappingProxyType({})
    _PLAN: ClassVar[tuple[tuple[str, str, Check], ...]] = ()
    """(field, "kind.field", check) for every field, envelope first; set by _build_registry."""

    src: str = ""
    seq: int = 0
    t: int = 0
    inc: int = 0

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        for name, path, check in self._PLAN:
            set_(self, name, check(path, getattr(self, name)))


@dataclass(frozen=True)
class Tick(Envelope):
    """World clock tick: agents must answer with an action before ``deadline_ms``."""

    KIND: ClassVar[str] = KIND_TICK
    PLACE: ClassVar[tuple[str, ...]] = (keys.WORLD, keys.TICK)
    CHECKS: ClassVar[Mapping[str, Check]] = MappingProxyType(
        {"tick": _uint63, "episode": _uint63, "sim_time": _nonneg, "deadline_ms": _positive, "n_uavs": _n_uavs}
    )
    tick: int
    episode: int
    sim_time: float
    deadline_ms: float
    n_uavs: int


@dataclass(frozen=True)
class Obs(Envelope):
    """World -> agent ``uav``: its local observation and last-step reward terms."""

    KIND: ClassVar[str] = KIND_OBS
    PLACE: ClassVar[tuple[str, ...]] = (keys.UAV, keys.OBS)
    CHECKS: ClassVar[Mapping[str, Check]] = MappingProxyType(
        {
            "tick": _uint63,
            "episode": _uint63,
            "uav": _uav_id,
            "pos": _vec2,
            "vehicles_in_range": _uint63,
            "queued_packets": _uint63,
            "relayed": _uint63,
            "covered": _uint63,
            "energy_j": _nonneg,
            "speed_max": _nonneg,
            "done": _bool,
            "densest_sector": _sector,
        }
    )
    tick: int
    episode: int
    uav: int
    pos: tuple[float, float]
    vehicles_in_range: int
    queued_packets: int
    relayed: int
    covered: int
    energy_j: float
    speed_max: float
    done: bool
    densest_sector: int = 0
    """Sensing of denser areas (learner.sense_range_m): 1 + the densest direction sector, 0 none / off."""


@dataclass(frozen=True)
class Beacon(Envelope):
    """Agent ``uav`` -> all: lightweight position/velocity beacon."""

    KIND: ClassVar[str] = KIND_BEACON
    PLACE: ClassVar[tuple[str, ...]] = (keys.UAV, keys.BEACON)
    CHECKS: ClassVar[Mapping[str, Check]] = MappingProxyType(
        {"uav": _uav_id, "tick": _uint63, "pos": _vec2, "vel": _vec2}
    )
    uav: int
    tick: int
    pos: tuple[float, float]
    vel: tuple[float, float]


@dataclass(frozen=True)
class Action(Envelope):
    """Agent ``uav`` -> world: chosen action for ``tick``, in ``[0, N_ACTIONS)``."""

    KIND: ClassVar[str] = KIND_ACTION
    PLACE: ClassVar[tuple[str, ...]] = (keys.UAV, keys.ACTION)
    CHECKS: ClassVar[Mapping[str, Check]] = MappingProxyType(
        {"uav": _uav_id, "tick": _uint63, "action": _action_or_hover})
    uav: int
    tick: int
    action: int


@dataclass(frozen=True)
class State(Envelope):
    """Agent ``uav`` -> central controller: its local state report for ``tick`` (scheme central).

    The values the controller's joint state and reward need (agents.central.uav_states), and
    ``pad``: the message is padded to ``central.upload_bytes``, the report size the in-process
    control-plane model charges, so the traffic measured on the bus is the modelled one."""

    KIND: ClassVar[str] = KIND_STATE
    PLACE: ClassVar[tuple[str, ...]] = (keys.UAV, keys.STATE)
    CHECKS: ClassVar[Mapping[str, Check]] = MappingProxyType(
        {
            "uav": _uav_id,
            "tick": _uint63,
            "episode": _uint63,
            "step": _uint63,
            "pos": _vec2,
            "vehicles_in_range": _uint63,
            "queued_packets": _uint63,
            "relayed": _uint63,
            "covered": _uint63,
            "energy_j": _nonneg,
            "done": _bool,
            "pad": _pad,
        }
    )
    uav: int
    tick: int
    episode: int
    step: int
    """Step within the episode (the world's t when the observation was made)."""
    pos: tuple[float, float]
    vehicles_in_range: int
    queued_packets: int
    relayed: int
    covered: int
    energy_j: float
    done: bool
    pad: bytes


@dataclass(frozen=True)
class Command(Envelope):
    """Central controller -> agent ``uav``: the action to fly from ``tick`` on, padded to
    ``central.download_bytes`` (see :class:`State`)."""

    KIND: ClassVar[str] = KIND_COMMAND
    PLACE: ClassVar[tuple[str, ...]] = (keys.CONTROLLER,)
    CHECKS: ClassVar[Mapping[str, Check]] = MappingProxyType(
        {"uav": _uav_id, "tick": _uint63, "action": _action, "pad": _pad})
    uav: int
    tick: int
    action: int
    pad: bytes


@dataclass(frozen=True)
class Metrics(Envelope):
    """World -> recorder: named finite numbers for one step or one episode."""

    KIND: ClassVar[str] = KIND_METRICS
    PLACE: ClassVar[tuple[str, ...]] = (keys.METRICS_ROOT,)
    CHECKS: ClassVar[Mapping[str, Check]] = MappingProxyType(
        {
            "scope": _choice(SCOPES),
            "tick": _uint63,
            "episode": _uint63,
            "values": _str_map(MAX_METRIC_VALUES, _finite),
        }
    )
    scope: str
    tick: int
    episode: int
    values: dict[str, float]


@dataclass(frozen=True)
class Fault(Envelope):
    """Fault controller -> all: a fault of kind ``fault`` starts or ends on ``target``."""

    KIND: ClassVar[str] = KIND_FAULT
    PLACE: ClassVar[tuple[str, ...]] = (keys.FAULT_ROOT,)
    CHECKS: ClassVar[Mapping[str, Check]] = MappingProxyType(
        {
            "fault": _name,
            "phase": _choice(PHASES),
            "target": _text(MAX_TARGET_LEN),
            "params": _str_map(MAX_FAULT_PARAMS, _param_value),
        }
    )
    fault: str
    phase: str
    target: str
    params: dict[str, float | int | str]


@dataclass(frozen=True)
class Control(Envelope):
    """Operator/tool -> all: a command (e.g. a replay or fault plan) with JSON-like args."""

    KIND: ClassVar[str] = KIND_CONTROL
    PLACE: ClassVar[tuple[str, ...]] = (keys.CONTROL_ROOT,)
    CHECKS: ClassVar[Mapping[str, Check]] = MappingProxyType({"command": _name, "args": _json_like})
    command: str
    args: dict[str, Any]


@dataclass(frozen=True)
class Positions(Envelope):
    """World -> recorder: all UAV and (capped) vehicle positions, for maps."""

    KIND: ClassVar[str] = KIND_POSITIONS
    PLACE: ClassVar[tuple[str, ...]] = (keys.WORLD, keys.POSITIONS)
    CHECKS: ClassVar[Mapping[str, Check]] = MappingProxyType(
        {"tick": _uint63, "uavs": _points(MAX_UAVS), "vehicles": _points(MAX_VEHICLE_POSITIONS)}
    )
    tick: int
    uavs: tuple[tuple[float, float], ...]
    vehicles: tuple[tuple[float, float], ...]


HEALTH_PERIOD_S = 1.0
"""How often an agent publishes its Health report (and once at its start)."""
DEFAULT_LOCKSTEP_WAIT_S = 60.0
"""Lock-step (``--lockstep-wait``): how long the world waits for a live agent's action and an agent for a
live peer's beacon (a paused or swapped-out process) before going on without it; the run is then no
longer exact, and says so (the supervisor)."""
LOCKSTEP_JOIN_GRACE_S = 2.0
"""Lock-step: a peer not heard from since it (re)joined is waited for this long only: a restarted agent
joins between the world's ticks and gets no observation before the next one, so its beacon of the
current tick never comes."""


@dataclass(frozen=True)
class Health(Envelope):
    """Agent ``uav`` -> supervisor, status, recorder: what it refused so far, every HEALTH_PERIOD_S.

    Bounded whatever a flood sends it: ``rejected`` by reason (the fixed ``R_*`` codes), ``senders``
    only the :data:`MAX_HEALTH_SENDERS` most refused senders."""

    KIND: ClassVar[str] = KIND_HEALTH
    PLACE: ClassVar[tuple[str, ...]] = (keys.UAV, keys.HEALTH)
    CHECKS: ClassVar[Mapping[str, Check]] = MappingProxyType(
        {
            "uav": _uav_id,
            "last_tick": _int(-1, (1 << 63) - 1),
            "steps": _uint63,
            "stale_obs_skipped": _uint63,
            "rejected": _count_map(MAX_HEALTH_REASONS, _name),
            "senders": _count_map(MAX_HEALTH_SENDERS, _printable_src),
        }
    )
    uav: int
    last_tick: int
    """The last observation's tick it answered (-1: none yet); not ``tick``, so an agent far behind
    the world still gets its report through the receivers' tick window."""
    steps: int
    stale_obs_skipped: int
    rejected: dict[str, int]
    senders: dict[str, int]


Message = Union[Tick, Obs, Beacon, Action, Metrics, Fault, Control, Positions, State, Command, Health]
M = TypeVar("M", bound=Envelope)

_ENVELOPE_FIELDS = frozenset(f.name for f in fields(Envelope))


def _build_registry() -> Mapping[str, type[Envelope]]:
    registry: dict[str, type[Envelope]] = {}
    for cls in (Tick, Obs, Beacon, Action, Metrics, Fault, Control, Positions, State, Command, Health):
        body = [f.name for f in fields(cls) if f.name not in _ENVELOPE_FIELDS]
        assert body == list(cls.CHECKS), f"{cls.__name__}: CHECKS must list the fields in order"
        checks = {"src": _src, "seq": _uint64, "t": _uint63, "inc": _uint63, **cls.CHECKS}
        cls._PLAN = tuple((name, f"{cls.KIND}.{name}", check) for name, check in checks.items())
        registry[cls.KIND] = cls
    return MappingProxyType(registry)


MESSAGE_CLASSES: Mapping[str, type[Envelope]] = _build_registry()
KINDS: tuple[str, ...] = tuple(MESSAGE_CLASSES)
_BODY_FIELDS: Mapping[str, tuple[str, ...]] = MappingProxyType(
    {kind: tuple(cls.CHECKS) for kind, cls in MESSAGE_CLASSES.items()}
)
_WIRE_KEYS: Mapping[str, frozenset[str]] = MappingProxyType(
    {kind: frozenset((*_ENVELOPE_KEYS, *body)) for kind, body in _BODY_FIELDS.items()}
)
_LEGACY_WIRE_KEYS: Mapping[str, frozenset[str]] = MappingProxyType(
    {kind: keys_ - {"inc"} for kind, keys_ in _WIRE_KEYS.items()})
"""Payloads from before incarnations (older recordings): decoded with ``inc`` 0."""
_SIZE_LIMIT: Mapping[str, int] = MappingProxyType(
    {
        kind: MAX_PAYLOAD_BYTES
        if kind == KIND_POSITIONS
        else MAX_CONTROL_PAYLOAD_BYTES
        if kind == KIND_CONTROL
        else MAX_SMALL_PAYLOAD_BYTES
        for kind in KINDS
    }
)


# msgpack limits per kind, applied while parsing: the longest map, array, str of any valid message
# of that kind (the envelope's src and kind strings included); no bin or ext type is ever valid.
# (max_map_len 18: an obs, 6 envelope keys + 12 fields.)
_SMALL_LIMITS = {"max_map_len": 18, "max_array_len": 2, "max_str_len": MAX_SRC_LEN, "max_bin_len": 0,
                 "max_ext_len": 0}
_UNPACK_LIMITS: Mapping[str, Mapping[str, int]] = MappingProxyType({
    KIND_TICK: _SMALL_LIMITS, KIND_OBS: _SMALL_LIMITS, KIND_BEACON: _SMALL_LIMITS, KIND_ACTION: _SMALL_LIMITS,
    KIND_METRICS: {**_SMALL_LIMITS, "max_map_len": MAX_METRIC_VALUES, "max_array_len": 0},
    KIND_FAULT: {**_SMALL_LIMITS, "max_map_len": MAX_FAULT_PARAMS, "max_array_len": 0,
                 "max_str_len": max(MAX_PARAM_STR_LEN, MAX_TARGET_LEN)},
    KIND_POSITIONS: {**_SMALL_LIMITS, "max_array_len": MAX_VEHICLE_POSITIONS},
    KIND_STATE: {**_SMALL_LIMITS, "max_map_len": 20, "max_bin_len": MAX_SMALL_PAYLOAD_BYTES},
    KIND_COMMAND: {**_SMALL_LIMITS, "max_bin_len": MAX_SMALL_PAYLOAD_BYTES},
    KIND_HEALTH: {**_SMALL_LIMITS, "max_map_len": max(MAX_HEALTH_REASONS, MAX_HEALTH_SENDERS, 18), "max_array_len": 0},
    KIND_CONTROL: {**_SMALL_LIMITS, "max_map_len": MAX_ARGS_NODES, "max_array_len": MAX_ARGS_NODES,
                   "max_str_len": MAX_ARGS_STR_LEN},
})
_LOOSE_LIMITS: Mapping[str, int] = MappingProxyType(
    {k: max(lim[k] for lim in _UNPACK_LIMITS.values()) for k in _SMALL_LIMITS})


def size_limit(kind: str) -> int:
    """Largest encoded size in bytes accepted for ``kind``."""
    return _SIZE_LIMIT[kind]


# --- encode / decode ------------------------------------------------------------------
def encode(msg: Message) -> bytes:
    """Encode a stamped message to msgpack bytes; SchemaError if unstamped or too large."""
    kind = getattr(type(msg), "KIND", None)
    if MESSAGE_CLASSES.get(kind) is not type(msg):  # type: ignore[arg-type]
        raise SchemaError(R_BAD_TYPE, f"cannot encode {type(msg).__name__}: not a schema message")
    if not msg.src:
        raise SchemaError(R_UNSTAMPED, f"{kind} has no src; stamp it with a Sequencer (or publish via a Bus)")
    wire: dict[str, Any] = {"v": SCHEMA_VERSION, "kind": kind, "src": msg.src, "seq": msg.seq, "t": msg.t,
                            "inc": msg.inc}
    for name in _BODY_FIELDS[kind]:
        wire[name] = getattr(msg, name)
    try:
        data = msgpack.packb(wire, use_bin_type=True)
    except Exception as exc:  # only reachable if a caller mutated a message's dict fields
        raise SchemaError(R_BAD_TYPE, f"{kind} cannot be packed: {exc}", src=msg.src) from None
    if len(data) > _SIZE_LIMIT[kind]:
        raise SchemaError(R_TOO_LARGE, f"{kind} is {len(data)} bytes, limit {_SIZE_LIMIT[kind]}", src=msg.src)
    return data


def unpack_limits(kind: str | None) -> Mapping[str, int]:
    """msgpack Unpacker limits for a payload of ``kind`` (None: the loosest of any kind)."""
    return _UNPACK_LIMITS.get(kind, _LOOSE_LIMITS) if kind is not None else _LOOSE_LIMITS


def decode(data: bytes | bytearray | memoryview, expect: str | None = None) -> Message:
    """Decode and validate one message; raises only SchemaError on bad input.

    ``expect`` is the kind the key carries (see ``transport.expected_kind``):
    the payload is then held to that kind's size and msgpack limits *before*
    parsing (a 1 MB "observation" with 124k extra keys costs a length check,
    not a parse).  Without it, the loosest limits of any kind apply."""
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise SchemaError(R_NOT_BYTES, f"expected bytes, got {type(data).__name__}")
    limit = _SIZE_LIMIT.get(expect, MAX_PAYLOAD_BYTES) if expect is not None else MAX_PAYLOAD_BYTES
    if len(data) > limit:
        raise SchemaError(R_TOO_LARGE, f"{len(data)} bytes, limit {limit}" + (f" for {expect}" if expect else ""))
    try:
        unpacker = msgpack.Unpacker(raw=False, strict_map_key=True, use_list=True,
                                    max_buffer_size=max(limit, 1), **unpack_limits(expect))
        unpacker.feed(data)
        obj = unpacker.unpack()
        if unpacker.tell() != len(data):
            raise msgpack.ExtraData(obj, b"")
    except ValueError as exc:
        if "exceeds max" in str(exc):  # msgpack's own limits: refused while parsing, before building it
            raise SchemaError(R_TOO_LARGE, str(exc)[:80]) from None
        raise SchemaError(R_NOT_MSGPACK, f"{type(exc).__name__}: {str(exc)[:80] or 'invalid msgpack'}") from None
    except Exception as exc:  # msgpack raises many types (OutOfData, ExtraData, StackError, ...)
        raise SchemaError(R_NOT_MSGPACK, f"{type(exc).__name__}: {str(exc)[:80] or 'invalid msgpack'}") from None
    if not isinstance(obj, dict):
        raise SchemaError(R_NOT_MAP, f"top level is {type(obj).__name__}")
    src = obj.get("src")
    src = src if isinstance(src, str) and len(src) <= MAX_SRC_LEN else None
    try:
        return _from_map(obj, len(data))
    except SchemaError as exc:
        exc.src = src
        raise
    except Exception as exc:  # defensive: validators should only raise SchemaError
        raise SchemaError(R_BAD_TYPE, f"{type(exc).__name__}: {str(exc)[:80]}", src=src) from None


def peek_src(data: bytes | bytearray | memoryview) -> str | None:
    """Best-effort sender id of a payload without decoding its body (None if unreadable).

    Reads only the first envelope entries, so it is cheap even for a large
    ``positions`` payload; the result is *not* validated against the schema.
    """
    try:
        unpacker = msgpack.Unpacker(raw=False, strict_map_key=True, max_buffer_size=max(len(data), 1))
        unpacker.feed(data)
        for _ in range(min(unpacker.read_map_header(), len(_ENVELOPE_KEYS))):
            if unpacker.unpack() == "src":
                src = unpacker.unpack()
                return src if isinstance(src, str) and 0 < len(src) <= MAX_SRC_LEN else None
            unpacker.skip()
    except Exception:  # hostile bytes: any msgpack failure just means "unknown"
        return None
    return None


def _from_map(obj: dict[Any, Any], size: int) -> Message:
    if "v" not in obj:
        raise SchemaError(R_VERSION, "missing schema version 'v'")
    v = obj["v"]
    if type(v) is not int or v != SCHEMA_VERSION:
        raise SchemaError(R_VERSION, f"version {v!r:.20}, expected {SCHEMA_VERSION}")
    kind = obj.get("kind")
    if not isinstance(kind, str) or kind not in MESSAGE_CLASSES:
        raise SchemaError(R_UNKNOWN_KIND, f"kind {kind!r:.40}")
    if size > _SIZE_LIMIT[kind]:
        raise SchemaError(R_TOO_LARGE, f"{kind} is {size} bytes, limit {_SIZE_LIMIT[kind]}")
    if obj.keys() != _WIRE_KEYS[kind]:
        if obj.keys() == _LEGACY_WIRE_KEYS[kind]:  # an older sender: incarnation unknown
            obj = {**obj, "inc": 0}
        else:
            expected = (*_ENVELOPE_KEYS, *_BODY_FIELDS[kind])
            missing = [k for k in expected if k not in obj]
            if missing:
                raise SchemaError(R_MISSING_FIELD, f"{kind} lacks {missing}")
            extra = [k for k in obj if k not in expected]
            raise SchemaError(R_EXTRA_FIELD, f"{kind} has unexpected {[repr(k)[:40] for k in extra[:5]]}")
    if obj["src"] == "":
        raise SchemaError(R_UNSTAMPED, f"{kind} has an empty src")
    cls = MESSAGE_CLASSES[kind]
    # The checks the constructor would run, without its keyword plumbing (decode is the hot path:
    # every agent decodes its 19 neighbours' beacons each tick).
    msg = object.__new__(cls)
    msg.__dict__.update({name: check(path, obj[name]) for name, path, check in cls._PLAN})
    return msg  # type: ignore[return-value]


def padded(msg: M, size: int) -> M:
    """A copy of a stamped ``msg`` whose ``pad`` makes its encoding ``size`` bytes long (or up to
    2 bytes short, where msgpack's bin length header grows), or unpadded when it is longer anyway."""
    rest = len(encode(_with_pad(msg, b""))) - 2  # without the empty bin's 2 bytes

    def total(n: int) -> int:
        return rest + n + (2 if n < 256 else 3 if n < 65536 else 5)

    fits = [n for n in range(max(size - rest - 5, 0), max(size - rest - 1, 0)) if total(n) <= size]
    return _with_pad(msg, bytes(max(fits, default=0)))


def _with_pad(msg: M, pad: bytes) -> M:
    out = copy.copy(msg)
    object.__setattr__(out, "pad", pad)
    return out


# --- stamping ---------------------------------------------------------------------------
def new_incarnation() -> int:
    """A fresh incarnation id: 63 random bits from the OS, never 0 (0 means "unknown").

    It names a process lifetime, not simulation randomness, so it comes from ``os.urandom``
    and not from the run's seeded generators (two starts with the same seed must differ)."""
    while True:
        inc = int.from_bytes(os.urandom(8), "little") >> 1
        if inc:
            return inc


class Sequencer:
    """Stamps ``src``, ``seq`` (per kind, from 0), ``t`` and ``inc`` on outgoing messages.

    ``clock`` returns int nanoseconds (default :func:`time.time_ns`); inject a
    fake for deterministic tests.  ``incarnation`` (default :func:`new_incarnation`)
    tells this numbering apart from that of an earlier or later sender of the same
    ``src``.  Thread-safe.
    """

    def __init__(self, src: str, clock: Callable[[], int] = time.time_ns, incarnation: int | None = None) -> None:
        self._src = _src("src", src)
        if not self._src:
            raise ValueError("Sequencer src must be non-empty")
        self._inc = new_incarnation() if incarnation is None else _uint63("inc", incarnation)
        self._clock = clock
        self._next: dict[str, int] = {}
        self._lock = threading.Lock()

    @property
    def src(self) -> str:
        return self._src

    @property
    def incarnation(self) -> int:
        return self._inc

    def stamp(self, msg: M) -> M:
        """A copy of ``msg`` with this sender's src and incarnation, the next seq of its kind and t=clock()."""
        kind = type(msg).KIND
        if MESSAGE_CLASSES.get(kind) is not type(msg):
            raise SchemaError(R_BAD_TYPE, f"cannot stamp {type(msg).__name__}: not a schema message")
        with self._lock:
            seq = self._next.get(kind, 0)
            self._next[kind] = seq + 1
            t = _uint63(f"{kind}.t", self._clock())
        stamped = copy.copy(msg)  # the body is already validated: skip __post_init__
        object.__setattr__(stamped, "src", self._src)
        object.__setattr__(stamped, "seq", seq)
        object.__setattr__(stamped, "t", t)
        object.__setattr__(stamped, "inc", self._inc)
        return stamped
