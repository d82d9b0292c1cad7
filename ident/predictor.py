"""The innovations predictor shared by the prediction-error methods (:mod:`ident.pem`,
:mod:`ident.greybox`).

Both fit continuous-time models of the canonical form (``ident.canonical``, Chen & Dao's
state order [phi, phidot, delta, deltadot]) through the same one-step predictor::

    yhat[k] = C xhat[k],  e[k] = y[k] - yhat[k],
    xhat[k+1] = Ad xhat[k] + Bd u[k] + K e[k]

with (Ad, Bd) the zero-order-hold sampling of (A, B) at the data's dt.  This module holds
what they share: the sampling and its exact derivatives (:func:`discretize`,
:func:`discretize_with_derivatives`), the output matrix of the measured states
(:func:`output_matrix`), the compiled error/sensitivity recursion
(:func:`prediction_kernel`), the runs as (u, y, dt, v) (:func:`run_data`), the stacked,
weighted, x0-projected problem (:class:`PredictionProblem`, which :mod:`ident.greybox`
subclasses for its matrix-entry parameters), the Levenberg-Marquardt minimizer
(:func:`levenberg_marquardt`, :func:`solve`), the sandwich covariance
(:func:`sandwich_covariance`) and the start innovation gain (:func:`initial_gain`).  The
model classes and the fitting entry points stay in :mod:`ident.pem` and
:mod:`ident.greybox`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numba
import numpy as np
from scipy.linalg import expm_frechet, solve_discrete_are
from scipy.optimize import least_squares

from bikeid.dataset.run import Run
from bikeid.ident.canonical import A_POS, B_POS, canonical_ab
from bikeid.sim.conventions import CANONICAL_STATE
from bikeid.sim.errors import UntrustworthyResult
from bikeid.sim.sampling import zoh

__all__ = [
    "DEFAULT_OUTPUTS",
    "INPUT",
    "discretize",
    "initial_gain",
    "kalman_gain",
    "kstep_kernel",
    "levenberg_marquardt",
    "output_matrix",
    "run_data",
    "sandwich_covariance",
    "single_threaded_blas",
    "solve",
]

#: All four canonical states are measured (Moore & Hubbard Table 1); Chen & Dao used
#: ("phi", "delta").  Closed-loop consistency needs every signal the controller feeds
#: back among the outputs (a controller using phidot reveals state information a
#: phi/delta-only predictor lacks, biasing the estimate).
DEFAULT_OUTPUTS = ("phi", "phidot", "delta", "deltadot")
INPUT = "T_delta"


@numba.njit(cache=True)
def prediction_kernel(Ad, Bd, K, dAd, dBd, u, y, out_idx, x0, free_k):
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


def discretize_with_derivatives(theta: np.ndarray, dt: float):
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


def discretize(theta: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """The canonical model ``theta`` sampled with a zero-order hold.

    Parameters
    ----------
    theta : (10,) ndarray
        Canonical parameters [a1, ..., a8, b1, b2] (:func:`ident.canonical.canonical_ab`).
    dt : float
        Sample period [s].

    Returns
    -------
    Ad : (4, 4) ndarray
        Discrete state matrix, Chen & Dao's order [phi, phidot, delta, deltadot].
    Bd : (4,) ndarray
        Discrete input column for T_delta [rad/(N m), rad/(N m s) by row].
    """
    Ad, Bd = zoh(*canonical_ab(theta), dt)
    return Ad, Bd[:, 0]


def output_matrix(outputs: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
    """Output matrix C (y = C x) of the measured canonical states.

    Parameters
    ----------
    outputs : sequence of str
        Measured states in order, from ("phi", "delta", "phidot", "deltadot"); must
        include phi and delta, without repeats.

    Returns
    -------
    C : (L, 4) ndarray
        Rows of the identity picking each output from x = [phi, delta, phidot, deltadot].
    idx : (L,) int64 ndarray
        The state index of each output.

    Raises
    ------
    ValueError
        If an output is unknown or repeated, or phi or delta is missing.
    """
    bad = [o for o in outputs if o not in CANONICAL_STATE]
    if bad or len(set(outputs)) != len(outputs) or not {"phi", "delta"} <= set(outputs):
        raise ValueError(
            f"outputs {tuple(outputs)}: need 'phi' and 'delta' and optionally 'phidot', "
            "'deltadot', without repeats"
        )
    idx = np.array([CANONICAL_STATE.index(o) for o in outputs], dtype=np.int64)
    return np.eye(4)[idx], idx


def kalman_gain(Ad, Bd, C, q, r, covariance: bool = False):
    """Steady-state Kalman (innovation) gain for process noise through the input columns.

    Parameters
    ----------
    Ad : (n, n) ndarray
        Discrete state matrix (n = 4 for the canonical models; more for an augmented one).
    Bd : (n,) or (n, m) ndarray
        Discrete input column(s) the process noise enters through.
    C : (L, n) ndarray
        Output matrix.
    q : float or (m,) ndarray
        Variance of each input noise [(N m)^2] (process noise Bd diag(q) Bd').
    r : (L,) ndarray
        Variances of the output noises (squared output units).
    covariance : bool, optional
        Also return the a-priori state error covariance P of the predictor.

    Returns
    -------
    K : (n, L) ndarray
        The innovation gain K of xhat[k+1] = Ad xhat[k] + Bd u[k] + K e[k].
    P : (n, n) ndarray
        Only with ``covariance``: the stabilizing solution of the Riccati equation, the
        covariance of x[k] - xhat[k] (state units squared).
    """
    G = np.asarray(Bd, float).reshape(Ad.shape[0], -1)
    Q = (G * np.broadcast_to(np.asarray(q, float), G.shape[1])) @ G.T
    Q = Q + 1e-12 * np.eye(Ad.shape[0])
    R = np.diag(r)
    P = solve_discrete_are(Ad.T, C.T, Q, R)
    K = Ad @ P @ C.T @ np.linalg.inv(C @ P @ C.T + R)
    return (K, P) if covariance else K


@numba.njit(cache=True)
def kstep_kernel(Ad, Bd, K, C, d, u, y, x0, k, sidx, scol, scoef, eps):
    """k-step-ahead predictions of the innovations predictor (one window).

    The one-step predictor xhat[t+1] = Ad xhat[t] + Bd u_t + K (y[t] - C xhat[t] - d) runs
    over the data; the output at t is predicted from xhat[s], s = max(t - k + 1, 0) (data
    up to s - 1), propagated t - s steps with the known inputs and no innovation:
    k = 1 is the one-step predictor, k >= N the simulation from x0.  ``u_t`` is the known
    input row u[t] plus the smoothed signs of states: column scol[j] receives
    scoef[j] tanh(x[sidx[j]] / eps) (the sign evaluated on the state being propagated).

    Parameters
    ----------
    Ad, Bd : (n, n), (n, m) ndarray
        Sampled state and input matrices.
    K : (n, L) ndarray
        Innovation gain (Ad - K C stable).
    C : (L, n) ndarray
        Output matrix; ``d`` (L,) the output offsets (output units).
    d : (L,) ndarray
        Output offsets.
    u : (N, m) ndarray
        Known inputs per sample (N m).
    y : (N, L) ndarray
        Measured outputs (rad, rad/s).
    x0 : (n,) ndarray
        Start state estimate.
    k : int
        Horizon [samples], >= 1.
    sidx, scol : (ns,) int64 ndarray
        State and input column of each sign term.
    scoef : (ns,) ndarray
        Coefficient of each sign term (N m).
    eps : float
        Smoothing of the signs (state units).

    Returns
    -------
    Yh : (N, L) ndarray
        The k-step predicted outputs (offset d included).
    Xp : (N, n) ndarray
        The one-step predictor's states.
    """
    N = u.shape[0]
    n = Ad.shape[0]
    L = C.shape[0]
    Xp = np.empty((N, n))
    Yh = np.empty((N, L))
    x = x0.copy()
    xn = np.zeros(n)
    ut = np.zeros(u.shape[1])
    e = np.zeros(L)
    for t in range(N):  # the one-step predictor
        Xp[t] = x
        _output(C, d, x, e)
        for c in range(L):
            e[c] = y[t, c] - e[c]
        _propagate(Ad, Bd, u[t], sidx, scol, scoef, eps, x, ut, xn)
        for r in range(n):
            acc = xn[r]
            for c in range(L):
                acc += K[r, c] * e[c]
            x[r] = acc
    z = np.zeros(n)
    for t in range(N):  # propagate from xhat[s] to t without innovations
        s = max(t - k + 1, 0)
        z[:] = Xp[s]
        for tt in range(s, t):
            _propagate(Ad, Bd, u[tt], sidx, scol, scoef, eps, z, ut, xn)
            z[:] = xn
        _output(C, d, z, Yh[t])
    return Yh, Xp


@numba.njit(cache=True)
def _output(C, d, x, out):
    """out = C x + d, in place (explicit loops: BLAS calls cost more on 4 x 6 matrices)."""
    for c in range(C.shape[0]):
        acc = d[c]
        for i in range(x.shape[0]):
            acc += C[c, i] * x[i]
        out[c] = acc


@numba.njit(cache=True)
def _propagate(Ad, Bd, u_t, sidx, scol, scoef, eps, x, ut, xn):
    """xn = Ad x + Bd (u_t + the smoothed signs of x), in place (``kstep_kernel``)."""
    ut[:] = u_t
    for j in range(sidx.shape[0]):
        ut[scol[j]] += scoef[j] * np.tanh(x[sidx[j]] / eps)
    for r in range(x.shape[0]):
        acc = 0.0
        for i in range(x.shape[0]):
            acc += Ad[r, i] * x[i]
        for j in range(ut.shape[0]):
            acc += Bd[r, j] * ut[j]
        xn[r] = acc


@dataclass
class RunData:
    u: np.ndarray
    y: np.ndarray
    dt: float
    v: float


def run_data(runs: Sequence[Run], outputs: Sequence[str]) -> list[RunData]:
    """The runs as the predictor reads them: input T_delta, the outputs, dt and speed.

    Parameters
    ----------
    runs : sequence of Run
        The data; ``T_delta`` [N m] must be nonzero in each.
    outputs : sequence of str
        Measured states, in the order of the columns of ``y``.

    Returns
    -------
    list of RunData
        Per run ``u`` (N,) [N m], ``y`` (N, L) (rad, rad/s), ``dt`` [s], ``v`` [m/s].

    Raises
    ------
    ValueError
        If T_delta is zero in a run.
    """
    out = []
    for r in runs:
        y = np.column_stack([r[o] for o in outputs])
        u = np.asarray(r[INPUT], float)
        if not np.any(u):
            raise ValueError("T_delta is zero in a run: the canonical model has nothing to fit")
        out.append(RunData(u=u, y=y, dt=r.dt, v=r.speed))
    return out


class PredictionProblem:
    """Stacked, weighted, x0-projected prediction errors of several runs.

    ``residual(x)`` costs one state-only kernel pass per run (the errors are affine in
    x0: e = E0 + Psi x0, x0 by least squares); ``jacobian(x)`` adds the sensitivity
    pass.  Both return None at a point whose predictor Ad - K C is unstable.
    """

    def __init__(self, data, mapping, Ks, free_k, weights, outputs):
        self.data, self.mapping, self.Ks, self.free_k = data, mapping, Ks, free_k
        self.C, self.idx = output_matrix(outputs)
        self.L = len(outputs)
        self.w = np.asarray(weights, float)
        self._x, self._r, self._J, self.x0s = None, None, None, []
        self._cache: dict = {}

    def split(self, x):
        P = self.mapping[0].shape[1]
        nk = 4 * self.L
        return x[:P], (x[P : P + nk].reshape(4, self.L) if self.free_k else None)

    def _models(self, x, derivatives: bool):
        """Per run (Ad, Bd, dAd, dBd, K, S) or None if a predictor is unstable."""
        p, Kfree = self.split(x)
        out, cache = [], {}
        for i, d in enumerate(self.data):
            S = self.mapping[i]
            theta = S @ p
            key = (d.dt, theta.tobytes())
            if key not in cache:
                if derivatives:
                    cache[key] = discretize_with_derivatives(theta, d.dt)
                else:
                    cache[key] = (*discretize(theta, d.dt), None, None)
            Ad, Bd, dAd, dBd = cache[key]
            K = Kfree if self.free_k else self.Ks[i]
            rho = np.max(np.abs(np.linalg.eigvals(Ad - K @ self.C)))
            if not rho < 1.0:
                return None
            out.append((Ad, Bd, dAd, dBd, K, S))
        return out

    def residual(self, x):
        """Weighted prediction errors (x0 projected out), or None (unstable predictor)."""
        models = self._models(x, derivatives=False)
        if models is None:
            return None
        res, x0s = [], []
        empty_a, empty_b = np.zeros((0, 4, 4)), np.zeros((0, 4))
        for i, (d, model) in enumerate(zip(self.data, models, strict=True)):
            Ad, Bd, _, _, K = model[:5]
            E0, Psi = prediction_kernel(
                Ad, Bd, K, empty_a, empty_b, d.u, d.y, self.idx, np.zeros(4), False
            )
            Psi = (Psi * self.w[None, :, None]).reshape(-1, 4)
            e0 = ((E0 + self._extra_error(i, model)) * self.w).ravel()
            x0, *_ = np.linalg.lstsq(Psi, -e0, rcond=None)
            res.append(e0 + Psi @ x0)
            x0s.append(x0)
        self.x0s = x0s
        return np.concatenate(res)

    def _extra_error(self, i: int, model) -> np.ndarray | float:
        """Prediction errors of run ``i`` from inputs beyond u, added to the kernel's (none)."""
        return 0.0

    def jacobian(self, x):
        """(residual, projected Jacobian) at x, or (None, None)."""
        r = self.residual(x)
        if r is None:
            return None, None
        models = self._models(x, derivatives=True)
        jac = []
        for d, x0, (Ad, Bd, dAd, dBd, K, S) in zip(self.data, self.x0s, models, strict=True):
            _, J = prediction_kernel(Ad, Bd, K, dAd, dBd, d.u, d.y, self.idx, x0, self.free_k)
            J = (J * self.w[None, :, None]).reshape(-1, J.shape[2])
            nm = J.shape[1] - 4
            Jm = np.hstack([J[:, :10] @ S, J[:, 10:nm]])
            Q, _ = np.linalg.qr(J[:, nm:])
            Jm -= Q @ (Q.T @ Jm)
            jac.append(Jm)
        self._x, self._r, self._J = x.copy(), r, np.vstack(jac)
        return r, self._J

    def normal_equations(self, x):
        """(residual, J'J, J'r) at x (the Levenberg-Marquardt inputs), or (None, None, None)."""
        r, J = self.jacobian(x)
        if r is None:
            return None, None, None
        return r, J.T @ J, J.T @ r

    # scipy.optimize.least_squares interface (method="scipy")
    def fun(self, x):
        r = self.residual(x)
        return np.full(sum(self.L * d.u.size for d in self.data), 1e6) if r is None else r

    def jac(self, x):
        r, J = self.jacobian(x)
        if J is None:
            raise RuntimeError("Jacobian requested at a rejected point")
        return J

    def evaluate(self, x):
        if self._x is None or not np.array_equal(x, self._x):
            self.jacobian(x)

    def residuals(self) -> np.ndarray:
        """Unweighted prediction errors (N_total, L) at the last Jacobian point."""
        return self._r.reshape(-1, self.L) / self.w


@dataclass
class Solution:
    x: np.ndarray
    nfev: int
    success: bool
    message: str


def levenberg_marquardt(
    problem: PredictionProblem, x: np.ndarray, max_nfev: int, ftol: float = 1e-3
) -> Solution:
    """Levenberg-Marquardt on the normal equations (Marquardt scaling, Nielsen's damping).

    Each trial point costs one residual pass; the Jacobian is formed only at accepted
    points, and the small (P x P) normal equations replace MINPACK's QR of the full
    N x P Jacobian (which dominated the run time).  Stopping rule on statistical
    grounds: a step that lowers the cost by less than ``ftol`` residual variances
    (cost / number of residuals) moves the estimate by about sqrt(ftol) standard errors
    or less, so iterating further only chases round-off.  Near the predictor-stability
    boundary (where a free K may push the optimum) trial steps that destabilize
    Ad - K C are rejected and the damping raised tenfold.

    Parameters
    ----------
    problem : PredictionProblem
        The stacked prediction errors (or a subclass, e.g. the grey-box problem).
    x : (P,) ndarray
        Start point (parameters, then any free innovation gain entries).
    max_nfev : int
        Largest number of residual evaluations.
    ftol : float, optional
        Stopping threshold, in residual variances of cost decrease.

    Returns
    -------
    Solution
        ``x`` at the end, ``nfev``, ``success`` and a ``message``; ``problem`` holds the
        Jacobian and residuals at ``x``.

    Raises
    ------
    UntrustworthyResult
        If the start point gives an unstable predictor.
    """
    r, H, g = problem.normal_equations(x)
    if r is None:
        raise UntrustworthyResult("the start model gives an unstable predictor; give another start")
    cost = float(r @ r)
    m = max(r.size, 1)
    lam, nu = 1e-3, 2.0
    nfev, success, message = 1, False, "maximum number of evaluations reached"
    while nfev < max_nfev:
        if not np.any(g):  # e.g. parameters held where they no longer act (a clipped bound)
            success, message = True, "converged (zero gradient)"
            break
        D = np.maximum(np.diag(H), 1e-12 * max(np.max(np.diag(H)), 1e-300))
        try:
            h = np.linalg.solve(H + lam * np.diag(D), -g)
        except np.linalg.LinAlgError:
            lam, nu = lam * nu, nu * 2
            continue
        xn = x + h
        rn = problem.residual(xn)
        nfev += 1
        if rn is None:
            lam *= 10.0
        elif (cn := float(rn @ rn)) < cost:
            pred = -(2.0 * h @ g + h @ H @ h)
            rho = (cost - cn) / pred if pred > 0 else 1.0
            lam *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
            nu = 2.0
            small = cost - cn <= ftol * cost / m
            x, cost = xn, cn
            r, H, g = problem.normal_equations(x)
            if small:
                success, message = True, "converged"
                break
        else:
            lam *= nu
            nu *= 2.0
        if lam > 1e12:
            success, message = True, "no further decrease (damping limit)"
            break
    if problem._x is None or not np.array_equal(problem._x, x):
        problem.normal_equations(x)
    return Solution(x=x, nfev=nfev, success=success, message=message)


def solve(problem: PredictionProblem, x0: np.ndarray, max_nfev: int, method: str):
    """Minimize the prediction errors of ``problem`` from ``x0``.

    Parameters
    ----------
    problem : PredictionProblem
        The stacked prediction errors.
    x0 : (P,) ndarray
        Start point.
    max_nfev : int
        Largest number of residual evaluations.
    method : {"lm", "scipy"}
        :func:`levenberg_marquardt` or MINPACK (``scipy.optimize.least_squares``).

    Returns
    -------
    Solution or scipy.optimize.OptimizeResult
        With ``x``, ``nfev``, ``success``, ``message``.

    Raises
    ------
    ValueError
        For an unknown ``method``; UntrustworthyResult if the fit ends at an unstable
        predictor.
    """
    if method == "lm":
        return levenberg_marquardt(problem, np.asarray(x0, float), max_nfev)
    if method != "scipy":
        raise ValueError(f"method {method!r}: choose 'lm' (normal equations) or 'scipy'")
    sol = least_squares(problem.fun, x0, jac=problem.jac, method="lm", x_scale="jac",
                        max_nfev=max_nfev, xtol=1e-10, ftol=1e-10, gtol=1e-10)  # fmt: skip
    problem.evaluate(sol.x)
    if problem._J is None:
        raise UntrustworthyResult("the prediction-error fit ended at an unstable predictor")
    return sol


def sandwich_covariance(problem: PredictionProblem, n_extra: int) -> np.ndarray:
    """Sandwich covariance (J'J)^-1 (sum_t J_t' Lambda J_t) (J'J)^-1 of the estimate.

    J (N L x P) and r are the weighted Jacobian and residuals, J_t the L x P block of
    sample t and Lambda the L x L sample covariance of the weighted innovations (degrees of
    freedom N L - P - n_extra).  The per-output weights whiten each output but not the
    correlation between outputs; this sandwich accounts for it (a prediction-error
    estimate under a non-optimal weighting; Ljung 1999, Sec. 9.3) and equals
    sigma^2 (J'J)^-1 when Lambda = sigma^2 I.

    Parameters
    ----------
    problem : PredictionProblem
        The problem at the optimum (its last Jacobian and residuals are used).
    n_extra : int
        Parameters not in the Jacobian's columns (the projected initial states), for the
        degrees of freedom.

    Returns
    -------
    (P, P) ndarray
        Symmetric covariance of the Jacobian's parameters (their squared units).
    """
    J, r = problem._J, problem._r
    n_out = problem.L
    dof = max(r.size - J.shape[1] - n_extra, 1)
    R = r.reshape(-1, n_out)
    lam = (R.T @ R) / dof * n_out
    Jt = J.reshape(R.shape[0], n_out, -1)
    inv = np.linalg.pinv(J.T @ J)
    meat = np.einsum("tlp,lm,tmq->pq", Jt, lam, Jt)
    cov = inv @ meat @ inv
    return 0.5 * (cov + cov.T)


def initial_gain(theta, dt, C, data, yvar, free_k) -> np.ndarray | None:
    """Start innovation gain: the Kalman gain of the start model (Q = Bd Bd' var(u),
    R = diag(var(y)) 1e-2), or zeros when K is not estimated.

    Parameters
    ----------
    theta : (10,) ndarray
        Start canonical parameters.
    dt : float
        Sample period [s].
    C : (L, 4) ndarray
        Output matrix.
    data : sequence of RunData
        The runs (their input variance).
    yvar : (L,) ndarray
        Output variances.
    free_k : bool
        Whether K is estimated (``noise_model="free"``).

    Returns
    -------
    (4, L) ndarray or None
        The gain; None when the Riccati equation fails or the predictor is unstable.
    """
    if not free_k:
        return np.zeros((4, C.shape[0]))
    Ad, Bd = discretize(theta, dt)
    uvar = float(np.mean([np.var(d.u) for d in data]))
    try:
        K = kalman_gain(Ad, Bd, C, uvar, 1e-2 * yvar)
    except (ValueError, np.linalg.LinAlgError):
        return None
    return K if np.max(np.abs(np.linalg.eigvals(Ad - K @ C))) < 1.0 else None


def single_threaded_blas(func):
    """Run ``func`` with one BLAS thread: the fits are loops over 4x4 and 10x10 products,
    which threaded OpenBLAS makes ~10x slower on a shared 2-core machine (bench_ident).

    Parameters
    ----------
    func : callable
        The function to wrap.

    Returns
    -------
    callable
        ``func`` run under ``threadpoolctl.threadpool_limits(1)``.
    """
    import functools

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        from threadpoolctl import threadpool_limits

        with threadpool_limits(1):
            return func(*args, **kwargs)

    return wrapper
