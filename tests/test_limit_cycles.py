"""Tests of the Poincare-section periodicity check (experiments.limit_cycles)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bikeid.experiments import limit_cycles as lc


class _FakeTrajectory:
    """Just enough of sim.integrate.Trajectory for ``periodicity``."""

    def __init__(self, t, phi, phidot, delta=None, deltadot=None, v=None):
        n = t.size
        self.t = t
        self._s = {
            "phi": phi,
            "phidot": phidot,
            "delta": np.zeros(n) if delta is None else delta,
            "deltadot": np.zeros(n) if deltadot is None else deltadot,
            "v": np.full(n, 3.5) if v is None else v,
            "psidot": np.zeros(n),
        }
        self.energy = np.full(n, 100.0)
        self.fell_at = None
        self.stop_reason = None

    def signal(self, name):
        return self._s[name]


def test_section_points_find_analytic_maxima():
    """phi = A sin(w t) + c has maxima A + c at t = (pi/2 + 2 pi k) / w.  Linear interpolation of
    phidot between samples locates them to O((w dt)^2) in time: with w dt = 0.01 the timing error
    is below 1e-5 s and the value error below A (w dt)^2 = 1e-4 rad."""
    w, A, c, dt = 2.0, 0.3, 0.05, 0.005
    t = np.arange(0, 20, dt)
    phi, phidot = A * np.sin(w * t) + c, A * w * np.cos(w * t)
    tc, pts = lc.section_points(t, phi, phidot, phi, phidot, np.full(t.size, 4.0))
    expect = (math.pi / 2 + 2 * math.pi * np.arange(tc.size)) / w
    np.testing.assert_allclose(tc, expect, atol=1e-5)
    np.testing.assert_allclose(pts[:, 0], math.degrees(A + c), atol=math.degrees(1e-4))
    np.testing.assert_allclose(pts[:, 3], 400.0)  # speed in cm/s


def test_period_two_orbit_detected():
    """phi = sin(t) + 0.4 sin(t / 2) repeats after 4 pi and has two different maxima per period:
    the check must report 2 returns per period and the period 4 pi (to the interpolation error)."""
    dt = 0.002
    t = np.arange(0, 200, dt)
    phi = np.sin(t) + 0.4 * np.sin(t / 2)
    phidot = np.cos(t) + 0.2 * np.cos(t / 2)
    res = lc.periodicity(_FakeTrajectory(t, phi, phidot))
    assert res.verdict == "periodic"
    assert res.returns_per_period == 2
    assert res.period == pytest.approx(4 * math.pi, abs=1e-4)


def test_contraction_factor_of_a_decaying_approach():
    """phi = (1 + a e^{-lam t}) sin(t): the maxima approach 1 with d_n proportional to
    e^{-lam t_n}, so d_n shrinks by exp(-2 pi lam) per return (period 2 pi).  The fitted factor
    must match to 2 % (the maxima are shifted slightly by the envelope's slope)."""
    lam, a, dt = 0.05, 0.5, 0.002
    t = np.arange(0, 150, dt)
    env = 1 + a * np.exp(-lam * t)
    phi = env * np.sin(t)
    phidot = -lam * a * np.exp(-lam * t) * np.sin(t) + env * np.cos(t)
    res = lc.periodicity(_FakeTrajectory(t, phi, phidot), closure_tol=10.0)
    assert res.returns_per_period == 1
    assert res.contraction == pytest.approx(math.exp(-2 * math.pi * lam), rel=0.02)


def test_quasi_periodic_motion_is_not_closed():
    """Two incommensurate frequencies (1 and sqrt 2) never repeat: no p <= 4 closes."""
    dt = 0.002
    t = np.arange(0, 300, dt)
    r2 = math.sqrt(2)
    phi = np.sin(t) + 0.3 * np.sin(r2 * t)
    phidot = np.cos(t) + 0.3 * r2 * np.cos(r2 * t)
    assert lc.periodicity(_FakeTrajectory(t, phi, phidot)).verdict == "not closed"


def test_small_motion_grows_at_the_linear_weave_rate():
    """From a 1e-5 deg roll, the uncontrolled benchmark at 3.5 m/s stays in its linear range for
    10 s (roll below 1 deg), so successive roll maxima grow by exp(Re(weave) T) per period
    T = 2 pi / Im(weave) of the linearization (Meijaard 2007, sim.linear); the speed change is
    second order in the amplitude.  Tolerance 1 % on the growth rate covers the remaining
    nonlinearity (amplitude < 1 deg) and the section interpolation."""
    from bikeid.sim.linear import eigenvalues
    from bikeid.sim.parameters import benchmark

    p = benchmark()
    weave = max(eigenvalues(p, 3.5), key=lambda z: z.imag)
    tr = lc.coast(p, lc.InitialCondition("tiny", phi=1e-5), duration=10.0, dt=0.005)
    tc, pts = lc.section_points(
        tr.t, tr.signal("phi"), tr.signal("phidot"), tr.signal("delta"), tr.signal("deltadot"),
        tr.signal("v"),
    )  # fmt: skip
    pos = pts[:, 0] > 0
    tc, amp = tc[pos][1:], pts[pos, 0][1:]  # skip the first (transient of the other modes)
    rate = np.polyfit(tc, np.log(amp), 1)[0]
    assert amp.size >= 3 and np.max(np.abs(amp)) < 1.0
    assert rate == pytest.approx(weave.real, rel=0.01)
    assert np.mean(np.diff(tc)) == pytest.approx(2 * math.pi / weave.imag, rel=0.01)


def test_fall_is_reported_for_a_large_initial_lean():
    """A 25 deg lean at 3.5 m/s with no steer (paper's Fig. 5 case) falls within 10 s; the
    verdict must say so and carry the fall time and cause from the integrator.  The front
    wheel folds first (|steer| > 90 deg at 0.53 s, roll 40 deg): before the steer limit
    existed the run went on with the steer turning through 366 deg and was reported fallen
    (|roll| > 60 deg) only at 7.55 s."""
    from bikeid.sim.parameters import benchmark

    tr = lc.coast(benchmark(), lc.InitialCondition("lean", phi=25.0), duration=10.0)
    res = lc.periodicity(tr, "lean")
    assert res.verdict == "fell" and res.stop_cause == "steer_limit"
    assert res.fell_at is not None and res.fell_at < 10.0
    assert abs(tr.signal("phi")[-1]) > math.radians(25)
    assert abs(tr.signal("delta")[-1]) > math.radians(60)
