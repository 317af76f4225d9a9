"""Checks of a swarm's flags and files, run before anything starts: each raises a one-line UserError.

Fault plans, trained Q-tables and controllers, agent checkpoints, beacon cells, the flags that belong
to one scheme, the central scheme's message sizes, transport endpoints and credentials. The command
line (truav/cli/swarm*.py) calls them; nothing here parses arguments.
"""

from __future__ import annotations

import importlib.util
import json
import zipfile
import zlib
from pathlib import Path

import numpy as np

from agents.process.agent_options import AgentOptions
from agents.state import StateEncoder
from truav.analysis import policy_scenario, runio
from truav.analysis.policy_scenario import Fit
from truav.bus import security
from truav.checks import check_in_file, check_out_file
from truav.config import Config
from truav.errors import UserError
from truav.faults import check_plan_for, load_plan
from truav.wire import schema
from world.uavs import N_ACTIONS

SCHEMES = ("truav", "central", "patrol")
"""What flies the UAVs: TRUAV's agents, the central controller's commands, the patrol plan."""
DEFAULT_COMMAND_HOLD_S = AgentOptions.command_hold_s


def check_plan(flag: str, path: str, n_uavs: int, scheme: str | None = None):
    """A fault plan file that is valid and names only UAVs (and a controller) this swarm has."""
    check_in_file(flag, path)
    return check_plan_for(load_plan(path), n_uavs, path, scheme)


def check_qtable(flag: str, run: str, cfg: Config, index: int | None = None, full: bool = True,
                 allow_mismatch: bool = False) -> Fit | None:
    """A trained run (or its qtables.npz) whose tables fit this scenario; ``full``: read every
    entry and compare the scenario it was trained in (once, in `up`: its fit, for the summary), else
    only the array headers (each agent process, just before it loads them; None)."""
    try:
        if full:
            seeds, q = runio.read_qtables(run)
            n_seeds, shape = len(seeds), q.shape
        else:
            n_seeds, shape = runio.qtable_shapes(run)
        runio.check_qtables(run, shape, cfg, exact_uavs=False)
    except runio.RunDirError as exc:
        raise UserError(f"{flag}: {exc}") from None
    if index is not None and index >= n_seeds:
        raise UserError(f"--qtable-index {index}: {run} holds {n_seeds} table(s) (indices 0-{n_seeds - 1})")
    if not full:
        return None
    return policy_scenario.check(flag, run, runio.qtable_file(run), cfg, allow_mismatch, exact_uavs=False)


def check_agent_start(flag: str, run: str, name: str, cfg: Config, allow_mismatch: bool = False,
                      index: int = 0) -> Fit:
    """A run of `truav train --agent NAME` to start a swarm of agent ``name`` from: trained by that name, for
    this many UAVs, in a scenario that fits (truav.analysis.policy_scenario), and a state the class loads (tried on a
    throwaway instance of UAV 0, within its call_limit_s)."""
    from truav.analysis import agent_loader
    from truav.analysis.agent_run import agent_file, agent_start_states
    try:
        states = agent_start_states(run, name, cfg.scenario.n_uavs, index)
    except runio.RunDirError as exc:
        raise UserError(f"{flag}: {exc}") from None
    fit = policy_scenario.check(flag, run, agent_file(run), cfg, allow_mismatch)
    agent_loader.check_state(f"{flag} {run}", agent_loader.resolve(name), cfg, {"UAV 0's state": states[0]})
    return fit


def check_beacon_cell(cell_m: float | None, cfg: Config) -> None:
    """--beacon-cell only where a far neighbour cannot change the state (agents/beacon_cells.py)."""
    if cell_m is not None and cfg.learner.neighbour_sectors > 0:
        raise UserError(f"--beacon-cell {cell_m:g}: learner.neighbour_sectors = {cfg.learner.neighbour_sectors} puts "
                         f"the nearest neighbour's direction in the state, at any distance; range-limited beacons "
                         f"would change it")


def check_scheme_flags(args) -> None:
    """Flags that belong to one scheme only, given with another (one line, before anything starts)."""
    scheme = args.scheme
    if scheme != "truav" and not scheme.startswith("agent:"):  # an agent class starts from its training run
        for flag, given in (("--qtable", args.qtable), ("--greedy", args.greedy)):
            if given:
                raise UserError(f"{flag}: only --scheme truav and --agent fly trained policies (this is --scheme "
                                f"{scheme})")
    if scheme != "central":
        if getattr(args, "policy", None) is not None:
            raise UserError(f"--policy: only --scheme central flies a trained controller (this is --scheme {scheme})")
        if getattr(args, "command_hold", None) != DEFAULT_COMMAND_HOLD_S:
            raise UserError(f"--command-hold: only --scheme central has commands (this is --scheme {scheme})")


def check_policy(flag: str, run: str, cfg: Config, index: int, allow_mismatch: bool = False) -> Fit:
    """A trained central controller (`truav train --scheme central`) that fits this scenario; its fit."""
    try:
        runio.read_policy(run, index, cfg)
    except runio.RunDirError as exc:
        raise UserError(f"{flag}: {exc}") from None
    path = Path(run)
    return policy_scenario.check(flag, run, path / runio.POLICY_FILE if path.is_dir() else path, cfg, allow_mismatch)


def check_central_sizes(cfg: Config) -> None:
    """The central scheme's messages are padded to the model's sizes: they must fit one bus message,
    and the controller needs torch."""
    limit = schema.MAX_SMALL_PAYLOAD_BYTES
    for key in ("upload_bytes", "download_bytes"):
        value = getattr(cfg.central, key)
        if value > limit:
            raise UserError(f"central.{key} = {value}: a message on the bus holds at most {limit} bytes")
    if importlib.util.find_spec("torch") is None:
        raise UserError("--scheme central: the controller needs PyTorch: pip install -e '.[central]'")


def check_checkpoint(path: str, cfg: Config, api_agent: bool = False) -> None:
    """An agent checkpoint: resumed from if it exists (then it must be one), else creatable. ``api_agent``:
    of an agents.api class (agents.process.api_process: its state arrays, steps, rng_state; no Q-table)."""
    p = Path(path)
    if not p.exists():
        check_out_file("--checkpoint", path)
        return
    check_in_file("--checkpoint", path)
    try:
        with np.load(p, allow_pickle=False) as ck:
            shape = None if api_agent else ck["q"].shape
            _, _ = int(ck["steps"]), json.loads(str(ck["rng_state"]))
    except (OSError, EOFError, ValueError, KeyError, TypeError, AttributeError, zipfile.BadZipFile, zlib.error) as exc:
        raise UserError(f"--checkpoint {path}: not an agent checkpoint (.npz with {'' if api_agent else 'q, '}steps, "
                        f"rng_state): {type(exc).__name__}") from None
    if api_agent:
        return
    want = (StateEncoder(cfg).n_states, N_ACTIONS)
    if shape != want:
        raise UserError(f"--checkpoint {path}: its Q-table is {shape}, this scenario needs {want}")



def check_creds_fit(args, cfg: Config) -> None:
    """``--creds`` made for another number of agents than the scenario flies: one line, before anything starts."""
    if not getattr(args, "creds", None):
        return
    try:
        creds = security.load(args.creds, args.run)
    except security.CredentialsError as exc:
        raise UserError(str(exc)) from None
    if creds.n_uavs != cfg.scenario.n_uavs:
        raise UserError(f"--creds {args.creds} was made for {creds.n_uavs} agents, the scenario has "
                        f"{cfg.scenario.n_uavs} (scenario.n_uavs): pass --set scenario.n_uavs={creds.n_uavs}")

