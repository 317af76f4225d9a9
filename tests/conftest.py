"""Fixtures shared by every tier, the tier markers, and the test order from recorded durations."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from tests.support.waits import free_port
from truav.bus import transport
from truav.bus.transport import Bus
from truav.config import Config
from truav.user_cache import truav_cache_dir

TESTS = Path(__file__).resolve().parent
TIERS = ("unit", "bus", "swarm", "docs")  # a test's tier is the folder it is in
DURATIONS = TESTS / "durations.json"
"""{nodeid: seconds of setup+call+teardown} of a recorded run (`--record-durations`)."""
PACKAGES = ("truav", "agents", "world", "recorder", "tests")
SLOW_S = 20.0  # a test recorded longer than this is marked `slow`


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--record-durations", action="store_true",
                     help=f"rewrite {DURATIONS.relative_to(TESTS.parent)} with this run's test durations")


def pytest_configure(config: pytest.Config) -> None:
    """With PYTHONDONTWRITEBYTECODE set (a clean source tree), every process the suite starts (a thousand:
    swarm parts, CLI runs) compiled TRUAV's ~300 modules from source again, ~0.1 CPU-s each. The suite's
    processes keep their bytecode outside the tree instead (PYTHONPYCACHEPREFIX, under the user's cache
    directory beside the numba kernels): nothing is written into the checkout either way."""
    if os.environ.get("PYTHONDONTWRITEBYTECODE") and not os.environ.get("PYTHONPYCACHEPREFIX"):
        os.environ["PYTHONPYCACHEPREFIX"] = str(truav_cache_dir() / "test-bytecode")
        del os.environ["PYTHONDONTWRITEBYTECODE"]


def pytest_sessionstart(session: pytest.Session) -> None:
    """Compile the numba kernels once, before any test (and, under xdist, before the workers start; this
    hook runs ahead of xdist's): the commands' (truav.analysis.warmup.compile_kernels) and the other
    specializations the tests meet (compile_test_kernels), in two processes side by side. A fresh clone
    has none cached: left to the tests, the first ones to meet a kernel compile it, each worker and each
    swarm process its own copy at once, and the compile lands in whichever test came first. Cached, this
    loads them in seconds (only with -n or on a cold machine)."""
    if hasattr(session.config, "workerinput"):
        return
    from truav.analysis.warmup import needs_compile
    workers = getattr(session.config.option, "numprocesses", None)
    if not needs_compile() and not workers:  # a single test file: only a cold machine waits here
        return
    reporter = session.config.pluginmanager.get_plugin("terminalreporter")
    say = reporter.write_line if reporter is not None else print
    began = time.monotonic()
    say("compiling (or loading) the numba kernels before the tests, on two processes ...")
    # the sources' bytecode first (where pytest_configure put it): the kernel processes start from it
    subprocess.run([sys.executable, "-m", "compileall", "-q", "-j", "2", *PACKAGES], cwd=TESTS.parent,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    compiles = [subprocess.Popen([sys.executable, "-c", code], cwd=TESTS.parent, stdout=subprocess.DEVNULL,
                                 stderr=subprocess.PIPE, text=True)
                for code in ("from truav.analysis.warmup import compile_kernels; compile_kernels()",
                             "from tests.support.kernels import compile_test_kernels; compile_test_kernels()")]
    for proc in compiles:
        _, err = proc.communicate()
        if proc.returncode != 0:  # the tests that need the kernels will say what is wrong, each with its name
            say(f"compiling the kernels failed (exit {proc.returncode}): {err.strip().splitlines()[-1:]}")
    say(f"compiled in {time.monotonic() - began:.0f} s")


def recorded_durations() -> dict[str, float]:
    try:
        return json.loads(DURATIONS.read_text())
    except FileNotFoundError:
        return {}


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Mark each test with its tier and, if recorded longer than SLOW_S, `slow`; then order the modules
    longest-recorded test first: on two workers (`-n 2`) a long test started last would keep one worker
    busy alone at the end. A module's tests stay together and in order (its module fixtures are set up
    once); tests without a recorded time count as 0, and equal modules keep their collected order."""
    recorded = recorded_durations()
    longest: dict[str, float] = {}
    for item in items:
        tier = item.path.relative_to(TESTS).parts[0] if item.path.is_relative_to(TESTS) else None
        if tier in TIERS:
            item.add_marker(tier)
        seconds = recorded.get(item.nodeid, 0.0)
        if seconds > SLOW_S:
            item.add_marker("slow")
        module = item.nodeid.split("::")[0]
        longest[module] = max(longest.get(module, 0.0), seconds)
    items.sort(key=lambda item: -longest[item.nodeid.split("::")[0]])  # stable


_measured: dict[str, float] = {}  # nodeid: seconds, of this run
_skipped: set[str] = set()  # a skipped test's time says nothing of its run: its recorded time stays


def pytest_runtest_logreport(report: pytest.TestReport) -> None:
    """Setup + call + teardown of each test; under xdist the controller gets every worker's reports."""
    _measured[report.nodeid] = _measured.get(report.nodeid, 0.0) + report.duration
    if report.skipped:
        _skipped.add(report.nodeid)


def pytest_sessionfinish(session: pytest.Session) -> None:
    config = session.config
    if not config.getoption("--record-durations") or hasattr(config, "workerinput"):
        return  # only the controller writes, once, with every worker's tests
    durations = recorded_durations()
    durations.update({nodeid: round(s, 2) for nodeid, s in _measured.items() if nodeid not in _skipped})
    # entries of tests whose file is gone (moved, renamed) are dropped; tests not run keep theirs
    kept = {n: s for n, s in sorted(durations.items()) if (TESTS.parent / n.split("::")[0]).is_file()}
    DURATIONS.write_text(json.dumps(kept, indent=0) + "\n")


@pytest.fixture(scope="module")
def endpoint() -> Iterator[str]:
    """A Zenoh router on a free loopback port, shared by one test module."""
    ep = f"tcp/127.0.0.1:{free_port()}"
    router = transport.open_router([ep])
    try:
        yield ep
    finally:
        router.close()


@pytest.fixture
def bus_factory(endpoint: str, request: pytest.FixtureRequest) -> Iterator[Callable[..., Bus]]:
    """``make(identity, run=None, **bus_kwargs)``: a Bus on the module's router,
    closed when the test ends; ``run`` defaults to the test module's ``RUN``."""
    default_run = getattr(request.module, "RUN", "test")
    buses: list[Bus] = []

    def make(identity: str, run: str | None = None, **kwargs) -> Bus:
        bus = Bus(identity, run or default_run, transport.make_config("client", connect=[endpoint]), **kwargs)
        buses.append(bus)
        return bus

    yield make
    for bus in buses:
        bus.close()


@pytest.fixture
def small_cfg() -> Config:
    """A reduced city (fewer vehicles, short episodes) that runs in milliseconds."""
    return Config().replace(
        scenario={"n_vehicles": 60, "steps_per_episode": 20},
        roads={"warmup_steps": 20},
        learner={"episodes": 3},
    )
