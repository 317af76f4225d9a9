"""Shared fixtures: small, fast configurations of the paper's scenario."""

from __future__ import annotations

import signal
import socket
import subprocess
import time
from pathlib import Path
from collections.abc import Callable, Iterator

import pytest

from truav.bus import transport
from truav.bus.transport import Bus
from truav.config import Config


LONG_FIRST = ("tests/test_readme_commands.py", "tests/test_cold_start.py", "tests/test_nemesis.py",
              "tests/test_healing.py", "tests/test_shared_parts.py", "tests/test_experiments.py")
"""Modules of the longest tests (a minute or more each), started first: on two workers (`pytest -n 2`)
a long test started last would keep one worker busy alone at the end."""


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    rank = {module: i for i, module in enumerate(LONG_FIRST)}
    items.sort(key=lambda item: rank.get(item.nodeid.split("::")[0], len(LONG_FIRST)))  # stable: else as collected


def wait_until(pred: Callable[[], bool], timeout_s: float, poll_s: float = 0.01) -> bool:
    """Poll ``pred`` until it holds or ``timeout_s`` passes; its last value."""
    deadline = time.monotonic() + timeout_s
    while not pred() and time.monotonic() < deadline:
        time.sleep(poll_s)
    return pred()


def wait_matched(sender, key: str, timeout_s: float = 30.0) -> bool:
    """Wait until ``sender`` (a zenoh Session or a Bus) knows of a subscriber to ``key``: the subscription
    has reached the router and the router has told the sender. A fixed sleep for that (0.3 s) was too
    short on a loaded machine, and a put before it is dropped."""
    if isinstance(sender, Bus):
        return sender.await_subscribers(key, timeout_s)
    pub = sender.declare_publisher(key)
    try:
        return wait_until(lambda: pub.matching_status.matching, timeout_s, poll_s=0.02)
    finally:
        pub.undeclare()


def free_port() -> int:
    """A free TCP port on loopback (bound once, then released)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def run_to_end(cmd: list[str], log_path: Path, timeout_s: float, *, env: dict | None = None,
               term_wait_s: float = 30.0) -> int:
    """Run a `truav-swarm` command to its end, output in ``log_path``; its exit code. If it outlives
    ``timeout_s`` (the wait raises) it gets SIGTERM (the supervisor stops every process it started),
    then SIGKILL after ``term_wait_s``."""
    with open(log_path, "wb") as log:
        proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=env)
    try:
        return proc.wait(timeout=timeout_s)
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(timeout=term_wait_s)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=10)


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


def up_to_end(tmp: Path, name: str, cfg: Config, *args: str, timeout_s: float = 300.0) -> Path:
    """`truav-swarm up` of scenario ``cfg`` (written to ``tmp/<name>.toml``) with ``args``, run to its end;
    asserts exit 0 (the log in the message otherwise) and returns its --out directory."""
    import sys

    from truav.config import to_toml
    scenario = tmp / f"{name}.toml"
    scenario.write_text(to_toml(cfg))
    out = tmp / name
    cmd = [sys.executable, "-m", "truav.swarm.cli", "up", "--run", name, "--scenario", str(scenario),
           "--out", str(out), "--quiet", "--no-plot", *args]
    rc = run_to_end(cmd, tmp / f"{name}.log", timeout_s, term_wait_s=60)
    assert rc == 0, (tmp / f"{name}.log").read_text(errors="replace")
    return out
