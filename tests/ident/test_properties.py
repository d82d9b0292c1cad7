"""Property tests T1-T11 of the identification reference (§4.2), with hypothesis.

Plant: ``dataset.linear_loop`` (exact ZOH, so the truth is known exactly).  Scenarios are
drawn from :mod:`bikeid.testing` (the strategies any user's property test uses): bicycles
are the benchmark with perturbed trail, steer tilt, front-frame mass and rear-body inertia
(``bicycles()``), kept only if ``BicycleParameters`` validates them and the roll PID
stabilizes them; speeds and seeds from ``speeds()`` and ``seeds()``.  T8 is a consistency
study (``assert_consistent``).  Tolerances are stated per test.
"""

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from bikeid.dataset.linear_loop import simulate
from bikeid.dataset.run import Run
from bikeid.ident import pem
from bikeid.ident.canonical import theta_from_matrices
from bikeid.ident.direct import identify, vaf_moore, vaf_variance
from bikeid.ident.subspace import po_moesp
from bikeid.ident.validate import resid
from bikeid.sim.errors import UntrustworthyResult
from bikeid.sim.linear import canonical_matrices, eigenvalues
from bikeid.sim.parameters import benchmark
from bikeid.testing import bicycles, scenarios, seeds, speeds

BASE = benchmark()
FAST = settings(max_examples=4, deadline=None, suppress_health_check=[HealthCheck.too_slow])
SLOW = settings(max_examples=2, deadline=None, suppress_health_check=[HealthCheck.too_slow])
STEER = ("Mdd", "C1dp", "C1dd", "K0dd", "K2dd")


def _sim(p, v, **kw):
    try:
        return simulate(p, v, **kw)
    except ValueError:  # the fixed PID does not stabilize this bicycle/speed
        assume(False)


def _entry(cm, name):
    m, r, c = name[:-2], "pd".index(name[-2]), "pd".index(name[-1])
    return getattr(cm, m)[r, c]


def _logged(run):
    """Exact states and accelerations, but the *logged* torque (T5, T6)."""
    s = dict(run.truth)
    s["T_delta"] = run.signals["T_delta"]
    return Run(t=run.t, signals=s, dither=run.dither, meta=run.meta)


@FAST
@given(p=bicycles(), v1=speeds(1.5, 4.0), dv=st.floats(1.0, 6.0), seed=seeds())
def test_t1_exact_recovery(p, v1, dv, seed):
    """T1: noise-free states, exact accelerations, dither, 2 speeds: free entries to
    1e-9 relative (float64 LS at cond <~ 100; reference measured 3e-15)."""
    runs = [_sim(p, v, duration=10, seed=seed + i, dither=1.0, dither_hold=3)
            for i, v in enumerate((v1, v1 + dv))]  # fmt: skip
    res = identify(runs, p, source="truth")
    cm = canonical_matrices(p)
    for name, val in res.free.items():
        assert val == pytest.approx(_entry(cm, name), rel=1e-9, abs=1e-9)


@FAST
@given(p=bicycles(), v=speeds(2.0, 8.0), dither=st.sampled_from([0.0, 1.0]))
def test_t2_roll_relation_makes_free_steer_row_singular(p, v, dither):
    """T2: with T_phi = F = 0 the roll equation is an exact linear relation among the
    steer regressors; freeing all seven steer entries must raise (cond >~ 1e15,
    regardless of dither), while Moore's symmetric set has cond < 100 (ref: 8.8/17.2)."""
    runs = [_sim(p, v, duration=10, seed=1, dither=dither), _sim(p, v + 2, duration=10, seed=2)]
    # the structural singularity, not the excitation, is under test: the informativity check
    # (which refuses runs without dither first) is skipped, as the test holds regardless of it
    with pytest.raises(UntrustworthyResult, match="unidentifiable") as exc:  # exit status 4
        identify(runs, p, source="truth", symmetric=False, informativity="skip",
                 free_steer=("Mdp", "Mdd", "C1dp", "C1dd", "K0dp", "K0dd", "K2dd"))  # fmt: skip
    assert "condition number" in str(exc.value)
    assert identify(runs, p, source="truth", informativity="skip").condition["steer"] < 100


@FAST
@given(p=bicycles(), v=speeds(1.5, 10.0))
def test_t3_single_speed_separability(p, v):
    """T3: at one constant speed g*delta and v^2*delta are collinear -> ValueError that
    names K0/K2 and asks for other speeds; per-sample speed variation fixes it."""
    run = _sim(p, v, duration=10, seed=3, dither=1.0)
    with pytest.raises(UntrustworthyResult, match="constant speed cannot separate K0 from K2"):
        identify(run, p, source="truth")
    varied = _sim(p, v, duration=20, seed=3, dither=1.0, speed_variation=0.3 * v)
    res = identify(varied, p, source="truth")
    assert res.free["K2dd"] == pytest.approx(canonical_matrices(p).K2[1, 1], rel=1e-7)


