"""References, dither and lateral pulses: statistics, analytic identities, reproducibility."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from bikeid.controllers.excitation import (
    ChirpReference,
    LateralForcePulses,
    StepReference,
    UniformDither,
    ZeroReference,
)


# -- dither --------------------------------------------------------------------------------
def test_dither_is_uniform_with_right_bounds_and_variance():
    """20,000 held values of U(-a, a), a = 0.8 N m.  Kolmogorov-Smirnov against U(-a, a)
    at alpha = 0.001 (false-alarm rate 0.1 % over seeds); mean within 4 sigma of 0
    (sigma = a / sqrt(3 n)); variance within 4 sigma of a^2/3 (the variance of the sample
    variance of a uniform is (a^4/5 - a^4/9) / n); all values inside [-a, a]."""
    a, n = 0.8, 20000
    d = UniformDither(amplitude=a, hold=0.01, seed=12345)
    x = d.sample(np.arange(n) * 0.01)
    assert x.min() >= -a and x.max() <= a
    assert stats.kstest(x, stats.uniform(loc=-a, scale=2 * a).cdf).pvalue > 1e-3
    assert abs(x.mean()) < 4 * a / math.sqrt(3 * n)
    sd_var = math.sqrt((a**4 / 5 - a**4 / 9) / n)
    assert abs(x.var() - a**2 / 3) < 4 * sd_var


def test_dither_is_reproducible_and_order_independent():
    t = np.linspace(0, 30, 3001)
    a = UniformDither(seed=3)
    b = UniformDither(seed=3)
    back = np.array([b(x) for x in t[::-1]])[::-1]  # queried in reverse order
    np.testing.assert_array_equal(a.sample(t), back)
    assert not np.array_equal(a.sample(t), UniformDither(seed=4).sample(t))


def test_dither_is_held_over_hold_time():
    d = UniformDither(hold=0.05, seed=1)
    for k in range(20):
        vals = {d(k * 0.05 + f * 0.05) for f in (0.0, 0.3, 0.7, 0.999)}
        assert len(vals) == 1
    assert d(-1.0) == 0.0


def test_dither_amplitude_limit():
    with pytest.raises(ValueError, match="max_amplitude"):
        UniformDither(amplitude=1.5)
    assert UniformDither(amplitude=1.5, max_amplitude=2.0).amplitude == 1.5


# -- references ----------------------------------------------------------------------------
def test_chirp_rate_is_derivative_and_zero_crossings_count_cycles():
    """rate() against a central difference (error O(h^2 phi''') ~ 1e-9); the number of zero
    crossings of a linear sweep is 2 (f0 + f1) / 2 * D (+-1)."""
    c = ChirpReference(amplitude=0.1, f0=0.1, f1=1.0, duration=20.0, start=2.0)
    h = 1e-5
    for t in np.linspace(2.1, 21.9, 37):
        num = (c(t + h) - c(t - h)) / (2 * h)
        assert abs(num - c.rate(t)) < 1e-6
    t = np.arange(2.0, 22.0, 1e-4)
    s = np.sign(c.sample(t)[1:])  # skip the sin(0) = 0 start
    crossings = int(np.count_nonzero(np.diff(s) != 0))
    assert abs(crossings - 2 * 0.55 * 20.0) <= 1
    assert c(1.9) == 0.0 and c(22.1) == 0.0 and c(2.0) == 0.0


def test_step_and_zero_references():
    s = StepReference([1.0, 3.0], [0.1, -0.2])
    assert [s(0.5), s(1.0), s(2.9), s(5.0)] == [0.0, 0.1, 0.1, -0.2]
    np.testing.assert_array_equal(s.sample([0.5, 1.0, 2.9, 5.0]), [0.0, 0.1, 0.1, -0.2])
    assert s.rate(1.0) == 0.0 and ZeroReference()(3.0) == 0.0
    with pytest.raises(ValueError, match="increasing"):
        StepReference([2.0, 1.0], [0.0, 1.0])


# -- lateral pulses ------------------------------------------------------------------------
def test_pulse_impulse_and_shape():
    """Each half-sine pulse carries the impulse 2 F_peak T / pi (analytic integral);
    check by trapezoidal integration (error O(dt^2)) over the first pulses."""
    p = LateralForcePulses(peak=80.0, duration=0.25, mean_gap=2.0, min_gap=0.5, seed=9)
    pulses = p.pulses_until(30.0)
    assert len(pulses) >= 5
    dt = 1e-4
    for t0, sign in pulses[:5]:
        t = np.arange(t0, t0 + 0.25 + dt / 2, dt)
        f = p.sample(t)
        assert np.all(sign * f >= 0)
        assert abs(np.trapezoid(f, t) - sign * 2 * 80.0 * 0.25 / math.pi) < 1e-4
    assert abs(p(pulses[0][0] + 0.125) - pulses[0][1] * 80.0) < 1e-12


def test_pulse_gaps_and_directions_statistics():
    """Gaps between pulse end and next start are min_gap + Exp(mean - min): all >= min_gap
    and their mean within 4 standard errors of mean_gap; directions +-1 balanced within
    4 sigma (binomial)."""
    p = LateralForcePulses(duration=0.2, mean_gap=3.0, min_gap=1.0, seed=5)
    pulses = p.pulses_until(20000.0)
    starts = np.array([t for t, _ in pulses])
    gaps = np.diff(starts) - 0.2
    n = gaps.size
    assert gaps.min() >= 1.0 - 1e-12
    assert abs(gaps.mean() - 3.0) < 4 * 2.0 / math.sqrt(n)
    signs = np.array([s for _, s in pulses])
    assert abs(signs.mean()) < 4 / math.sqrt(signs.size)


def test_pulses_reproducible():
    t = np.linspace(0, 60, 6001)
    a = LateralForcePulses(seed=2).sample(t)
    b = np.array([LateralForcePulses(seed=2)(x) for x in t])
    np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError, match="min_gap"):
        LateralForcePulses(mean_gap=1.0, min_gap=2.0)
