"""Check a re-simulation against its recording, tick by tick, bit for bit.

:class:`RecordedTicks` reads the recording's observations, beacons (one per message, or split out of a
process's batch, `--batch-beacons`) and actions and hands them out per tick; :func:`verify` steps a
recorder.resim.Resimulation and compares every message it would send with the recorded one of the same
tick, kind and UAV: every payload field, floats by their bits (the envelope's sender, sequence, time stamp
and incarnation are the run's, not the model's, and are not compared). A message re-simulated but not
recorded, or recorded but not re-simulated, is a divergence too.
"""

from __future__ import annotations

import math
import os
import struct
from collections import defaultdict
from dataclasses import dataclass, field
from typing import Any, Callable

from recorder.reader import iter_messages
from recorder.resim import Resimulation, Round, payload_fields
from recorder.resim_snapshots import differing_arrays, iter_snapshots
from truav.wire import keys, schema

LOOKAHEAD_TICKS = 2
"""A tick's recorded messages are taken once a message this many ticks later was read: the recorder receives
the processes' messages in arrival order, which across senders may differ from the tick order by a little."""
MAX_KEPT = 20
"""Divergences kept with their values (the first is always among them); the rest are counted."""

KINDS = (schema.KIND_OBS, schema.KIND_BEACON, schema.KIND_ACTION)
Slot = tuple[str, int]  # (kind, uav)


@dataclass(frozen=True)
class Divergence:
    """One message of a tick that the re-simulation did not reproduce."""

    tick: int
    key: str
    field: str
    recorded: Any
    simulated: Any

    def format(self) -> str:
        return f"tick {self.tick}, {self.key}, {self.field}: recorded {self.recorded!r}, re-simulated {self.simulated!r}"


@dataclass
class Verification:
    """What a comparison found: totals per kind, the first divergences."""

    ticks: int = 0
    compared: dict[str, int] = field(default_factory=lambda: {k: 0 for k in KINDS})
    matched: dict[str, int] = field(default_factory=lambda: {k: 0 for k in KINDS})
    divergent_messages: int = 0
    divergences: list[Divergence] = field(default_factory=list)
    duplicates: int = 0
    """Recorded messages of a (tick, kind, UAV) already recorded (the first is compared)."""
    undecodable: int = 0
    leftover: int = 0
    """Recorded messages of ticks the re-simulation never reached (or arriving after their tick was checked)."""
    cut_short: int = 0
    """Messages of the recording's last tick it does not hold (a run stopped amid a tick): not compared."""
    recording_ended: bool = False
    """The recording ended before the run's last tick (its run was stopped early): checked up to there."""
    snapshots_checked: int = 0
    """Recorded state snapshots compared with the re-simulated state at their tick, array by array."""
    snapshots_differing: int = 0

    @property
    def first(self) -> Divergence | None:
        return self.divergences[0] if self.divergences else None

    @property
    def exact(self) -> bool:
        return self.divergent_messages == 0 and self.leftover == 0 and self.undecodable == 0 \
            and self.snapshots_differing == 0

    def summary_lines(self) -> list[str]:
        total = sum(self.compared.values())
        per_kind = ", ".join(f"{self.matched[k]}/{self.compared[k]} {k}" for k in KINDS)
        lines = [f"{self.ticks} ticks re-simulated: {total - self.divergent_messages} of {total} messages reproduced "
                 f"bit for bit ({per_kind})"]
        if self.first is not None:
            lines.append(f"first divergence: {self.first.format()}")
            lines += [f"  then: {d.format()}" for d in self.divergences[1:5]]
            if self.divergent_messages > 5:
                lines.append(f"  ... {self.divergent_messages - 5} more divergent message(s)")
        extra = [f"{n} {what}" for n, what in ((self.leftover, "recorded message(s) never compared (of ticks not re-simulated, or late)"),
                                               (self.undecodable, "undecodable recorded message(s)"),
                                               (self.duplicates, "duplicate recorded message(s), first compared"),
                                               (self.cut_short, "message(s) of the last recorded tick not recorded "
                                                                "(the run stopped amid it), not compared"))
                 if n]
        if extra:
            lines.append("also: " + "; ".join(extra))
        if self.snapshots_checked:
            lines.append(f"{self.snapshots_checked - self.snapshots_differing} of {self.snapshots_checked} recorded "
                         f"state snapshot(s) equal the re-simulated state, array by array")
        if self.recording_ended:
            lines.append(f"the recording ends after tick {self.ticks - 1}, before the run's last episode ended "
                         f"(stopped early): checked up to there")
        return lines


