"""How a recording is laid out in files: one file, parts split by size/time/command, or snapshots.

:class:`RecordModes` declares the flags once (``truav.options.opt``): ``truav log record`` and
``truav-swarm record`` add them from here, ``truav-swarm up --record`` too, and the supervisor
passes them to its recorder with ``truav.options.to_argv``.  The file names and the metadata
records that other tools read (``truav log merge``, replay of a split run) are named here:

* parts: ``<stem>_0001.mcap``, ``<stem>_0002.mcap``, ... beside the requested path, each with a
  metadata record :data:`PART_METADATA` (:data:`PART_FIELDS`), and ``<stem>.parts.json`` listing
  them in order (rewritten as each part finishes);
* snapshots: ``<stem>_snap_0001.mcap``, ... each with a metadata record :data:`SNAPSHOT_METADATA`.

Pure: no bus, no files written here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

from truav.errors import UserError
from truav.options import opt

__all__ = ["RecordModes", "parse_snapshot", "part_path", "snapshot_path", "parts_index_path",
           "PART_METADATA", "SNAPSHOT_METADATA", "PART_FIELDS", "MODE_FLAGS"]

PART_METADATA = "truav.part"
"""Metadata record of every part of a split recording (string values, PART_FIELDS)."""
PART_FIELDS = ("session", "part", "reason", "first_log_time_ns", "last_log_time_ns")
"""session: one random hex id for the whole recording; part: 1-based; reason: why this part ended
(REASONS); first/last_log_time_ns: the part's log-time range ("" for a part without messages)."""
SNAPSHOT_METADATA = "truav.snapshot"
"""Metadata record of a snapshot file: trigger kind, time and what, the window, and every trigger it holds."""
PAUSE_METADATA = "truav.pause"
"""Metadata record written when recording pauses and when it resumes: a pause is not a loss."""

REASON_SIZE, REASON_DURATION, REASON_COMMAND, REASON_SIGNAL, REASON_END = "size", "duration", "command", "signal", "end"
REASONS = (REASON_SIZE, REASON_DURATION, REASON_COMMAND, REASON_SIGNAL, REASON_END)

PARTS_INDEX_SUFFIX = ".parts.json"
DEFAULT_SNAPSHOT_MAX_MB = 256.0
MODE_FLAGS = ("split_size_mb", "split_duration_s", "split_on_command", "snapshot", "snapshot_max_mb")
"""The fields a supervisor passes to its recorder (truav.options.to_argv)."""


def parse_snapshot(text: str) -> tuple[float, float]:
    """``BEFORE_S:AFTER_S`` (seconds, each finite and > 0) -> (before, after); ValueError otherwise."""
    head, sep, tail = str(text).partition(":")
    try:
        if not sep:
            raise ValueError
        before, after = float(head), float(tail)
    except ValueError:
        raise ValueError(f"expected BEFORE_S:AFTER_S such as 10:5, got {text!r}") from None
    if not (math.isfinite(before) and math.isfinite(after) and before > 0 and after > 0):
        raise ValueError(f"both seconds must be finite and > 0, got {text!r}")
    return before, after


@dataclass(frozen=True)
class RecordModes:
    """Split, snapshot or neither (one file, as before); see the module docstring."""

    split_size_mb: Optional[float] = opt(None, flag="--split-size", type="positive_float", metavar="MB",
                                         help="start a new part once the current one holds this many MB on disk "
                                              "(<stem>_0001.mcap, ... and <stem>.parts.json)")
    split_duration_s: Optional[float] = opt(None, flag="--split-duration", type="positive_float", metavar="S",
                                            help="start a new part every S seconds")
    split_on_command: bool = opt(False, flag="--split-on-command", action="store_true",
                                 help="start a new part on SIGHUP or a `split` command on control/recorder (also "
                                      "with --split-size/--split-duration)")
    snapshot: Optional[str] = opt(None, flag="--snapshot", type="snapshot_window", metavar="BEFORE_S:AFTER_S",
                                  help="snapshot mode: keep the last BEFORE_S seconds in memory and write BEFORE_S "
                                       "before to AFTER_S after each trigger (fault, sequence gap, missed actions, "
                                       "`snapshot` command, SIGUSR1) into <stem>_snap_NNNN.mcap")
    snapshot_max_mb: float = opt(DEFAULT_SNAPSHOT_MAX_MB, flag="--snapshot-max-mb", type="positive_float",
                                 metavar="MB", help="snapshot mode: memory cap of the kept seconds "
                                                    f"(default {DEFAULT_SNAPSHOT_MAX_MB:g}; the oldest go first)")

    @property
    def split(self) -> bool:
        return self.split_size_mb is not None or self.split_duration_s is not None or self.split_on_command

    @property
    def window(self) -> Optional[tuple[float, float]]:
        """(before_s, after_s) in snapshot mode, else None."""
        return None if self.snapshot is None else parse_snapshot(self.snapshot)

    def validate(self) -> "RecordModes":
        """UserError (one line naming the flag) for a value a user got wrong; returns self."""
        for flag, value in (("--split-size", self.split_size_mb), ("--split-duration", self.split_duration_s),
                            ("--snapshot-max-mb", self.snapshot_max_mb)):
            if value is not None and not (math.isfinite(value) and value > 0):
                raise UserError(f"{flag}: must be a finite number > 0, got {value}")
        if self.snapshot is not None:
            try:
                parse_snapshot(self.snapshot)
            except ValueError as exc:
                raise UserError(f"--snapshot: {exc}") from None
            if self.split:
                raise UserError("--snapshot: snapshot mode writes one file per trigger; it does not mix with "
                                "--split-size/--split-duration/--split-on-command")
        return self


def _numbered(out: Path, infix: str, n: int) -> Path:
    out = Path(out)
    return out.with_name(f"{out.stem}{infix}_{n:04d}{out.suffix or '.mcap'}")


def part_path(out: Path, n: int) -> Path:
    """``<stem>_0001.mcap`` beside ``out`` for part 1."""
    return _numbered(out, "", n)


def snapshot_path(out: Path, n: int) -> Path:
    """``<stem>_snap_0001.mcap`` beside ``out`` for snapshot 1."""
    return _numbered(out, "_snap", n)


def parts_index_path(out: Path) -> Path:
    """``<stem>.parts.json`` beside ``out``."""
    out = Path(out)
    return out.with_name(out.stem + PARTS_INDEX_SUFFIX)
