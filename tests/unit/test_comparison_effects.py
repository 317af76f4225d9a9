"""chaos, experiment faults and the scheme comparison state each effect with its 95% interval, paired over
episodes, or say that none is detectable at their size."""

from __future__ import annotations

from truav.swarm.chaos import effects, effects_table
from truav.swarm.fault_sweep import effects_text
from truav.swarm.scheme_faults import comparison_effects


def summary(coverage, pdr):
    return {"world": {"episodes": [{"coverage_pct": c, "pdr": p, "delay_ms": None, "energy_j": 1000.0}
                                   for c, p in zip(coverage, pdr)]}}


def test_chaos_pairs_the_episodes_of_its_two_runs():
    base = summary([10.0, 12.0, 11.0, 9.0], [0.50, 0.60, 0.55, 0.52])
    faulted = summary([10.0, 12.0, 11.0, 9.0], [0.40, 0.52, 0.44, 0.43])  # PDR down 9-11 points in every pair
    found = effects(base, faulted)
    assert found["coverage %"].identical
    assert found["PDR %"].resolved and found["PDR %"].diff < 0
    assert found["relay delay ms"].n == 0  # no delay measured: no pair, said so
    table = effects_table(base, faulted)
    assert "paired over 4 episode(s), 95% t-interval" in table
    assert f"{'coverage %':<24}+0.00: identical in all 4 episodes" in table
    assert f"{'PDR %':<24}-9.50 ±" in table and "(95% CI, 4 episodes)" in table
    assert f"{'relay delay ms':<24}n/a (no pair with both values)" in table


def test_chaos_says_when_an_effect_is_inside_the_noise():
    base = summary([10.0, 12.0, 11.0], [0.5, 0.5, 0.5])
    faulted = summary([10.5, 11.2, 11.6], [0.5, 0.5, 0.5])  # +0.5 -0.8 +0.6
    table = effects_table(base, faulted)
    assert f"{'coverage %':<24}+0.10: no effect detectable at this size (±" in table
    assert "episodes would resolve a difference of 0.10" in table


def test_chaos_with_runs_of_unequal_length_pairs_what_both_finished():
    base = summary([10.0, 12.0, 11.0], [0.5, 0.5, 0.5])
    faulted = summary([10.0], [0.4])  # interrupted after one episode
    assert effects(base, faulted)["coverage %"].n == 1
    assert "1 pair: no interval" in effects_table(base, faulted)


def test_the_sweep_compares_each_point_with_its_kinds_no_fault_point():
    metrics = {"coverage_pct": [1.0, 2.0, 3.0], "pdr": [50.0, 60.0, 70.0], "delay_ms": [1.0, 2.0, 3.0],
               "energy_j": [1.0, 1.0, 1.0]}
    worse = {**metrics, "pdr": [40.0, 52.0, 61.0]}
    text = effects_text({("loss", 0.0): metrics, ("loss", 0.5): worse, ("latency", 0.0): metrics,
                         ("latency", 300.0): metrics})
    assert "beacon loss 0.5:\n  coverage (%)              +0.00: identical in all 3 episodes" in text
    assert "PDR (%)                   -9.00 ±2.48 (95% CI, 3 episodes)" in text
    assert "beacon latency 300:" in text and "beacon loss 0:" not in text


def test_the_scheme_comparison_pairs_schemes_at_each_point_and_points_with_no_fault():
    m = {"coverage_pct": [10.0, 11.0, 12.0], "pdr": [50.0, 50.0, 50.0], "delay_ms": [1.0, 1.0, 1.0],
         "energy_j": [1.0, 1.0, 1.0]}
    better = {**m, "coverage_pct": [20.0, 22.0, 23.0]}
    text = comparison_effects({("truav", "none", 0.0): m, ("truav", "loss", 0.5): m,
                               ("patrol", "none", 0.0): better, ("patrol", "loss", 0.5): better},
                              ("truav", "patrol"))
    assert "patrol - truav at none 0:\n  coverage (%)              +10.67 ±" in text
    assert "truav: loss 0.5 - no fault:\n  coverage (%)              +0.00: identical in all 3 episodes" in text


def test_evaluate_against_references_pairs_them_over_seeds(tmp_path, capsys):
    from truav.cli.main import main
    run = tmp_path / "run"
    assert main(["train", "--seeds", "3", "--episodes", "2", "--workers", "1", "--quiet", "--out", str(run),
                 "--set", "scenario.n_vehicles=30", "--set", "scenario.steps_per_episode=10",
                 "--set", "roads.warmup_steps=5"]) == 0
    capsys.readouterr()
    assert main(["evaluate", str(run), "--episodes", "1", "--workers", "1", "--quiet", "--against", "hover"]) == 0
    out = capsys.readouterr().out
    assert "truav - hover, paired over seeds, 95% t-interval:" in out
    lines = out.split("truav - hover, paired over seeds, 95% t-interval:\n", 1)[1].splitlines()
    assert [line.split()[0] for line in lines[:4]] == ["coverage", "PDR", "delay", "energy"]
    assert all(" seeds" in line or "no pair" in line for line in lines[:4]), lines  # a NaN delay drops its seed
