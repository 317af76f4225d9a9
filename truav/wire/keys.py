"""Every Zenoh key expression TRUAV uses, in one place.

All traffic of one emulation run lives under ``truav/<run>/``:

==============================  ==================  ===========================
key (after ``truav/<run>/``)    direction           payload kind (truav.wire.schema)
==============================  ==================  ===========================
``world/tick``                  world -> all        ``tick``
``world/positions``             world -> recorder   ``positions``
``uav/<i>/obs``                 world -> agent i    ``obs``
``uav/<i>/beacon``              agent i -> all      ``beacon``
``uav/<i>/beacon/<cx>_<cy>``    agent i -> near     ``beacon`` (range-limited: map cell of its position)
``uav/<i>/action``              agent i -> world    ``action``
``uav/<i>/state``               agent i -> ctrl     ``state`` (scheme central: the state upload)
``uav/<i>/rejected``            world -> agent i    ``rejection`` (what the world refused of agent i)
``uav/<i>/qshare/<part>``       agent i -> all      ``qshare`` (federated TRUAV: part of its Q rows)
``controller/cmd/<i>``          ctrl -> agent i     ``command`` (scheme central)
``group/<a>-<b>/beacons``       agents a..b -> all  ``beacons`` (``--batch-beacons``: one process's UAVs a..b)
``metrics/step``                world -> recorder   ``metrics`` (scope "step")
``metrics/episode``             world -> recorder   ``metrics`` (scope "episode")
``fault/<kind>``                faults -> all       ``fault``
``control/<a>[/<b>...]``        operator -> all     ``control``
``control/override/<i>``        operator -> world   ``override`` (steer UAV i to a goal, or release it)
``alive/world``                 liveliness token of the world process
``alive/uav/<i>``               liveliness token of agent i
``alive/recorder``              liveliness token of the recorder
``alive/controller``            liveliness token of the central controller
==============================  ==================  ===========================

Sender identities (the ``src`` field of every message and the identity of a
:class:`truav.bus.transport.Bus`) are ``world``, ``recorder``, ``fault``,
``replay``, ``controller``, ``operator`` (who steers a UAV from outside) or ``uav/<i>``; helpers for those live here too.

Nothing here talks to Zenoh: these are plain string builders and parsers, so
run names and ids are validated with a clear :class:`ValueError`.
"""

from __future__ import annotations

import re

ROOT = "truav"
MAX_UAVS = 1024  # UAV ids are in [0, MAX_UAVS)
MAX_CHUNK_LEN = 64
MAX_CELLS = 1024  # range-limited beacon cells per axis are in [0, MAX_CELLS)

_CHUNK_RE = re.compile(r"[A-Za-z0-9_-]+")
_UAV_KEY_RE = re.compile(r"truav/[A-Za-z0-9_-]+/(?:alive/)?uav/(0|[1-9][0-9]*)(?:/.*)?")
_UAV_IDENTITY_RE = re.compile(r"uav/(0|[1-9][0-9]*)")
_UAV_CHUNK_RE = re.compile(r"0|[1-9][0-9]{0,3}")
_RUN_KEY_RE = re.compile(r"truav/([A-Za-z0-9_-]+)(?:/.*)?")
_GROUP_KEY_RE = re.compile(r"truav/[A-Za-z0-9_-]+/group/(0|[1-9][0-9]*)-(0|[1-9][0-9]*)/beacons")

# Sender identities (``src``) of the non-UAV processes.
SRC_WORLD = "world"
SRC_RECORDER = "recorder"
SRC_FAULT = "fault"
SRC_REPLAY = "replay"
SRC_CONTROLLER = "controller"
SRC_OPERATOR = "operator"  # steers a UAV from outside: control/override/<i> (truav-swarm steer, the MAVLink bridge)

# First chunks (after ``truav/<run>/``) of the data keys, and the world's two keys.
WORLD = "world"
TICK = "tick"
POSITIONS = "positions"
UAV = "uav"
METRICS_ROOT = "metrics"  # metrics(run, scope) builds its keys
FAULT_ROOT = "fault"
CONTROL_ROOT = "control"
OVERRIDE = "override"  # control/override/<i>: a UAV steered from outside
GROUP = "group"  # group/<first>-<last>/beacons: the beacons of one process's UAVs first..last, batched
REPLAY_ROOT = "replay"  # replay/status (a replay's position, ~5 Hz) and replay/ctl (its queryable)
REPLAY_STATUS = "status"
REPLAY_CTL = "ctl"

