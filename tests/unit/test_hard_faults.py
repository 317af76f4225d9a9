"""Hard faults met by the pure writers (issue 43): checkpoint temporaries unique per process, a full
disk that never leaves a partial file, and one line (exit 1) for a command whose disk filled up."""

from __future__ import annotations

import errno

import pytest

from truav.cli_args import run_main


def test_checkpoint_temporaries_are_unique_per_process(tmp_path, monkeypatch):
    from truav import atomic
    target = tmp_path / "agent2.npz"
    names = set()
    for pid in (101, 202):  # two writers of one checkpoint: each its own temporary
        monkeypatch.setattr(atomic.os, "getpid", lambda pid=pid: pid)
        names.add(atomic.tmp_path(target).name)
        atomic.write_atomic(target, lambda f: f.write(b"x"))
    assert names == {"agent2.npz.101.tmp", "agent2.npz.202.tmp"} and target.read_bytes() == b"x"
    assert [p.name for p in tmp_path.iterdir()] == ["agent2.npz"]


def test_a_full_disk_keeps_the_last_complete_file_and_says_where(tmp_path):
    from truav.atomic import write_kept
    ck = tmp_path / "agent0.npz"
    ck.write_bytes(b"the last good checkpoint")

    def half_then_full(f):
        f.write(b"half a checkpoint")
        raise OSError(errno.ENOSPC, "No space left on device")

    said = []
    assert write_kept(ck, half_then_full, said.append) is False
    assert ck.read_bytes() == b"the last good checkpoint"  # never replaced by a partial one
    assert [p.name for p in tmp_path.iterdir()] == ["agent0.npz"]  # the temporary removed
    assert len(said) == 1 and said[0].startswith(f"no space left on {tmp_path}")
    with pytest.raises(PermissionError):  # any other failure is not hidden
        write_kept(ck, lambda f: (_ for _ in ()).throw(PermissionError(errno.EACCES, "denied")), said.append)


def test_a_command_whose_disk_fills_up_says_so_in_one_line(tmp_path, capsys):
    from truav.atomic import write_atomic

    def body() -> int:
        write_atomic(tmp_path / "qtables.npz", lambda f: (_ for _ in ()).throw(OSError(errno.ENOSPC, "full")))
        return 0

    assert run_main("truav", body) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"truav: error: no space left on {tmp_path}"]
