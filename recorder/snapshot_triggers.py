"""What starts a snapshot, read off the bus messages as they pass: pure, no files.

:class:`TriggerWatch` looks at each recorded message and names a trigger when

* a fault window starts (a ``fault`` message with phase ``start``, on ``truav/<run>/fault/*``);
* a sender's sequence numbers jump (:class:`recorder.seq_stats.SenderStats`, as the recorder counts them);
* the world's step metrics say actions were missed (a ``uav.<i>.missed`` count grew:
  :func:`world.world_stats.uav_metrics` names them).

The other triggers (a ``snapshot`` command, SIGUSR1) come from the recorder process.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

from recorder.schemas import envelope_fields
from recorder.seq_stats import SenderStats
from world.world_stats import UAV_METRIC_PREFIX

__all__ = ["Trigger", "TriggerWatch", "FAULT", "GAP", "MISSED", "COMMAND", "SIGNAL"]

FAULT, GAP, MISSED, COMMAND, SIGNAL = "fault", "gap", "missed", "command", "signal"
MISSED_SUFFIX = ".missed"
MAX_WHAT = 200  # characters of a trigger's description kept (the sender chooses some of them)
MAX_MISSED_NAMES = 4096  # "uav.<i>.missed" counts followed (bounded: the names come off the bus)


@dataclass(frozen=True)
class Trigger:
    kind: str  # FAULT | GAP | MISSED | COMMAND | SIGNAL
    at_ns: int  # log time (wall clock, ns) of the message or request that triggered
    what: str  # what happened, for people


class TriggerWatch:
    """Feed every message to :meth:`observe`; it returns the triggers that message raises."""

    def __init__(self) -> None:
        self._found: list[Trigger] = []
        self._stats = SenderStats(on_loss=self._on_loss)
        self._missed: dict[str, float] = {}  # "uav.<i>.missed" -> last value seen

    def _on_loss(self, src: str, kind: str, skipped: int, log_time: int, _pub: int) -> None:
        self._found.append(Trigger(GAP, log_time, f"{src} {kind}: {skipped} message(s) skipped by seq"[:MAX_WHAT]))

    def observe(self, payload: bytes, log_time_ns: int) -> list[Trigger]:
        env = envelope_fields(payload)
        if env is None:
            return []
        kind, src, seq, _t, body, inc = env
        self._stats.observe(src, kind, inc, seq, log_time_ns, log_time_ns)
        if kind == "fault" and body.get("phase") == "start":
            what = f"{body.get('fault')} fault starts on {body.get('target')} (from {src})"
            self._found.append(Trigger(FAULT, log_time_ns, what[:MAX_WHAT]))
        elif kind == "metrics" and body.get("scope") == "step":
            self._check_missed(body.get("values"), body.get("tick"), log_time_ns)
        if not self._found:
            return []
        found, self._found = self._found, []
        return found

    def _check_missed(self, values: object, tick: object, log_time_ns: int) -> None:
        if not isinstance(values, dict):
            return
        grew: list[str] = []
        for name, value in values.items():
            if isinstance(name, str) and name.startswith(UAV_METRIC_PREFIX) and name.endswith(MISSED_SUFFIX) \
                    and isinstance(value, (int, float)):
                before: Optional[float] = self._missed.get(name)
                if before is None and len(self._missed) >= MAX_MISSED_NAMES:
                    continue
                self._missed[name] = value
                if value > (before or 0):
                    grew.append(f"{name[len(UAV_METRIC_PREFIX):-len(MISSED_SUFFIX)]}")
        if grew:
            self._found.append(Trigger(MISSED, log_time_ns,
                                       f"tick {tick}: UAV(s) {', '.join(grew)} missed actions"[:MAX_WHAT]))
