"""Prediction-error identification of Chen & Dao's canonical model (C&D §II, Ljung ch. 7).

Predictor.  The continuous-time canonical model (``ident.canonical``) is sampled
exactly with a zero-order hold at the data's dt (Ad, Bd = blocks of
expm([[A, B], [0, 0]] dt)), and the one-step prediction error comes from the
innovations (steady-state Kalman) predictor::

    yhat[k] = C xhat[k],  e[k] = y[k] - yhat[k],
    xhat[k+1] = Ad xhat[k] + Bd u[k] + K e[k]

``noise_model="free"``: the discrete-time innovation gain K (4x2, at the data's dt)
is estimated with the plant (the model set then contains any plant-input and
sensor noise of the true loop, which makes direct PEM consistent in closed loop,
reference F1).  ``noise_model="none"``: K = 0, output error (biased in closed loop,
diverges for an unstable plant over long runs).  K is started from the Kalman gain
of the start model with Q = Bd Bd' var(u), R = diag(var(y)) 1e-2 (any stabilizing
gain would do).  Because the predictor is stable (Ad - K C), unstable plants do not
blow up.

Initial state.  Estimated per run by variable projection: e is affine in x0, so
x0 is solved by least squares at each evaluation and the Jacobian is projected
(Kaufman).  Jacobian: exact sensitivities, the derivative of expm by
``scipy.linalg.expm_frechet`` and a compiled recursion for d xhat / d theta.
Minimizer: ``scipy.optimize.least_squares(method="lm")`` (Levenberg-Marquardt,
MINPACK).  A trial step whose predictor is unstable gets a large finite residual
and is rejected.  Outputs are weighted by the inverse residual standard deviation
(two passes), so the covariance sigma^2 (J'J)^-1 is that of a whitened residual.

Start.  ``ident.subspace.pbsid`` on decimated data (closed-loop safe), converted to
continuous time and to the canonical form.

Speed-parameterized model (``fit_speed_model``): per-speed fits give the start
and each speed's K; then alpha, beta, gamma, b are refined jointly over all runs
with each speed's K held fixed (shared structural parameters, speed-specific
noise model).  The runs' nominal speed ``run.speed`` is used (per-sample speed
variation is ignored here).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import control
import numba
import numpy as np
from scipy.linalg import expm_frechet, solve_discrete_are
from scipy.optimize import least_squares

from dataset.run import Run
from sim.conventions import CANONICAL_STATE
from sim.linear import critical_speeds, eigenvalues_vs_speed

from .canonical import (
    A_POS,
    B_POS,
    SPEED_NAMES,
    THETA_NAMES,
    canonical_ab,
    matrices_from_speed_params,
    speed_map,
    to_bikeid_order,
    to_canonical_form,
)
from .subspace import d2c, decimate, pbsid

__all__ = ["CanonicalModel", "SpeedCanonicalModel", "fit", "fit_speed_model", "subspace_start"]

#: All four canonical states are measured (Moore & Hubbard Table 1); Chen & Dao used
#: ("phi", "delta").  Closed-loop consistency needs every signal the controller feeds
#: back among the outputs (a controller using phidot reveals state information a
#: phi/delta-only predictor lacks, biasing the estimate).
DEFAULT_OUTPUTS = ("phi", "phidot", "delta", "deltadot")
INPUT = "T_delta"


@numba.njit(cache=True)
def _kernel(Ad, Bd, K, dAd, dBd, u, y, out_idx, x0, free_k):
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


def _discretize_with_derivatives(theta: np.ndarray, dt: float):
    """Ad, Bd and their derivatives with respect to the 10 canonical parameters."""
    A, B = canonical_ab(theta)
    Z = np.zeros((5, 5))
    Z[:4, :4], Z[:4, 4:] = A * dt, B * dt
    dAd = np.empty((10, 4, 4))
    dBd = np.empty((10, 4))
    E = None
    for i in range(10):
        dZ = np.zeros((5, 5))
        if i < 8:
            dZ[A_POS[i]] = dt
        else:
            dZ[B_POS[i - 8], 4] = dt
        E, dE = expm_frechet(Z, dZ)
        dAd[i], dBd[i] = dE[:4, :4], dE[:4, 4]
    return E[:4, :4], E[:4, 4], dAd, dBd


def _discretize(theta: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    from scipy.linalg import expm

    A, B = canonical_ab(theta)
    Z = np.zeros((5, 5))
    Z[:4, :4], Z[:4, 4:] = A * dt, B * dt
    E = expm(Z)
    return E[:4, :4], E[:4, 4]


def _out_matrix(outputs: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
    bad = [o for o in outputs if o not in CANONICAL_STATE]
    if bad or len(set(outputs)) != len(outputs) or not {"phi", "delta"} <= set(outputs):
        raise ValueError(
            f"outputs {tuple(outputs)}: need 'phi' and 'delta' and optionally 'phidot', "
            "'deltadot', without repeats"
        )
    idx = np.array([CANONICAL_STATE.index(o) for o in outputs], dtype=np.int64)
    return np.eye(4)[idx], idx


def _kalman_gain(Ad, Bd, C, q: float, r: np.ndarray) -> np.ndarray:
    Q = np.outer(Bd, Bd) * q + 1e-12 * np.eye(4)
    R = np.diag(r)
    P = solve_discrete_are(Ad.T, C.T, Q, R)
    return Ad @ P @ C.T @ np.linalg.inv(C @ P @ C.T + R)


@dataclass
class _Data:
    u: np.ndarray
    y: np.ndarray
    dt: float
    v: float


def _run_data(runs: Sequence[Run], outputs: Sequence[str]) -> list[_Data]:
    out = []
    for r in runs:
        y = np.column_stack([r[o] for o in outputs])
        u = np.asarray(r[INPUT], float)
        if not np.any(u):
            raise ValueError("T_delta is zero in a run: the canonical model has nothing to fit")
        out.append(_Data(u=u, y=y, dt=r.dt, v=r.speed))
    return out


@dataclass(frozen=True)
class CanonicalModel:
    """A fixed-speed canonical model (states [phi, phidot, delta, deltadot]).

    ``theta`` = [a1..a8, b1, b2] (:data:`ident.canonical.THETA_NAMES`), ``covariance``
    (10x10), ``outputs`` the measured states used, ``K`` the discrete innovation gain
    at ``dt`` (4 x len(outputs)), ``noise_covariance`` of the innovations, ``x0`` per
    run, ``speed`` [m/s].
    """

    theta: np.ndarray
    covariance: np.ndarray
    K: np.ndarray
    dt: float
    speed: float
    noise_covariance: np.ndarray
    outputs: tuple[str, ...] = DEFAULT_OUTPUTS
    x0: tuple[np.ndarray, ...] = ()
    cost: float = float("nan")
    nfev: int = 0
    notes: tuple[str, ...] = field(default_factory=tuple)

    @property
    def A(self) -> np.ndarray:
        return canonical_ab(self.theta)[0]

    @property
    def B(self) -> np.ndarray:
        return canonical_ab(self.theta)[1]

    @property
    def C(self) -> np.ndarray:
        return _out_matrix(self.outputs)[0]

    @property
    def stderr(self) -> dict[str, float]:
        return dict(zip(THETA_NAMES, np.sqrt(np.diag(self.covariance)), strict=True))

    def params(self) -> dict[str, float]:
        return dict(zip(THETA_NAMES, self.theta, strict=True))

    def state_space(self) -> control.StateSpace:
        """Continuous-time model, states in Chen & Dao's order [phi, phidot, delta, deltadot]
        (``ident.canonical.to_bikeid_order`` permutes), outputs ``self.outputs``."""
        C = self.C
        return control.ss(self.A, self.B, C, np.zeros((C.shape[0], 1)), inputs=[INPUT],
                          outputs=list(self.outputs), states=list(CANONICAL_STATE))  # fmt: skip

    def state_space_bikeid(self) -> control.StateSpace:
        return to_bikeid_order(self.state_space())

    def predictor(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(Ad, Bd, C, K) of the discrete innovations predictor at ``dt``."""
        Ad, Bd = _discretize(self.theta, self.dt)
        return Ad, Bd[:, None], self.C, self.K

    def eigenvalues(self) -> np.ndarray:
        return np.linalg.eigvals(self.A)


