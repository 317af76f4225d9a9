"""bench/bench_common.py: the real-time benchmarks' load gate and world.json figures."""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import threading
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))

import bench_common  # noqa: E402


def _args(*argv: str) -> argparse.Namespace:
    ap = argparse.ArgumentParser()
    bench_common.add_load_options(ap)
    return ap.parse_args(list(argv))


def test_a_loaded_machine_is_refused_in_one_line_unless_anyway(capsys) -> None:
    assert bench_common.refuse_loaded("bench_x", _args("--max-load", "0"))  # any load average is >= 0
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("bench_x: error: load average ") and "--max-load 0:" in err
    assert not bench_common.refuse_loaded("bench_x", _args("--max-load", "0", "--anyway"))
    assert not bench_common.refuse_loaded("bench_x", _args("--max-load", "1e9"))


def test_a_run_still_loaded_after_the_wait_is_marked_loaded(capsys) -> None:
    assert bench_common.wait_for_load(_args("--max-load", "0", "--load-wait", "0"))
    assert "(LOADED)" in capsys.readouterr().out
    assert not bench_common.wait_for_load(_args("--max-load", "1e9"))
    assert capsys.readouterr().out == ""


def test_the_world_figures_and_the_json_rows(tmp_path) -> None:
    world = {"per_uav": [{"missed": 2}, {"missed": 3}, "junk", {}], "tick_lateness_ms": {"p99": 12.5}}
    assert bench_common.missed(world) == 5 and bench_common.tick_p99_ms(world) == 12.5
    assert bench_common.missed({}) == 0 and bench_common.tick_p99_ms({"tick_lateness_ms": 3}) != 0.0
    bench_common.write_rows(None, [{"a": 1}])
    bench_common.write_rows(tmp_path / "rows.json", [{"a": 1}])
    assert json.loads((tmp_path / "rows.json").read_text()) == [{"a": 1}]


def test_a_flag_not_positive_is_named_in_one_line(capsys) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--agents", type=int, default=4)
    ap.add_argument("--per-process", type=int, default=2)
    bench_common.add_tick_options(ap)
    flags = ("--agents", "--per-process", "--seconds", "--rate")
    assert not bench_common.refuse_nonpositive("bench_x", ap.parse_args([]), flags)
    assert bench_common.refuse_nonpositive("bench_x", ap.parse_args(["--per-process", "0"]), flags)
    assert capsys.readouterr().err == ("bench_x: error: --agents, --per-process, --seconds and --rate must be "
                                       "positive\n")


def test_cpu_of_a_process_and_none_once_it_is_gone() -> None:
    assert bench_common.cpu_s(os.getpid()) >= 0.0 and bench_common.cpu_s(str(os.getpid())) >= 0.0
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    assert bench_common.cpu_s(proc.pid) is None


def test_a_process_group_is_stopped_with_the_signal_asked() -> None:
    proc = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"], start_new_session=True)
    assert bench_common.stop_group(proc, signal.SIGTERM, timeout_s=30) == -signal.SIGTERM
    assert bench_common.stop_group(proc) == -signal.SIGTERM  # already ended: its code, nothing sent


def test_a_ratio_over_a_base_and_over_zero() -> None:
    assert bench_common.ratio(3.0, 2.0, "more") == "x1.50"
    assert bench_common.ratio(0.0, 0.0, "more") == "x1.00" and bench_common.ratio(1.0, 0.0, "more") == "more"


def test_the_parser_describes_with_the_first_paragraph() -> None:
    ap = bench_common.parser("What it measures,\n  on two lines.\n\nThe rest.")
    assert ap.description == "What it measures,\n  on two lines." and "  on two lines." in ap.format_help()


def test_a_poller_samples_in_its_thread_until_stopped() -> None:
    class Counter(bench_common.Poller):
        def __init__(self) -> None:
            self.sampled = threading.Event()
            self._start_polling()

        def _loop(self) -> None:
            while not self._stop.is_set():
                self.sampled.set()
                self._stop.wait(0.01)

    c = Counter()
    assert c.sampled.wait(timeout=30)
    c.stop()
    assert not c._thread.is_alive()
