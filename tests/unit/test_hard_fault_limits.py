"""Hard faults met by the pure writers (issue 43): checkpoint temporaries unique per process, a full
disk that never leaves a partial file, and one line (exit 1) for a command whose disk filled up."""

from __future__ import annotations

import errno

import pytest

from truav.cli.args import run_main


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


# -- ranges that hold ---------------------------------------------------------------------------
def _one_line_exit_2(argv, capsys) -> str:
    from truav.cli.main import main as truav_main
    assert truav_main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "Traceback" not in err[0], err
    return err[0]


def test_vehicles_that_do_not_fit_on_the_road_grid_are_refused_up_front(capsys):
    line = _one_line_exit_2(["config", "show", "--set", "scenario.n_vehicles=100000"], capsys)
    assert "scenario.n_vehicles" in line and "do not fit on the road grid" in line and "roads.block_m" in line
    import numpy as np
    from truav.config import Config, grid_vehicle_capacity
    from world.roads import RoadGrid
    cfg, rng = Config(), np.random.default_rng(0)
    grid, most = RoadGrid(cfg), grid_vehicle_capacity(cfg)
    assert grid.spawn(rng, most).road.shape == (1, most)  # the config's bound is the grid's own
    with pytest.raises(ValueError, match="do not fit"):
        grid.spawn(rng, most + 1)


def test_q_tables_too_large_for_memory_are_refused_in_one_line(capsys):
    line = _one_line_exit_2(["config", "show", "--set", "learner.grid_cells=1000"], capsys)
    assert "learner.grid_cells" in line and "1000" in line
    line = _one_line_exit_2(["train", "--seeds", "10", "--out", "/nonexistent/never-written", "--set",
                             "learner.grid_cells=50", "--set", "learner.neighbour_sectors=8"], capsys)
    assert "learner.grid_cells = 50" in line and "GiB" in line and "10 seed(s) x 5 UAV(s)" in line


def test_a_deeply_nested_config_is_one_line(tmp_path, capsys):
    deep = tmp_path / "deep.toml"
    deep.write_text("[scenario]\nn_uavs = " + "[" * 100_000 + "]" * 100_000 + "\n")
    line = _one_line_exit_2(["config", "show", "--config", str(deep)], capsys)
    assert str(deep) in line and "nested too deeply" in line
    line = _one_line_exit_2(["config", "show", "--set", "scenario.n_uavs=" + "[" * 100_000 + "]" * 100_000], capsys)
    assert "--set scenario.n_uavs" in line and "nested too deeply" in line


def test_a_metric_without_data_is_no_data_not_nan():
    import numpy as np
    from truav.cli.main import format_table
    from truav.stats import shown
    table = format_table({"truav": {"coverage_pct": np.array([10.0, 12.0]), "pdr": np.array([np.nan, np.nan]),
                                    "delay_ms": np.array([np.nan, np.nan]), "energy_j": np.array([1e3, 1e3])}})
    assert "nan" not in table and table.count("no data") == 2
    assert shown(float("nan"), ".3f") == "no data" and shown(0.25, ".3f") == "0.250"
