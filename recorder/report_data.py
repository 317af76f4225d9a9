"""What ``truav report`` reads from a recording: one lenient pass over its bus channels.

:func:`load_recording` keeps what the figures need (:class:`Recording`: UAV
position series from beacons, observations and positions messages, vehicle
points with bounded memory, metrics bodies, fault events) and the map's
geometry from the run config stored as metadata (:class:`MapConfig`).
Payloads are decoded leniently (msgpack maps with the envelope), so a
recording with odd messages still reports; but a UAV's message whose claimed
UAV disagrees with its key (``uav/<i>/...``), whose sender is not that UAV, or
whose id is past the schema's MAX_UAVS is left out and counted
(:attr:`Recording.refused`), as the bus's guard refuses it: a file from
elsewhere cannot make the report draw thousands of UAVs.
"""

from __future__ import annotations

import math
import tomllib
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

import msgpack
import numpy as np

from recorder.metadata import read_config_toml
from recorder.reader import iter_messages
from truav.wire.keys import MAX_UAVS

NS = 1e9
MAX_VEHICLE_POINTS = 4_000_000  # keep every k-th positions message beyond this (bounded memory)
MAX_METRIC_NAMES = 200  # values kept per metrics message (the world publishes about a dozen)
MAX_HEALTH_STREAMS = 10_000  # agent processes (uav, incarnation) whose beacon counts are kept
MAX_HEARD = 1024  # senders per count list (the schema's MAX_UAVS)


class ReportError(ValueError):
    """A user mistake: missing file, not an MCAP file."""


# --- what is read from the file ------------------------------------------------------------
@dataclass
class Series:
    """Receive time, publish time and position samples of one UAV."""

    log_ns: list[int] = field(default_factory=list)
    pub_ns: list[int] = field(default_factory=list)
    xy: list[tuple[float, float]] = field(default_factory=list)


@dataclass
class FaultSpan:
    fault: str
    target: str
    start_s: float
    end_s: Optional[float]  # None: never ended within the recording


@dataclass
class MapConfig:
    """What the map needs from the run config."""

    area_m: float
    block_m: float
    rsus: list[tuple[float, float]]
    majors: list[tuple[float, float]]
    comm_range_m: float


@dataclass
class Recording:
    first_ns: Optional[int] = None
    last_ns: Optional[int] = None
    messages: int = 0
    undecodable: int = 0
    beacons: dict[int, Series] = field(default_factory=lambda: defaultdict(Series))
    obs: dict[int, Series] = field(default_factory=lambda: defaultdict(Series))
    positions_uavs: dict[int, Series] = field(default_factory=lambda: defaultdict(Series))
    vehicles: list[np.ndarray] = field(default_factory=list)
    vehicle_stride: int = 1  # keep every stride-th positions message
    positions_seen: int = 0
    metrics: list[dict[str, Any]] = field(default_factory=list)  # decoded metrics bodies + times
    faults: list[tuple[int, dict[str, Any]]] = field(default_factory=list)  # (log_ns, body)
    batched_sent_ns: dict[int, list[int]] = field(default_factory=lambda: defaultdict(list))
    """Send times of the beacons that came in batches (--batch-beacons), by sender."""
    heard: dict[tuple[int, int], tuple[int, tuple[int, ...]]] = field(default_factory=dict)
    """(receiver uav, incarnation) -> (send time, beacons heard by sender id) of that agent process's
    latest health report: what each receiver heard (report_links)."""
    refused: dict[str, int] = field(default_factory=lambda: defaultdict(int))
    """Messages left out, by reason (:data:`REFUSED_REASONS`)."""
    config: Optional[MapConfig] = None

    def t(self, ns: int) -> float:
        """Seconds since the first message."""
        return (ns - (self.first_ns or 0)) / NS

    @property
    def duration_s(self) -> float:
        return 0.0 if self.first_ns is None or self.last_ns is None else (self.last_ns - self.first_ns) / NS

    def tracks(self) -> tuple[str, dict[int, Series]]:
        """The best source of UAV tracks: beacons, else observations, else positions messages."""
        for name, source in (("beacons", self.beacons), ("observations", self.obs),
                             ("positions", self.positions_uavs)):
            if any(s.xy for s in source.values()):
                return name, source
        return "none", {}

    def fault_spans(self) -> list[FaultSpan]:
        """Start/end events paired per (fault, target); an unmatched start lasts to the end."""
        open_: dict[tuple[str, str], float] = {}
        spans: list[FaultSpan] = []
        for log_ns, body in sorted(self.faults, key=lambda f: f[0]):
            k = (str(body.get("fault")), str(body.get("target")))
            if body.get("phase") == "start":
                open_.setdefault(k, self.t(log_ns))
            elif body.get("phase") == "end":
                start = open_.pop(k, 0.0)
                spans.append(FaultSpan(k[0], k[1], start, self.t(log_ns)))
        spans += [FaultSpan(f, tg, s, None) for (f, tg), s in open_.items()]
        return sorted(spans, key=lambda s: s.start_s)