# Last chunks of the per-UAV keys.
OBS = "obs"
BEACON = "beacon"
ACTION = "action"
STATE = "state"
HEALTH = "health"
REJECTED = "rejected"
SNAPSHOT = "snapshot"  # world/snapshot and uav/<i>/snapshot: a lock-step recording's state snapshots
QSHARE = "qshare"
BEACONS = "beacons"  # last chunk of a group's batch key
CONTROLLER = "controller"
COMMAND = "cmd"

# Metric scopes (also the last chunk of the metrics keys).
SCOPE_STEP = "step"
SCOPE_EPISODE = "episode"


def _check_chunk(value: str, what: str) -> str:
    if not isinstance(value, str) or not value:
        raise ValueError(f"{what} must be a non-empty string, got {value!r}")
    if len(value) > MAX_CHUNK_LEN or not _CHUNK_RE.fullmatch(value):
        raise ValueError(
            f"{what} {value!r} is invalid: use 1..{MAX_CHUNK_LEN} characters from [A-Za-z0-9_-]"
        )
    return value


def validate_run(run: str) -> str:
    """Return ``run`` if it is a valid run name (non-empty, ``[A-Za-z0-9_-]`` only)."""
    return _check_chunk(run, "run name")


def validate_uav_id(i: int) -> int:
    """Return ``i`` if it is a valid UAV id: an int in ``[0, MAX_UAVS)``."""
    if isinstance(i, bool) or not isinstance(i, int) or not 0 <= i < MAX_UAVS:
        raise ValueError(f"UAV id must be an int in [0, {MAX_UAVS}), got {i!r}")
    return i


def prefix(run: str) -> str:
    """``truav/<run>`` (no trailing slash)."""
    return f"{ROOT}/{validate_run(run)}"


def everything(run: str) -> str:
    """``truav/<run>/**``: every message and token of one run (the recorder's view)."""
    return f"{prefix(run)}/**"


# --- world ---------------------------------------------------------------
def world_tick(run: str) -> str:
    return f"{prefix(run)}/{WORLD}/{TICK}"


def world_positions(run: str) -> str:
    return f"{prefix(run)}/{WORLD}/{POSITIONS}"


# --- per UAV ---------------------------------------------------------------
def uav_prefix(run: str, i: int) -> str:
    """``truav/<run>/uav/<i>``: everything agent ``i`` may publish lives below this."""
    return f"{prefix(run)}/{UAV}/{validate_uav_id(i)}"


def uav_obs(run: str, i: int) -> str:
    return f"{uav_prefix(run, i)}/{OBS}"


def uav_beacon(run: str, i: int) -> str:
    return f"{uav_prefix(run, i)}/{BEACON}"


def uav_action(run: str, i: int) -> str:
    return f"{uav_prefix(run, i)}/{ACTION}"


def uav_state(run: str, i: int) -> str:
    """``truav/<run>/uav/<i>/state``: agent i's state upload to the central controller."""
    return f"{uav_prefix(run, i)}/{STATE}"


def all_states(run: str) -> str:
    return f"{prefix(run)}/{UAV}/*/{STATE}"


def uav_qshare(run: str, i: int, part: int) -> str:
    """``truav/<run>/uav/<i>/qshare/<part>``: part ``part`` of agent i's federated Q share (one key per part, so
    a share's parts, sent together, pass a per-key rate cap)."""
    return f"{uav_prefix(run, i)}/{QSHARE}/{int(part)}"


def uav_qshares(run: str, i: int) -> str:
    return f"{uav_prefix(run, i)}/{QSHARE}/*"


def all_qshares(run: str) -> str:
    return f"{prefix(run)}/{UAV}/*/{QSHARE}/*"


def uav_health(run: str, i: int) -> str:
    """``truav/<run>/uav/<i>/health``: agent i's own statistics (what it refused), about once a second."""
    return f"{uav_prefix(run, i)}/{HEALTH}"


def world_snapshot(run: str) -> str:
    """``truav/<run>/world/snapshot``: the world's whole state every --snapshot-every ticks (lock-step)."""
    return f"{prefix(run)}/{WORLD}/{SNAPSHOT}"


