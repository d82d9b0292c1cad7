"""The cheaper PEM (exact sensitivities fused in one kernel, normal equations by Schur
complement) against the implementation it replaced, and its two exact derivatives against
independent methods.

Independent sources: the previous implementation of the fixed-speed fit, kept here as it
was (its compiled recursion, the x0 projection by SVD least squares, the stacked Jacobian
projected by QR, the sandwich by ``einsum``, the innovation gain's derivative not needed for
the free gain) and run through the same ``pem.fit``; ``scipy.linalg.expm_frechet`` for the
compiled Frechet derivatives; central differences of the Riccati solution for the gain's
analytic derivative.
"""

from __future__ import annotations

import numba
import numpy as np
import pytest
from scipy.linalg import expm_frechet

from bikeid.dataset.linear_loop import simulate
from bikeid.ident import pem, subspace
from bikeid.ident.canonical import A_POS, B_POS, canonical_ab, theta_from_matrices
from bikeid.ident.innovation_gain import _gain, gain_derivative, kalman_gain_of, noise_input
from bikeid.ident.predictor import (
    PredictionProblem,
    discretize,
    discretize_with_derivatives,
    expm_frechet_stack,
    output_matrix,
)
from bikeid.sim import linear
from bikeid.sim.parameters import benchmark

KW = dict(dither=1.0, dither_hold=5, disturbance=0.5, angle_noise=1e-3, rate_noise=1e-2)


@numba.njit(cache=True)
def _old_kernel(Ad, Bd, K, dAd, dBd, u, y, out_idx, x0, free_k):
    """Prediction errors e (N, l) and de/dparam (N, l, P + 4 l free_k + 4)."""
    N = u.shape[0]
    L = out_idx.shape[0]
    P = dAd.shape[0]
    nK = 4 * L if free_k else 0
    npar = P + nK + 4
    E = np.empty((N, L))
    J = np.empty((N, L, npar))
    x = x0.copy()
    S = np.zeros((4, npar))
    for i in range(4):
        S[i, P + nK + i] = 1.0
    Sn = np.zeros((4, npar))
    xn = np.zeros(4)
    e = np.zeros(L)
    for k in range(N):
        for c in range(L):
            e[c] = y[k, c] - x[out_idx[c]]
            E[k, c] = e[c]
            for j in range(npar):
                J[k, c, j] = -S[out_idx[c], j]
        for r in range(4):
            for j in range(npar):
                acc = 0.0
                for c in range(L):
                    acc += K[r, c] * J[k, c, j]
                for i in range(4):
                    acc += Ad[r, i] * S[i, j]
                Sn[r, j] = acc
        for j in range(P):
            for r in range(4):
                acc = dBd[j, r] * u[k]
                for i in range(4):
                    acc += dAd[j, r, i] * x[i]
                Sn[r, j] += acc
        if free_k:
            for r in range(4):
                for c in range(L):
                    Sn[r, P + L * r + c] += e[c]
        for r in range(4):
            acc = Bd[r] * u[k]
            for c in range(L):
                acc += K[r, c] * e[c]
            for i in range(4):
                acc += Ad[r, i] * x[i]
            xn[r] = acc
        for r in range(4):
            x[r] = xn[r]
            for j in range(npar):
                S[r, j] = Sn[r, j]
    return E, J


def _old_discretize_with_derivatives(theta, dt):
    A, B = canonical_ab(theta)
    Z = np.zeros((5, 5))
    Z[:4, :4], Z[:4, 4:] = A * dt, B * dt
    dAd, dBd, E = np.empty((10, 4, 4)), np.empty((10, 4)), None
    for i in range(10):
        dZ = np.zeros((5, 5))
        if i < 8:
            dZ[A_POS[i]] = dt
        else:
            dZ[B_POS[i - 8], 4] = dt
        E, dE = expm_frechet(Z, dZ)
        dAd[i], dBd[i] = dE[:4, :4], dE[:4, 4]
    return E[:4, :4], E[:4, 4], dAd, dBd