def _xy(v: Any) -> Optional[tuple[float, float]]:
    try:
        x, y = float(v[0]), float(v[1])
    except (TypeError, ValueError, IndexError, KeyError):
        return None
    return (x, y) if math.isfinite(x) and math.isfinite(y) else None


def _numbers(values: dict) -> dict[str, float]:
    """A metrics message's values as the figures and the CSV use them: names that are strings (at most
    MAX_METRIC_NAMES of them, each at most 200 characters) with a number; anything else (a string "abc",
    a list, a map, a bytes name: a message from elsewhere) is left out."""
    out: dict[str, float] = {}
    for name, value in values.items():
        if len(out) >= MAX_METRIC_NAMES:
            break
        if type(name) is str and len(name) <= 200 and type(value) in (int, float):
            try:
                out[name] = float(value)
            except OverflowError:  # an int beyond float
                continue
    return out


R_KEY, R_SENDER, R_RANGE = "uav differs from its key", "sender is not that uav", f"uav id not below {MAX_UAVS}"
REFUSED_REASONS = (R_KEY, R_SENDER, R_RANGE)


def _key_uav(key: str) -> Optional[int]:
    """``i`` of a key ``truav/<run>/uav/<i>/...`` (None: not a UAV's key)."""
    parts = key.split("/", 4)
    if len(parts) > 3 and parts[2] == "uav" and parts[3].isdigit() and len(parts[3]) <= 6:
        return int(parts[3])
    return None


def _uav(body: dict, key: str, rec: Optional[Recording] = None, own: bool = False) -> Optional[int]:
    """The UAV a message is of: its ``uav`` field, else its key's. None, counted in ``rec.refused``, when the
    two disagree, when the id is not below MAX_UAVS, or (``own``: a message a UAV sends about itself, a beacon
    or a health report) when its ``src`` is a string other than ``uav/<id>``."""
    claimed, on_key = body.get("uav"), _key_uav(key)
    uav = claimed if type(claimed) is int else on_key
    reason = None
    if uav is None:
        return None
    if on_key is not None and uav != on_key:
        reason = R_KEY
    elif not 0 <= uav < MAX_UAVS:
        reason = R_RANGE
    elif own and isinstance(body.get("src"), str) and body["src"] != f"uav/{uav}":
        reason = R_SENDER
    if reason is not None:
        if rec is not None:
            rec.refused[reason] += 1
        return None
    return uav


