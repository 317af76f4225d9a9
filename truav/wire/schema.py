"""TRUAV wire schema: the one module that encodes and decodes bus messages.

Its parts, every name of which is re-exported here (use ``schema.<name>``): :mod:`truav.wire.schema_names`
(version, kinds, limits, :class:`SchemaError` and its reasons), :mod:`truav.wire.field_checks`,
:mod:`truav.wire.messages` (one frozen dataclass per kind) and :mod:`truav.wire.codec` (encode, decode, stamp).

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

followed by the fields of that kind; one frozen dataclass per kind (:mod:`truav.wire.messages`)
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

Size (measured, pinned by ``tests/unit/test_schema.py``): a stamped beacon from
``uav/3`` at tick 1234 with a 19-digit ns timestamp is 114 bytes: map header
1 B, envelope with its keys 54 B (13 of them the incarnation), body 59 B (of
which the four float64 of pos/vel are 36 B).  The worst case (``uav/1023``,
64-bit seq/tick/t) is :data:`BEACON_MAX_BYTES` = 133 bytes.  Zenoh adds its own framing on top.
Every kind but ``positions`` and ``control`` must fit in
:data:`MAX_SMALL_PAYLOAD_BYTES`.
"""

from __future__ import annotations

from truav.wire.keys import MAX_UAVS  # noqa: F401
from truav.wire.schema_names import (  # noqa: F401
    BEACON_FIELDS_MAX_BYTES, BEACON_MAX_BYTES, MAX_BEACON_FIELD_NAME, MAX_BEACON_FIELDS, FAULT_CRASH, FAULT_FREEZE, FAULT_KINDS, FAULT_LATENCY, FAULT_LOSS, FAULT_OVERRIDE, FAULT_PARTITION,
    INT64_MAX, KIND_ACTION, KIND_BEACON, KIND_COMMAND, KIND_CONTROL, KIND_FAULT, KIND_HEALTH, KIND_METRICS,
    KIND_OBS, KIND_OVERRIDE, KIND_POSITIONS, KIND_QSHARE, KIND_REJECTION, KIND_REPLAY_STATUS, KIND_STATE, KIND_TICK, MAX_ARGS_DEPTH,
    MAX_ARGS_NODES, MAX_ARGS_STR_LEN,
    MAX_CONTROL_PAYLOAD_BYTES, MAX_DETAIL_LEN, MAX_FAULT_PARAMS, MAX_HEALTH_REASONS, MAX_HEALTH_SENDERS, MAX_METRIC_VALUES,
    MAX_NAME_LEN, MAX_PARAM_STR_LEN, MAX_PAYLOAD_BYTES, MAX_QSHARE_PARTS, MAX_QSHARE_PAYLOAD_BYTES, MAX_QSHARE_ROWS, MAX_SMALL_PAYLOAD_BYTES, MAX_SRC_LEN, MAX_TARGET_LEN,
    MAX_VEHICLE_POSITIONS, PHASES, PHASE_END, PHASE_START, R_BAD_TYPE, R_EXTRA_FIELD, R_MISSING_FIELD,
    R_LATE_ACTION, R_NOT_BYTES, R_NOT_MAP, R_NOT_MSGPACK, R_OUT_OF_RANGE, R_STALE_ACTION, R_TOO_LARGE, R_UNKNOWN_KIND, R_UNSTAMPED, R_VERSION,
    REPLAY_ENDED, REPLAY_PAUSED, REPLAY_PLAYING, REPLAY_STATES, REPLAY_WAITING,
    SCHEMA_VERSION, SCOPES, SCOPE_EPISODE, SCOPE_STEP, UINT64_MAX, SchemaError)
from truav.wire.field_checks import (  # noqa: F401
    Check)
from truav.wire.messages import (  # noqa: F401
    DEFAULT_LOCKSTEP_WAIT_S, HEALTH_PERIOD_S, KINDS, LOCKSTEP_JOIN_GRACE_S, M, MESSAGE_CLASSES, Action, Beacon,
    Command, Control, Envelope, Fault, Health, Message, Metrics, Obs, Positions, State, Tick, size_limit,
    KIND_BEACONS, MAX_BATCH_ENTRIES, Beacons, REJECTION_PERIOD_S, Rejection, REPLAY_STATUS_PERIOD_S, ReplayStatus, QShare,
    Override)
from truav.wire.messages import AgentSnapshot, SnapshotArrays, WorldSnapshot  # noqa: F401
from truav.wire.schema_names import (  # noqa: F401
    KIND_AGENT_SNAPSHOT, KIND_WORLD_SNAPSHOT, MAX_SNAPSHOT_ARRAYS, MAX_SNAPSHOT_BYTES)
from truav.wire.codec import (  # noqa: F401
    Sequencer, decode, encode, new_incarnation, padded, peek_src, unpack_limits)
from truav.actions import HOVER, N_ACTIONS  # noqa: F401  (an action is an int in [0, N_ACTIONS), or HOVER, an
# agent's explicit hover: the central scheme's autopilot without commands; truav/actions.py is their one source)