class _OldProblem(PredictionProblem):
    """The fixed-speed problem as the previous implementation evaluated it."""

    def _models(self, x, derivatives):
        p, Kfree = self.split(x)
        out = []
        for i, d in enumerate(self.data):
            theta = self.mapping[i] @ p
            if derivatives:
                Ad, Bd, dAd, dBd = _old_discretize_with_derivatives(theta, d.dt)
            else:
                (Ad, Bd), dAd, dBd = discretize(theta, d.dt), None, None
            K = Kfree if self.free_k else self.Ks[i]
            if not np.max(np.abs(np.linalg.eigvals(Ad - K @ self.C))) < 1.0:
                return None
            out.append((Ad, Bd, dAd, dBd, K, self.mapping[i]))
        return out

    def residual(self, x):
        models = self._models(x, derivatives=False)
        if models is None:
            return None
        res, x0s = [], []
        for d, (Ad, Bd, _, _, K, _) in zip(self.data, models, strict=True):
            E0, Psi = _old_kernel(Ad, Bd, K, np.zeros((0, 4, 4)), np.zeros((0, 4)), d.u, d.y,
                                  self.idx, np.zeros(4), False)  # fmt: skip
            Psi = (Psi * self.w[None, :, None]).reshape(-1, 4)
            e0 = (E0 * self.w).ravel()
            x0 = np.linalg.lstsq(Psi, -e0, rcond=None)[0]
            res.append(e0 + Psi @ x0)
            x0s.append(x0)
        self.x0s = x0s
        return np.concatenate(res)

    def normal_equations(self, x):
        r = self.residual(x)
        if r is None:
            return None, None, None
        jac = []
        models = self._models(x, derivatives=True)
        for d, x0, (Ad, Bd, dAd, dBd, K, S) in zip(self.data, self.x0s, models, strict=True):
            _, J = _old_kernel(Ad, Bd, K, dAd, dBd, d.u, d.y, self.idx, x0, self.free_k)
            J = (J * self.w[None, :, None]).reshape(-1, J.shape[2])
            nm = J.shape[1] - 4
            Jm = np.hstack([J[:, :10] @ S, J[:, 10:nm]])
            Q, _ = np.linalg.qr(J[:, nm:])
            jac.append(Jm - Q @ (Q.T @ Jm))
        J = np.vstack(jac)
        self._x, self._r, self._H, self.old_J = x.copy(), r, J.T @ J, J
        return r, self._H, J.T @ r

    def projected_blocks(self):
        yield self.old_J


def _old_sandwich(J, r, n_out, n_extra):
    dof = max(r.size - J.shape[1] - n_extra, 1)
    R = r.reshape(-1, n_out)
    lam = (R.T @ R) / dof * n_out
    Jt = J.reshape(R.shape[0], n_out, -1)
    inv = np.linalg.pinv(J.T @ J)
    cov = inv @ np.einsum("tlp,lm,tmq->pq", Jt, lam, Jt) @ inv
    return 0.5 * (cov + cov.T)


def test_fixed_speed_fit_same_optimum_as_previous_implementation(monkeypatch):
    """The fit of bench_ident's benchmark 1 (50 s at 100 Hz, 4 m/s, default options): every
    parameter within 0.01 of its standard error of the previous implementation's, computed
    here by running ``pem.fit`` on it (the brief's tolerance; both fits start from the
    same subspace estimate to rounding and take the same Levenberg-Marquardt steps, so they
    differ by rounding: 3e-14 standard errors measured).  The standard errors agree to 1e-6
    relative (6e-8 measured: the Schur complement against the QR projection)."""
    run = simulate(benchmark(), 4.0, duration=50, seed=1, **KW)
    new = pem.fit(run, structure=False)
    with monkeypatch.context() as mp:
        mp.setattr(pem, "PredictionProblem", _OldProblem)
        mp.setattr(subspace, "_regression", lambda Z, Y: np.linalg.lstsq(Z, Y, rcond=None)[0])
        old = pem.fit(run, structure=False)
    se = np.sqrt(np.diag(old.covariance))
    assert np.max(np.abs(new.theta - old.theta) / se) < 0.01
    assert np.allclose(np.sqrt(np.diag(new.covariance)), se, rtol=1e-6, atol=0)
    assert new.nfev == old.nfev


