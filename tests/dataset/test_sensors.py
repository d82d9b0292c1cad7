"""Sensor models against analytic results: gain/offset, noise statistics, quantization error,
Butterworth gains, sampling, and seeded determinism."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bikeid.dataset.sensors import AntiAlias, Channel, Sensors, channel_noise
from bikeid.sim.conventions import MEASURED


def fine_grid(duration: float = 2.0, h: float = 1e-3) -> np.ndarray:
    return np.arange(round(duration / h) + 1) * h


def test_ideal_sensors_sample_truth_exactly():
    t = fine_grid()
    truth = {"phi": np.sin(3 * t), "v": 5 + 0 * t}
    t_s, meas, tr = Sensors.ideal(rate=200).measure(t, truth, seed=0)
    np.testing.assert_array_equal(t_s, t[::5])  # 1 kHz -> 200 Hz: every 5th sample
    np.testing.assert_array_equal(meas["phi"], np.sin(3 * t[::5]))
    np.testing.assert_array_equal(tr["v"], truth["v"][::5])


def test_bias_and_scale_are_exact_affine_maps():
    t = fine_grid()
    x = np.cos(2 * t)
    s = Sensors({"delta": Channel(bias=0.02, scale=1.1)}, rate=100)
    _, meas, _ = s.measure(t, {"delta": x}, seed=3)
    # scale * x + bias, rounding only (relative 1e-15 from two float operations)
    np.testing.assert_allclose(meas["delta"], 1.1 * x[::10] + 0.02, rtol=0, atol=4e-16)


def test_white_noise_statistics():
    """Sample mean, std and lag-1 autocorrelation of n = 2e5 draws within 5 standard errors
    of N(0, sigma^2): SE(mean) = sigma/sqrt(n), SE(std) ~ sigma/sqrt(2n), SE(r1) ~ 1/sqrt(n)."""
    n, sigma = 200_000, 1e-2
    t = np.arange(n) * 0.01
    _, meas, _ = Sensors({"phidot": Channel(std=sigma)}).measure(t, {"phidot": 0 * t}, seed=11)
    e = meas["phidot"]
    assert abs(e.mean()) < 5 * sigma / math.sqrt(n)
    assert abs(e.std() - sigma) < 5 * sigma / math.sqrt(2 * n)
    r1 = np.dot(e[1:] - e.mean(), e[:-1] - e.mean()) / np.sum((e - e.mean()) ** 2)
    assert abs(r1) < 5 / math.sqrt(n)


def test_quantization_error_is_bounded_and_uniform():
    """Rounding error lies in [-step/2, step/2]; on a ramp that crosses many steps it is
    uniform with variance step^2/12 (Widrow); 2 % tolerance >> 1/sqrt(n) sampling error."""
    step = 1e-3
    t = np.arange(100_001) * 1e-3
    x = 0.0123456 * t + 0.3  # a slow ramp over ~1200 steps
    _, meas, _ = Sensors({"phi": Channel(step=step)}, rate=1000).measure(t, {"phi": x}, seed=0)
    y = meas["phi"]
    k = y / step
    np.testing.assert_allclose(k, np.round(k), atol=1e-9)  # multiples of the step
    err = y - x
    assert np.max(np.abs(err)) <= step / 2 * (1 + 1e-9)
    assert abs(err.var() / (step**2 / 12) - 1) < 0.02


@pytest.mark.parametrize("order", [1, 2])
def test_antialias_gain_matches_butterworth(order):
    """Steady-state sine amplitude after the filter vs the analytic Butterworth gain
    |H(f)| = 1/sqrt(1 + (f/fc)^(2n)).  At f = fc the pre-warped bilinear filter is exactly
    -3 dB; at other frequencies the frequency warping f -> tan(pi f h)/(pi h) changes the
    gain by O((pi f h)^2) ~ 1e-3 relative here, hence the tolerance 3e-3."""
    h, fc = 1e-4, 25.0
    aa = AntiAlias(cutoff=fc, order=order)
    s = Sensors({}, rate=100, antialias=aa)
    for f in (fc / 4, fc, 45.0):
        t = np.arange(round(4.0 / h) + 1) * h
        _, meas, _ = s.measure(t, {"phi": np.sin(2 * np.pi * f * t)}, seed=0)
        y = meas["phi"]
        # amplitude from a least-squares sine fit over the last 2 s (transient gone)
        tt = t[::100][-200:]
        basis = np.column_stack([np.sin(2 * np.pi * f * tt), np.cos(2 * np.pi * f * tt)])
        coef, *_ = np.linalg.lstsq(basis, y[-200:], rcond=None)
        gain = math.hypot(*coef)
        expected = 1 / math.sqrt(1 + (f / fc) ** (2 * order))
        tol = 1e-6 if f == fc else 3e-3
        assert gain == pytest.approx(expected, rel=tol), (order, f)


def test_antialias_starts_in_steady_state():
    """A constant input passes unchanged from the first sample (DC gain 1, no transient)."""
    t = fine_grid()
    s = Sensors({}, rate=100, antialias=AntiAlias(20.0, 2))
    _, meas, _ = s.measure(t, {"v": 4.2 + 0 * t}, seed=0)
    np.testing.assert_allclose(meas["v"], 4.2, rtol=1e-12)


def test_noise_is_deterministic_and_independent_of_layout():
    n = 500
    a = channel_noise(7, "phi", n)
    np.testing.assert_array_equal(a, channel_noise(7, "phi", n))  # same seed, same noise
    np.testing.assert_array_equal(a[:100], channel_noise(7, "phi", 100))  # prefix-stable
    assert not np.array_equal(a, channel_noise(8, "phi", n))
    assert not np.array_equal(a, channel_noise(7, "delta", n))
    # adding channels does not change the noise of another channel
    t = np.arange(n) * 0.01
    one = Sensors({"phi": Channel(std=1e-3)}).measure(t, {"phi": 0 * t}, seed=7)[1]["phi"]
    many = Sensors.default().measure(t, {k: 0 * t for k in MEASURED}, seed=7)[1]["phi"]
    np.testing.assert_array_equal(one, many)
    np.testing.assert_array_equal(one, 1e-3 * a)


def test_chain_equals_offline_measurement_bit_for_bit():
    """What the controller sees in the loop (SensorChain) is what a run records."""
    s = Sensors({**Sensors.default().channels, "phi": Channel(1e-3, 0.01, 1.02, 1e-4)}, rate=100)
    t = np.arange(300) * 0.01
    rng = np.random.default_rng(0)
    truth = {k: rng.standard_normal(t.size) for k in MEASURED}
    _, meas, _ = s.measure(t, truth, seed=5)
    chain = s.chain(seed=5, n=t.size)
    for k in (0, 1, 150, 299):
        y = chain(k, np.array([truth[name][k] for name in MEASURED]))
        expect = np.array([meas[name][k] for name in MEASURED])
        np.testing.assert_array_equal(y, expect)


def test_describe_round_trip():
    s = Sensors.default(rate=200, antialias=AntiAlias(50.0, 1))
    assert Sensors.from_dict(s.describe()) == s
    assert s.describe()["channels"]["phi"]["std"] == 1e-3
    assert s.describe()["channels"]["phidot"]["std"] == 1e-2


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda: Channel(std=-1), "std must be >= 0"),
        (lambda: Channel(scale=0), "scale must be > 0"),
        (lambda: Channel(step=float("nan")), "must be finite"),
        (lambda: AntiAlias(10.0, order=3), "order must be 1 or 2"),
        (lambda: Sensors({}, rate=100, antialias=AntiAlias(60.0)), "below the sensor Nyquist"),
        (lambda: Sensors({}, rate=-1), "rate must be > 0"),
        (
            lambda: Sensors.ideal(rate=300).measure(np.arange(10) * 1e-3, {}, 0),
            "not a whole multiple",
        ),
        (lambda: channel_noise(-1, "phi", 3), "non-negative integer"),
    ],
)
def test_bad_settings_raise_clear_errors(make, message):
    with pytest.raises(ValueError, match=message):
        make()


def test_chain_antialias_agrees_with_offline_filter():
    """The loop's sample-by-sample filter (direct form II transposed) and scipy's sosfilt
    implement the same recursion; they differ only by round-off (bound 1e-12 rad on
    signals of order 1)."""
    s = Sensors(Sensors.default().channels, rate=100, antialias=AntiAlias(20.0, 2))
    h = 1e-3
    t = np.arange(2001) * h
    rng = np.random.default_rng(1)
    truth = {k: np.sin((i + 1) * t) + 0.1 * rng.standard_normal(t.size) for i, k in
             enumerate(MEASURED)}  # fmt: skip
    _, meas, _ = s.measure(t, truth, seed=2)
    chain = s.chain(seed=2, n=201, fine_dt=h)
    for j in range(t.size):
        yf = chain.filter(np.array([truth[k][j] for k in MEASURED]))
        if j % 10 == 0:
            y = chain(j // 10, yf)
            np.testing.assert_allclose(y, [meas[k][j // 10] for k in MEASURED], atol=1e-12)
