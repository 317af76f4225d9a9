"""``truav report FILE``: pictures of a recorded swarm run, and its metrics as CSV.

Writes into ``--out`` (default ``<file stem>_report/`` next to the file):

``map.png``       roads and RSUs (from the run config stored in the file, when
                  there is one), the vehicle density heat map (from
                  ``world/positions``), each UAV's track fading in over time
                  (from beacons; observations or positions when there are
                  none) and coverage discs at its last position;
``metrics.png``   every step metric over time, fault intervals shaded,
                  episode starts dotted;
``agents.png``    beacon rate per agent over time as the recorder heard it (a
                  heat map: agents that sent none show as gaps; the recorder
                  hears every beacon, so receiver-side loss is in links.png), one-way beacon latency per agent
                  (receive time - sender timestamp: same-host clocks, so it is
                  the bus latency) and its median/p99 over time;
``links.png``     beacon delivery per link (sender x receiver, share heard) from the
                  agents' own counts in their health reports: receiver-side loss,
                  partitions and restarts show here (recorder.report_links);
``metrics.csv``   one row per metrics message (step and episode scope).

Only what is in the file is drawn; a figure with nothing to show is skipped
and said so.  Payloads are decoded leniently (msgpack maps with the
envelope), so a recording with odd messages still reports.

The pieces: :mod:`recorder.report_data` reads the recording,
:mod:`recorder.report_figures` draws the pictures; this module writes the CSV
and puts the report together.
"""

from __future__ import annotations

import csv
import os
from pathlib import Path

from recorder.reader import open_source, probe
from truav.csvio import cell
from recorder.report_data import (  # noqa: F401  (re-exported: the tests read a recording through here)
    FaultSpan,
    MapConfig,
    Recording,
    ReportError,
    Series,
    load_recording,
)
from recorder.report_figures import agents_figure, map_figure, metrics_figure
from recorder.report_links import links_figure

MAP_FILE, METRICS_FIG_FILE, AGENTS_FILE, METRICS_CSV_FILE = "map.png", "metrics.png", "agents.png", "metrics.csv"
LINKS_FILE = "links.png"
REPORT_DIR_SUFFIX = "_report"
CSV_FIXED = ("time_s", "log_time_ns", "publish_time_ns", "src", "scope", "episode", "tick")


def write_metrics_csv(rec: Recording, path: Path) -> str:
    """Every metrics message, ordered by receive time; one column per metric name."""
    names = sorted({n for m in rec.metrics for n in m["values"]})
    with open(path, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow([*CSV_FIXED, *names])
        for m in sorted(rec.metrics, key=lambda m: m["_log_ns"]):
            values = m["values"]
            writer.writerow([f"{rec.t(m['_log_ns']):.6f}", m["_log_ns"], m["_pub_ns"], m.get("src", ""),
                             m.get("scope", ""), m.get("episode", ""), m.get("tick", ""),
                             *(cell(None if values.get(n) is None else float(values[n])) for n in names)])
    return f"metrics.csv: {len(rec.metrics)} rows x {len(names)} metrics"


# --- entry point -------------------------------------------------------------------------------------
def default_out_dir(path: Path) -> Path:
    return path.with_name(path.stem + REPORT_DIR_SUFFIX)


def report(path: str | os.PathLike[str], out: str | os.PathLike[str] | None = None) -> tuple[Path, list[str]]:
    """Write the report of ``path`` into ``out``; returns (out dir, one line per output or skip)."""
    path = Path(path)
    if not path.is_file():
        raise ReportError(f"{path}: no such file")
    try:
        with open_source(path) as stream:
            state = probe(stream)
    except ValueError as exc:
        raise ReportError(f"{path}: {exc}") from None
    out_dir = Path(out) if out is not None else default_out_dir(path)
    if out_dir.exists() and not out_dir.is_dir():
        raise ReportError(f"{out_dir} exists and is not a directory")
    out_dir.mkdir(parents=True, exist_ok=True)
    rec = load_recording(path)
    lines = [f"{path}: {rec.messages} messages over {rec.duration_s:.1f} s"
             + ("" if state.finished else " (unfinished file: read up to its last complete chunk)")]
    if rec.refused:
        lines.append(f"  left out {sum(rec.refused.values())} UAV message(s): "
                     + ", ".join(f"{n} {reason}" for reason, n in sorted(rec.refused.items())))
    for fname, make, what in ((MAP_FILE, map_figure, "no positions"), (METRICS_FIG_FILE, metrics_figure, "no metrics"),
                              (AGENTS_FILE, agents_figure, "no beacons"),
                              (LINKS_FILE, links_figure, "no agent counted the beacons it heard")):
        done = make(rec, out_dir / fname)
        lines.append(f"  {out_dir / fname}  ({done})" if done else f"  {fname}: skipped, {what} in the recording")
    lines.append(f"  {out_dir / METRICS_CSV_FILE}  ({write_metrics_csv(rec, out_dir / METRICS_CSV_FILE)})")
    return out_dir, lines