def uav_snapshot(run: str, i: int) -> str:
    """``truav/<run>/uav/<i>/snapshot``: agent i's learner state at the world's snapshot ticks."""
    return f"{uav_prefix(run, i)}/{SNAPSHOT}"


def all_health(run: str) -> str:
    return f"{prefix(run)}/{UAV}/*/{HEALTH}"


def uav_rejected(run: str, i: int) -> str:
    """``truav/<run>/uav/<i>/rejected``: the world tells agent i what it refused of its messages."""
    return f"{uav_prefix(run, i)}/{REJECTED}"


def all_rejected(run: str) -> str:
    return f"{prefix(run)}/{UAV}/*/{REJECTED}"


def controller_cmd(run: str, i: int) -> str:
    """``truav/<run>/controller/cmd/<i>``: the central controller's command to UAV i."""
    return f"{prefix(run)}/{CONTROLLER}/{COMMAND}/{validate_uav_id(i)}"


def all_commands(run: str) -> str:
    return f"{prefix(run)}/{CONTROLLER}/{COMMAND}/*"


def all_obs(run: str) -> str:
    return f"{prefix(run)}/{UAV}/*/{OBS}"


def all_beacons(run: str) -> str:
    """``truav/<run>/uav/*/beacon``."""
    return f"{prefix(run)}/{UAV}/*/{BEACON}"


def uav_beacon_in_cell(run: str, i: int, cell: tuple[int, int]) -> str:
    """``truav/<run>/uav/<i>/beacon/<cx>_<cy>``: a range-limited beacon, under the map cell it was sent from
    (agents.beacon_cells); receivers subscribe only to the cells within range."""
    return f"{uav_beacon(run, i)}/{cell_chunk(cell)}"


def beacons_in_cell(run: str, cell: tuple[int, int]) -> str:
    """``truav/<run>/uav/*/beacon/<cx>_<cy>``: every range-limited beacon sent from one map cell."""
    return f"{all_beacons(run)}/{cell_chunk(cell)}"


def all_beacons_in_cells(run: str) -> str:
    """``truav/<run>/uav/*/beacon/*``: every range-limited beacon (the supervisor's monitor)."""
    return f"{all_beacons(run)}/*"


def cell_chunk(cell: tuple[int, int]) -> str:
    cx, cy = cell
    if isinstance(cx, bool) or isinstance(cy, bool) or not (isinstance(cx, int) and isinstance(cy, int)) \
            or not (0 <= cx < MAX_CELLS and 0 <= cy < MAX_CELLS):
        raise ValueError(f"map cell must be two ints in [0, {MAX_CELLS}), got {cell!r}")
    return f"{cx}_{cy}"


def group_beacons(run: str, first: int, last: int) -> str:
    """``truav/<run>/group/<first>-<last>/beacons``: the batched beacons of UAVs ``first..last``, which one
    process hosts (``--batch-beacons``); only ``uav/<first>`` sends on it."""
    if validate_uav_id(last) < validate_uav_id(first):
        raise ValueError(f"group {first}-{last}: the last UAV id comes before the first")
    return f"{prefix(run)}/{GROUP}/{first}-{last}/{BEACONS}"


def all_beacon_batches(run: str) -> str:
    """``truav/<run>/group/*/beacons``: every group's batched beacons."""
    return f"{prefix(run)}/{GROUP}/*/{BEACONS}"


def parse_group(key: str) -> tuple[int, int] | None:
    """(first, last) of ``truav/<run>/group/<first>-<last>/beacons`` (valid ids, first <= last); else None."""
    m = _GROUP_KEY_RE.fullmatch(key) if isinstance(key, str) else None
    if m is None:
        return None
    first, last = int(m.group(1)), int(m.group(2))
    return (first, last) if first <= last < MAX_UAVS else None


def all_actions(run: str) -> str:
    """``truav/<run>/uav/*/action`` (what the world subscribes to)."""
    return f"{prefix(run)}/{UAV}/*/{ACTION}"


# --- metrics, faults, control -----------------------------------------------
def metrics(run: str, scope: str) -> str:
    if scope not in (SCOPE_STEP, SCOPE_EPISODE):
        raise ValueError(f"metrics scope must be {SCOPE_STEP!r} or {SCOPE_EPISODE!r}, got {scope!r}")
    return f"{prefix(run)}/{METRICS_ROOT}/{scope}"


def metrics_step(run: str) -> str:
    return metrics(run, SCOPE_STEP)