def load_recording(path: Path) -> Recording:
    """One pass over the bus channels, keeping what the figures need."""
    rec = Recording()
    for key, payload, log_ns, pub_ns in iter_messages(path):
        rec.messages += 1
        rec.first_ns = log_ns if rec.first_ns is None else min(rec.first_ns, log_ns)
        rec.last_ns = log_ns if rec.last_ns is None else max(rec.last_ns, log_ns)
        try:
            body = msgpack.unpackb(payload)
        except Exception:  # any msgpack failure: the message is just not drawn
            rec.undecodable += 1
            continue
        if not isinstance(body, dict):
            rec.undecodable += 1
            continue
        kind = body.get("kind")
        if kind in ("beacon", "obs"):
            uav, xy = _uav(body, key, rec, own=kind == "beacon"), _xy(body.get("pos"))
            if uav is not None:
                series = (rec.beacons if kind == "beacon" else rec.obs)[uav]
                series.log_ns.append(log_ns)
                series.pub_ns.append(pub_ns)
                if xy is not None:
                    series.xy.append(xy)
                else:
                    series.xy.append((math.nan, math.nan))
        elif kind == "positions":
            _add_positions(rec, body, log_ns, pub_ns)
        elif kind == "metrics" and isinstance(body.get("values"), dict):
            rec.metrics.append({**body, "values": _numbers(body["values"]), "_log_ns": log_ns, "_pub_ns": pub_ns})
        elif kind == "fault":
            rec.faults.append((log_ns, body))
        elif kind == "health":
            _add_heard(rec, body, key, pub_ns)
        elif kind == "beacons" and isinstance(body.get("entries"), list):
            for e in body["entries"][:MAX_HEARD]:
                if isinstance(e, list) and e and type(e[0]) is int and 0 <= e[0] < MAX_HEARD:
                    rec.batched_sent_ns[e[0]].append(pub_ns)
    rec.config = _map_config(path)
    return rec


def _add_heard(rec: Recording, body: dict, key: str, pub_ns: int) -> None:
    """Keep an agent process's latest beacon counts (a health report's ``heard``; older ones have none)."""
    uav, inc, heard = _uav(body, key, rec, own=True), body.get("inc", 0), body.get("heard")
    if uav is None or type(inc) is not int or not isinstance(heard, list) or not heard or len(heard) > MAX_HEARD:
        return
    if not all(type(n) is int and n >= 0 for n in heard):
        return
    stream = (uav, inc)
    if stream in rec.heard and rec.heard[stream][0] > pub_ns:
        return
    if stream in rec.heard or len(rec.heard) < MAX_HEALTH_STREAMS:
        rec.heard[stream] = (pub_ns, tuple(heard))


def _add_positions(rec: Recording, body: dict, log_ns: int, pub_ns: int) -> None:
    uavs = body.get("uavs")
    if isinstance(uavs, list):
        for i, p in enumerate(uavs[:MAX_UAVS]):
            xy = _xy(p)
            if xy is not None:
                s = rec.positions_uavs[i]
                s.log_ns.append(log_ns)
                s.pub_ns.append(pub_ns)
                s.xy.append(xy)
    vehicles = body.get("vehicles")
    rec.positions_seen += 1
    if not isinstance(vehicles, list) or not vehicles or (rec.positions_seen - 1) % rec.vehicle_stride:
        return
    try:
        arr = np.asarray(vehicles, dtype=np.float32).reshape(-1, 2)
    except (TypeError, ValueError):
        return
    rec.vehicles.append(arr[np.isfinite(arr).all(axis=1)])
    if sum(len(a) for a in rec.vehicles) > MAX_VEHICLE_POINTS:  # halve what we keep, double the stride
        rec.vehicles = rec.vehicles[::2]
        rec.vehicle_stride *= 2


def _map_config(path: Path) -> Optional[MapConfig]:
    """Roads, RSUs and range from the run config stored as metadata (defaults filled in)."""
    text = read_config_toml(path)
    if text is None:
        return None
    try:
        from truav.config import config_from_dict

        cfg = config_from_dict(tomllib.loads(text))
    except Exception:  # an old or foreign config: draw without roads rather than fail
        return None
    block = cfg.roads.block_m
    return MapConfig(
        area_m=cfg.scenario.area_m, block_m=block,
        rsus=[(i * block, j * block) for i, j in cfg.scenario.rsu_intersections],
        majors=[(i * block, j * block) for i, j in cfg.roads.major_intersections],
        comm_range_m=cfg.scenario.comm_range_m,
    )