@FAST
@given(seed=seeds())
def test_t4_attenuation_monotone(seed):
    """T4 (multi-regressor): noise on deltadot only shrinks C1dd monotonically with the
    noise level (ref sim: ratio 0.727, 0.397 at sigma_n/sigma_x = 0.5, 1)."""
    runs = [simulate(BASE, v, duration=30, seed=seed + i, dither=1.0, dither_hold=5)
            for i, v in enumerate((2.0, 4.0, 6.0))]  # fmt: skip
    rng = np.random.default_rng(seed)
    est = []
    for level in (0.0, 0.5, 1.0):
        noisy = []
        for r in runs:
            s = dict(r.truth)
            s["deltadot"] = s["deltadot"] + rng.normal(
                scale=level * np.std(s["deltadot"]), size=r.n
            )
            noisy.append(Run(t=r.t, signals=s, meta=r.meta))
        est.append(identify(noisy, BASE, free_steer=STEER).free["C1dd"])
    true = canonical_matrices(BASE).C1[1, 1]
    assert est[0] == pytest.approx(true, rel=1e-8)
    assert true > est[1] > est[2] > 0


@SLOW
@given(seed=seeds(), sigma_w=st.sampled_from([1.0, 3.0]))
def test_t5_disturbance_biases_ls_iv_fixes(seed, sigma_w):
    """T5: an unlogged white steer torque enters q''(k) and, through the loop, the
    regressors: LS is biased (Mdd off by > 10 of its own standard errors; ref sim 0.39
    relative), IV with 1-sample-lagged regressors is consistent (every steer entry within
    4.5 of its IV standard errors; Bonferroni over 5 entries at ~1e-4 two-sided)."""
    kw = dict(duration=200, dither=1.0, dither_hold=10, disturbance=sigma_w)
    runs = [_logged(simulate(BASE, v, seed=seed + i, **kw)) for i, v in enumerate((2, 4, 6, 8))]
    cm = canonical_matrices(BASE)
    ls = identify(runs, BASE)
    iv = identify(runs, BASE, method="iv", instruments="lagged", lags=1)
    assert abs(ls.free["Mdd"] - cm.M[1, 1]) > 10 * ls.stderr["Mdd"]
    for n in STEER:
        assert abs(iv.free[n] - _entry(cm, n)) < 4.5 * iv.stderr[n], n


@FAST
@given(seed=seeds())
def test_t6_logged_torque_noise_is_benign(seed):
    """T6: noise only on the recorded T_delta is regressand noise: LS stays unbiased
    (every entry within 4.5 standard errors), unlike T5."""
    runs = [simulate(BASE, v, duration=100, seed=seed + i, dither=1.0, dither_hold=10,
                     torque_noise=1.0) for i, v in enumerate((2.0, 4.0, 6.0, 8.0))]  # fmt: skip
    runs = [Run(t=r.t, signals={**r.truth, "T_delta": r.signals["T_delta"]}, meta=r.meta)
            for r in runs]  # fmt: skip
    cm = canonical_matrices(BASE)
    res = identify(runs, BASE)
    for n in STEER:
        assert abs(res.free[n] - _entry(cm, n)) < 4.5 * res.stderr[n], n


@SLOW
@given(seed=seeds())
def test_t7_open_loop_subspace_biased_pem_not(seed):
    """T7 (v = 3 m/s, true weave real part +1.71): weak dither 0.5 N m under a 2 N m
    disturbance.  Open-loop PO-MOESP returns a stable model (the closed loop's
    poles leak in); direct PEM with an innovations model keeps an unstable pole.
    The sign of the largest real part is the reference's criterion."""
    r = simulate(BASE, 3.0, duration=100, seed=seed, dither=0.5, disturbance=2.0,
                 angle_noise=1e-3, rate_noise=1e-2)  # fmt: skip
    assert eigenvalues(BASE, 3.0).real.max() == pytest.approx(1.7068, abs=1e-3)
    A, _ = po_moesp(r["T_delta"], np.column_stack([r["phi"], r["delta"]]), n=4, f=20)
    moesp = np.log(np.linalg.eigvals(A).astype(complex)) / r.dt
    assert moesp.real.max() < 0
    assert pem.fit(r).eigenvalues().real.max() > 0


def pem_at_truth(runs, context):
    """Innovations-model PEM (the default noise model) per run, started at the truth (T8)."""
    return {r.speed: pem.fit(r, theta0=_truth(context, r.speed), multistart=False) for r in runs}


def oe_at_truth(runs, context):
    """Output-error PEM (K = 0) per run, started at the truth (T8; the estimate's bias is
    the subject, so its nominal-plant check, a second Kalman-gain fit tested in
    tests/ident/test_trust.py, is skipped)."""
    return {r.speed: pem.fit(r, theta0=_truth(context, r.speed), multistart=False,
                             noise_model="none", plant_check=False) for r in runs}  # fmt: skip


def _truth(context, v):
    return theta_from_matrices(canonical_matrices(context.bicycle), v)


