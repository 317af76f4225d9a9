"""The layer order of the project's modules, read from their source with ast.

Every import of every project module (truav/, agents/, world/, recorder/, bench/) is read,
those inside functions too, relative imports resolved, and the test fails:

(a) on an import cycle among project modules (the cycle is named);
(b) when a module imports a module of a higher layer than its own (LAYERS below);
(c) when a non-CLI module imports argparse, or a pure layer (base, model, wire, analysis) imports zenoh;
(d) when a non-CLI module imports a CLI module;
(e) when argparse is imported, or truav.cli is imported, outside the folder truav/cli/ (bench/'s
    scripts, command lines of their own, aside).

Every project module must match a pattern of LAYERS: an unmatched module fails the test, so a new
module is placed deliberately. Imports that break a rule today and are being removed (issue 27)
are listed in KNOWN_VIOLATIONS; an entry that no longer occurs fails the test too, so the list
only shrinks.
"""
from __future__ import annotations

import ast
import fnmatch
from pathlib import Path

import pytest

# ---------------------------------------------------------------------------------------------
# The layer map: module name pattern (fnmatch) -> layer. The FIRST matching row wins, so the
# specific rows come before the catch-all rows of a package. A module may import its own layer
# or a lower one, never a higher one.
# ---------------------------------------------------------------------------------------------
BASE, MODEL, WIRE, ANALYSIS, BUS, PROCESS, ORCHESTRATION, CLI, BENCH = range(1, 10)
LAYER_NAMES = {BASE: "base", MODEL: "model", WIRE: "wire", ANALYSIS: "analysis", BUS: "bus",
               PROCESS: "process", ORCHESTRATION: "orchestration", CLI: "cli", BENCH: "bench"}
PURE = {BASE, MODEL, WIRE, ANALYSIS}   # may not import zenoh

