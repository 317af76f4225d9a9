"""Whether other work shared the CPU while a real-time measurement ran: millisecond timing is then the
scheduler's, and a test reports its bounds instead of asserting them. The 1-minute load average lags (a
suite's last minutes end with it falling while the other workers still run), so the machine's busy cores are
also measured over the attempt itself, from /proc/stat."""

from __future__ import annotations

import os
from pathlib import Path

BUSY_CORES_LOADED = 1.0
"""More than this many cores busy during an attempt (its own work is a small part of one core): another job
competed for the CPU."""


def _jiffies() -> tuple[int, int] | None:
    """(total, idle incl. iowait) CPU jiffies of the whole machine; None where /proc/stat is not readable."""
    try:
        fields = [int(v) for v in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]]
    except (OSError, ValueError):
        return None
    return sum(fields), fields[3] + (fields[4] if len(fields) > 4 else 0)


class BusyCores:
    """``with BusyCores() as busy: ...``; then ``busy.cores``: the machine's average busy cores over the block
    (None where unknown), and ``busy.loaded``: whether other work competed (or the load average says so)."""

    def __enter__(self) -> "BusyCores":
        self._start, self.cores = _jiffies(), None
        return self

    def __exit__(self, *exc) -> None:
        end = _jiffies()
        if self._start is not None and end is not None and end[0] > self._start[0]:
            total, idle = end[0] - self._start[0], end[1] - self._start[1]
            self.cores = (total - idle) / total * (os.cpu_count() or 1)

    @property
    def loaded(self) -> bool:
        over_load_average = os.getloadavg()[0] > (os.cpu_count() or 1)
        return over_load_average or (self.cores is not None and self.cores > BUSY_CORES_LOADED)
