"""truav.stats' paired effects: the difference with and without a change, its 95% t-interval, and how many
pairs would resolve it; the wording every comparison prints."""

from __future__ import annotations

import math

import pytest

from truav.stats import Effect, effect_text, paired_effect, pairs_to_resolve, t95


def test_the_interval_is_the_t_interval_of_the_paired_differences():
    e = paired_effect([1, 2, 3, 4], [1.5, 2.4, 3.7, 4.2])  # differences 0.5 0.4 0.7 0.2
    assert e.n == 4 and e.diff == pytest.approx(0.45)
    assert e.sd == pytest.approx(0.2081666, rel=1e-6)
    assert e.half == pytest.approx(3.182 * 0.2081666 / 2, rel=1e-6)
    assert e.resolved and not e.identical and e.lo > 0


def test_pairs_with_a_missing_value_are_dropped_not_the_whole_metric():
    e = paired_effect([1.0, math.nan, 3.0], [2.0, 5.0, 4.0])
    assert (e.n, e.diff) == (2, 1.0) and e.identical is False and e.half == 0.0


def test_unequal_lengths_are_not_pairs():
    with pytest.raises(ValueError):
        paired_effect([1, 2], [1, 2, 3])


@pytest.mark.parametrize("sd, size", [(1.0, 0.5), (1.0, 1.0), (3.0, 0.2), (0.1, 1.0)])
def test_pairs_to_resolve_is_the_first_count_whose_half_width_is_below_the_size(sd, size):
    n = pairs_to_resolve(sd, size)
    assert t95(n - 1) * sd / math.sqrt(n) < size
    assert n == 2 or t95(n - 2) * sd / math.sqrt(n - 1) >= size


def test_pairs_to_resolve_says_nothing_it_cannot_know():
    assert pairs_to_resolve(math.nan, 1.0) is None and pairs_to_resolve(1.0, 0.0) is None
    assert pairs_to_resolve(1.0, 1e-9) is None  # past the limit


def test_a_difference_inside_the_noise_says_so_with_its_interval_and_the_size_that_would_resolve_it():
    e = paired_effect([1, 2, 3, 4], [1.1, 1.9, 3.2, 3.9])
    text = effect_text(e, noun="episodes")
    assert not e.resolved
    assert text.startswith(f"+0.03: no effect detectable at this size (±{e.half:.2f}, 4 episodes); ~")
    need = pairs_to_resolve(e.sd, abs(e.diff))
    assert f"~{need} episodes would resolve a difference of 0.03" in text
    assert f"~{pairs_to_resolve(e.sd, 1.0)} episodes would resolve a difference of 1.00" in \
        effect_text(e, noun="episodes", size=1.0)


def test_the_other_cases_read_as_what_they_are():
    assert effect_text(paired_effect([1, 2, 3], [1, 2, 3]), noun="seeds") == "+0.00: identical in all 3 seeds"
    assert effect_text(paired_effect([1], [3])) == "+2.00 (1 pair: no interval; more pairs give one)"
    assert effect_text(paired_effect([math.nan], [3])) == "n/a (no pair with both values)"
    assert effect_text(Effect(-2.0, 0.5, 5, 0.4), digits=1) == "-2.0 ±0.5 (95% CI, 5 pairs)"


def test_a_difference_that_prints_as_zero_asks_for_no_more_pairs():
    # the chaos comparison printed "~77959 episodes would resolve a difference of 0.00"
    e = Effect(0.0023, 0.03, 20, 0.064)
    text = effect_text(e, noun="episodes")
    assert text == "+0.00: no effect detectable at this size (±0.03, 20 episodes)"
    assert "would resolve" not in effect_text(e, noun="episodes", size=0.004)
    assert "would resolve a difference of 0.01" in effect_text(e, noun="episodes", size=0.01)
