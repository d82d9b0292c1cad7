"""Delta-method intervals (ident.uncertainty) and the coverage harness
(experiments.testbed.coverage).

Independent sources: central differences of ``numpy.linalg.eigvals`` and of
``sim.linear.critical_speeds`` (second method for the analytic/implicit derivatives); Monte
Carlo draws from the same covariance (second method for the propagated standard errors);
the exact truth of the linear plant (coverage); the closed form of the Clopper-Pearson bound.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import binom

from bikeid.experiments.testbed.coverage import (
    QUANTITIES,
    CoverageResult,
    binomial_verdict,
    run_coverage,
)
from bikeid.ident.canonical import speed_params_from_matrices, theta_from_matrices
from bikeid.ident.pem import CanonicalModel, SpeedCanonicalModel
from bikeid.ident.uncertainty import (
    bode_bands,
    critical_speed_intervals,
    eigenvalue_intervals,
    eigenvalue_jacobian,
    monte_carlo,
)
from bikeid.sim.errors import InputError
from bikeid.sim.linear import canonical_matrices, critical_speeds, match_eigenvalues
from bikeid.sim.parameters import benchmark

SPEED = 5.0
#: Monte Carlo draws: the relative standard error of a sample standard deviation is
#: 1/sqrt(2 D) = 1.1 % at D = 4000, so the 10 % tolerance below is ~9 of them; the rest of
#: the tolerance covers the second-order (curvature) terms the delta method drops, which
#: scale with the relative parameter spread (0.2 % here: "small covariance").
DRAWS = 4000
REL_SPREAD = 2e-3
#: Critical speeds searched up to 8 m/s (v_c = 6.02): a quarter of the default scan's cost.
VMAX = 8.0


def _small_cov(p: np.ndarray, seed: int = 0) -> np.ndarray:
    """Covariance with sd = REL_SPREAD |p| and a random correlation (fixed seed)."""
    rng = np.random.default_rng(seed)
    X = rng.standard_normal((3 * p.size, p.size))
    R = np.corrcoef(X.T)
    d = REL_SPREAD * np.maximum(np.abs(p), 1e-3)
    return R * np.outer(d, d)


@pytest.fixture(scope="module")
def fixed_model() -> CanonicalModel:
    theta = theta_from_matrices(canonical_matrices(benchmark()), SPEED)
    return CanonicalModel(theta=theta, covariance=_small_cov(theta), K=np.zeros((4, 4)),
                          dt=0.01, speed=SPEED, noise_covariance=np.eye(4))  # fmt: skip


@pytest.fixture(scope="module")
def speed_model() -> SpeedCanonicalModel:
    params = speed_params_from_matrices(canonical_matrices(benchmark()))
    return SpeedCanonicalModel(params=params, covariance=_small_cov(params, 1), per_speed={},
                               dt=0.01, g=9.81)  # fmt: skip


def test_eigen_jacobian_matches_central_differences(fixed_model):
    """Analytic (left/right eigenvector) derivative vs central differences, step 1e-6 |theta_j|:
    truncation ~ h^2 |lambda'''| and round-off ~ eps |lambda| / h are both below 1e-7 here."""
    lam, jac, cond = eigenvalue_jacobian(fixed_model.theta)
    assert np.all(cond < 100)  # simple, well-separated eigenvalues at 5 m/s
    for j in range(10):
        h = 1e-6 * abs(fixed_model.theta[j])
        ev = []
        for s in (1, -1):
            th = fixed_model.theta.copy()
            th[j] += s * h
            ev.append(match_eigenvalues(np.linalg.eigvals(_A(th)), lam))
        fd = (ev[0] - ev[1]) / (2 * h)
        np.testing.assert_allclose(jac[:, j], fd, rtol=1e-6, atol=1e-7 * np.abs(jac).max())
    assert np.all(jac[:, 8:] == 0)  # b1, b2 do not enter A


def _A(theta):
    from bikeid.ident.canonical import canonical_ab

    return canonical_ab(theta)[0]


def test_eigen_intervals_match_monte_carlo(fixed_model):
    ei = eigenvalue_intervals(fixed_model)
    mc = monte_carlo(fixed_model, DRAWS, np.random.default_rng(1))
    np.testing.assert_allclose(mc.eigenvalues.real.std(axis=0, ddof=1), ei.std_real, rtol=0.1)
    cplx = np.abs(ei.values.imag) > 0
    np.testing.assert_allclose(mc.eigenvalues.imag.std(axis=0, ddof=1)[cplx], ei.std_imag[cplx],
                               rtol=0.1)  # fmt: skip
    # 95 % intervals: the draws fall inside about 95 % of the time (binomial sd 0.34 % at
    # D = 4000, plus the 10 % sd tolerance above -> +-3 %)
    inside = (mc.eigenvalues.real >= ei.real_lower) & (mc.eigenvalues.real <= ei.real_upper)
    np.testing.assert_allclose(inside.mean(axis=0), 0.95, atol=0.03)


def test_bode_bands_match_monte_carlo(fixed_model):
    w = np.array([0.5, 3.0, 20.0])
    bands = bode_bands(fixed_model, w)
    mc = monte_carlo(fixed_model, DRAWS, np.random.default_rng(2), frequencies=w)
    assert [b.output for b in bands] == list(fixed_model.outputs)
    for i, b in enumerate(bands):
        np.testing.assert_allclose(mc.magnitude_db[:, i].std(axis=0, ddof=1),
                                   b.std_magnitude_db, rtol=0.1)  # fmt: skip
        np.testing.assert_allclose(mc.phase_deg[:, i].std(axis=0, ddof=1), b.std_phase_deg,
                                   rtol=0.1)  # fmt: skip
        assert np.all(b.magnitude_lower_db < b.magnitude_db)
        assert np.all(b.magnitude_db < b.magnitude_upper_db)
    # phidot = s phi: same relative error, so the same dB band; phase offset 90 deg
    np.testing.assert_allclose(bands[1].std_magnitude_db, bands[0].std_magnitude_db, rtol=1e-9)
    np.testing.assert_allclose((bands[1].phase_deg - bands[0].phase_deg) % 360, 90, atol=1e-9)


def test_critical_speed_interval_matches_differences_and_monte_carlo(speed_model):
    ci = critical_speed_intervals(speed_model, vmax=VMAX)
    # Meijaard 2007 benchmark: v_w = 4.292 m/s, v_c = 6.024 m/s (reference Table)
    assert ci.v_w == pytest.approx(4.2924, abs=1e-3)
    assert ci.v_c == pytest.approx(6.0243, abs=1e-3)
    # implicit-function gradient vs central differences of the brentq root (tol 1e-15), step
    # 1e-6 |p_j|: error ~ 1e-15 / 1e-6 relative to the gradient scale
    p = speed_model.params
    from bikeid.ident.canonical import matrices_from_speed_params

    for j in range(14):
        h = 1e-6 * max(abs(p[j]), 1e-3)
        vals = []
        for s in (1, -1):
            q = p.copy()
            q[j] += s * h
            vals.append(critical_speeds(matrices_from_speed_params(q), VMAX)["v_w"])
        fd = (vals[0] - vals[1]) / (2 * h)
        assert ci.gradient_v_w[j] == pytest.approx(fd, rel=1e-5, abs=1e-7 * np.abs(
            ci.gradient_v_w).max())  # fmt: skip
    mc = monte_carlo(speed_model, 600, np.random.default_rng(3), v=SPEED, critical=True,
                     vmax=VMAX)  # fmt: skip
    # 600 draws: sd of a sample sd 2.9 %; 10 % tolerance (module note)
    assert np.isnan(mc.v_w).sum() == 0
    assert np.std(mc.v_w, ddof=1) == pytest.approx(ci.std_v_w, rel=0.1)
    assert np.std(mc.v_c, ddof=1) == pytest.approx(ci.std_v_c, rel=0.1)
    delta = critical_speed_intervals(speed_model, vmax=VMAX, method="delta")
    lo, hi = delta.interval("v_w")
    assert hi - lo == pytest.approx(2 * 1.959964 * ci.std_v_w, rel=1e-6)  # z to 7 digits
    # the profile interval (the default) differs from it by the second-order term, of the
    # order of z x the relative spread (2e-3) of the first-order width: 1e-2 bounds it
    plo, phi = ci.interval("v_w")
    assert plo == pytest.approx(lo, abs=1e-2 * (hi - lo))
    assert phi == pytest.approx(hi, abs=1e-2 * (hi - lo))
    assert ci.to_json()["v_w"]["value"] == pytest.approx(ci.v_w)


def test_speed_model_eigen_intervals_use_the_speed_map(speed_model):
    """The speed model at v equals a fixed-speed model with theta = S p, cov = S P S'."""
    from bikeid.ident.canonical import speed_map

    a = eigenvalue_intervals(speed_model, v=SPEED)

    S = speed_map(SPEED)
    m = CanonicalModel(theta=S @ speed_model.params, covariance=S @ speed_model.covariance @ S.T,
                       K=np.zeros((4, 4)), dt=0.01, speed=SPEED,
                       noise_covariance=np.eye(4))  # fmt: skip
    b = eigenvalue_intervals(m)
    np.testing.assert_allclose(a.std_real, b.std_real, rtol=1e-10)
    np.testing.assert_allclose(a.values, b.values, rtol=1e-12)


def test_bad_input_is_refused(fixed_model, speed_model):
    with pytest.raises(InputError, match="level"):
        eigenvalue_intervals(fixed_model, level=1.0)
    with pytest.raises(InputError, match="pass v="):
        eigenvalue_intervals(speed_model)
    with pytest.raises(InputError, match="fitted at"):
        eigenvalue_intervals(fixed_model, v=3.0)
    with pytest.raises(InputError, match="frequencies"):
        bode_bands(fixed_model, [0.0, 1.0])
    with pytest.raises(InputError, match="speed-parameterized"):
        critical_speed_intervals(fixed_model)
    with pytest.raises(InputError, match="draws"):
        monte_carlo(fixed_model, 1, np.random.default_rng(0))


def test_binomial_verdict_both_ways():
    # Clopper-Pearson with k = n: the lower bound is (alpha/2)^(1/n) in closed form
    lo, hi, _ = binomial_verdict(40, 40)
    assert lo == pytest.approx(0.025 ** (1 / 40), rel=1e-9) and hi == 1.0
    assert binomial_verdict(95, 100)[2] == "consistent"
    assert binomial_verdict(50, 100)[2] == "too narrow"
    assert binomial_verdict(100, 100, level=0.5)[2] == "too wide"


@pytest.fixture(scope="module")
def coverage40() -> CoverageResult:
    # 40 seeds x 15 s of the linear loop (~11 s of CPU); a 10 N m dither so that the
    # eigenvalue standard errors stay small in so short a run (docs/uncertainty.md)
    return run_coverage(40, duration=15.0, dither=10.0)


@pytest.mark.slow
def test_coverage_is_nominal_on_the_linear_plant(coverage40):
    """Each quantity's count of 95 % intervals containing the exact truth lies in the 99.9 %
    two-sided binomial acceptance region of Bin(40, 0.95) (computed here), and the joint
    95 % region of the 10 parameters is consistent with nominal."""
    res = coverage40
    assert res.n == 40 and not res.failed
    lo = binom.ppf(0.0005, 40, 0.95)  # 32: P(count < 32) < 0.0005 when coverage is 95 %
    summary = res.summary()
    for name, row in summary.items():
        assert lo <= row["covered"] <= 40, (name, row)
        assert row.get("infinite", 0) == 0, (name, row)
    assert summary["theta_joint"]["verdict"] == "consistent"
    # parameter z-scores: sd near 1 (the sd of a sample sd at n = 40 is ~0.11; 0.7..1.4 is
    # ~3 of them either side). Eigenvalue z sd are not bounded here: in 15 s runs the
    # first-order propagation is visibly nonlinear (sd up to ~1.4, docs/uncertainty.md).
    z_std = np.array([summary[q]["z_std"] for q in QUANTITIES[:10]])
    assert np.all((z_std > 0.7) & (z_std < 1.4)), z_std


@pytest.mark.slow
def test_coverage_fails_when_the_covariance_is_too_small(coverage40):
    """Covariance x 0.1: z grows by sqrt(10) exactly (checked on 3 seeds through the
    harness), and coverage drops to ~P(|z| < 0.62) = 46 %, far below the region."""
    small = run_coverage(3, duration=15.0, dither=10.0, covariance_scale=0.1)
    for name in ("a1", "weave_re", "caster_re"):
        np.testing.assert_allclose(small.z[name], coverage40.z[name][:3] * math.sqrt(10),
                                   rtol=1e-9)  # fmt: skip
    scaled = CoverageResult(settings={**coverage40.settings, "covariance_scale": 0.1},
                            z={k: v * math.sqrt(10) for k, v in coverage40.z.items()},
                            mahalanobis=coverage40.mahalanobis * 10)  # fmt: skip
    lo = binom.ppf(0.0005, 40, 0.95)
    for name, row in scaled.summary().items():
        assert row["covered"] < lo and row["verdict"] == "too narrow", (name, row)
