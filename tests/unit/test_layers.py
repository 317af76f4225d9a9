"""The layer order of the project's folders, read from the modules' source with ast.

Every import of every project module (truav/, agents/, world/, recorder/, bench/) is read,
those inside functions too, relative imports resolved. Each folder (package) holds one layer
(FOLDERS below: a module's layer is its folder's) and the test fails:

(a) on an import cycle among project modules (the cycle is named);
(b) when a module imports a module of a higher layer than its own;
(c) when a non-CLI module imports argparse, or a pure layer (base, model, wire, analysis) imports zenoh;
(d) when a non-CLI module imports a CLI module;
(e) when argparse is imported, or truav.cli is imported, outside the folder truav/cli/ (bench/'s
    scripts, command lines of their own, aside);
(f) when a folder holds both a module of a pure layer and a module that reaches zenoh (imports it,
    or imports a project module that does, directly or through others);
(g) when a folder is in no rule of FOLDERS: a new folder is placed deliberately (a new module
    takes its folder's layer).

There is no allowlist: an import that breaks a rule is fixed, not listed.
"""
from __future__ import annotations

import ast
import functools
from pathlib import Path

import pytest

# ---------------------------------------------------------------------------------------------
# The layer map: folder (package) -> layer. A module may import its own layer or a lower one,
# never a higher one. Every package of the project is listed (subfolders are not inherited).
# ---------------------------------------------------------------------------------------------
BASE, MODEL, WIRE, ANALYSIS, BUS, PROCESS, ORCHESTRATION, CLI, BENCH = range(1, 10)
LAYER_NAMES = {BASE: "base", MODEL: "model", WIRE: "wire", ANALYSIS: "analysis", BUS: "bus",
               PROCESS: "process", ORCHESTRATION: "orchestration", CLI: "cli", BENCH: "bench"}
PURE = {BASE, MODEL, WIRE, ANALYSIS}   # may not import zenoh

FOLDERS: dict[str, int] = {
    "truav":             BASE,           # errors, checks, config, presets, options, seeding, stats, faults, lifecycle
    "world":             MODEL,          # the numeric world: roads, vehicles, channel, network, step, env
    "truav.wire":        WIRE,           # the messages: schema, codec, keys, guard, world and snapshot messages
    "agents":            ANALYSIS,       # learners, policies, the agent API and its classes, the decision cycle
    "truav.analysis":    ANALYSIS,       # driver, trainer, run files, agent loading, SUMO traffic, figures
    "truav.experiments": ANALYSIS,       # the in-process experiments: cells, runner, velocity, scale
    "recorder":          ANALYSIS,       # MCAP format, reader, replay engine, tools, re-simulation
    "truav.bus":         BUS,            # Zenoh: Bus, router, security, link filter
    "world.process":     PROCESS,        # the world process
    "agents.process":    PROCESS,        # the agent processes
    "recorder.process":  PROCESS,        # the recorder and replay processes
    "truav.swarm":       ORCHESTRATION,  # supervisor, chaos, fault sweeps, live view
    "truav.cli":         CLI,            # every argparse parser; nothing outside imports it
    "bench":             BENCH,          # benchmark scripts, above everything
}

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


@functools.cache
def _all_modules() -> dict[str, Path]:
    return project_modules()


def folder_of(module: str, mods=None) -> str:
    """The package a module is in (a package's __init__ is in the package itself)."""
    path = (_all_modules() if mods is None else mods).get(module)
    if path is not None and path.name == "__init__.py":
        return module
    return module.rpartition(".")[0]


def layer_of(module: str, mods=None) -> int | None:
    return FOLDERS.get(folder_of(module, mods))


def is_cli(module: str, mods=None) -> bool:
    return layer_of(module, mods) in (CLI, BENCH)   # bench modules are command-line scripts


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
        mine = layer_of(importer, mods)
        if mine is None:
            continue                        # reported by test_every_folder_has_a_layer
        for dep in sorted(deps):
            if dep in mods:
                theirs = layer_of(dep, mods)
                if theirs is not None and theirs > mine:
                    found.append((importer, dep, f"{LAYER_NAMES[mine]} imports {LAYER_NAMES[theirs]}"))
                elif theirs == CLI and not is_cli(importer, mods):
                    found.append((importer, dep, "non-CLI module imports a CLI module"))
            elif dep == "argparse" and not is_cli(importer, mods):
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


def reaches_zenoh(graph: dict[str, set[str]]) -> set[str]:
    """The project modules that import zenoh, or import (directly or through others) one that does."""
    reach = {m for m, deps in graph.items() if "zenoh" in deps}
    grew = True
    while grew:
        more = {m for m, deps in graph.items() if m not in reach and deps & reach}
        grew = bool(more)
        reach |= more
    return reach


def mixed_folders(graph: dict[str, set[str]], mods) -> list[tuple[str, list[str], list[str]]]:
    """(folder, its pure-layer modules, its modules reaching zenoh) of every folder holding both."""
    reach = reaches_zenoh(graph)
    by_folder: dict[str, list[str]] = {}
    for m in graph:
        by_folder.setdefault(folder_of(m, mods), []).append(m)
    found = []
    for folder, members in sorted(by_folder.items()):
        pure = sorted(m for m in members if layer_of(m, mods) in PURE)
        zenohy = sorted(m for m in members if m in reach)
        if pure and zenohy:
            found.append((folder, pure, zenohy))
    return found


