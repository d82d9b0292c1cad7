"""ident.signals: zero-phase Butterworth, differentiation (incl. the T9 pitfall), means."""

import numpy as np
import pytest

from bikeid.dataset.linear_loop import simulate
from bikeid.ident.signals import differentiate, lowpass, prepare, remove_means
from bikeid.sim.parameters import benchmark


@pytest.mark.parametrize("f", [2.0, 15.0, 30.0])
def test_lowpass_gain_is_squared_butterworth(f):
    """filtfilt applies |H|^2; the digital (bilinear) 2nd-order Butterworth has
    |H(f)|^2 = 1 / (1 + (tan(pi f dt) / tan(pi fc dt))^4).

    Tolerance 2e-3: the steady-state amplitude of a 200-period sinusoid, edges cut.
    """
    dt, fc = 0.005, 15.0
    t = np.arange(0, 200 / f, dt)
    y = lowpass(np.sin(2 * np.pi * f * t), dt, fc, 2)
    core = slice(len(t) // 4, 3 * len(t) // 4)
    amp = np.sqrt(2 * np.mean(y[core] ** 2))
    ratio = np.tan(np.pi * f * dt) / np.tan(np.pi * fc * dt)
    assert amp == pytest.approx(1 / (1 + ratio**4), abs=2e-3)


def test_lowpass_rejects_cutoff_above_nyquist():
    with pytest.raises(ValueError, match="Nyquist"):
        lowpass(np.zeros(100), 0.01, 60.0)


def test_central_difference_exact_on_quadratic():
    """Central differences are exact for polynomials of degree <= 2 (interior points)."""
    dt = 0.01
    t = np.arange(0, 1, dt)
    d = differentiate(3 * t**2 + 2 * t, dt, "central")
    assert np.allclose(d[1:-1], 6 * t[1:-1] + 2, atol=1e-10)


def test_forward_difference_first_order():
    """Forward difference of sin: error ~ dt/2 |sin''| -> halving dt halves the error."""
    errs = []
    for dt in (0.01, 0.005):
        t = np.arange(0, 2, dt)
        errs.append(np.abs(differentiate(np.sin(t), dt, "forward")[:-1] - np.cos(t[:-1])).max())
    assert errs[0] / errs[1] == pytest.approx(2.0, rel=0.05)


def test_t9_zoh_forward_difference_beats_central():
    """T9: with a held dither, q'' jumps at each sample; the forward difference of the
    sampled rate is the mean of q'' over the hold interval, the central one straddles
    the jump.  Max error of forward must be well below that of central (second method:
    the simulator's exact accelerations)."""
    r = simulate(benchmark(), 4.0, duration=10, dt=0.01, seed=2, dither=1.0, dither_hold=4)
    exact = r.truth["deltaddot"][:-1]
    central = differentiate(r.truth["deltadot"], r.dt, "central")[:-1]
    forward = differentiate(r.truth["deltadot"], r.dt, "forward")[:-1]
    e_c = np.abs(central - exact).max() / np.abs(exact).max()
    e_f = np.abs(forward - exact).max() / np.abs(exact).max()
    assert e_c > 0.1  # the jump error does not vanish
    assert e_f < 0.5 * e_c


def test_remove_means_keeps_speed_and_force():
    sig = {"phi": np.array([1.0, 3.0]), "v": np.array([5.0, 5.0]), "F": np.array([1.0, 1.0])}
    out = remove_means(sig)
    assert (
        np.allclose(out["phi"], [-1, 1]) and np.allclose(out["v"], 5) and np.allclose(out["F"], 1)
    )


def test_prepare_adds_accelerations():
    r = simulate(benchmark(), 5.0, duration=5, seed=1)
    out = prepare(r, cutoff=None, subtract_mean=False, derivative="forward", source="truth")
    expect = np.diff(r.truth["phidot"]) / r.dt
    assert np.allclose(out.signals["phiddot"][:-1], expect, rtol=0, atol=1e-12)
