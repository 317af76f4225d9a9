"""The trainer: determinism, batch equivalence, and the CLI end to end (worker processes:
tests/swarm/test_worker_processes.py)."""

import numpy as np

from truav.analysis import runio
from truav.analysis.trainer import run_chunk
from truav.cli.main import main


def test_training_is_deterministic_and_batch_equivalent(small_cfg):
    seeds = [0, 7, 9]
    batch = run_chunk("truav", small_cfg, seeds, 3)
    again = run_chunk("truav", small_cfg, seeds, 3)
    for k in batch.metrics:
        np.testing.assert_array_equal(batch.metrics[k], again.metrics[k])
    np.testing.assert_array_equal(batch.q, again.q)
    for b, seed in enumerate(seeds):
        alone = run_chunk("truav", small_cfg, [seed], 3)
        for k in ("coverage_pct", "delivered", "energy_j", "reward"):
            np.testing.assert_array_equal(alone.metrics[k][:, 0], batch.metrics[k][:, b])
        np.testing.assert_array_equal(alone.q[0], batch.q[b])


def test_learning_changes_the_tables(small_cfg):
    r = run_chunk("truav", small_cfg, [0], 2)
    fresh = run_chunk("truav", small_cfg, [0], 2, train=False)
    assert not np.array_equal(r.q, fresh.q)


def test_cli_train_then_evaluate(tmp_path, capsys):
    out = tmp_path / "run"
    rc = main(["train", "--seeds", "2", "--episodes", "3", "--out", str(out), "--quiet", "--workers", "1",
               "--set", "scenario.n_vehicles=50", "--set", "scenario.steps_per_episode=10",
               "--set", "roads.warmup_steps=5"])
    assert rc == 0
    for name in (runio.METRICS_FILE, runio.QTABLE_FILE, runio.CONVERGENCE_FILE, runio.CONFIG_FILE):
        assert (out / name).is_file()
    seeds, metrics = runio.read_metrics(out / runio.METRICS_FILE)
    assert seeds == [0, 1] and metrics["coverage_pct"].shape == (3, 2)
    assert main(["evaluate", str(out), "--episodes", "2", "--quiet", "--against", "random", "hover"]) == 0
    text = capsys.readouterr().out
    assert "truav" in text and "random" in text and "hover" in text
    # refuses to overwrite a finished run
    assert main(["train", "--seeds", "1", "--episodes", "1", "--out", str(out), "--quiet"]) == 2
    assert "not empty" in capsys.readouterr().err


def test_cli_reports_config_mistakes(capsys):
    assert main(["config", "show", "--set", "scenario.n_uavs=-1"]) == 2
    assert "scenario.n_uavs" in capsys.readouterr().err
    assert main(["config", "show", "--set", "novalue"]) == 2
    assert main(["evaluate", "/nonexistent/run"]) == 2
