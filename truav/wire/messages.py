"""The message kinds of the wire schema (:mod:`truav.wire.schema`): one frozen dataclass per kind, which
validates itself on construction, its key placement (``PLACE``), the registry by kind and the size
and parsing limits of each kind."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import MISSING, dataclass, field, fields
from types import MappingProxyType
from typing import Any, ClassVar, TypeVar, Union

import numpy as _np

from truav.wire import keys
from truav.wire.field_checks import (Check, _action, _beacon_fields, _action_or_hover, _bool, _choice, _count_map, _counts, _finite, _floats, _int, _ints,
                                    _json_like, _n_uavs, _name, _nonneg, _pad, _param_value, _points, _positive,
                                    _printable_src, _sector, _src, _str_map, _text, _uav_id, _uint63, _uint64, _vec2)
from truav.wire.keys import MAX_UAVS
from truav.wire.schema_names import (
    _ENVELOPE_KEYS, KIND_ACTION, KIND_BEACON, KIND_COMMAND, KIND_CONTROL, KIND_FAULT, KIND_HEALTH, KIND_METRICS,
    KIND_OBS, KIND_OVERRIDE, KIND_POSITIONS, KIND_QSHARE, KIND_REJECTION, KIND_REPLAY_STATUS, KIND_STATE, KIND_TICK, MAX_ARGS_NODES, MAX_DETAIL_LEN,
    MAX_NAME_LEN, MAX_ARGS_STR_LEN, MAX_CONTROL_PAYLOAD_BYTES, MAX_QSHARE_PARTS, MAX_QSHARE_PAYLOAD_BYTES,
    MAX_QSHARE_ROWS, INT64_MAX,
    MAX_FAULT_PARAMS, MAX_HEALTH_REASONS, MAX_HEALTH_SENDERS, MAX_METRIC_VALUES, MAX_PARAM_STR_LEN, MAX_PAYLOAD_BYTES,
    MAX_SMALL_PAYLOAD_BYTES, MAX_SRC_LEN, MAX_TARGET_LEN, MAX_VEHICLE_POSITIONS, PHASES, R_BAD_TYPE, REPLAY_STATES, SCOPES,
    SchemaError)
from truav.wire.schema_names import (KIND_AGENT_SNAPSHOT, KIND_WORLD_SNAPSHOT, MAX_SNAPSHOT_ARRAYS,
                                    MAX_SNAPSHOT_BYTES, MAX_SNAPSHOT_DIMS, R_OUT_OF_RANGE, SNAPSHOT_DTYPES)

NO_FIELDS: Mapping[str, Any] = MappingProxyType({})
"""A beacon's fields when it has none (shared, read-only)."""


# --- message classes ------------------------------------------------------------------
@dataclass(frozen=True, kw_only=True)
class Envelope:
    """Envelope fields shared by every kind; ``src=""`` means "not stamped yet"."""

    KIND: ClassVar[str] = ""
    PLACE: ClassVar[tuple[str, ...]] = ()
    """The key it is published on, after ``truav/<run>/``: its first chunks, named in :mod:`truav.wire.keys`
    (a ``uav`` key: ``uav``, then the UAV id, then its last chunk; see :mod:`truav.bus.placement`)."""
    CHECKS: ClassVar[Mapping[str, Check]] = MappingProxyType({})
    ADDED: ClassVar[tuple[str, ...]] = ()
    """Body fields added since the kind first went on the wire: a payload without them (an older sender's)
    decodes with their defaults."""
    SENT_IF_SET: ClassVar[tuple[str, ...]] = ()
    """ADDED map fields left off the wire while empty (their default, decoded as {}): a message that does
    not use them keeps its size and its decoder's fast path."""
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
            "exclusive": _uint63,
            "disc_offset": _vec2,
            "disc_vehicles": _uint63,
        }
    )
    ADDED: ClassVar[tuple[str, ...]] = ("disc_offset", "disc_vehicles")
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
    exclusive: int = 0
    """Vehicles in this UAV's range and no other UAV's (world.network.EXCLUSIVE; the difference reward)."""
    disc_offset: tuple[float, float] = (0.0, 0.0)
    """With learner.sense_disc: the densest sensed disc's centre minus own position, m (world.network.DISC_DX)."""
    disc_vehicles: int = 0
    """With learner.sense_disc: the vehicles within comm range of that centre; 0 none sensed / off."""


