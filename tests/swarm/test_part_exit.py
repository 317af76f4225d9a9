"""A swarm's part ends without the interpreter's finalization (truav.lifecycle.exit_after_work), yet loses
nothing: its threads' writes, its log lines and its exit code are all there."""

from __future__ import annotations

import subprocess
import sys
import textwrap


def test_exit_after_work_joins_threads_flushes_logs_and_keeps_the_code(tmp_path) -> None:
    out = tmp_path / "late.txt"
    program = textwrap.dedent(f"""
        import logging, sys, threading, time
        from truav.lifecycle import exit_after_work
        logging.basicConfig(level=logging.INFO, stream=sys.stderr)

        def late():
            time.sleep(0.3)
            open({str(out)!r}, "w").write("written")

        threading.Thread(target=late).start()  # not a daemon: finalization would wait for it
        print("buffered stdout", end="")
        logging.getLogger("part").info("last log line")
        exit_after_work(3)
        print("never")
    """)
    done = subprocess.run([sys.executable, "-c", program], capture_output=True, text=True, timeout=60)
    assert done.returncode == 3, done.stderr
    assert out.read_text() == "written"
    assert done.stdout == "buffered stdout"
    assert "last log line" in done.stderr


def test_a_part_exits_with_its_code_through_the_entry(tmp_path) -> None:
    """`python -m truav.cli.swarm world` with a mistake: one line, exit 2, through the part's exit."""
    done = subprocess.run([sys.executable, "-m", "truav.cli.swarm", "world", "--scenario", str(tmp_path / "none.toml")],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2, done.stderr
    assert done.stderr.count("\n") == 1 and "none.toml" in done.stderr, done.stderr
    done = subprocess.run([sys.executable, "-m", "truav.cli.swarm", "router", "-l", "tcp/nowhere"],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and done.stderr.count("\n") == 1 and "-l/--listen" in done.stderr, done.stderr