class RecordedTicks:
    """The recording's observations, beacons and actions of run ``run``, handed out per tick in order."""

    def __init__(self, path: str | os.PathLike[str], run: str, result: Verification, from_tick: int = 0):
        prefix = keys.prefix(run)
        self._messages = iter_messages(path, include=[f"{prefix}/uav/*", f"{prefix}/group/*"])
        self._pending: dict[int, dict[Slot, tuple[str, Any]]] = defaultdict(dict)
        self._newest = -1
        self._done = False
        self._from = from_tick  # earlier ticks are not wanted (a branch compares from its tick on)
        self._result = result

    def take(self, tick: int) -> dict[Slot, tuple[str, Any]]:
        """{(kind, uav): (key, message)} recorded for ``tick``."""
        while not self._done and self._newest < tick + LOOKAHEAD_TICKS:
            self._read_one()
        for late in [t for t in self._pending if t < tick]:  # arrived after its tick was compared: never compared
            self._result.leftover += len(self._pending.pop(late))
        return self._pending.pop(tick, {})

    def ended_before(self, tick: int) -> bool:
        """Whether the recording holds nothing of ``tick`` or later (its run stopped before)."""
        while not self._done and self._newest < tick:
            self._read_one()
        return self._done and not any(t >= tick for t in self._pending)

    def lowest(self) -> int | None:
        """The lowest tick held, once the ticks near the first one read are in (arrival order)."""
        if not self._pending:
            return None
        self.ended_before(min(self._pending) + LOOKAHEAD_TICKS)
        return min(self._pending)

    def leftover(self) -> int:
        """Recorded messages not taken: drains the rest of the file."""
        while not self._done:
            self._read_one()
        return self._result.leftover + sum(len(slots) for slots in self._pending.values())

    def _read_one(self) -> None:
        try:
            key, payload, _, _ = next(self._messages)
        except StopIteration:
            self._done = True
            return
        try:
            msg = schema.decode(payload)
        except schema.SchemaError:
            self._result.undecodable += 1
            return
        if isinstance(msg, schema.Beacons):  # a process's batch: one beacon per entry, keyed as it would be alone
            for uav, tick, pos, vel in msg.entries:
                self._keep(key, schema.Beacon(uav=uav, tick=tick, pos=pos, vel=vel))
        elif msg.KIND in KINDS:
            self._keep(key, msg)

    def _keep(self, key: str, msg: Any) -> None:
        self._newest = max(self._newest, msg.tick)
        if msg.tick < self._from:
            return
        slots = self._pending[msg.tick]
        slot = (msg.KIND, msg.uav)
        if slot in slots:
            self._result.duplicates += 1
        else:
            slots[slot] = (key, msg)


def same(a: Any, b: Any) -> bool:
    """Equal bit for bit: floats by their IEEE bits (so -0.0 differs from 0.0, a NaN equals the same NaN),
    sequences element by element."""
    if isinstance(a, (tuple, list)) and isinstance(b, (tuple, list)):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b))
    if isinstance(a, float) or isinstance(b, float):
        if not isinstance(a, (int, float)) or not isinstance(b, (int, float)) or isinstance(a, bool) \
                or isinstance(b, bool):
            return False
        return struct.pack("<d", float(a)) == struct.pack("<d", float(b))
    return type(a) is type(b) and a == b if isinstance(a, bool) or isinstance(b, bool) else a == b


def _plain(value: Any) -> Any:
    """A value as a report shows it (numpy floats as Python floats, tuples kept)."""
    if isinstance(value, (tuple, list)):
        return tuple(_plain(v) for v in value)
    if isinstance(value, float) and not math.isnan(value):
        return float(value)
    return value


def _key_of(run: str, kind: str, uav: int) -> str:
    return {schema.KIND_OBS: keys.uav_obs, schema.KIND_BEACON: keys.uav_beacon,
            schema.KIND_ACTION: keys.uav_action}[kind](run, uav)