def test_sandwich_by_blocks_matches_einsum():
    """``sandwich_covariance`` (run blocks, Lambda = F F') against the former einsum of the
    stacked Jacobian, on a random problem-shaped J: equal to rounding (1e-10 relative)."""
    from bikeid.ident.predictor import sandwich_covariance

    rng = np.random.default_rng(3)
    J, r = rng.normal(size=(400, 6)), rng.normal(size=400)

    class Stub:
        L, _r, _H = 4, r, J.T @ J

        def projected_blocks(self):
            yield J[:200]
            yield J[200:]

    ref = _old_sandwich(J, r, 4, 8)
    assert np.allclose(sandwich_covariance(Stub(), 8), ref, rtol=1e-10, atol=0)


@pytest.mark.parametrize("scale", [1e-3, 0.5, 30.0])
def test_expm_frechet_stack_matches_scipy(scale):
    """All directions at once against scipy's expm_frechet one by one, with no scaling, and
    with 3 squarings (norm 30 > 4.74 x 2^2): 1e-12 relative (same algorithm, rounding)."""
    rng = np.random.default_rng(7)
    A = rng.normal(size=(7, 7)) * scale / 7
    Es = rng.normal(size=(3, 7, 7))
    R, Ls = expm_frechet_stack(A, Es)
    for E, L in zip(Es, Ls, strict=True):
        R0, L0 = expm_frechet(A, E)
        assert np.allclose(R, R0, rtol=1e-12, atol=1e-13 * np.abs(R0).max())
        assert np.allclose(L, L0, rtol=1e-12, atol=1e-12 * np.abs(L0).max())


@pytest.mark.parametrize("n_eta", [3, 5, 8])
@pytest.mark.parametrize("v", [2.0, 6.0])
def test_gain_derivative_matches_central_differences(v, n_eta):
    """dK/d[theta, eta] from the Stein equation against central differences (step 1e-6
    relative) of the Riccati solution, on the benchmark bicycle (unstable at 2 m/s, stable
    at 6 m/s), for each noise structure (acceleration noise; angle-row noise too; and the
    sensor-noise ratios of outputs 1-3 as well):
    agreement within 1e-6 of the largest entry, the differences' own error (truncation
    ~h^2, round-off ~1e-14 / h = 1e-8)."""
    theta = theta_from_matrices(linear.canonical_matrices(benchmark()), v)
    C = output_matrix(("phi", "phidot", "delta", "deltadot"))[0]
    rd, ref = np.array([1e-6, 1e-4, 1e-6, 1e-4]), np.array([0.2, 6.0, 0.5, 1.5])[:min(n_eta, 5) - 1]
    eta = np.array([np.log(0.1), 0.3, np.log(0.03), np.log(0.02), np.log(0.05), 0.4, -0.7,
                    1.1])[:n_eta]  # fmt: skip
    dt = 0.01
    Ad, _, dAd, _, G, dG = discretize_with_derivatives(theta, dt, noise_input(n_eta))
    K, P, Sinv, Lf, dL, _, dR = _gain(Ad, G, C, rd, eta, ref)
    dK = gain_derivative(Ad, G, C, K, P, Sinv, Lf, dL, dAd, dG, dR)
    assert dK.shape[0] == 10 + n_eta
    z = np.concatenate([theta, eta])
    for j in range(10 + n_eta):
        h = 1e-6 * max(abs(z[j]), 1.0)
        zp, zm = z.copy(), z.copy()
        zp[j] += h
        zm[j] -= h
        fd = (kalman_gain_of(zp[:10], dt, C, rd, zp[10:], ref)
              - kalman_gain_of(zm[:10], dt, C, rd, zm[10:], ref)) / (2 * h)  # fmt: skip
        scale = max(np.abs(fd).max(), 1e-3 * np.abs(dK).max())  # b1, b2: K does not move
        assert np.max(np.abs(dK[j] - fd)) < 1e-6 * scale, (j, np.max(np.abs(dK[j] - fd)) / scale)