LAYERS: list[tuple[str, int]] = [
    # -- 9 bench: scripts above everything (may import anything; no cycles among them) -------
    ("bench.*",                         BENCH),
    # -- 8 cli: command-line modules (argparse lives only here) --------------------------------
    ("truav.cli",                       CLI),    # the command-line package: every parser of
    ("truav.cli.*",                     CLI),    # truav, truav-swarm and truav log, nothing else
    # -- 1 base: errors, checks, seeds, statistics, config, fault model ------------------------
    ("truav",                           BASE),   # package __init__ files hold nothing above base
    ("truav.bus",                       BASE),
    ("truav.swarm",                     BASE),
    ("truav.experiments",               BASE),
    ("agents",                          BASE),
    ("world",                           BASE),
    ("recorder",                        BASE),
    ("truav.errors",                    BASE),
    ("truav.stopping",                  BASE),
    ("truav.jsonio",                    BASE),
    ("truav.atomic",                    BASE),
    ("truav.call_limit",                BASE),
    ("truav.channel_catalog",           BASE),
    ("truav.actions",                   BASE),
    ("truav.checks",                    BASE),
    ("truav.seeding",                   BASE),
    ("truav.stats",                     BASE),
    ("truav.lograte",                   BASE),
    ("truav.kernel_cache",              BASE),
    ("truav.presets",                   BASE),
    ("truav.config",                    BASE),
    ("truav.config_*",                  BASE),
    ("truav.options",                   BASE),
    ("truav.bus.keys",                  BASE),
    ("truav.faults",                    BASE),
    ("truav.fault_*",                   BASE),
    ("truav.nemesis",                   BASE),
    # -- 6 process: the components' bus processes ----------------------------------------------
    ("world.world_process",             PROCESS),
    ("world.world_host",                PROCESS),
    ("agents.controller_host",          PROCESS),
    ("agents.agent_process",            PROCESS),
    ("agents.agent_process_*",          PROCESS),
    ("agents.agent_host",               PROCESS),
    ("agents.shared_beacons",           PROCESS),
    ("agents.scheme_process",           PROCESS),
    ("agents.api_process",              PROCESS),    # an agents.api class flying one UAV on the bus
    ("agents.central_process",          PROCESS),
    ("recorder.process",                PROCESS),
    ("recorder.replay",                 PROCESS),
    ("recorder.replay_bus",             PROCESS),   # the replay on the bus: commands, queryable, status, lock-step
    ("truav.swarm.view",                PROCESS),
    ("truav.swarm.monitor",             PROCESS),
    ("truav.swarm.fault_control",       PROCESS),
    ("world.world_messages",            WIRE),       # the world's observation messages, from the model
    ("world.snapshot_messages",         WIRE),       # snapshot messages from state arrays and back
    ("agents.agent_decision",           ANALYSIS),   # one agent's cycle over wire messages (process and resim)
    ("agents.decision_state",           ANALYSIS),
    ("agents.truav_agent",              ANALYSIS),   # TRUAV through the API: agent_decision's cycle per UAV
    ("agents.api_decision",             ANALYSIS),   # an agents.api class's cycle over wire messages   # that cycle's state captured and restored (snapshots)
    # -- 2 model: the pure simulation and the learners -----------------------------------------
    ("world.*",                         MODEL),
    ("agents.*",                        MODEL),
    # -- 3 wire: pure message definitions ------------------------------------------------------
    ("truav.bus.schema",                WIRE),
    ("truav.bus.schema_names",          WIRE),
    ("truav.bus.field_checks",          WIRE),
    ("truav.bus.messages",              WIRE),
    ("truav.bus.codec",                 WIRE),
    ("truav.bus.guard",                 WIRE),
    ("truav.bus.rejection_notices",     WIRE),   # what the world tells a sender it refused (pure)
    ("truav.bus.protocol_doc",          WIRE),   # docs/reference/protocol.md's tables, generated from the schema
    # -- 4 analysis / drivers: pure or file I/O, no zenoh --------------------------------------
    ("truav.driver",                    ANALYSIS),
    ("truav.trainer",                   ANALYSIS),
    ("truav.warmup",                    ANALYSIS),
    ("truav.pettingzoo_env",            ANALYSIS),
    ("truav.runio",                     ANALYSIS),
    ("truav.policy_scenario",           ANALYSIS),
    ("truav.agent_loader",              ANALYSIS),   # an agents.api class by name: imported and checked
    ("truav.agent_run",                 ANALYSIS),   # a `truav train --agent` run's agent.npz
    ("truav.sumo_traffic",              ANALYSIS),   # SUMO's tools and libsumo: builds, caches, loads traces
    ("truav.plots",                     ANALYSIS),
    ("truav.swarm.plots",               ANALYSIS),
    ("recorder.mcap_log",               ANALYSIS),
    ("recorder.reader",                 ANALYSIS),
    ("recorder.mcap_guard",             ANALYSIS),  # the one guarded reading of MCAP records (untrusted files)
    ("recorder.replay_source",          ANALYSIS),  # what a replay reads: parts resolved, the seek timeline
    ("recorder.replay_setup",           ANALYSIS),  # a replay's options, checked before it starts
    ("recorder.mcap_writer",            ANALYSIS),
    ("recorder.mcap_chunk",             ANALYSIS),
    ("recorder.mirror_channels",        ANALYSIS),
    ("recorder.seq_stats",              ANALYSIS),
    ("recorder.summary",                ANALYSIS),
    ("recorder.report_data",            ANALYSIS),
    ("recorder.report_figures",         ANALYSIS),
    ("recorder.report_links",           ANALYSIS),
    ("recorder.check",                  ANALYSIS),
    ("recorder.recover",                ANALYSIS),
    ("recorder.report",                 ANALYSIS),
    ("recorder.metadata",               ANALYSIS),
    ("recorder.resim",                  ANALYSIS),
    ("recorder.resim_*",                ANALYSIS),
    ("recorder.schemas",                ANALYSIS),
    ("recorder.foxglove",               ANALYSIS),
    ("recorder.record_modes",           ANALYSIS),
    ("recorder.parts",                  ANALYSIS),
    ("recorder.pause",                  ANALYSIS),
    ("recorder.snapshot",               ANALYSIS),
    ("recorder.snapshot_triggers",      ANALYSIS),
    ("recorder.log_copy",               ANALYSIS),
    ("recorder.cut",                    ANALYSIS),
    ("recorder.merge",                  ANALYSIS),
    ("recorder.info",                   ANALYSIS),
    ("truav.experiments.cells",         ANALYSIS),
    ("truav.experiments.runner",        ANALYSIS),
    ("truav.experiments.report",        ANALYSIS),
    ("truav.experiments.velocity",      ANALYSIS),
    ("truav.experiments.scale",         ANALYSIS),
    ("truav.experiments.ray_executor",  ANALYSIS),
    # -- 5 bus: zenoh ---------------------------------------------------------------------------
    ("truav.lifecycle",                 BUS),
    ("truav.bus.*",                     BUS),
    # -- 7 orchestration: the swarm's supervisor and what runs swarms --------------------------
    ("truav.experiments.fault_sweep",   ORCHESTRATION),
    ("truav.experiments.scheme_faults", ORCHESTRATION),
    ("truav.swarm.*",                   ORCHESTRATION),
]

