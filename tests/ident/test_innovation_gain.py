"""The innovation gain from noise covariances: a one-step predictor stable by construction.

Independent sources: scipy's QZ solver of the discrete Riccati equation (against the
doubling of ``filter_riccati``); the eigenvalues of Ad - K C (stability, computed apart from
the Riccati solution); the linearized benchmark bicycle (Meijaard 2007, ``sim.linear``) for
where it is open-loop unstable.
"""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.linalg import solve_discrete_are

from bikeid.ident.canonical import theta_from_matrices
from bikeid.ident.innovation_gain import NOISE_LOG_RANGE, filter_riccati, kalman_gain_of
from bikeid.ident.predictor import discretize, output_matrix
from bikeid.sim import linear
from bikeid.sim.parameters import benchmark

C4 = output_matrix(("phi", "phidot", "delta", "deltadot"))[0]
P = benchmark()


def _theta(v: float) -> np.ndarray:
    return theta_from_matrices(linear.canonical_matrices(P), v)


@settings(max_examples=25, deadline=None)
@given(v=st.floats(1.0, 10.0), logq=st.floats(-24.0, 0.0), seed=st.integers(0, 2**16))
def test_doubling_matches_qz(v, logq, seed):
    """Same stabilizing solution as scipy's QZ method.  Tolerance 1e-7 relative: at the
    smallest process noise (Q ~ 1e-12 of R) the two solvers agree to ~2e-10 on the
    benchmark (measured), and QZ's own error grows as Q/R falls."""
    rng = np.random.default_rng(seed)
    Ad, _ = discretize(_theta(v), 0.01)
    G = rng.normal(size=(4, 2))
    Q = np.exp(logq) * G @ G.T + 1e-12 * np.eye(4)
    R = np.diag(rng.uniform(1e-6, 1e-4, 4))
    mine, qz = filter_riccati(Ad, C4, Q, R), solve_discrete_are(Ad.T, C4.T, Q, R)
    assert np.max(np.abs(mine - qz)) <= 1e-7 * np.max(np.abs(qz))


@settings(max_examples=25, deadline=None)
@given(
    v=st.floats(1.0, 10.0),
    eta=st.tuples(st.floats(*NOISE_LOG_RANGE), st.floats(-5.0, 5.0), st.floats(*NOISE_LOG_RANGE)),
    scale=st.floats(0.8, 1.25),
)
def test_every_noise_covariance_gives_a_stable_predictor(v, eta, scale):
    """For any noise parameters and any model near the benchmark (stable or not) the
    predictor Ad - K C is stable: its spectral radius, from its eigenvalues, is below 1."""
    theta = _theta(v) * scale
    K = kalman_gain_of(theta, 0.01, C4, np.full(4, 1e-6), np.array(eta), np.array([1.0, 3.0]))
    Ad, _ = discretize(theta, 0.01)
    assert np.max(np.abs(np.linalg.eigvals(Ad - K @ C4))) < 1.0


def test_zero_gain_is_unstable_where_the_bicycle_is():
    """The other way: at 4 m/s the benchmark's weave is unstable (Re +0.41 1/s), so the
    output-error predictor (K = 0) is unstable, and the Kalman gain with vanishing process
    noise is not (the weave's predictor poles mirrored inside the unit circle:
    |z| = exp(-0.41 dt))."""
    lam = linear.eigenvalues(P, 4.0)
    assert np.max(lam.real) > 0.4
    Ad, _ = discretize(_theta(4.0), 0.01)
    assert np.max(np.abs(np.linalg.eigvals(Ad))) > 1.0
    lo = NOISE_LOG_RANGE[0]
    # sensor variances 1: the solver's fixed 1e-12 process-noise floor is then negligible
    K = kalman_gain_of(_theta(4.0), 0.01, C4, np.ones(4), np.array([lo, 0.0, lo]),
                       np.array([1.0, 3.0]))  # fmt: skip
    radius = np.abs(np.linalg.eigvals(Ad - K @ C4))
    weave = np.exp(-np.max(lam.real) * 0.01)
    # mirror image to 1e-5 (measured 2e-9; the 1e-12 floor moves it by ~1e-6 at R = 1e-3)
    assert np.min(np.abs(radius - weave)) < 1e-5


def test_a_failed_alternation_keeps_the_joint_fit(monkeypatch):
    """Where the alternating refinement finds no stable start (a noise bound or new output
    weights; measured on the accuracy sweep's 1.5 m/s PID run, seed 2), the Kalman fit keeps
    its joint fit and says so, instead of failing the whole identification.  Known both
    ways: without the failure no such note; with it the model's predictor is the joint
    fit's, stable (spectral radius of Ad - K C below 1)."""
    from bikeid.dataset.linear_loop import simulate
    from bikeid.ident import pem
    from bikeid.sim.errors import UntrustworthyResult

    run = simulate(benchmark(), 5.0, duration=20, seed=1, dither=1.0, disturbance=0.5,
                   angle_noise=1e-3, rate_noise=1e-2)  # fmt: skip
    ok = pem.fit(run, multistart=False)
    assert not any("alternating refinement stopped" in n for n in ok.notes)

    def fail(*args, **kwargs):
        raise UntrustworthyResult("the start model gives an unstable predictor")

    monkeypatch.setattr(pem, "alternate", fail)  # the name pem.fit calls
    kept = pem.fit(run, multistart=False)
    assert any("alternating refinement stopped" in n for n in kept.notes), kept.notes
    Ad, _, C, K = kept.predictor()
    assert np.max(np.abs(np.linalg.eigvals(Ad - K @ C))) < 1.0


def test_prediction_kernel_takes_any_layout_and_compiles_one_version():
    """The predictor kernel called with transposed (Fortran-order) and sliced views gives
    the same errors and sensitivities, bit for bit, as with C-contiguous copies, and numba
    holds only C-contiguous versions of it (a view passed straight through would compile an
    'A'-layout version, ~2 s, in every fresh environment)."""
    from bikeid.ident import predictor

    rng = np.random.default_rng(0)
    Ad = np.asfortranarray(0.2 * rng.standard_normal((4, 4)))  # a transposed-like view
    Bd = rng.standard_normal((4, 3))[:, 1]  # a strided column
    K = 0.1 * rng.standard_normal((4, 2))
    dAd, dBd, dK = rng.standard_normal((2, 4, 4)), rng.standard_normal((2, 4)), np.zeros((0, 4, 2))
    u, y = rng.standard_normal(50), rng.standard_normal((50, 2))
    idx, x0, w = np.array([0, 1]), np.zeros(4), np.ones(2)
    E, J = predictor.prediction_kernel(Ad, Bd, K, dAd, dBd, dK, u, y, idx, x0, True, w)
    c = np.ascontiguousarray
    E0, J0 = predictor._prediction_kernel(c(Ad), c(Bd), K, dAd, dBd, dK, u, y, idx, x0, True, w)
    assert np.array_equal(E, E0) and np.array_equal(J, J0)
    layouts = {a.layout for sig in predictor._prediction_kernel.signatures for a in sig
               if hasattr(a, "layout")}  # fmt: skip
    assert layouts == {"C"}, predictor._prediction_kernel.signatures
