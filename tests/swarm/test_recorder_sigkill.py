"""The MCAP writer's durability under SIGKILL.

The test runs a real writer in a child process at a known message rate, kills it, recovers the file
and measures how old the oldest lost message was when the child last wrote: the durability promise is
that the loss is confined to the last ~100 ms of writes.
"""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import msgpack

from recorder.reader import iter_messages
from recorder.recover import recover

REPO = Path(__file__).resolve().parents[2]
MS = 1_000_000

CHILD = textwrap.dedent(
    """
    import os, sys, time
    import msgpack
    from recorder.mcap_log import McapLog

    path, report_path, rate, limit_s = sys.argv[1], sys.argv[2], float(sys.argv[3]), float(sys.argv[4])
    report = os.open(report_path, os.O_WRONLY | os.O_CREAT | os.O_APPEND)
    log = McapLog(path, flush_interval_s=0.05)
    period, start = 1.0 / rate, time.monotonic()
    seq = 0
    while time.monotonic() - start < limit_s:  # bounded even if nobody kills us
        now = time.time_ns()
        payload = msgpack.packb({"v": 1, "kind": "beacon", "src": "uav/1", "seq": seq, "t": now,
                                 "uav": 1, "tick": seq, "pos": [1.0, 2.0], "vel": [0.0, 0.0]})
        log.write("truav/kill/uav/1/beacon", payload, now)
        # reported only once write() returned; the kernel keeps it after SIGKILL
        os.write(report, b"%d %d\\n" % (seq, now))
        seq += 1
        delay = start + seq * period - time.monotonic()
        if delay > 0:
            time.sleep(delay)
    log.close()
    """
)


def test_sigkill_loses_at_most_the_last_100ms(tmp_path: Path) -> None:
    path, report_path = tmp_path / "killed.mcap", tmp_path / "written.txt"
    rate, run_s, window_ns = 1000.0, 1.0, 100 * MS
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.Popen([sys.executable, "-c", CHILD, str(path), str(report_path), str(rate), "20"],
                            env=env, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 15
        while _lines(report_path) < rate * run_s:  # ~1 s of writes once it runs
            assert proc.poll() is None, proc.stderr.read().decode()  # type: ignore[union-attr]
            assert time.monotonic() < deadline, "child too slow"
            time.sleep(0.01)
        time.sleep(random.uniform(0.0, 0.06))  # land anywhere in the 50 ms flush cycle
        os.kill(proc.pid, signal.SIGKILL)  # this child only
        assert proc.wait(timeout=10) == -signal.SIGKILL
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait(timeout=10)
        if proc.stderr is not None:
            proc.stderr.close()
    written = _written(report_path)  # seq -> log_time the child saw write() return for
    last_seq = max(written)
    report = recover(path, tmp_path / "recovered.mcap")
    assert report.truncated and report.clean
    got = [msgpack.unpackb(m.payload)["seq"] for m in iter_messages(tmp_path / "recovered.mcap")]
    times = [m.log_time for m in iter_messages(tmp_path / "recovered.mcap")]
    assert got == list(range(len(got)))  # nothing missing before the cut
    assert len(got) <= last_seq + 2  # at most one written but not yet reported
    assert [t for s, t in zip(got, times) if s in written] == [written[s] for s in got if s in written]
    lost = [s for s in range(len(got), last_seq + 1)]
    # age of the oldest lost message when the child last wrote: the loss window
    age_ns = written[last_seq] - written[lost[0]] if lost else 0
    print(f"\nSIGKILL: {last_seq + 1} written, {len(got)} recovered, {len(lost)} lost, "
          f"oldest lost was {age_ns / MS:.1f} ms old at the last write")
    assert age_ns <= window_ns
    assert len(got) >= 0.8 * (last_seq + 1)


def _lines(path: Path) -> int:
    try:
        with open(path, "rb") as f:
            return f.read().count(b"\n")
    except FileNotFoundError:
        return 0


def _written(path: Path) -> dict[int, int]:
    out = {}
    for line in path.read_bytes().splitlines():
        parts = line.split()
        if len(parts) == 2:  # a line torn by the kill is ignored
            out[int(parts[0])] = int(parts[1])
    return out
