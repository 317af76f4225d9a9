"""The swarm benchmark's CPU split by thread (bench/swarm_runs.py): each thread's CPU lands in its class."""

from __future__ import annotations

import os
import sys
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))

import swarm_runs  # noqa: E402


def test_thread_classes_follow_zenoh_names_and_the_main_thread():
    assert swarm_runs.thread_class(100, 100, "python3") == "main"
    assert swarm_runs.thread_class(100, 101, "python3") == "python"
    assert swarm_runs.thread_class(100, 102, "rx-0") == "zenoh-rx"
    assert swarm_runs.thread_class(100, 103, "tx-1") == "zenoh-tx"
    assert swarm_runs.thread_class(100, 104, "app-0") == "zenoh-app"
    assert swarm_runs.thread_class(100, 105, "net-0") == "zenoh-other"


def test_a_busy_python_thread_is_counted_as_python_not_main():
    spun, done = threading.Event(), threading.Event()

    def spin() -> None:
        end = time.thread_time() + 0.3  # CPU time, not wall time: the same work on a busy machine
        while time.thread_time() < end:
            pass
        spun.set()
        done.wait(60)  # alive while sampled: an exited thread's task is no longer listed

    before = swarm_runs.agent_thread_cpu({os.getpid()})
    worker = threading.Thread(target=spin)
    worker.start()
    try:
        assert spun.wait(60)
        during = swarm_runs.agent_thread_cpu({os.getpid()})
    finally:
        done.set()
        worker.join()
    assert set(during) == set(swarm_runs.THREAD_CLASSES)
    assert during["python"] - before["python"] >= 0.2  # 0.3 s in 10 ms clock ticks
    assert during["main"] - before["main"] < 0.2  # the main thread waited
    assert swarm_runs.agent_thread_cpu({2**22 + 12345}) == dict.fromkeys(swarm_runs.THREAD_CLASSES, 0.0)  # no such pid


def test_wake_ups_count_each_time_a_thread_blocked_and_woke():
    woken = threading.Event()
    rounds = 50

    def sleeper() -> None:
        for _ in range(rounds):  # blocks and is woken each time: one voluntary switch at least
            time.sleep(0.001)
        woken.set()
        stay.wait(60)

    stay = threading.Event()
    worker = threading.Thread(target=sleeper)
    worker.start()
    try:
        assert woken.wait(60)
        cpu, during = swarm_runs.agent_thread_totals({os.getpid()})
        with open(f"/proc/{os.getpid()}/task/{worker.native_id}/status") as f:
            own = swarm_runs._voluntary_switches(f.read())
    finally:
        stay.set()
        worker.join()
    assert set(during) == set(cpu) == set(swarm_runs.THREAD_CLASSES)
    # The sleeper's own count, and the python class's total holds it (not a difference of totals: another
    # thread of this process, e.g. a test runner's, may end between the samples and take its count along).
    assert own >= rounds
    assert during["python"] >= own
    assert swarm_runs._voluntary_switches("Name:\tx\nvoluntary_ctxt_switches:\t42\n") == 42
    assert swarm_runs._voluntary_switches("Name:\tx\n") == 0