@pytest.fixture(scope="module")
def mods():
    return project_modules()


@pytest.fixture(scope="module")
def graph(mods):
    return import_graph(mods)


def test_every_folder_has_a_layer(mods):
    unplaced = sorted({folder_of(m, mods) for m in mods} - set(FOLDERS))
    assert not unplaced, f"folders in no rule of FOLDERS (place them in tests/unit/test_layers.py): {unplaced}"
    stale = sorted(set(FOLDERS) - {folder_of(m, mods) for m in mods})
    assert not stale, f"FOLDERS rules for folders that hold no module (delete them): {stale}"
    assert len(FOLDERS) <= 15, "a few folder rules, not a module map"


def test_no_import_cycles(graph):
    found = components(graph)
    assert not found, "import cycles:\n" + "\n".join(
        f"  {' -> '.join(_cycle_path(graph, c))}   (all modules of the cycle: {c})" for c in found)


def test_layer_order(graph, mods):
    found = violations(graph, mods)
    assert not found, "imports breaking the layer rules:\n" + "\n".join(
        f"  {a} -> {b}: {why}" for a, b, why in found)


def test_no_folder_mixes_pure_modules_and_zenoh(graph, mods):
    """The numeric model and the messages never share a folder with what reaches Zenoh."""
    found = mixed_folders(graph, mods)
    assert not found, "folders holding pure-layer modules and modules reaching zenoh:\n" + "\n".join(
        f"  {f}/: pure {p}; reaching zenoh {z}" for f, p, z in found)


def test_checker_catches_a_planted_upward_import(mods):
    """world/env.py importing the swarm's command line (inside a function): an upward import and a cycle."""
    planted = "import numpy\n\ndef f():\n    import truav.cli.swarm\n"
    graph = import_graph(mods)
    graph["world.env"] = imports_of("world.env", planted, mods)
    assert "truav.cli.swarm" in graph["world.env"]
    found = {(a, b, why) for a, b, why in violations(graph, mods) if a == "world.env"}
    assert ("world.env", "truav.cli.swarm", "model imports cli") in found
    # truav.cli.swarm imports world (through the processes), so the planted import closes a cycle
    assert any("world.env" in c for c in components(graph))
    # and world/ now holds a module reaching zenoh beside the numeric model
    assert any(f == "world" and "world.env" in z for f, _, z in mixed_folders(graph, mods))


def test_checker_catches_a_planted_bus_import_in_the_model(mods):
    """agents/qlearning.py importing the Bus: an upward import, and agents/ mixing pure and zenoh."""
    graph = import_graph(mods)
    graph["agents.qlearning"] = imports_of("agents.qlearning", "from truav.bus import transport\n", mods)
    found = {(a, b, why) for a, b, why in violations(graph, mods)}
    assert ("agents.qlearning", "truav.bus.transport", "analysis imports bus") in found
    mixed = {f: z for f, _, z in mixed_folders(graph, mods)}
    assert "agents.qlearning" in mixed["agents"]   # (and every pure folder importing qlearning)


def test_checker_catches_argparse_zenoh_and_relative_imports(mods):
    source = "from . import uavs\nfrom .roads import X\nimport argparse\nimport zenoh\n"
    deps = imports_of("world.env", source, mods)
    assert "world.uavs" in deps and "world.roads" in deps and "argparse" in deps and "zenoh" in deps
    graph = {"world.env": deps}
    found = {(b, why) for _, b, why in violations(graph, mods)}
    assert ("argparse", "non-CLI module imports argparse") in found
    assert ("zenoh", "pure layer model imports zenoh") in found
    assert layer_of("truav.experiments.something_new", mods) == ANALYSIS   # a new module takes its folder's layer
    assert layer_of("truav.newfolder.module", mods) is None               # a new folder must be placed


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


def imports_of_test_modules(source: str) -> list[str]:
    """The test modules (``test_*``) a test file's source imports, in any form."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):  # `from tests.unit.test_x import y`, `from tests.unit import test_x`
            names = [node.module or ""] + [f"{node.module or ''}.{a.name}" for a in node.names]
        else:
            continue
        found += [n for n in names if n.rsplit(".", 1)[-1].startswith("test_")]
    return found


def test_no_test_module_imports_another():
    """Tests share helpers through tests/support (tests/README.md), never by importing a test module: that
    runs the other module's tests' imports and ties two files' edits together."""
    found = {str(p.relative_to(REPO)): imports_of_test_modules(p.read_text())
             for p in sorted((REPO / "tests").rglob("*.py"))}
    found = {path: names for path, names in found.items() if names}
    assert not found, f"test modules importing test modules (move what they share to tests/support): {found}"
    planted = ("def f():\n    from tests.unit.test_channel_models import GOLDEN\nfrom test_agent_api_swarm import up\n"
               "from tests.unit import test_deep_iql\nimport tests.swarm.test_swarm as s\nfrom tests.support import waits\n")
    assert sorted(imports_of_test_modules(planted)) == ["test_agent_api_swarm", "tests.swarm.test_swarm",
                                                         "tests.unit.test_channel_models", "tests.unit.test_deep_iql"]
