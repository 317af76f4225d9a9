"""SUMO traffic traces: build them with the eclipse-sumo wheel's tools and
libsumo, cache them, load them for the world (scenario.mobility = "sumo").

The thin I/O around world/sumo_scenario.py (arguments, weights, the driving
loop) and world/trace.py (the arrays): netgenerate and randomTrips.py run as
subprocesses of the wheel (randomTrips.py is no console script: it runs with
this interpreter), with SUMO_HOME set to the wheel's own for them and for
libsumo, so a SUMO_HOME set elsewhere for another install cannot mix files of
two versions. libsumo runs one simulation at a time in a process; this module
starts and closes it around each build.

A trace is cached under `cache_root()` by scenario and seed
(sumo_scenario.cache_key): `<root>/<key>/trace.npz` beside the network and
trips it was made from.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
import zipfile
import zlib
from pathlib import Path
from typing import Callable

import numpy as np

from truav.checks import make_dir
from truav.config import Config
from truav.errors import UserError
from truav.user_cache import truav_cache_dir
from world import sumo_scenario
from world.trace import Trace, rows_needed
from truav import jsonio

INSTALL_HINT = "pip install -e '.[sumo]' (eclipse-sumo and libsumo 1.28)"
TRACE_FILE = "trace.npz"
NET_FILE = "grid.net.xml"
TRIPS_FILE = "trips.xml"


def sumo_home() -> str:
    """The eclipse-sumo wheel's SUMO_HOME, set for this process; one line naming what to install if it is missing."""
    try:
        import sumo
        import sumolib  # noqa: F401
    except ImportError:
        raise UserError(f"scenario.mobility = sumo needs SUMO, which is not installed: {INSTALL_HINT}") from None
    os.environ["SUMO_HOME"] = sumo.SUMO_HOME  # the wheel's, even where another install set its own
    return sumo.SUMO_HOME


def sumo_version() -> str:
    from importlib.metadata import version
    sumo_home()
    return version("eclipse-sumo")


def cache_root() -> Path:
    """Where traces are cached: $TRUAV_TRACE_CACHE, else <XDG cache>/truav/sumo."""
    if os.environ.get("TRUAV_TRACE_CACHE"):
        return Path(os.environ["TRUAV_TRACE_CACHE"])
    return truav_cache_dir() / "sumo"


def trace_dir(cfg: Config, root: Path | None = None) -> Path:
    return (root or cache_root()) / sumo_scenario.cache_key(cfg, sumo_version())


def check_size(cfg: Config) -> None:
    """A trace that fits in memory: its arrays (rows_needed x scenario.n_vehicles) are held whole by the builder
    and by every world that replays it; one line naming the sizes if they could not be (before SUMO runs for
    hours drawing the trips of such a run)."""
    rows, n = rows_needed(cfg), cfg.scenario.n_vehicles
    need = rows * n * (2 * 8 + 1)  # positions (float64 x 2) and active (bool) per vehicle and row
    try:
        memory = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return
    if need > memory // 2:
        raise UserError(f"sumo.trace_episodes {cfg.sumo.trace_episodes} x scenario.steps_per_episode "
                        f"{cfg.scenario.steps_per_episode} x scenario.n_vehicles {n}: the trace would hold {rows} rows "
                        f"of {n} vehicles ({need / 1e9:.3g} GB), more than half this machine's memory "
                        f"({memory / 1e9:.3g} GB); give fewer sumo.trace_episodes")


def _run_tool(argv: list[str], what: str, cwd: Path) -> None:
    done = subprocess.run(argv, capture_output=True, text=True, cwd=cwd,
                          env={**os.environ, "SUMO_HOME": sumo_home()})
    if done.returncode != 0:
        tail = (done.stderr or done.stdout).strip().splitlines()[-1:] or ["no output"]
        raise RuntimeError(f"{what} failed (exit {done.returncode}): {tail[0]}")


def make_network(cfg: Config, work: Path) -> Path:
    """The grid network and the hotspot-weighted trips, in work/ (NET_FILE, TRIPS_FILE)."""
    import sumolib
    home = sumo_home()
    net = work / NET_FILE
    _run_tool([os.path.join(home, "bin", "netgenerate"), *sumo_scenario.netgenerate_args(cfg, str(net))],
              "netgenerate", work)
    edges = [e for e in sumolib.net.readNet(str(net)).getEdges() if e.allows("passenger")]
    centres = np.array([np.mean(e.getShape(), axis=0) for e in edges])
    weights = sumo_scenario.weights_xml([e.getID() for e in edges], sumo_scenario.hotspot_weights(centres, cfg))
    for suffix in (".src.xml", ".dst.xml"):
        (work / f"weights{suffix}").write_text(weights)
    trips = work / TRIPS_FILE
    _run_tool([sys.executable, os.path.join(home, "tools", "randomTrips.py"),
               *sumo_scenario.randomtrips_args(cfg, str(net), str(work / "weights"), str(trips),
                                               str(work / "routes.rou.xml"))], "randomTrips.py", work)
    return net


