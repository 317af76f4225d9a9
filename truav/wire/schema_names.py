"""The names of the wire format (:mod:`truav.wire.schema`): the schema version, the message kinds, the
enumerated string values, the size and count limits, and :class:`SchemaError` with its reason codes."""

from __future__ import annotations

import re


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
KIND_REJECTION = "rejection"
KIND_REPLAY_STATUS = "replay_status"
KIND_WORLD_SNAPSHOT = "world_snapshot"
KIND_AGENT_SNAPSHOT = "agent_snapshot"
KIND_QSHARE = "qshare"
KIND_OVERRIDE = "override"

# --- enumerated string values ------------------------------------------------
SCOPE_STEP = "step"
SCOPE_EPISODE = "episode"
SCOPES = (SCOPE_STEP, SCOPE_EPISODE)

PHASE_START = "start"
PHASE_END = "end"
PHASES = (PHASE_START, PHASE_END)

REPLAY_PLAYING = "playing"
REPLAY_PAUSED = "paused"
REPLAY_WAITING = "waiting"  # --lockstep: for the live agents' answers
REPLAY_ENDED = "ended"
REPLAY_STATES = (REPLAY_PLAYING, REPLAY_PAUSED, REPLAY_WAITING, REPLAY_ENDED)

FAULT_LOSS = "loss"
FAULT_LATENCY = "latency"
FAULT_PARTITION = "partition"
FAULT_CRASH = "crash"
FAULT_FREEZE = "freeze"
FAULT_KINDS = (FAULT_LOSS, FAULT_LATENCY, FAULT_PARTITION, FAULT_CRASH, FAULT_FREEZE)
FAULT_OVERRIDE = "override"  # the world's fault/override events: a UAV steered from outside (control/override/<i>)

# --- limits -------------------------------------------------------------------
MAX_PAYLOAD_BYTES = 1 << 20  # 1 MiB: the largest payload of any kind (positions)
MAX_CONTROL_PAYLOAD_BYTES = 256 << 10  # control messages may carry plans
MAX_SMALL_PAYLOAD_BYTES = 16 << 10  # everything else
BEACON_MAX_BYTES = 133  # worst case of a stamped beacon, see module docstring
MAX_BEACON_FIELDS = 8  # a beacon's optional fields (an API agent's beacon_fields()): at most this many
MAX_BEACON_FIELD_NAME = 32  # characters of a beacon field's name (printable ASCII)
BEACON_FIELDS_MAX_BYTES = 352  # the most MAX_BEACON_FIELDS fields add to a beacon (tests/unit/test_schema.py)
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
MAX_DETAIL_LEN = 160  # a rejection's detail text (cut to this)
# Snapshots (a lock-step recording's periodic state: world_snapshot, agent_snapshot), named arrays each
# [dtype, shape, raw little-endian bytes]; a state that does not fit one message is not published.
MAX_SNAPSHOT_BYTES = MAX_PAYLOAD_BYTES
MAX_SNAPSHOT_ARRAYS = 40  # a world snapshot has 28
MAX_SNAPSHOT_DIMS = 3
SNAPSHOT_DTYPES = ("<f8", "<i8", "<u8")
MAX_QSHARE_ROWS = 320  # Q rows in one qshare message (16 float64 each: ~47 KB of values)
MAX_QSHARE_PARTS = 64  # messages one share may be split over: 20,480 rows, more than any table has
MAX_QSHARE_PAYLOAD_BYTES = 64 << 10  # MAX_QSHARE_ROWS rows of ~150 bytes, and the envelope
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
# Not refused by the bus, but not applied by the world either: told to the sender in a rejection.
R_LATE_ACTION = "late_action"
R_STALE_ACTION = "stale_action"

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