# Imports that break a rule today, in helpers' areas still being refactored (issue 27).
# (importer, imported module, why it is allowed for now). The imported module may be an
# external one (argparse, zenoh) for rule (c).
KNOWN_VIOLATIONS: list[tuple[str, str, str]] = [
]

ROOTS = ("truav", "agents", "world", "recorder", "bench")
REPO = Path(__file__).resolve().parents[2]


def project_modules(repo: Path = REPO) -> dict[str, Path]:
    """Module name -> path of every .py file under the project's roots."""
    mods = {}
    for root in ROOTS:
        for path in sorted((repo / root).rglob("*.py")):
            name = ".".join(path.relative_to(repo).with_suffix("").parts)
            if name.endswith(".__init__"):
                name = name[: -len(".__init__")]
            mods[name] = path
    return mods


def layer_of(module: str) -> int | None:
    for pattern, layer in LAYERS:
        if fnmatch.fnmatchcase(module, pattern):
            return layer
    return None


def is_cli(module: str) -> bool:
    return layer_of(module) in (CLI, BENCH)   # bench modules are command-line scripts


def _resolve(name: str, mods) -> str | None:
    """The project module that `import name` loads last (the longest prefix that is a module)."""
    while name and name not in mods:
        name = name.rpartition(".")[0]
    return name or None


def imports_of(module: str, source: str, mods, is_package: bool = False) -> set[str]:
    """Every module `module` imports (project modules by name, external ones by their top name)."""
    tree = ast.parse(source)
    package = module if is_package else module.rpartition(".")[0]
    siblings_on_path = module.startswith("bench.")   # bench/ is on sys.path when its scripts run
    found: set[str] = set()

    def add(name: str) -> None:
        if siblings_on_path and "bench." + name.partition(".")[0] in mods:
            name = "bench." + name
        target = _resolve(name, mods)
        if target is not None:
            found.add(target)
        elif name.partition(".")[0] not in ROOTS:
            found.add(name.partition(".")[0])

    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                add(alias.name)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")
                parts = parts[: len(parts) - (node.level - 1)]
                base = ".".join(parts + ([base] if base else []))
            for alias in node.names:
                full = base + "." + alias.name
                if (("bench." + full) if siblings_on_path else full) in mods or full in mods:
                    add(full)               # `from pkg import module`
                else:
                    add(base)               # `from module import name`
    found.discard(module)
    return found


def import_graph(mods: dict[str, Path]) -> dict[str, set[str]]:
    return {m: imports_of(m, p.read_text(), mods, p.name == "__init__.py") for m, p in mods.items()}


def violations(graph: dict[str, set[str]], mods) -> list[tuple[str, str, str]]:
    """(importer, imported, rule broken) for every import that breaks rules (b), (c) or (d)."""
    found = []
    for importer, deps in sorted(graph.items()):
        mine = layer_of(importer)
        if mine is None:
            continue                        # reported by test_every_module_has_a_layer
        for dep in sorted(deps):
            if dep in mods:
                theirs = layer_of(dep)
                if theirs is not None and theirs > mine:
                    found.append((importer, dep, f"{LAYER_NAMES[mine]} imports {LAYER_NAMES[theirs]}"))
                elif theirs == CLI and not is_cli(importer):
                    found.append((importer, dep, "non-CLI module imports a CLI module"))
            elif dep == "argparse" and not is_cli(importer):
                found.append((importer, dep, "non-CLI module imports argparse"))
            elif dep == "zenoh" and mine in PURE:
                found.append((importer, dep, f"pure layer {LAYER_NAMES[mine]} imports zenoh"))
    return found


