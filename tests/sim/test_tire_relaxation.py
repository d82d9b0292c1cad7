"""Front-tyre lateral relaxation (``tire_relaxation``) in the experiment model.

The model (``ident/effects/experiment_model.py`` docstring) replaces the front contact's lateral
non-slip constraint by a heading lag sigma / v.  Checked here against the Whipple model of
``sim.linear`` (Meijaard 2007) in the limit sigma -> 0, against the Meijaard appendix A
intermediate values for the yaw coupling, and against a second formulation in absolute
headings.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import scipy.linalg as sla
from hypothesis import given, settings
from hypothesis import strategies as st

from bikeid.ident.effects.experiment_model import ExperimentModel, yaw_coupling
from bikeid.sim.linear import canonical_matrices, state_matrices
from bikeid.sim.parameters import benchmark, steer_by_wire


def _match(a: np.ndarray, b: np.ndarray) -> float:
    """Largest distance between two eigenvalue sets after optimal pairing."""
    from scipy.optimize import linear_sum_assignment

    d = np.abs(a[:, None] - b[None, :])
    i, j = linear_sum_assignment(d)
    return float(d[i, j].max())


def test_yaw_coupling_matches_meijaard_intermediate_values():
    """a = [I_Txz, I_Alz + mu I_Tzz] from the benchmark intermediate values of Meijaard 2007
    App. A (whipple-benchmarks.md: I_Txz 28.93344, I_Alz 0.3301214520762357, mu
    0.07459266794471792, I_Tzz 17.01908); nu = cos(lam) / w.  Tolerance 1e-12 relative."""
    p = benchmark()
    a, nu = yaw_coupling(p)
    assert a[0] == pytest.approx(28.93344, rel=1e-12)
    assert a[1] == pytest.approx(0.3301214520762357 + 0.07459266794471792 * 17.01908, rel=1e-12)
    assert nu == pytest.approx(math.cos(math.pi / 10) / 1.02, rel=1e-14)


def test_split_leaves_the_front_wheel_gyroscopic_terms():
    """The canonical matrices minus the yaw terms (a psi'' + v b psi' with the Whipple
    kinematics) leave the non-yaw parts derived by hand: M_phid - mu a_phi = I_Alx
    (0.1611908396686716), M_dd - mu a_d = I_All + mu I_Alz, and in the steer column of C1
    the front wheel's gyroscopic terms only: S_F cos(lam) (roll row) and -mu S_F sin(lam)
    (steer row: the yaw torque -S_F sin(lam) v delta' of the steered wheel, times the
    trail ratio mu).  Benchmark values, tolerance 1e-12 (round-off)."""
    p = benchmark()
    cm = canonical_matrices(p)
    a, nu = yaw_coupling(p)
    mu, IAlz, SF = 0.07459266794471792, 0.3301214520762357, 0.8
    sl, cl = math.sin(p.lam), math.cos(p.lam)
    assert cm.M[0, 1] - mu * a[0] == pytest.approx(0.1611908396686716, abs=1e-12)
    assert cm.M[1, 1] - mu * a[1] == pytest.approx(0.15389731601426776 + mu * IAlz, abs=1e-12)
    b = cm.K2[:, 1] / nu
    rest = cm.C1[:, 1] - nu * a - mu * b
    assert rest[0] == pytest.approx(SF * cl, abs=1e-12)
    assert rest[1] == pytest.approx(-mu * SF * sl, abs=1e-12)


@settings(max_examples=15, deadline=None)
@given(v=st.floats(0.5, 10.0), bike=st.sampled_from(["benchmark", "sbw"]))
def test_sigma_zero_is_the_whipple_model(v, bike):
    """At sigma = 0 the descriptor system (delta_k row algebraic: delta_k = delta) has one
    infinite and four finite generalized eigenvalues, equal to sim.linear's eigenvalues to
    round-off (1e-9 absolute, eigenvalues of size <= 20 1/s)."""
    p = benchmark() if bike == "benchmark" else steer_by_wire()
    E, A, _ = ExperimentModel(p=p).descriptor(v, relax=True)
    w = sla.eig(A, E, right=False)
    fin = w[np.isfinite(w)]
    assert fin.size == 4
    ref = np.linalg.eigvals(state_matrices(p, v)[0])
    assert _match(fin, ref) < 1e-9


@pytest.mark.parametrize("v", [2.0, 4.5])
def test_small_sigma_converges_first_order(v):
    """Singular perturbation: the slow eigenvalues differ from Whipple's by O(sigma), so
    halving sigma halves the error (ratio 2 within 5 %: the O(sigma^2) term at sigma = 1e-3
    m), and the extra eigenvalue is the heading relaxation -v / sigma (within 1 %)."""
    m = ExperimentModel()
    ref = np.linalg.eigvals(state_matrices(m.p, v)[0])
    errs = []
    for sig in (1e-3, 5e-4):
        ev = np.linalg.eigvals(m.with_effects(tire_relaxation=sig).continuous(v)[0])
        fast = ev[np.argmin(ev.real)]
        assert fast.real * sig / v == pytest.approx(-1.0, abs=0.01)
        slow = np.delete(ev, np.argmin(ev.real))
        errs.append(_match(slow, ref))
    assert errs[0] / errs[1] == pytest.approx(2.0, rel=0.05)


def _absolute_heading_model(p, v: float, sigma: float) -> np.ndarray:
    """Second formulation: states [phi, delta, psi, psi_c, phidot, deltadot] with the rear-frame
    yaw psi and the front contact path heading psi_c, straight from the constraints
    w psi' - c cos(lam) delta' = v (psi_c - psi),
    sigma (psi_c - psi)' = v (psi + delta cos(lam) - psi_c)
    and the roll/steer equations M_d q'' + v C1_d q' + g K0 q + a psi'' + v b psi' = 0."""
    cm = canonical_matrices(p)
    a, nu = yaw_coupling(p)
    mu = p.c * math.cos(p.lam) / p.w
    b = cm.K2[:, 1] / nu
    C1d = cm.C1.copy()
    C1d[:, 1] -= nu * a + mu * b
    # linear maps from the state to psi' and psi_c'
    dpsi = np.array([0, 0, -v, v, 0, p.c * math.cos(p.lam)]) / p.w
    dpsic = dpsi + np.array([0, v * math.cos(p.lam), v, -v, 0, 0]) / sigma
    A = np.zeros((6, 6))
    A[0, 4] = A[1, 5] = 1.0
    A[2] = dpsi
    A[3] = dpsic
    # M q'' = -(v C1d q' + g K0 q + a v (psi_c' - psi') / w + v b psi')  (mu a delta'' is in M)
    rhs = np.zeros((2, 6))
    rhs[:, 4:6] = -v * C1d
    rhs[:, 0:2] = -cm.g * cm.K0
    rhs -= np.outer(a * v / p.w, dpsic - dpsi) + np.outer(v * b, dpsi)
    A[4:6] = np.linalg.solve(cm.M, rhs)
    return A


@pytest.mark.parametrize("sigma", [0.05, 0.2, 0.5])
@pytest.mark.parametrize("v", [1.5, 3.0, 6.0])
def test_matches_absolute_heading_formulation(sigma, v):
    """The one-state model (kinematic steer delta_k) has the eigenvalues of the two-heading
    formulation minus its zero (heading invariance).  Tolerance 1e-9: round-off of two
    different eliminations."""
    p = steer_by_wire()
    ev = np.linalg.eigvals(ExperimentModel(p=p, effects={"tire_relaxation": sigma})
                           .continuous(v)[0])  # fmt: skip
    ev6 = np.linalg.eigvals(_absolute_heading_model(p, v, sigma))
    zero = np.argmin(np.abs(ev6))
    assert abs(ev6[zero]) < 1e-9
    assert _match(ev, np.delete(ev6, zero)) < 1e-9


def test_steady_turn_unchanged():
    """A lag on the path heading cannot change steady turning: the static gain from steer
    torque to (phi, delta) is the Whipple one for any sigma (delta_k = delta at rest).
    Tolerance 1e-10 relative (round-off)."""
    p = steer_by_wire()
    A0, B0 = state_matrices(p, 7.0)  # any speed with A invertible (a static solve)
    g0 = -np.linalg.solve(A0, B0[:, 1])[:2]
    A, B = ExperimentModel(p=p, effects={"tire_relaxation": 0.3}).continuous(7.0)
    g = -np.linalg.solve(A, B[:, 1])[:2]
    np.testing.assert_allclose(g, g0, rtol=1e-10)


def test_simulation_with_relaxation_matches_closed_loop():
    """The vectorized simulation with the extra state equals powers of the augmented loop
    matrix to round-off (1e-10), lag and relaxation together (state layout check)."""
    from bikeid.ident.effects.synthetic_decays import synthetic_windows

    m = ExperimentModel(effects={"tire_relaxation": 0.2, "actuator_lag": 0.02})
    w = replace(synthetic_windows(ExperimentModel(), [3.0], 1, noise=0.0)[0], hist=np.zeros(20))
    s = m.simulate([w])[0]
    Phi, _, c, npl = m.closed_loop(float(np.mean(w.v_sensor)))
    assert npl == 6
    x0 = w.state0()
    v = m.true_speed(float(np.mean(w.v_sensor)))
    z = np.zeros(Phi.shape[0])
    z[:4] = x0
    z[5] = x0[1] - 0.2 / v * x0[3]
    for k in range(w.n):
        assert abs(z[1] - s["delta"][k]) < 1e-10
        z = Phi @ z + c


def test_negative_relaxation_rejected():
    with pytest.raises(ValueError, match="tire_relaxation"):
        ExperimentModel(effects={"tire_relaxation": -0.1})
