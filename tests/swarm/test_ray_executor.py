"""Experiment cells as Ray tasks: the same CSV as the local pool, and resumable.
Runs on a local Ray instance (2 CPUs, loopback, no dashboard)."""

import pytest

from truav.cli.main import main

ray = pytest.importorskip("ray")


@pytest.fixture(scope="module")
def local_ray():
    ray.init(address="local", num_cpus=2, include_dashboard=False, _node_ip_address="127.0.0.1", log_to_driver=False)
    try:
        yield
    finally:
        ray.shutdown()


def _args(out, *extra):
    return ["experiment", "velocity", "--quick", "--out", str(out), "--quiet", "--workers", "2",
            "--schemes", "truav", "patrol", "--speeds", "5", "25", *extra]


def test_ray_sweep_gives_the_local_csv_and_resumes(tmp_path, capsys, local_ray):
    assert main(_args(tmp_path / "local")) == 0
    assert main(_args(tmp_path / "ray", "--executor", "ray")) == 0
    for name in ("velocity.csv", "summary.csv"):
        assert (tmp_path / "ray" / name).read_text() == (tmp_path / "local" / name).read_text(), name
    cells = sorted((tmp_path / "ray" / "cells").glob("*.npz"))
    assert len(cells) == 2 * 2 * 1  # schemes x speeds x one chunk of 2 seeds
    cells[0].unlink()
    capsys.readouterr()
    assert main(_args(tmp_path / "ray", "--executor", "ray")) == 0
    assert "3 already finished, 1 to run" in capsys.readouterr().out
    assert (tmp_path / "ray" / "velocity.csv").read_text() == (tmp_path / "local" / "velocity.csv").read_text()


def test_address_without_ray_executor_is_a_usage_error(tmp_path, capsys):
    assert main(_args(tmp_path / "x", "--address", "127.0.0.1:6379")) == 2
    assert "--address needs --executor ray" in capsys.readouterr().err


@pytest.mark.parametrize("address, says", [
    ("notanaddress:x", "expected HOST:PORT"),
    ("head:99999", "expected HOST:PORT"),
    ("127.0.0.1:{closed}", "no Ray head answers there"),
    ("ray://127.0.0.1:{closed}", "no Ray head answers there"),
])
def test_a_bad_or_dead_ray_address_is_refused_before_anything_runs(tmp_path, capsys, address, says):
    from tests.support.waits import free_port
    address = address.format(closed=free_port())  # nothing listens on a port just released
    assert main(_args(tmp_path / "x", "--executor", "ray", "--address", address)) == 2
    err = capsys.readouterr().err.strip()
    assert says in err and f"--address {address}" in err and len(err.splitlines()) == 1
    assert not (tmp_path / "x").exists()