@pytest.mark.slow  # 24 PEM fits of 25-400 s and 24 output-error fits of 25-100 s: ~40 s CPU
@settings(max_examples=1, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(scenario=scenarios(durations=(25.0, 100.0, 400.0), seeds=8, speed_range=(5.0, 5.0),
                          dither_range=(1.0, 1.0), first_seeds=(0, 0)))  # fmt: skip
def test_t8_pem_consistency(scenario):
    """T8 (F1), as a consistency study of :mod:`bikeid.testing`: PEM with the default noise
    model (the Kalman gain of fitted noise covariances) on closed-loop data with process
    (0.5 N m) and sensor noise is not biased (Hotelling T^2 at 400 s does not reject at 0.01)
    and its RMSE falls as 1/sqrt(N): the verdict's own rule, the slope's 95 % bootstrap
    interval below -0.25 (measured -0.47 [-0.63, -0.31] at seeds 0-7 over 25-400 s; over
    25-100 s the interval, -0.21 [-0.47, 0.13], cannot decide: the 400 s records are what
    make this a verdict).  Output-error PEM on the same data is ``biased`` (25-100 s,
    measured T^2 = 2.6e4, p = 2e-7).  Both started at the truth: consistency concerns the
    minimizer near it; local minima are a separate matter."""
    import dataclasses

    from bikeid.testing import assert_verdict

    res = assert_verdict("consistent with 1/sqrt(N)", pem_at_truth, scenario)
    assert min(res["verdict_detail"]["p_value"].values()) > 0.01
    short = dataclasses.replace(scenario, durations=(25.0, 50.0, 100.0))
    assert_verdict("biased", oe_at_truth, short)


@FAST
@given(seed=seeds())
def test_t10_residual_band(seed):
    """T10: with the true model and its Kalman gain, white innovations: about 1 % of the
    autocorrelations at lags 1..25 leave the 99 % band (allow <= 3 of 25 per output,
    binomial P ~ 0.002), and the residual-dither cross-correlation stays mostly inside."""
    from bikeid.ident.pem import CanonicalModel
    from bikeid.ident.predictor import discretize, kalman_gain

    v = 5.0
    r = simulate(BASE, v, duration=100, seed=seed, dither=1.0, dither_hold=5, disturbance=0.5,
                 angle_noise=1e-3, rate_noise=1e-2)  # fmt: skip
    theta = theta_from_matrices(canonical_matrices(BASE), v)
    Ad, Bd = discretize(theta, r.dt)
    C = np.eye(4)[[0, 2]]
    K = kalman_gain(Ad, Bd, C, 0.25, np.array([1e-6, 1e-6]))
    m = CanonicalModel(theta=theta, covariance=np.zeros((10, 10)), K=K, dt=r.dt, speed=v,
                       noise_covariance=np.eye(2), outputs=("phi", "delta"))  # fmt: skip
    rr = resid(r, m, input="dither")
    assert rr.band == pytest.approx(2.576 / np.sqrt(r.n), rel=1e-3)
    for o in ("phi", "delta"):
        assert rr.fraction_outside[o] <= 3 / 25
        assert rr.cross_outside[o] <= 3 / 26


@FAST
@given(st.lists(st.floats(-10, 10), min_size=20, max_size=200), st.floats(0.01, 2.0))
def test_t11_vaf_bookkeeping(values, scale):
    """T11: vaf_moore = 1 - ||e|| / ||y - mean||; for zero-mean e,
    vaf_variance = 1 - (1 - vaf_moore)^2 exactly (1e-9 for round-off)."""
    y = np.asarray(values)
    assume(np.std(y) > 1e-3)
    e = np.cos(np.arange(y.size)) * scale
    e -= e.mean()
    m, v = vaf_moore(y, y + e), vaf_variance(y, y + e)
    assert m == pytest.approx(1 - np.linalg.norm(e) / np.linalg.norm(y - y.mean()), abs=1e-12)
    assert v == pytest.approx(1 - (1 - m) ** 2, abs=1e-9)


def test_kalman_gain_without_a_stabilizing_solution_says_why():
    """Both ways on a 2-state model: with the unstable mode (z = 2) observed the gain exists
    and the predictor Ad - K C is stable (spectral radius < 1: the Riccati equation's
    stabilizing solution, Anderson & Moore ch. 4); with that mode unobserved no gain can
    stabilize it, and kalman_gain says so in one ValueError naming the largest eigenvalue
    modulus, 2, instead of scipy's QZ message alone; the doubling solver's QZ fallback
    (``filter_riccati``) says the same, being the same function."""
    from bikeid.ident.predictor import kalman_gain

    Ad, Bd = np.diag([2.0, 0.5]), np.array([[1.0], [1.0]])
    K = kalman_gain(Ad, Bd, np.array([[1.0, 0.0]]), 1.0, np.array([0.01]))
    assert np.max(np.abs(np.linalg.eigvals(Ad - K @ np.array([[1.0, 0.0]])))) < 1.0
    with pytest.raises(ValueError, match=r"no stabilizing solution .*modulus is 2 per sample"):
        kalman_gain(Ad, Bd, np.array([[0.0, 1.0]]), 1.0, np.array([0.01]))
    from bikeid.ident.innovation_gain import filter_riccati

    with pytest.raises(ValueError, match=r"no stabilizing solution .*modulus is 2 per sample"):
        filter_riccati(Ad, np.array([[0.0, 1.0]]), Bd @ Bd.T, np.array([[0.01]]))
