"""Ctrl-C that lands while numba loads a cached kernel surfaces as a SystemError wrapping the
KeyboardInterrupt (found by CI: a sweep stopped then exited 1 with a traceback, not 130). It is still a stop:
one line and the stop's exit code; any other SystemError stays a bug with its traceback."""

from __future__ import annotations

import pytest

from truav.cli.args import run_main
from truav.stopping import is_interrupt


def _wrapped_interrupt() -> SystemError:
    try:
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as inner:
            raise SystemError("CPUDispatcher(<function f>) returned a result with an exception set") from inner
    except SystemError as exc:
        return exc


def test_a_system_error_caused_by_ctrl_c_is_an_interrupt():
    assert is_interrupt(_wrapped_interrupt())
    assert is_interrupt(KeyboardInterrupt())
    assert not is_interrupt(SystemError("a bug"))
    assert not is_interrupt(ValueError("a bug"))


def test_a_command_stopped_inside_a_kernel_load_exits_130_in_one_line(capsys):
    def body() -> int:
        raise _wrapped_interrupt()

    assert run_main("truav", body) == 130
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["truav: stopped by Ctrl-C"]


def test_a_system_error_of_its_own_keeps_its_traceback():
    def body() -> int:
        raise SystemError("a bug")

    with pytest.raises(SystemError, match="a bug"):
        run_main("truav", body)