def compare_round(rnd: Round, recorded: dict[Slot, tuple[str, Any]], run: str, result: Verification,
                  last: bool = False) -> int:
    """Compare one re-simulated tick with its recorded messages; the number of divergent messages. ``last``: the
    recording's last tick, which a stopped run may have cut short: what it lacks is not compared."""
    divergent = 0
    simulated = [*rnd.obs, *rnd.beacons, *rnd.actions]
    for msg in simulated:
        slot = (msg.KIND, msg.uav)
        result.compared[msg.KIND] += 1
        got = recorded.pop(slot, None)
        if got is None and last:
            result.compared[msg.KIND] -= 1
            result.cut_short += 1
            continue
        if got is None:
            found = [Divergence(rnd.tick, _key_of(run, *slot), "(message)", "not recorded", "sent")]
        else:
            key, rec = got
            mine, theirs = payload_fields(msg), payload_fields(rec)
            found = [Divergence(rnd.tick, key, name, _plain(theirs.get(name)), _plain(value))
                     for name, value in mine.items() if not same(theirs.get(name), value)]
        if found:
            divergent += 1
            room = MAX_KEPT - len(result.divergences)
            result.divergences.extend(found[:max(room, 0)] if room > 0 else [])
        else:
            result.matched[msg.KIND] += 1
    for (kind, uav), (key, _) in sorted(recorded.items()):  # recorded, never re-simulated
        divergent += 1
        result.compared[kind] += 1
        if len(result.divergences) < MAX_KEPT:
            result.divergences.append(Divergence(rnd.tick, key, "(message)", "recorded", "not sent"))
    result.divergent_messages += divergent
    return divergent


def first_tick(path: str | os.PathLike[str], run: str) -> int | None:
    """The first tick the recording holds observations, beacons or actions of run ``run`` of (reads the file's
    first few ticks only); None when it holds none."""
    ticks = RecordedTicks(path, run, Verification())
    ticks.ended_before(0)
    return ticks.lowest()


def verify(path: str | os.PathLike[str], run: str, sim: Resimulation, until_tick: int | None = None,
           on_round: Callable[[Round, int], None] | None = None, stop_at_first: bool = False,
           check_snapshots: bool = True) -> Verification:
    """Step ``sim`` and compare each tick with the recording, up to (not including) ``until_tick``, the run's
    end or the recording's (a run stopped early); ``on_round(round, divergent)`` after each tick (progress).
    ``stop_at_first``: stop after the first divergent tick. ``check_snapshots``: at each tick the recording
    holds a state snapshot of, compare it with the re-simulated state, array by array (a snapshot that
    differs would restore a branch wrongly)."""
    result = Verification()
    recorded = RecordedTicks(path, run, result, from_tick=sim.tick)  # a restored sim starts at its snapshot
    snapshots = iter_snapshots(path, run, len(sim.agents)) if check_snapshots else iter(())
    snap = next(snapshots, None)
    while sim.episode < sim.episodes and (until_tick is None or sim.tick < until_tick):
        if recorded.ended_before(sim.tick):
            result.recording_ended = True
            break
        while snap is not None and snap.tick < sim.tick:
            snap = next(snapshots, None)
        if snap is not None and snap.tick == sim.tick:
            _check_snapshot(snap, sim, run, result)
        rnd = sim.step()
        messages = recorded.take(rnd.tick)
        last = recorded.ended_before(rnd.tick + 1)
        divergent = compare_round(rnd, messages, run, result, last)
        result.ticks += 1
        if on_round is not None:
            on_round(rnd, divergent)
        if divergent and stop_at_first:
            break
        if last and sim.episode < sim.episodes:  # the run was stopped here
            result.recording_ended = True
            break
    if until_tick is None and not (stop_at_first and result.divergent_messages):
        result.leftover = recorded.leftover()
    return result


def _check_snapshot(snap, sim: Resimulation, run: str, result: Verification) -> None:
    _, world, agents = sim.snapshot()
    result.snapshots_checked += 1
    differing = differing_arrays(snap, world, agents, run)
    if differing:
        result.snapshots_differing += 1
        if len(result.divergences) < MAX_KEPT:
            key, name = differing[0]
            result.divergences.append(Divergence(snap.tick, key, f"state array {name}", "recorded",
                                                 f"differs ({len(differing)} array(s) in all)"))


__all__ = ["Divergence", "RecordedTicks", "Verification", "compare_round", "first_tick", "same", "verify"]