@dataclass(frozen=True)
class SpeedCanonicalModel:
    """Speed-parameterized canonical model: a_odd = alpha + beta v^2, a_even = gamma v.

    ``params`` in :data:`ident.canonical.SPEED_NAMES` order with ``covariance``
    (14x14); ``per_speed`` holds the fixed-speed fits (start values and each speed's
    innovation gain K).
    """

    params: np.ndarray
    covariance: np.ndarray
    per_speed: dict[float, CanonicalModel]
    dt: float
    g: float = 9.81
    outputs: tuple[str, ...] = DEFAULT_OUTPUTS
    cost: float = float("nan")
    nfev: int = 0

    @property
    def stderr(self) -> dict[str, float]:
        return dict(zip(SPEED_NAMES, np.sqrt(np.diag(self.covariance)), strict=True))

    def theta(self, v: float) -> np.ndarray:
        return speed_map(v) @ self.params

    def at(self, v: float) -> CanonicalModel:
        """The fixed-speed model at v (covariance propagated; K of the nearest fitted speed)."""
        S = speed_map(v)
        near = min(self.per_speed, key=lambda s: abs(s - v))
        return CanonicalModel(
            theta=S @ self.params, covariance=S @ self.covariance @ S.T,
            K=self.per_speed[near].K, dt=self.dt, speed=v,
            noise_covariance=self.per_speed[near].noise_covariance, outputs=self.outputs,
        )  # fmt: skip

    def state_space(self, v: float) -> control.StateSpace:
        return self.at(v).state_space()

    def eigenvalues(self, v: float) -> np.ndarray:
        return np.linalg.eigvals(canonical_ab(self.theta(v))[0])

    def scaled_matrices(self) -> dict[str, np.ndarray]:
        """M^-1 g K0, M^-1 K2, M^-1 C1 (2x2 each) and the second column of M^-1."""
        cm = matrices_from_speed_params(self.params, self.g)
        return {"Minv_gK0": cm.K0 * self.g, "Minv_K2": cm.K2, "Minv_C1": cm.C1,
                "Minv_col_delta": self.params[12:14].copy()}  # fmt: skip

    def canonical_matrices(self):
        """Equivalent ``CanonicalMatrices`` with M = I (same A(v), same eigenvalues)."""
        return matrices_from_speed_params(self.params, self.g)

    def eigenvalues_vs_speed(self, speeds):
        return eigenvalues_vs_speed(self.canonical_matrices(), speeds)

    def critical_speeds(self, vmax: float = 30.0) -> dict:
        return critical_speeds(self.canonical_matrices(), vmax)