def metrics_episode(run: str) -> str:
    return metrics(run, SCOPE_EPISODE)


def all_metrics(run: str) -> str:
    return f"{prefix(run)}/{METRICS_ROOT}/*"


def fault(run: str, kind: str) -> str:
    """``truav/<run>/fault/<kind>``, e.g. ``fault(run, "loss")``."""
    return f"{prefix(run)}/{FAULT_ROOT}/{_check_chunk(kind, 'fault kind')}"


def all_faults(run: str) -> str:
    return f"{prefix(run)}/{FAULT_ROOT}/*"


def control(run: str, *parts: str) -> str:
    """``truav/<run>/control/<part>[/<part>...]``, e.g. ``control(run, "replay", "plan")``."""
    if not parts:
        raise ValueError("control key needs at least one part, e.g. control(run, 'fault_plan')")
    return "/".join([f"{prefix(run)}/{CONTROL_ROOT}", *(_check_chunk(p, "control key part") for p in parts)])


def control_override(run: str, i: int) -> str:
    """``truav/<run>/control/override/<i>``: steer UAV ``i`` to a goal from outside, or release it."""
    return f"{prefix(run)}/{CONTROL_ROOT}/{OVERRIDE}/{validate_uav_id(i)}"


def all_overrides(run: str) -> str:
    return f"{prefix(run)}/{CONTROL_ROOT}/{OVERRIDE}/*"


def all_control(run: str) -> str:
    return f"{prefix(run)}/{CONTROL_ROOT}/**"


def replay_status(run: str) -> str:
    """``truav/<run>/replay/status``: where a replay publishing into ``run`` stands (about 5 Hz)."""
    return f"{prefix(run)}/{REPLAY_ROOT}/{REPLAY_STATUS}"


def replay_ctl(run: str) -> str:
    """``truav/<run>/replay/ctl``: the queryable that takes a replay's commands and answers its status."""
    return f"{prefix(run)}/{REPLAY_ROOT}/{REPLAY_CTL}"


# --- liveliness tokens --------------------------------------------------------
def alive_world(run: str) -> str:
    return f"{prefix(run)}/alive/world"


def alive_uav(run: str, i: int) -> str:
    return f"{prefix(run)}/alive/uav/{validate_uav_id(i)}"


def alive_recorder(run: str) -> str:
    return f"{prefix(run)}/alive/recorder"


def alive_controller(run: str) -> str:
    return f"{prefix(run)}/alive/{CONTROLLER}"


def all_alive(run: str) -> str:
    """``truav/<run>/alive/**``: every liveliness token of the run."""
    return f"{prefix(run)}/alive/**"


def all_alive_uavs(run: str) -> str:
    return f"{prefix(run)}/alive/uav/*"


# --- parsing -------------------------------------------------------------------
def parse_uav_id(key: str) -> int | None:
    """UAV id of ``truav/<run>/uav/<i>/...`` or ``truav/<run>/alive/uav/<i>``; else None.

    Returns None too for ids outside ``[0, MAX_UAVS)`` or with leading zeros.
    """
    m = _UAV_KEY_RE.fullmatch(key) if isinstance(key, str) else None
    if m is None:
        return None
    i = int(m.group(1))
    return i if i < MAX_UAVS else None


def parse_uav_chunk(chunk: str) -> int | None:
    """The UAV id a key chunk spells (``"3"``; no leading zeros, below MAX_UAVS), else None."""
    m = _UAV_CHUNK_RE.fullmatch(chunk) if isinstance(chunk, str) else None
    return int(chunk) if m is not None and int(chunk) < MAX_UAVS else None


def parse_run(key: str) -> str | None:
    """The ``<run>`` of ``truav/<run>/...``, or None."""
    m = _RUN_KEY_RE.fullmatch(key) if isinstance(key, str) else None
    return m.group(1) if m else None


# --- sender identities ---------------------------------------------------------
def uav_identity(i: int) -> str:
    """Sender id of agent ``i``: ``uav/<i>``."""
    return f"uav/{validate_uav_id(i)}"


def parse_uav_identity(src: str) -> int | None:
    """``i`` for a sender id ``uav/<i>`` (valid id), else None."""
    m = _UAV_IDENTITY_RE.fullmatch(src) if isinstance(src, str) else None
    if m is None:
        return None
    i = int(m.group(1))
    return i if i < MAX_UAVS else None
