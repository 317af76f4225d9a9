"""A lock-step central agent waits for the controller its world saw, even before its own liveliness watch
has reported it (the watch's history arrives asynchronously: under load, after the first observation).
Flying on without a command there hovered one UAV and made a lock-step run silently inexact."""

from __future__ import annotations

import logging
import threading
import time
from types import SimpleNamespace

from agents.process.scheme_process import CentralAgentNode


def _node(wait_s: float) -> CentralAgentNode:
    node = CentralAgentNode.__new__(CentralAgentNode)  # only the command wait is under test: no bus, no files
    node._make_learners()
    node.opts = SimpleNamespace(lockstep=True, lockstep_wait_s=wait_s, uav=0)
    node._stop = threading.Event()
    node.inexact = set()
    return node


def _later(delay_s: float, fn, *args) -> threading.Thread:
    t = threading.Thread(target=lambda: (time.sleep(delay_s), fn(*args)), daemon=True)
    t.start()
    return t


def test_the_first_round_waits_for_a_controller_not_yet_seen_and_stays_exact():
    node = _node(wait_s=30.0)
    obs = SimpleNamespace(tick=0)
    _later(0.2, node._on_controller, True)
    _later(0.4, node._on_command, "k", SimpleNamespace(tick=0, action=7), b"", 0)
    node._round_tick = 0
    node._await_command(obs)
    assert node._latest == (0, 7) and not node.inexact
    assert node._fly(obs) == 7


def test_a_lost_controller_is_not_waited_for():
    node = _node(wait_s=30.0)
    node._on_controller(True)
    node._on_controller(False)
    began = time.monotonic()
    node._await_command(SimpleNamespace(tick=3))
    assert time.monotonic() - began < 5.0  # returns at once: the world goes on without it too


def test_a_controller_never_seen_costs_one_bounded_wait_and_is_reported_inexact(caplog):
    node = _node(wait_s=0.3)
    with caplog.at_level(logging.WARNING):
        node._await_command(SimpleNamespace(tick=0))
    assert node.inexact == {0} and "never seen" in caplog.text
    began = time.monotonic()
    node._await_command(SimpleNamespace(tick=1))  # given up: no second wait
    assert time.monotonic() - began < 0.3 and node.inexact == {0}