class _Problem:
    """Stacked, weighted, x0-projected prediction errors of several runs."""

    def __init__(self, data, mapping, Ks, free_k, weights, outputs):
        self.data, self.mapping, self.Ks, self.free_k = data, mapping, Ks, free_k
        self.C, self.idx = _out_matrix(outputs)
        self.L = len(outputs)
        self.w = np.asarray(weights, float)
        self._x, self._r, self._J, self.x0s = None, None, None, []

    def split(self, x):
        P = self.mapping[0].shape[1]
        nk = 4 * self.L
        return x[:P], (x[P : P + nk].reshape(4, self.L) if self.free_k else None)

    def evaluate(self, x):
        if self._x is not None and np.array_equal(x, self._x):
            return
        p, Kfree = self.split(x)
        res, jac, x0s = [], [], []
        cache = {}
        empty_a, empty_b = np.zeros((0, 4, 4)), np.zeros((0, 4))
        for i, d in enumerate(self.data):
            S = self.mapping[i]
            theta = S @ p
            key = (d.dt, tuple(theta))
            if key not in cache:
                cache[key] = _discretize_with_derivatives(theta, d.dt)
            Ad, Bd, dAd, dBd = cache[key]
            K = Kfree if self.free_k else self.Ks[i]
            rho = np.max(np.abs(np.linalg.eigvals(Ad - K @ self.C)))
            if not rho < 1.0:
                self._x = x.copy()
                self._r = np.full(sum(self.L * dd.u.size for dd in self.data), 1e6)
                self._J = None
                return
            E0, Psi = _kernel(Ad, Bd, K, empty_a, empty_b, d.u, d.y, self.idx, np.zeros(4), False)
            wt = np.tile(self.w, d.u.size)
            Psi = Psi.reshape(-1, 4) * wt[:, None]
            x0, *_ = np.linalg.lstsq(Psi, -(E0 * self.w).ravel(), rcond=None)
            E, J = _kernel(Ad, Bd, K, dAd, dBd, d.u, d.y, self.idx, x0, self.free_k)
            e = (E * self.w).ravel()
            J = J.reshape(e.size, -1) * wt[:, None]
            nm = J.shape[1] - 4
            Jm = np.hstack([J[:, :10] @ S, J[:, 10:nm]])
            Q, _ = np.linalg.qr(J[:, nm:])
            Jm -= Q @ (Q.T @ Jm)
            res.append(e)
            jac.append(Jm)
            x0s.append(x0)
        self._x, self._r, self._J, self.x0s = x.copy(), np.concatenate(res), np.vstack(jac), x0s

    def fun(self, x):
        self.evaluate(x)
        return self._r

    def jac(self, x):
        self.evaluate(x)
        if self._J is None:
            raise RuntimeError("Jacobian requested at a rejected point")
        return self._J

    def residuals(self) -> np.ndarray:
        """Unweighted prediction errors (N_total, L)."""
        return self._r.reshape(-1, self.L) / self.w


