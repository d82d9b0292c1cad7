"""The before/after interval, paired test and verdict (ident/effects/before_after.py).

Independent sources: the ratios are known by construction (after = r x before per decay, with
or without multiplicative noise of known spread), the percentile interval of an exact ratio
has zero width, and the sign-flip test's smallest attainable p-value is 1 / (n_boot + 1) or,
for n decays, no smaller than about 2 / 2^n.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bikeid.ident.effects.before_after import (
    before_after,
    verdict,
    verdict_text,
    zero_motion_error,
)

FILES = [f for f in "abcd" for _ in range(8)]  # 4 logs x 8 decays, like two real speeds


def _errors(ratio: float, spread: float, seed: int = 0):
    rng = np.random.default_rng(seed)
    e0 = rng.uniform(0.4, 0.9, len(FILES))
    return e0, e0 * ratio * np.exp(rng.normal(0.0, spread, len(FILES)))


def test_truly_halved_is_called_halved():
    """after = 0.35 x before with 20 % scatter: the whole interval lies below 0.5."""
    s = before_after(*_errors(0.35, 0.2), FILES)
    assert s["ratio_ci"][1] < 0.5
    assert s["ratio_ci"][0] <= s["ratio"] <= s["ratio_ci"][1]
    assert s["p_value"] < 0.01
    assert s["verdict"] == "halved"
    assert "halved" in verdict_text(s)


def test_ratio_near_the_goal_is_not_called_halved():
    """after = 0.5 x before with 30 % scatter: the point may fall below 0.5 but the interval
    reaches above it, so the verdict is 'reduced' and the text says halving is not shown."""
    s = before_after(*_errors(0.5, 0.3, seed=3), FILES)
    assert s["ratio_ci"][0] < 0.5 < s["ratio_ci"][1]
    assert s["verdict"] == "reduced"
    assert "halving not shown" in verdict_text(s)


def test_verdict_text_names_the_level_it_was_computed_at():
    """The line states the interval's own level (90 % here, not a fixed 95 %), and a summary
    without a recorded level reads as the default 95 %."""
    s = before_after(*_errors(0.35, 0.2), FILES, level=0.9)
    assert "90 % interval" in verdict_text(s)
    assert "95 % interval" in verdict_text({k: v for k, v in s.items() if k != "level"})


def test_no_change_and_worse():
    """after = before x noise (median ratio 1): no significant change; after = 1.5 x before:
    worse (the interval above 1)."""
    same = before_after(*_errors(1.0, 0.3, seed=5), FILES)
    assert same["ratio_ci"][0] < 1.0 < same["ratio_ci"][1]
    assert same["verdict"] == "no significant change"
    worse = before_after(*_errors(1.5, 0.1), FILES)
    assert worse["ratio_ci"][0] > 1.0 and worse["verdict"] == "worse"


def test_interval_is_stratified_by_file():
    """Each file keeps its own decays: when every decay of a file has the same ratio to its
    before-error, and files differ in before-error only, the resampled ratio stays exact."""
    e0 = np.repeat([0.5, 1.0, 2.0, 4.0], 8)
    s = before_after(e0, 0.4 * e0, FILES)
    assert s["ratio"] == pytest.approx(0.4, rel=1e-12)
    assert s["ratio_ci"] == pytest.approx([0.4, 0.4], rel=1e-12)


def test_paired_test_smallest_p_is_bounded_by_the_flips():
    """With 3 decays every sign pattern of 8 is equally likely under no change: two of them
    (all +, all -) reach the observed |statistic|, so p cannot fall below ~2/8 however
    large the improvement; the verdict then is not 'halved' even at ratio 0.1."""
    s = before_after([1.0, 1.1, 0.9], [0.1, 0.11, 0.09], ["a", "a", "a"], n_boot=4000)
    assert s["p_value"] > 0.2
    assert s["ratio"] == pytest.approx(0.1)
    assert s["verdict"] == "halved"  # the interval is exact (ratio 0.1 in every resample)
    assert verdict(0.1, [0.05, 0.6], 0.3) == "no significant change"


def test_zero_motion_baseline():
    """||y|| / ||y - mean y||: 1 for a zero-mean signal, sqrt(1 + mean^2 / var) otherwise."""
    t = np.linspace(0, 2 * np.pi, 1000, endpoint=False)
    assert zero_motion_error(np.sin(t)) == pytest.approx(1.0, abs=1e-12)
    assert zero_motion_error(1.0 + np.sin(t)) == pytest.approx(np.sqrt(1 + 1 / 0.5), rel=1e-9)


def test_bad_input_is_refused():
    with pytest.raises(ValueError, match="one entry per decay"):
        before_after([1.0, 2.0], [1.0], ["a", "a"])
    with pytest.raises(ValueError, match="finite"):
        before_after([1.0, np.nan], [1.0, 1.0], ["a", "a"])


@settings(max_examples=30, deadline=None)
@given(
    scale=st.floats(1e-3, 1e3),
    ratio=st.floats(0.05, 3.0),
    seed=st.integers(0, 2**16),
)
def test_ratio_and_interval_invariant_to_units(scale, ratio, seed):
    """A common unit change of both errors leaves ratio, interval, p and verdict unchanged,
    and the interval always holds the point ratio of its own resamples' centre."""
    e0, e1 = _errors(ratio, 0.2, seed)
    a = before_after(e0, e1, FILES, n_boot=500, seed=1)
    b = before_after(scale * e0, scale * e1, FILES, n_boot=500, seed=1)
    assert b["ratio"] == pytest.approx(a["ratio"], rel=1e-9)
    assert b["ratio_ci"] == pytest.approx(a["ratio_ci"], rel=1e-9)
    assert b["p_value"] == a["p_value"] and b["verdict"] == a["verdict"]
    assert a["ratio_ci"][0] <= a["ratio_ci"][1]