def components(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    sccs: list[list[str]] = []
    counter = [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in graph:
                continue
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            scc = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                scc.append(w)
                if w == v:
                    break
            if len(scc) > 1:
                sccs.append(sorted(scc))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return sccs


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """One cycle (a -> b -> ... -> a) through each strongly connected component."""
    return [_cycle_path(graph, scc) for scc in components(graph)]


def _cycle_path(graph, scc: list[str]) -> list[str]:
    """One cycle through the component's first module, as a -> b -> ... -> a."""
    members = set(scc)
    start = scc[0]
    parent = {start: None}
    queue = [start]
    while queue:
        v = queue.pop(0)
        for w in sorted(graph[v] & members):
            if w == start:
                path = [v]
                while parent[path[-1]] is not None:
                    path.append(parent[path[-1]])
                return list(reversed(path)) + [start]
            if w not in parent:
                parent[w] = v
                queue.append(w)
    return scc


def _known_edges() -> set[tuple[str, str]]:
    return {(a, b) for a, b, _ in KNOWN_VIOLATIONS}


def _graph_without_known(graph):
    known = _known_edges()
    return {m: {d for d in deps if (m, d) not in known} for m, deps in graph.items()}


@pytest.fixture(scope="module")
def mods():
    return project_modules()


@pytest.fixture(scope="module")
def graph(mods):
    return import_graph(mods)


def test_every_module_has_a_layer(mods):
    unplaced = sorted(m for m in mods if layer_of(m) is None)
    assert not unplaced, f"modules matching no pattern of LAYERS (place them in tests/unit/test_layers.py): {unplaced}"


def test_no_import_cycles(graph):
    pruned = _graph_without_known(graph)
    found = components(pruned)
    assert not found, "import cycles:\n" + "\n".join(
        f"  {' -> '.join(_cycle_path(pruned, c))}   (all modules of the cycle: {c})" for c in found)


def test_layer_order(graph, mods):
    known = _known_edges()
    found = [v for v in violations(graph, mods) if (v[0], v[1]) not in known]
    assert not found, "imports breaking the layer rules:\n" + "\n".join(
        f"  {a} -> {b}: {why}" for a, b, why in found)


def test_known_violations_still_occur(graph, mods):
    """An allowlist entry whose import is gone (or no longer breaks a rule) must be deleted."""
    broken = {(a, b) for a, b, _ in violations(graph, mods)}
    sccs = [set(c) for c in components(graph)]
    cyclic = {(a, b) for a, deps in graph.items() for b in deps if any(a in c and b in c for c in sccs)}
    stale = [(a, b) for a, b, _ in KNOWN_VIOLATIONS if (a, b) not in broken and (a, b) not in cyclic]
    assert not stale, f"KNOWN_VIOLATIONS entries that no longer occur (delete them): {stale}"


def test_checker_catches_a_planted_upward_import(mods):
    """world/env.py importing the swarm's command line (inside a function): an upward import and a cycle."""
    planted = "import numpy\n\ndef f():\n    import truav.cli.swarm\n"
    graph = import_graph(mods)
    graph["world.env"] = imports_of("world.env", planted, mods)
    assert "truav.cli.swarm" in graph["world.env"]
    found = {(a, b, why) for a, b, why in violations(graph, mods) if a == "world.env"}
    assert ("world.env", "truav.cli.swarm", "model imports cli") in found
    # truav.cli.swarm imports world (through its process modules), so the planted import closes a cycle
    assert any("world.env" in c for c in components(_graph_without_known(graph)))


def test_checker_catches_argparse_zenoh_and_relative_imports(mods):
    source = "from . import uavs\nfrom .roads import X\nimport argparse\nimport zenoh\n"
    deps = imports_of("world.env", source, mods)
    assert "world.uavs" in deps and "world.roads" in deps and "argparse" in deps and "zenoh" in deps
    graph = {"world.env": deps}
    found = {(b, why) for _, b, why in violations(graph, mods)}
    assert ("argparse", "non-CLI module imports argparse") in found
    assert ("zenoh", "pure layer model imports zenoh") in found
    assert layer_of("truav.experiments.something_new") is None   # new modules must be placed


def _in_cli_folder(module: str) -> bool:
    return module == "truav.cli" or module.startswith("truav.cli.")


def test_argparse_only_under_truav_cli(graph):
    """The folder rule: argparse is imported only by modules under truav/cli/ (and bench/'s scripts)."""
    found = sorted(m for m, deps in graph.items()
                   if "argparse" in deps and not _in_cli_folder(m) and not m.startswith("bench."))
    assert not found, f"argparse imported outside truav/cli/: {found}"


def test_no_module_outside_truav_cli_imports_it(graph):
    """The folder rule: nothing outside truav/cli/ (but bench/'s scripts) imports truav.cli.*."""
    found = sorted((m, d) for m, deps in graph.items() for d in deps
                   if _in_cli_folder(d) and not _in_cli_folder(m) and not m.startswith("bench."))
    assert not found, f"modules outside truav/cli/ importing it: {found}"