def subspace_start(
    runs: Sequence[Run],
    outputs: Sequence[str] = DEFAULT_OUTPUTS,
    p_seconds: float = 0.5,
    coarse_dt: float = 0.01,
) -> np.ndarray:
    """Canonical theta from :func:`ident.subspace.pbsid` (closed-loop safe).

    Uses only phi and delta as subspace outputs; the data are decimated to about
    ``coarse_dt`` (outputs subsampled, input block-averaged) and the VARX past window
    is ``p_seconds``.
    """
    data = _run_data(runs, ("phi", "delta"))
    dt = data[0].dt
    factor = max(1, int(round(coarse_dt / dt)))
    us, ys = [], []
    for d in data:
        u, y = decimate(d.u, d.y, factor)
        us.append(u)
        ys.append(y)
    dtc = dt * factor
    p = max(8, int(math.ceil(p_seconds / dtc)))
    A, B, C, _ = pbsid(us, ys, n=4, p=p)
    Ac, Bc = d2c(A, B, dtc, strict=False)
    return to_canonical_form(Ac, Bc, C)


def _solve(problem: _Problem, x0: np.ndarray, max_nfev: int, method: str):
    sol = least_squares(problem.fun, x0, jac=problem.jac, method=method, x_scale="jac",
                        max_nfev=max_nfev, xtol=1e-10, ftol=1e-10, gtol=1e-10)  # fmt: skip
    problem.evaluate(sol.x)
    if problem._J is None:
        raise ValueError("the prediction-error fit ended at an unstable predictor")
    return sol


def _covariance(problem: _Problem, n_extra: int) -> np.ndarray:
    J, r = problem._J, problem._r
    dof = max(r.size - J.shape[1] - n_extra, 1)
    return float(r @ r) / dof * np.linalg.pinv(J.T @ J)