def drive_inputs(cfg: Config, work: Path) -> tuple[list[tuple[str, str]], tuple[list[str], np.ndarray]]:
    """What sumo_scenario.drive takes besides the simulation, from work/'s network and trips:
    ([(from, to)] trips, (the ids of the edges cars may take, their midpoints (E, 2)))."""
    import sumolib
    sumo_home()
    edges = [e for e in sumolib.net.readNet(str(work / NET_FILE)).getEdges() if e.allows("passenger")]
    centres = np.array([np.mean(e.getShape(), axis=0) for e in edges])
    trips = [(t.attr_from, t.to) for t in sumolib.xml.parse_fast(str(work / TRIPS_FILE), "trip", ["from", "to"])]
    return trips, ([e.getID() for e in edges], centres)


def record(cfg: Config, work: Path) -> Trace:
    """Run SUMO in-process (libsumo) over work/'s network and trips; the trace of its vehicle positions."""
    sumo_home()
    try:
        import libsumo
    except ImportError:
        raise UserError(f"scenario.mobility = sumo needs libsumo, which is not installed: {INSTALL_HINT}") from None
    n, rows = cfg.scenario.n_vehicles, rows_needed(cfg)
    positions = np.full((rows, n, 2), np.nan)
    active = np.zeros((rows, n), np.bool_)

    def on_row(r: int, pos: np.ndarray, act: np.ndarray) -> None:
        positions[r], active[r] = pos, act

    trips, edges = drive_inputs(cfg, work)
    libsumo.start(["sumo", *sumo_scenario.sumo_args(cfg, str(work / NET_FILE))])
    try:
        sumo_scenario.drive(libsumo, cfg, trips, edges, on_row)
    finally:
        libsumo.close()
    return Trace(positions, active, float(cfg.scenario.step_s), int(cfg.scenario.steps_per_episode))


def save_trace(trace: Trace, path: Path, meta: dict) -> None:
    tmp = path.with_suffix(".tmp.npz")
    np.savez_compressed(tmp, positions=trace.positions, active=trace.active, step_s=trace.step_s,
                        steps_per_episode=trace.steps_per_episode, meta=jsonio.dumps(meta))
    os.replace(tmp, path)


def read_trace(path: Path) -> Trace:
    """The trace in ``path``; one line naming it if it is empty, truncated, corrupt or not a trace."""
    # What np.load raises on an empty, truncated or foreign file: a damaged cache entry, not a bug.
    try:
        with np.load(path) as z:
            return Trace(z["positions"], z["active"], float(z["step_s"]), int(z["steps_per_episode"]))
    except (OSError, EOFError, KeyError, ValueError, TypeError, AttributeError, zipfile.BadZipFile,
            zlib.error) as exc:
        raise UserError(f"{path}: not a readable trace ({type(exc).__name__}: {exc}); build it again with "
                        f"`truav traffic build --force`") from None


def build_trace(cfg: Config, root: Path | None = None, force: bool = False,
                say: Callable[[str], None] = lambda line: None) -> tuple[Path, bool]:
    """The cached trace of cfg's scenario and sumo.trace_seed, built if missing
    (or with force): (its path, whether it was built now)."""
    out = trace_dir(cfg, root)
    path = out / TRACE_FILE
    if path.is_file() and not force:
        return path, False
    if path.exists() and not path.is_file():
        raise UserError(f"{path}: in the SUMO trace cache but not a regular file; remove it")
    check_size(cfg)
    make_dir("SUMO trace cache (--cache, $TRUAV_TRACE_CACHE)", out)
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(dir=out) as tmp:
        work = Path(tmp)
        say(f"building the SUMO trace {out.name}: netgenerate, randomTrips.py ...")
        make_network(cfg, work)
        t_net = time.perf_counter() - t0
        say(f"SUMO drives {cfg.scenario.n_vehicles} vehicles for {cfg.sumo.warmup_s:g} s + "
            f"{rows_needed(cfg) - 1} steps of {cfg.scenario.step_s:g} s ...")
        trace = record(cfg, work)
        for name in (NET_FILE, TRIPS_FILE):
            os.replace(work / name, out / name)
    meta = {"sumo": sumo_version(), "trace_seed": cfg.sumo.trace_seed, "build_s": time.perf_counter() - t0,
            "network_s": t_net, "inactive_share": float(1.0 - trace.active.mean())}
    save_trace(trace, path, meta)
    return path, True


def checked_trace(cfg: Config, root: Path | None = None, force: bool = False,
                  say: Callable[[str], None] = lambda line: None) -> tuple[Path, Trace, bool]:
    """build_trace, then the trace read and held against cfg: (its path, the trace, whether it was built now);
    a damaged or foreign cached file is one line naming it. The CLIs call it before anything starts."""
    path, built = build_trace(cfg, root, force, say)
    trace = read_trace(path)
    problem = trace.mismatch(cfg)
    if problem:
        raise UserError(f"{path}: {problem}; build it again with `truav traffic build --force`")
    return path, trace, built


def trace_for(cfg: Config, say: Callable[[str], None] = lambda line: None) -> Trace | None:
    """The trace a world of cfg replays (built and cached on first use), or None for the grid's own mobility."""
    if cfg.scenario.mobility != "sumo":
        return None
    return checked_trace(cfg, say=say)[1]


def make_world(cfg: Config, batch: int, say: Callable[[str], None] = lambda line: None):
    """A World of cfg, replaying its SUMO trace if scenario.mobility is "sumo"."""
    from world.env import World
    return World(cfg, batch, trace_for(cfg, say))


__all__ = ["build_trace", "cache_root", "checked_trace", "make_world", "read_trace", "trace_for", "INSTALL_HINT"]
