"""Profile intervals (``ident.uncertainty.profile_interval``) against closed forms, a second
optimizer and the exact truth of the linear plant.

Independent sources: the closed-form extremes of a linear form (and of a monotone function
of it) over an ellipsoid; ``scipy.optimize.minimize`` (SLSQP, a different algorithm) on the
same constrained problem; parameter draws around the exact benchmark canonical parameters
(Meijaard 2007, via ``sim.linear``), whose eigenvalues are the truth the intervals must
contain 95 % of the time.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy.optimize import minimize
from scipy.stats import binom

from bikeid.controllers.registry import make
from bikeid.dataset.linear_loop import simulate
from bikeid.ident import pem
from bikeid.ident.canonical import theta_from_matrices
from bikeid.ident.uncertainty import (
    eigenvalue_intervals,
    eigenvalue_jacobian,
    profile_interval,
    z_value,
)
from bikeid.sim.errors import InputError
from bikeid.sim.linear import canonical_matrices, eigenvalues, match_eigenvalues
from bikeid.sim.parameters import benchmark

SPEED = 5.0
Z = z_value(0.95)


def _cov(n: int, seed: int) -> np.ndarray:
    X = np.random.default_rng(seed).standard_normal((2 * n, n))
    return X.T @ X / (2 * n)


def test_linear_quantity_gives_the_first_order_interval():
    """q = a'p: max over (p'-p)' P^-1 (p'-p) <= z^2 is a'p + z sqrt(a'Pa) (Cauchy-Schwarz)."""
    rng = np.random.default_rng(0)
    p, a, P = rng.standard_normal(6), rng.standard_normal(6), _cov(6, 1)

    def q(x, s):
        return float(a @ x), a, s

    lo, hi, ok = profile_interval(q, p, P)
    half = Z * math.sqrt(a @ P @ a)
    assert ok
    assert lo == pytest.approx(a @ p - half, abs=1e-12 * half)
    assert hi == pytest.approx(a @ p + half, abs=1e-12 * half)


def test_monotone_transform_keeps_its_exact_asymmetric_ends():
    """q = exp(a'p) is increasing in a'p, so its ends are exp(a'p -+ z sqrt(a'Pa)) exactly:
    the profile is transformation-respecting; the first-order interval is symmetric."""
    rng = np.random.default_rng(2)
    p, a, P = rng.standard_normal(5), rng.standard_normal(5), _cov(5, 3)

    def q(x, s):
        e = math.exp(a @ x)
        return e, e * a, s

    lo, hi, ok = profile_interval(q, p, P)
    half = Z * math.sqrt(a @ P @ a)
    assert ok and half > 1.0  # strongly curved over the interval
    assert lo == pytest.approx(math.exp(a @ p - half), rel=1e-9)
    assert hi == pytest.approx(math.exp(a @ p + half), rel=1e-9)


def test_unknown_method_is_refused():
    theta = theta_from_matrices(canonical_matrices(benchmark()), SPEED)
    m = pem.CanonicalModel(theta=theta, covariance=np.eye(10) * 1e-6, K=np.zeros((4, 4)),
                           dt=0.01, speed=SPEED, noise_covariance=np.eye(4))  # fmt: skip
    with pytest.raises(InputError, match="profile, delta"):
        eigenvalue_intervals(m, method="bootstrap")


@pytest.fixture(scope="module")
def fitted():
    """A 50 s closed-loop PEM fit at 5 m/s (``bikeid coverage``'s default experiment, seed
    0): its covariance is large enough that the eigenvalues are curved in theta over it."""
    p = benchmark()
    run = simulate(p, SPEED, duration=50.0, controller=make("pid", p, sample_time=0.01),
                   seed=0, dither=3.0, dither_hold=5, disturbance=0.5, angle_noise=1e-3,
                   rate_noise=1e-2)  # fmt: skip
    return pem.fit(run)


def test_eigen_profile_ends_match_a_constrained_optimizer(fitted):
    """The weave and capsize real-part ends agree with SLSQP on max/min Re lambda(theta + L u)
    subject to |u|^2 <= z^2, to 1e-6 1/s (SLSQP's ftol 1e-12 on a function of size ~1)."""
    ei = eigenvalue_intervals(fitted)
    L = np.linalg.cholesky(fitted.covariance)
    for i in (1, 3):  # the weave (negative imaginary member) and the capsize root
        ref = ei.values

        def re(u, sign, i=i, ref=ref):
            lam = match_eigenvalues(eigenvalue_jacobian(fitted.theta + L @ u)[0], ref)
            return -sign * lam[i].real

        ends = []
        for sign in (-1.0, 1.0):
            r = minimize(re, np.zeros(10), args=(sign,), method="SLSQP",
                         constraints=[{"type": "ineq", "fun": lambda u: Z**2 - u @ u}],
                         options={"ftol": 1e-12, "maxiter": 500})  # fmt: skip
            assert r.success, r.message
            ends.append(-sign * r.fun)
        np.testing.assert_allclose([ei.real_lower[i], ei.real_upper[i]], ends, atol=1e-6)
    assert np.all(ei.converged)


@pytest.mark.slow
def test_profile_keeps_coverage_where_first_order_fails(fitted):
    """Draws theta_hat ~ N(theta_true, P) with P of the 50 s fit, each given P as its
    covariance (what a calibrated fit reports; ``bikeid coverage`` checks that on real
    fits): the profile intervals of the weave and capsize real parts contain the exact
    benchmark eigenvalues in a count inside the 99.9 % binomial acceptance region of
    Bin(400, 0.95), while the symmetric first-order intervals fall below it (their
    coverage here is ~0.91, benchmarks/bench_interval_curvature.py)."""
    theta = theta_from_matrices(canonical_matrices(benchmark()), SPEED)
    truth = eigenvalues(benchmark(), SPEED)
    L = np.linalg.cholesky(fitted.covariance)
    rng = np.random.default_rng(5)
    n = 400
    prof, delta = np.zeros(4), np.zeros(4)
    for _ in range(n):
        m = dataclasses.replace(fitted, theta=theta + L @ rng.standard_normal(10))
        prof += eigenvalue_intervals(m).contains(truth)[0]
        delta += eigenvalue_intervals(m, method="delta").contains(truth)[0]
    lo, hi = binom.ppf([0.0005, 0.9995], n, 0.95)
    order = np.argsort(truth.real)  # contains() is in the order of truth
    weave, capsize = order[1], order[3]
    for k in (weave, capsize):
        assert lo <= prof[k] <= hi, (prof, (lo, hi))
        assert delta[k] < lo, (delta, lo)


def _speed_model(rel: float):
    """The benchmark's exact speed parameters with sd = rel |p| (random correlation)."""
    from bikeid.ident.canonical import speed_params_from_matrices

    params = speed_params_from_matrices(canonical_matrices(benchmark()))
    X = np.random.default_rng(1).standard_normal((42, 14))
    d = rel * np.maximum(np.abs(params), 1e-3)
    cov = np.corrcoef(X.T) * np.outer(d, d)
    return pem.SpeedCanonicalModel(params=params, covariance=cov, per_speed={}, dt=0.01,
                                   g=9.81)  # fmt: skip


@pytest.mark.parametrize("rel", [0.01, 0.5])
def test_critical_speed_interval_is_open_exactly_when_the_ellipsoid_loses_the_speed(rel):
    """v_c over the confidence ellipsoid: with a 1 % spread every one of 150 points drawn on
    its surface has a v_c in (0, 8] m/s and the interval is closed, inside (0, 8); with a
    50 % spread some such point has none, and the interval is open at the range's edge.
    Second method: direct evaluation of ``sim.linear.critical_speeds`` at those points."""
    from bikeid.ident.canonical import matrices_from_speed_params
    from bikeid.ident.uncertainty import critical_speed_intervals
    from bikeid.sim.linear import critical_speeds

    vmax = 8.0
    m = _speed_model(rel)
    ci = critical_speed_intervals(m, vmax=vmax)
    evals, evecs = np.linalg.eigh(m.covariance)
    L = evecs * np.sqrt(np.maximum(evals, 0.0))
    u = np.random.default_rng(2).standard_normal((150, 14))
    u *= Z / np.linalg.norm(u, axis=1, keepdims=True)
    missing = sum(
        critical_speeds(matrices_from_speed_params(m.params + L @ x, 9.81), vmax)["v_c"] is None
        for x in u
    )
    lo, hi = ci.interval("v_c")
    if rel < 0.1:
        assert missing == 0 and not ci.open_v_c and 0 < lo < ci.v_c < hi < vmax
    else:
        assert missing > 0 and ci.open_v_c and (lo == 0.0 or hi == vmax)


def test_capsize_constant_is_the_quartics_constant_term():
    """The test inversion's det(alpha + v^2 beta) and its analytic gradient against a second
    route: ``sim.linear.quartic_coefficients``' e (the determinant expanded there) on the
    same parameters, and complex-step derivatives of it (exact to rounding), at 3 speeds
    and a random perturbation of the benchmark's speed parameters; 1e-12 relative is
    rounding of terms of size ~1e3."""
    from bikeid.ident.canonical import speed_params_from_matrices
    from bikeid.ident.uncertainty import _capsize_constant, _h
    from bikeid.sim.linear import constant_term

    p0 = speed_params_from_matrices(canonical_matrices(benchmark()))
    p = p0 * (1 + 0.1 * np.random.default_rng(4).standard_normal(p0.size))
    for v in (2.0, 6.0, 11.0):
        q, grad, _ = _capsize_constant(v * v)(p, None)
        assert q == pytest.approx(_h(p, 9.81, v, constant_term).real, rel=1e-12)
        cs = np.empty(p.size)
        for j in range(p.size):
            pc = p.astype(complex)
            pc[j] += 1e-30j
            cs[j] = _h(pc, 9.81, v, constant_term).imag / 1e-30
        np.testing.assert_allclose(grad, cs, rtol=1e-12, atol=1e-12 * np.abs(cs).max())