def fit(
    runs: Run | Sequence[Run],
    *,
    outputs: Sequence[str] = DEFAULT_OUTPUTS,
    theta0: np.ndarray | None = None,
    noise_model: str = "free",
    max_nfev: int = 100,
    method: str = "lm",
    passes: int = 2,
) -> CanonicalModel:
    """Fixed-speed canonical PEM from one or more runs at the same speed and dt.

    ``outputs``: measured states fitted (default all four; see module docstring);
    ``theta0``: start (default :func:`subspace_start`); ``noise_model`` "free" (K
    estimated) or "none" (output error); ``passes``: fits with re-estimated output
    weights (1 = weights from the output variances only).  Returns a :class:`CanonicalModel`.
    """
    runs = [runs] if isinstance(runs, Run) else list(runs)
    if not runs:
        raise ValueError("no runs given")
    if noise_model not in ("free", "none"):
        raise ValueError(f"noise_model {noise_model!r}: choose 'free' or 'none'")
    outputs = tuple(outputs)
    C, _ = _out_matrix(outputs)
    data = _run_data(runs, outputs)
    dts = {round(d.dt, 12) for d in data}
    if len(dts) > 1:
        raise ValueError(f"runs have different sample periods {sorted(dts)}; resample first")
    speeds = {round(d.v, 6) for d in data}
    if len(speeds) > 1:
        raise ValueError(
            f"runs at different speeds {sorted(speeds)}: use fit_speed_model for several speeds"
        )
    dt = data[0].dt
    theta = subspace_start(runs) if theta0 is None else np.asarray(theta0, float)
    yvar = np.mean([np.var(d.y, axis=0) for d in data], axis=0)
    Ad, Bd = _discretize(theta, dt)
    free_k = noise_model == "free"
    L = len(outputs)
    if free_k:
        uvar = float(np.mean([np.var(d.u) for d in data]))
        K = _kalman_gain(Ad, Bd, C, uvar, 1e-2 * yvar)
    else:
        K = np.zeros((4, L))
    mapping = [np.eye(10)] * len(data)
    w = 1.0 / np.sqrt(yvar)
    x = np.concatenate([theta, K.ravel()]) if free_k else theta
    nfev = 0
    notes = []
    for _ in range(max(1, passes)):
        prob = _Problem(data, mapping, [K] * len(data), free_k, w, outputs)
        sol = _solve(prob, x, max_nfev, method)
        nfev += sol.nfev
        x = sol.x
        w = 1.0 / np.sqrt(np.mean(prob.residuals() ** 2, axis=0))
    if not sol.success:
        notes.append(f"least_squares: {sol.message}")
    cov = _covariance(prob, 4 * len(data))
    theta, Kf = prob.split(x)
    return CanonicalModel(
        theta=theta.copy(), covariance=cov[:10, :10], K=Kf.copy() if free_k else K, dt=dt,
        speed=data[0].v, noise_covariance=np.atleast_2d(np.cov(prob.residuals().T)),
        outputs=outputs, x0=tuple(prob.x0s), cost=float(prob._r @ prob._r), nfev=nfev,
        notes=tuple(notes),
    )  # fmt: skip


def fit_speed_model(
    runs: Sequence[Run],
    *,
    outputs: Sequence[str] = DEFAULT_OUTPUTS,
    g: float = 9.81,
    noise_model: str = "free",
    max_nfev: int = 50,
    method: str = "lm",
) -> SpeedCanonicalModel:
    """Speed-parameterized canonical PEM over runs at >= 2 distinct speeds (see module doc)."""
    runs = list(runs)
    outputs = tuple(outputs)
    groups: dict[float, list[Run]] = {}
    for r in runs:
        groups.setdefault(round(r.speed, 6), []).append(r)
    if len(groups) < 2:
        raise ValueError(
            "the speed-parameterized model needs runs at >= 2 distinct speeds (alpha and beta "
            "are not separable at one speed, reference T3)"
        )
    per = {
        v: fit(rs, outputs=outputs, noise_model=noise_model, method=method, passes=1)
        for v, rs in groups.items()
    }
    Sstack = np.vstack([speed_map(v) for v in per])
    tstack = np.concatenate([m.theta for m in per.values()])
    params, *_ = np.linalg.lstsq(Sstack, tstack, rcond=None)
    data = _run_data(runs, outputs)
    mapping = [speed_map(d.v) for d in data]
    Ks = [per[round(r.speed, 6)].K for r in runs]
    w = 1.0 / np.sqrt(np.mean([np.var(d.y, axis=0) for d in data], axis=0))
    nfev = 0
    for _ in range(2):
        prob = _Problem(data, mapping, Ks, False, w, outputs)
        sol = _solve(prob, params, max_nfev, method)
        nfev += sol.nfev
        params = sol.x
        w = 1.0 / np.sqrt(np.mean(prob.residuals() ** 2, axis=0))
    cov = _covariance(prob, 4 * len(data))
    return SpeedCanonicalModel(
        params=params.copy(), covariance=cov, per_speed=per, dt=data[0].dt, g=g,
        outputs=outputs, cost=float(prob._r @ prob._r), nfev=nfev,
    )  # fmt: skip