@dataclass(frozen=True)
class Beacon(Envelope):
    """Agent ``uav`` -> all: lightweight position/velocity beacon."""

    KIND: ClassVar[str] = KIND_BEACON
    PLACE: ClassVar[tuple[str, ...]] = (keys.UAV, keys.BEACON)
    ADDED: ClassVar[tuple[str, ...]] = ("fields",)
    SENT_IF_SET: ClassVar[tuple[str, ...]] = ("fields",)
    CHECKS: ClassVar[Mapping[str, Check]] = MappingProxyType(
        {"uav": _uav_id, "tick": _uint63, "pos": _vec2, "vel": _vec2, "fields": _beacon_fields}
    )
    uav: int
    tick: int
    pos: tuple[float, float]
    vel: tuple[float, float]
    fields: Mapping[str, bool | int | float] = field(default_factory=dict)
    """An API agent's beacon_fields() (agents.api), at most MAX_BEACON_FIELDS; on the wire only if any."""


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
class Override(Envelope):
    """Operator -> world: steer UAV ``uav`` from outside, overriding its agent's actions, until released.

    While overridden the world flies the UAV toward ``goal`` (world.steer) instead of its agent's action; the
    agent still gets its observations and learns as usual. ``release`` ends the override (``goal`` and
    ``speed`` are then ignored). The world tells every start and end on ``fault/override``."""

    KIND: ClassVar[str] = KIND_OVERRIDE
    PLACE: ClassVar[tuple[str, ...]] = (keys.CONTROL_ROOT, keys.OVERRIDE)
    CHECKS: ClassVar[Mapping[str, Check]] = MappingProxyType(
        {"uav": _uav_id, "release": _bool, "goal": _vec2, "speed": _nonneg})
    uav: int
    release: bool
    """True: end the override, the agent flies the UAV again."""
    goal: tuple[float, float]
    """The point (x, y) in m to fly to (clipped to the area); the UAV hovers once within one step of it."""
    speed: float
    """m/s to fly at: the half or full speed of the 16 actions nearest to it; 0 (or above the UAV's): full."""


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
    ADDED: ClassVar[tuple[str, ...]] = ("heard",)
    CHECKS: ClassVar[Mapping[str, Check]] = MappingProxyType(
        {
            "uav": _uav_id,
            "last_tick": _int(-1, (1 << 63) - 1),
            "steps": _uint63,
            "stale_obs_skipped": _uint63,
            "rejected": _count_map(MAX_HEALTH_REASONS, _name),
            "senders": _count_map(MAX_HEALTH_SENDERS, _printable_src),
            "heard": _counts(MAX_UAVS),
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
    heard: tuple[int, ...] = ()
    """Beacons it heard so far (this process) from each UAV, indexed by sender id (one entry per UAV of
    the swarm; its own is 0): what its link filter let through, so a report sees receiver-side loss.
    Optional on the wire: a report from before it decodes with ``()``."""


REJECTION_PERIOD_S = 0.1
"""The world sends a UAV at most one rejection this often, however much of it it refuses (the rest counted
in the next one): a flood of bad actions makes the world no amplifier."""


@dataclass(frozen=True)
class Rejection(Envelope):
    """World -> agent ``uav``: what the world refused (or did not apply) of that agent's messages.

    The UAV is the one of the key the refused message arrived on (under ``--secure`` only ``uav/<i>`` may
    put there), never read from its payload. At most one per UAV every :data:`REJECTION_PERIOD_S`: it
    describes the first message refused since the last one and counts all of them by reason."""

    KIND: ClassVar[str] = KIND_REJECTION
    PLACE: ClassVar[tuple[str, ...]] = (keys.UAV, keys.REJECTED)
    CHECKS: ClassVar[Mapping[str, Check]] = MappingProxyType(
        {
            "uav": _uav_id,
            "at_tick": _int(-1, (1 << 63) - 1),
            "reason": _name,
            "refused_kind": _text(MAX_NAME_LEN, allow_empty=True),
            "key": _text(MAX_TARGET_LEN),
            "detail": _text(MAX_DETAIL_LEN, allow_empty=True),
            "counts": _count_map(MAX_HEALTH_REASONS, _name),
        }
    )
    uav: int
    at_tick: int
    """The refused action's tick (a late or stale one), else the world's latest tick when it refused the
    message (-1: before tick 0)."""
    reason: str
    refused_kind: str
    key: str
    detail: str
    counts: dict[str, int]
    """Everything refused of this UAV since the previous rejection, by reason (this one included)."""


KIND_BEACONS = "beacons"
MAX_BATCH_ENTRIES = MAX_UAVS
"""Beacons one batch may carry: at most every UAV of the swarm (the group of its key bounds it further)."""
MAX_BATCH_PAYLOAD_BYTES = 64 << 10
"""A batch's encoded size limit: MAX_BATCH_ENTRIES beacons of about 50 bytes each, and the envelope."""


def _beacon_entries(name: str, v: Any) -> tuple[tuple[int, int, tuple[float, float], tuple[float, float]], ...]:
    """Each entry ``[uav, tick, [x, y], [vx, vy]]``, checked as a beacon's fields are; 1 to MAX_BATCH_ENTRIES."""
    if not isinstance(v, (list, tuple)) or not 1 <= len(v) <= MAX_BATCH_ENTRIES:
        raise SchemaError(R_BAD_TYPE, f"{name} must be a list of 1 to {MAX_BATCH_ENTRIES} beacons")
    out = []
    for k, e in enumerate(v):
        if not isinstance(e, (list, tuple)) or len(e) != 4:
                raise SchemaError(R_BAD_TYPE, f"{name}[{k}] must be [uav, tick, [x, y], [vx, vy]]")
        out.append((_uav_id(f"{name}[{k}].uav", e[0]), _uint63(f"{name}[{k}].tick", e[1]),
                    _vec2(f"{name}[{k}].pos", e[2]), _vec2(f"{name}[{k}].vel", e[3])))
    return tuple(out)


@dataclass(frozen=True)
class Beacons(Envelope):
    """An agent process -> all (``--batch-beacons``): the beacons of the UAVs it hosts, one message per tick.

    Sent on ``group/<first>-<last>/beacons`` by ``uav/<first>``; it may carry only the UAVs its key names
    (:func:`truav.bus.placement.check_placement`). Receivers split it into beacons, each then checked,
    filtered per link and counted as if its UAV had sent it alone (agents.process.shared_beacons)."""

    KIND: ClassVar[str] = KIND_BEACONS
    PLACE: ClassVar[tuple[str, ...]] = (keys.GROUP,)
    CHECKS: ClassVar[Mapping[str, Check]] = MappingProxyType({"entries": _beacon_entries})
    entries: tuple[tuple[int, int, tuple[float, float], tuple[float, float]], ...]
    """(uav, tick, pos, vel) per beacon."""


REPLAY_STATUS_PERIOD_S = 0.2
"""How often a replay publishes its ReplayStatus while it runs (and at each change)."""


@dataclass(frozen=True)
class ReplayStatus(Envelope):
    """Replay -> operator, recorder: where a replay stands, every REPLAY_STATUS_PERIOD_S and after each
    command (also the answer of its ``replay/ctl`` queryable)."""

    KIND: ClassVar[str] = KIND_REPLAY_STATUS
    PLACE: ClassVar[tuple[str, ...]] = (keys.REPLAY_ROOT,)
    CHECKS: ClassVar[Mapping[str, Check]] = MappingProxyType(
        {
            "state": _choice(REPLAY_STATES),
            "position_s": _nonneg,
            "span_s": _nonneg,
            "tick": _int(-1, (1 << 63) - 1),
            "rate": _positive,
            "paused": _bool,
            "sent": _uint63,
            "restored": _uint63,
            "loop": _uint63,
        }
    )
    state: str
    position_s: float
    """Receive time of the last message sent, in seconds from the recording's first message."""
    span_s: float
    """The recording's length in seconds (first to last message)."""
    tick: int
    """The last world tick sent (-1: none yet)."""
    rate: float
    paused: bool
    sent: int
    """Recorded messages sent so far (a message sent again after a seek back counts again)."""
    restored: int
    """Messages re-sent after seeks to restore each channel's last value."""
    loop: int
    """Complete passes so far (--loop)."""


# --- snapshots: a lock-step recording's periodic state (truav log resim --from TICK restores it) ---------
SnapshotArrays = dict[str, tuple[str, tuple[int, ...], bytes]]


def _snapshot_arrays(name: str, v: Any) -> SnapshotArrays:
    """Named arrays, each ``[dtype, shape, data]``: a name as metric names are, a dtype of SNAPSHOT_DTYPES,
    at most MAX_SNAPSHOT_DIMS lengths, data exactly their product times 8 bytes; at most MAX_SNAPSHOT_ARRAYS."""
    if not isinstance(v, dict) or len(v) > MAX_SNAPSHOT_ARRAYS:
        raise SchemaError(R_BAD_TYPE, f"{name} must be a map of at most {MAX_SNAPSHOT_ARRAYS} arrays")
    out = {}
    for key, entry in v.items():
        where = f"{name}[{key!r}]"
        key = _name(f"{name} key", key)
        if not isinstance(entry, (list, tuple)) or len(entry) != 3:
            raise SchemaError(R_BAD_TYPE, f"{where} must be [dtype, shape, data]")
        dtype, shape, data = entry
        if dtype not in SNAPSHOT_DTYPES:
            raise SchemaError(R_OUT_OF_RANGE, f"{where} dtype must be one of {', '.join(SNAPSHOT_DTYPES)}")
        if not isinstance(shape, (list, tuple)) or len(shape) > MAX_SNAPSHOT_DIMS:
            raise SchemaError(R_BAD_TYPE, f"{where} shape must be at most {MAX_SNAPSHOT_DIMS} lengths")
        shape = tuple(_int(0, MAX_SNAPSHOT_BYTES)(f"{where}.shape", n) for n in shape)
        if not isinstance(data, (bytes, bytearray)):
            raise SchemaError(R_BAD_TYPE, f"{where} data must be bytes")
        count = 1
        for n in shape:
            count *= n
        if len(data) != 8 * count:
            raise SchemaError(R_OUT_OF_RANGE, f"{where} holds {len(data)} bytes, its shape {list(shape)} "
                                              f"needs {8 * count}")
        out[key] = (dtype, shape, bytes(data))
    return out


@dataclass(frozen=True)
class WorldSnapshot(Envelope):
    """World -> recorder (lock-step, ``--snapshot-every``): its whole state before tick ``tick``
    (world.world_state names the arrays)."""

    KIND: ClassVar[str] = KIND_WORLD_SNAPSHOT
    PLACE: ClassVar[tuple[str, ...]] = (keys.WORLD, keys.SNAPSHOT)
    CHECKS: ClassVar[Mapping[str, Check]] = MappingProxyType(
        {"tick": _uint63, "episode": _uint63, "arrays": _snapshot_arrays})
    tick: int
    episode: int
    arrays: SnapshotArrays


@dataclass(frozen=True)
class AgentSnapshot(Envelope):
    """Agent ``uav`` -> recorder (lock-step, ``--snapshot-every``): its learner and decision state before
    tick ``tick``, the Q-table's updated rows only (agents.decision_state names the arrays)."""

    KIND: ClassVar[str] = KIND_AGENT_SNAPSHOT
    PLACE: ClassVar[tuple[str, ...]] = (keys.UAV, keys.SNAPSHOT)
    CHECKS: ClassVar[Mapping[str, Check]] = MappingProxyType(
        {"uav": _uav_id, "tick": _uint63, "arrays": _snapshot_arrays})
    uav: int
    tick: int
    arrays: SnapshotArrays


@dataclass(frozen=True, eq=False)
class QShare(Envelope):
    """Agent ``uav`` -> all (federated TRUAV): part ``part`` of ``parts`` of the Q rows it shares after episode
    ``episode``: the rows of the states it visited since its last share, with its visit counts
    (agents.federated). Receivers merge a whole share (every part of one episode) or nothing, bounded."""

    KIND: ClassVar[str] = KIND_QSHARE
    PLACE: ClassVar[tuple[str, ...]] = (keys.UAV, keys.QSHARE)
    CHECKS: ClassVar[Mapping[str, Check]] = MappingProxyType(
        {
            "uav": _uav_id,
            "tick": _uint63,
            "episode": _uint63,
            "part": _int(0, MAX_QSHARE_PARTS - 1),
            "parts": _int(1, MAX_QSHARE_PARTS),
            "states": _ints(MAX_QSHARE_ROWS, 0, INT64_MAX),
            "counts": _ints(MAX_QSHARE_ROWS, 1, INT64_MAX),
            "q": _floats(MAX_QSHARE_ROWS * 16),
        }
    )
    uav: int
    tick: int
    episode: int
    part: int
    parts: int
    states: Any
    """numpy int64 array (a list of ints on the wire)"""
    counts: Any
    """numpy int64 array"""
    q: Any
    """numpy float64 array of 16 values per state, row-major"""

    def __eq__(self, other: object) -> bool:  # numpy arrays: compared entry for entry
        if type(other) is not QShare:
            return NotImplemented
        return all(_np.array_equal(a, b) if isinstance(a, _np.ndarray) else a == b
                   for a, b in ((getattr(self, f.name), getattr(other, f.name)) for f in fields(self)))

    __hash__ = None  # type: ignore[assignment]


Message = Union[Tick, Obs, Beacon, Action, Metrics, Fault, Control, Positions, State, Command, Health, Beacons,
                Rejection, ReplayStatus, WorldSnapshot, AgentSnapshot, QShare, Override]
M = TypeVar("M", bound=Envelope)

_ENVELOPE_FIELDS = frozenset(f.name for f in fields(Envelope))


def _build_registry() -> Mapping[str, type[Envelope]]:
    registry: dict[str, type[Envelope]] = {}
    for cls in (Tick, Obs, Beacon, Action, Metrics, Fault, Control, Positions, State, Command, Health, Beacons,
                Rejection, ReplayStatus, WorldSnapshot, AgentSnapshot, QShare, Override):
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
_OPTIONAL_FIELDS: Mapping[str, Mapping[str, Any]] = MappingProxyType(
    {kind: MappingProxyType({f.name: f.default if f.default is not MISSING else NO_FIELDS  # a factory: a map
                              for f in fields(cls) if f.name in cls.ADDED})
     for kind, cls in MESSAGE_CLASSES.items()})
"""Each kind's ``ADDED`` fields with their value when an older sender's payload lacks them (a health report
from before ``heard``): such a payload still decodes, so older recordings stay readable."""
_SENT_IF_SET: Mapping[str, frozenset[str]] = MappingProxyType(
    {kind: frozenset(cls.SENT_IF_SET) for kind, cls in MESSAGE_CLASSES.items()})
"""Each kind's fields encoded only when set (not empty)."""
_SIZE_LIMIT: Mapping[str, int] = MappingProxyType(
    {
        kind: MAX_PAYLOAD_BYTES
        if kind == KIND_POSITIONS
        else MAX_SNAPSHOT_BYTES
        if kind in (KIND_WORLD_SNAPSHOT, KIND_AGENT_SNAPSHOT)
        else MAX_BATCH_PAYLOAD_BYTES
        if kind == KIND_BEACONS
        else MAX_CONTROL_PAYLOAD_BYTES
        if kind == KIND_CONTROL
        else MAX_QSHARE_PAYLOAD_BYTES
        if kind == KIND_QSHARE
        else MAX_SMALL_PAYLOAD_BYTES
        for kind in KINDS
    }
)


# msgpack limits per kind, applied while parsing: the longest map, array, str of any valid message
# of that kind (the envelope's src and kind strings included); no bin or ext type is ever valid.
# (max_map_len: an obs's, the longest small kind, 6 envelope keys + 15 fields.)
_SMALL_LIMITS = {"max_map_len": len(_WIRE_KEYS[KIND_OBS]), "max_array_len": 2, "max_str_len": MAX_SRC_LEN, "max_bin_len": 0,
                 "max_ext_len": 0}
_UNPACK_LIMITS: Mapping[str, Mapping[str, int]] = MappingProxyType({
    KIND_TICK: _SMALL_LIMITS, KIND_OBS: _SMALL_LIMITS, KIND_BEACON: _SMALL_LIMITS, KIND_ACTION: _SMALL_LIMITS,
    KIND_METRICS: {**_SMALL_LIMITS, "max_map_len": MAX_METRIC_VALUES, "max_array_len": 0},
    KIND_FAULT: {**_SMALL_LIMITS, "max_map_len": MAX_FAULT_PARAMS, "max_array_len": 0,
                 "max_str_len": max(MAX_PARAM_STR_LEN, MAX_TARGET_LEN)},
    KIND_POSITIONS: {**_SMALL_LIMITS, "max_array_len": MAX_VEHICLE_POSITIONS},
    KIND_STATE: {**_SMALL_LIMITS, "max_map_len": 20, "max_bin_len": MAX_SMALL_PAYLOAD_BYTES},
    KIND_COMMAND: {**_SMALL_LIMITS, "max_bin_len": MAX_SMALL_PAYLOAD_BYTES},
    KIND_HEALTH: {**_SMALL_LIMITS, "max_map_len": max(MAX_HEALTH_REASONS, MAX_HEALTH_SENDERS, 18),
                  "max_array_len": MAX_UAVS},
    KIND_CONTROL: {**_SMALL_LIMITS, "max_map_len": MAX_ARGS_NODES, "max_array_len": MAX_ARGS_NODES,
                   "max_str_len": MAX_ARGS_STR_LEN},
    KIND_BEACONS: {**_SMALL_LIMITS, "max_array_len": MAX_BATCH_ENTRIES},
    KIND_REJECTION: {**_SMALL_LIMITS, "max_map_len": max(MAX_HEALTH_REASONS, 18), "max_array_len": 0,
                     "max_str_len": max(MAX_TARGET_LEN, MAX_DETAIL_LEN)},
    KIND_REPLAY_STATUS: {**_SMALL_LIMITS, "max_array_len": 0},
    **{kind: {**_SMALL_LIMITS, "max_map_len": max(MAX_SNAPSHOT_ARRAYS, 18), "max_array_len": 3,
              "max_bin_len": MAX_SNAPSHOT_BYTES} for kind in (KIND_WORLD_SNAPSHOT, KIND_AGENT_SNAPSHOT)},
    KIND_QSHARE: {**_SMALL_LIMITS, "max_array_len": MAX_QSHARE_ROWS * 16},
    KIND_OVERRIDE: _SMALL_LIMITS,
})
_LOOSE_LIMITS: Mapping[str, int] = MappingProxyType(
    {k: max(lim[k] for lim in _UNPACK_LIMITS.values()) for k in _SMALL_LIMITS})


def size_limit(kind: str) -> int:
    """Largest encoded size in bytes accepted for ``kind``."""
    return _SIZE_LIMIT[kind]

