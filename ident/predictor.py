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
from scipy.linalg import solve_discrete_are
from scipy.optimize import least_squares

from bikeid.dataset.run import Run
from bikeid.ident.canonical import A_POS, B_POS, canonical_ab
from bikeid.sim.blas import one_blas_thread, single_threaded_blas  # re-exported here
from bikeid.sim.conventions import CANONICAL_STATE
from bikeid.sim.errors import UntrustworthyResult
from bikeid.sim.sampling import zoh

__all__ = [
    "DEFAULT_OUTPUTS",
    "INPUT",
    "discretize",
    "eliminate_initial_state",
    "initial_gain",
    "kalman_gain",
    "kstep_kernel",
    "levenberg_marquardt",
    "output_matrix",
    "run_data",
    "sandwich_covariance",
    "one_blas_thread",
    "single_threaded_blas",
    "solve",
    "stabilizing_riccati",
]

#: All four canonical states are measured (Moore & Hubbard Table 1); Chen & Dao used
#: ("phi", "delta").  Closed-loop consistency needs every signal the controller feeds
#: back among the outputs (a controller using phidot reveals state information a
#: phi/delta-only predictor lacks, biasing the estimate).
DEFAULT_OUTPUTS = ("phi", "phidot", "delta", "deltadot")
INPUT = "T_delta"


def prediction_kernel(Ad, Bd, K, dAd, dBd, dK, u, y, out_idx, x0, free_k, w):
    """Prediction errors e (N, l) and the weighted sensitivities w de/dparam
    (N, l, P + 4 l free_k + 4): :func:`_prediction_kernel` on C-contiguous float copies
    (a view such as a transposed or sliced Ad would otherwise compile a second machine-code
    version of the kernel, ~2 s, in every fresh environment).
    """
    f = np.ascontiguousarray
    return _prediction_kernel(f(Ad, dtype=float), f(Bd, dtype=float), f(K, dtype=float),
                              f(dAd, dtype=float), f(dBd, dtype=float), f(dK, dtype=float),
                              f(u, dtype=float), f(y, dtype=float), f(out_idx, dtype=np.int64),
                              f(x0, dtype=float), bool(free_k), f(w, dtype=float))  # fmt: skip


@numba.njit(cache=True)
def _prediction_kernel(Ad, Bd, K, dAd, dBd, dK, u, y, out_idx, x0, free_k, w):
    """Prediction errors e (N, l) and the weighted sensitivities w de/dparam
    (N, l, P + 4 l free_k + 4).

    P = max(len(dAd), len(dK)) chained parameters: column j < P moves Ad by dAd[j] and Bd
    by dBd[j] (j < len(dAd)) and K by dK[j] (j < len(dK)); then, with ``free_k``, the
    4 l entries of K row by row; then the 4 entries of x0.  ``w`` (l,) weights each
    output's rows of the sensitivities (not e).  The recursions run on the predictor
    matrix F = Ad - K C: xhat[k+1] = F xhat[k] + Bd u[k] + K y[k], and per column
    s[k+1] = F s[k] + dAd x + dBd u + dK e (+ e_c in row r for K's entry (r, c)).
    """
    N = u.shape[0]
    L = out_idx.shape[0]
    Pa = dAd.shape[0]
    Pk = dK.shape[0]
    P = max(Pa, Pk)
    nK = 4 * L if free_k else 0
    npar = P + nK + 4
    F = Ad.copy()
    for r in range(4):
        for c in range(L):
            F[r, out_idx[c]] -= K[r, c]
    # the chained terms as one product per sample: s[:, j] += D[:, :, j]' [x, u, e]
    D = np.zeros((5 + L, 4, P))
    for j in range(Pa):
        for r in range(4):
            for i in range(4):
                D[i, r, j] = dAd[j, r, i]
            D[4, r, j] = dBd[j, r]
    for j in range(Pk):
        for r in range(4):
            for c in range(L):
                D[5 + c, r, j] = dK[j, r, c]
    v = np.zeros(5 + L)
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
            wc = -w[c]
            Srow = S[out_idx[c]]
            Jk = J[k, c]
            for j in range(npar):
                Jk[j] = wc * Srow[j]
        for r in range(4):
            Snr = Sn[r]
            for j in range(npar):
                Snr[j] = (F[r, 0] * S[0, j] + F[r, 1] * S[1, j]
                          + F[r, 2] * S[2, j] + F[r, 3] * S[3, j])  # fmt: skip
        for i in range(4):
            v[i] = x[i]
        v[4] = u[k]
        for c in range(L):
            v[5 + c] = e[c]
        for t in range(5 + L):
            vt = v[t]
            for r in range(4):
                Snr = Sn[r]
                Dtr = D[t, r]
                for j in range(P):
                    Snr[j] += vt * Dtr[j]
        if free_k:
            for r in range(4):
                for c in range(L):
                    Sn[r, P + L * r + c] += e[c]
        for r in range(4):
            acc = Bd[r] * u[k]
            for c in range(L):
                acc += K[r, c] * y[k, c]
            for i in range(4):
                acc += F[r, i] * x[i]
            xn[r] = acc
        for r in range(4):
            x[r] = xn[r]
        S, Sn = Sn, S
    return E, J


def eliminate_initial_state(G: np.ndarray, g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Normal equations of one run with its initial state (the last 4 columns) eliminated.

    The Schur complement G_mm - G_mx G_xx^-1 G_xm equals J'J of the Kaufman-projected
    Jacobian (the x0 columns projected out, variable projection), without forming it.

    Parameters
    ----------
    G : (m + 4, m + 4) ndarray
        J'J of the run's weighted Jacobian, parameters then x0.
    g : (m + 4,) ndarray
        J'r of the run.

    Returns
    -------
    H : (m, m) ndarray
        Projected J'J.
    gm : (m,) ndarray
        Projected J'r.
    """
    m = G.shape[0] - 4
    Gmx = G[:m, m:]
    B = np.linalg.solve(G[m:, m:], np.column_stack([Gmx.T, g[m:]]))
    return G[:m, :m] - Gmx @ B[:, :m], g[:m] - Gmx @ B[:, m]


#: Coefficients of the [13/13] Pade approximant of exp and the 1-norm up to which it needs
#: no scaling (Al-Mohy & Higham 2009, as ``scipy.linalg.expm_frechet``).
_PADE13 = (64764752532480000.0, 32382376266240000.0, 7771770303897600.0,
           1187353796428800.0, 129060195264000.0, 10559470521600.0, 670442572800.0,
           33522128640.0, 1323241920.0, 40840800.0, 960960.0, 16380.0, 182.0, 1.0)  # fmt: skip
_ELL13 = 4.74


@numba.njit(cache=True)
def expm_frechet_stack(A, Es):
    """expm(A) and its Frechet derivatives in the directions Es (P, n, n), sharing the
    Pade powers and the one factorization (scipy's scaling-and-squaring algorithm of order
    13, Al-Mohy & Higham 2009; equal to ``scipy.linalg.expm_frechet`` to rounding)."""
    b = _PADE13
    n = A.shape[0]
    norm = 0.0
    for j in range(n):
        col = 0.0
        for i in range(n):
            col += abs(A[i, j])
        norm = max(norm, col)
    s = 0
    if norm > _ELL13:
        s = int(np.ceil(np.log2(norm / _ELL13)))
    scale = 2.0**-s
    A = A * scale
    ident = np.eye(n)
    A2 = A @ A
    A4 = A2 @ A2
    A6 = A2 @ A4
    W1 = b[13] * A6 + b[11] * A4 + b[9] * A2
    W2 = b[7] * A6 + b[5] * A4 + b[3] * A2 + b[1] * ident
    Z1 = b[12] * A6 + b[10] * A4 + b[8] * A2
    Z2 = b[6] * A6 + b[4] * A4 + b[2] * A2 + b[0] * ident
    W = A6 @ W1 + W2
    U = A @ W
    V = A6 @ Z1 + Z2
    Minv = np.linalg.inv(V - U)
    R = Minv @ (U + V)
    Ls = np.empty((Es.shape[0], n, n))
    for p in range(Es.shape[0]):
        E = Es[p] * scale
        M2 = A @ E + E @ A
        M4 = A2 @ M2 + M2 @ A2
        M6 = A4 @ M2 + M4 @ A2
        Lw1 = b[13] * M6 + b[11] * M4 + b[9] * M2
        Lw2 = b[7] * M6 + b[5] * M4 + b[3] * M2
        Lz1 = b[12] * M6 + b[10] * M4 + b[8] * M2
        Lz2 = b[6] * M6 + b[4] * M4 + b[2] * M2
        Lw = A6 @ Lw1 + M6 @ W1 + Lw2
        Lu = A @ Lw + E @ W
        Lv = A6 @ Lz1 + M6 @ Z1 + Lz2
        Ls[p] = Minv @ (Lu + Lv + (Lu - Lv) @ R)
    for _ in range(s):
        for p in range(Es.shape[0]):
            Ls[p] = R @ Ls[p] + Ls[p] @ R
        R = R @ R
    return R, Ls


def discretize_with_derivatives(theta: np.ndarray, dt: float, noise_input=None,
                                derivatives: bool = True):  # fmt: skip
    """Ad, Bd and their derivatives with respect to the 10 canonical parameters (exact: the
    Frechet derivatives of the matrix exponential, :func:`expm_frechet_stack`).

    Parameters
    ----------
    theta : (10,) ndarray
        Canonical parameters [a1, ..., a8, b1, b2].
    dt : float
        Sample period [s].
    noise_input : (4, q) ndarray, optional
        Further input columns held over each sample (e.g. process noise), sampled with the
        model in the same matrix exponential.
    derivatives : bool, optional
        False: the derivative arrays are empty (first dimension 0), only the sampling.

    Returns
    -------
    Ad, Bd, dAd, dBd : ndarray
        (4, 4), (4,), (10, 4, 4), (10, 4): the zero-order-hold model and its derivatives.
    G, dG : ndarray
        Only with ``noise_input``: its sampling (4, q) and derivatives (10, 4, q).

    Notes
    -----
    Ad is dimensionless, Bd in rad/(N m) or rad/(N m s) by row, G in the noise input's
    units times s; the derivatives in those per unit of each parameter.
    """
    A, B = canonical_ab(theta)
    q = 0 if noise_input is None else noise_input.shape[1]
    Z = np.zeros((5 + q, 5 + q))
    Z[:4, :4], Z[:4, 4:5] = A * dt, B * dt
    if q:
        Z[:4, 5:] = np.asarray(noise_input, float) * dt
    dZ = np.zeros((10 if derivatives else 0, 5 + q, 5 + q))
    for i, pos in enumerate(A_POS if derivatives else ()):
        dZ[i][pos] = dt
    for i, row in enumerate(B_POS if derivatives else ()):
        dZ[8 + i, row, 4] = dt
    E, dE = expm_frechet_stack(Z, dZ)
    out = (E[:4, :4].copy(), E[:4, 4].copy(), dE[:, :4, :4].copy(), dE[:, :4, 4].copy())
    return out if not q else (*out, E[:4, 5:].copy(), dE[:, :4, 5:].copy())


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


def stabilizing_riccati(Ad, C, Q, R) -> np.ndarray:
    """Stabilizing solution P of the filter Riccati equation by the QZ method
    (``scipy.linalg.solve_discrete_are``), with a message that names the cause where none
    exists.

    Parameters
    ----------
    Ad : (n, n) ndarray
        Discrete state matrix.
    C : (L, n) ndarray
        Output matrix.
    Q, R : ndarray
        Process- (n, n) and sensor-noise (L, L) covariances.

    Returns
    -------
    (n, n) ndarray
        P, the one-step prediction covariance of the state.

    Raises
    ------
    ValueError
        If there is no stabilizing solution (an unstable mode the outputs do not see, or a
        model far from physical, e.g. eigenvalues of 1e100 per sample), naming the largest
        eigenvalue modulus of ``Ad`` besides scipy's own words.
    """
    try:
        return solve_discrete_are(Ad.T, C.T, Q, R)
    except (ValueError, np.linalg.LinAlgError) as exc:
        rho = float(np.max(np.abs(np.linalg.eigvals(Ad)))) if np.all(np.isfinite(Ad)) \
            else float("inf")  # fmt: skip
        raise ValueError(
            "the filter Riccati equation has no stabilizing solution (the sampled model's "
            f"largest eigenvalue modulus is {rho:.3g} per sample: an unstable mode the "
            f"outputs do not see, or a model far from physical; {exc})"
        ) from exc


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

    Raises
    ------
    ValueError
        If the Riccati equation has no stabilizing solution (:func:`stabilizing_riccati`).
    """
    G = np.asarray(Bd, float).reshape(Ad.shape[0], -1)
    Q = (G * np.broadcast_to(np.asarray(q, float), G.shape[1])) @ G.T
    Q = Q + 1e-12 * np.eye(Ad.shape[0])
    R = np.diag(r)
    P = stabilizing_riccati(Ad, C, Q, R)
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
    x0: e = E0 + Psi x0, x0 by least squares); ``normal_equations(x)`` adds the
    sensitivity pass and forms each run's J'J with x0 eliminated
    (:func:`eliminate_initial_state`), without stacking the Jacobian; ``jacobian(x)``
    also stacks the projected Jacobian (for MINPACK).  All return None at a point whose
    predictor Ad - K C is unstable.
    """

    def __init__(self, data, mapping, Ks, free_k, weights, outputs):
        self.data, self.mapping, self.Ks, self.free_k = data, mapping, Ks, free_k
        self.C, self.idx = output_matrix(outputs)
        self.L = len(outputs)
        self.w = np.asarray(weights, float)
        self._x, self._r, self._H, self.x0s = None, None, None, []
        self._blocks: list = []  # per run: weighted raw Jacobian (N L, c), map T (c, m + 4)
        self._stacked = None
        self._memo = None  # (x, residual, x0s) of the last stable residual
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
        if self._memo is not None and np.array_equal(self._memo[0], x):
            self.x0s = list(self._memo[2])
            return self._memo[1]
        models = self._models(x, derivatives=False)
        if models is None:
            return None
        res, x0s = [], []
        empty_a, empty_b = np.zeros((0, 4, 4)), np.zeros((0, 4))
        empty_k = np.zeros((0, 4, self.L))
        for i, (d, model) in enumerate(zip(self.data, models, strict=True)):
            Ad, Bd, _, _, K = model[:5]
            E0, Psi = prediction_kernel(Ad, Bd, K, empty_a, empty_b, empty_k, d.u, d.y,
                                        self.idx, np.zeros(4), False, self.w)  # fmt: skip
            Psi = Psi.reshape(-1, 4)
            e0 = ((E0 + self._extra_error(i, model)) * self.w).ravel()
            x0 = _least_squares_x0(Psi, e0)
            res.append(e0 + Psi @ x0)
            x0s.append(x0)
        self.x0s = x0s
        r = np.concatenate(res)
        self._memo = (np.array(x, dtype=float), r, tuple(x0s))
        return r

    def _extra_error(self, i: int, model) -> np.ndarray | float:
        """Prediction errors of run ``i`` from inputs beyond u, added to the kernel's (none)."""
        return 0.0

    def _jacobian_blocks(self, x):
        """Per run the weighted raw Jacobian (N L, c) at the residual's x0 and the map T
        (c, m + 4) of its columns to the problem's m parameters then x0; None if unstable."""
        models = self._models(x, derivatives=True)
        if models is None:
            return None
        empty_k = np.zeros((0, 4, self.L))
        blocks = []
        for d, x0, (Ad, Bd, dAd, dBd, K, S) in zip(self.data, self.x0s, models, strict=True):
            _, J = prediction_kernel(Ad, Bd, K, dAd, dBd, empty_k, d.u, d.y, self.idx, x0,
                                     self.free_k, self.w)  # fmt: skip
            J = J.reshape(-1, J.shape[2])
            P, c = S.shape[1], J.shape[1]
            T = np.zeros((c, P + c - 10))
            T[:10, :P] = S
            T[10:, P:] = np.eye(c - 10)
            blocks.append((J, T))
        return blocks

    def normal_equations(self, x):
        """(residual, J'J, J'r) at x (the Levenberg-Marquardt inputs), or (None, None, None).

        J is the weighted Jacobian with each run's x0 columns projected out (Kaufman); its
        J'J and J'r are summed run by run from the runs' Schur complements.
        """
        r = self.residual(x)
        if r is None:
            return None, None, None
        blocks = self._jacobian_blocks(x)
        if blocks is None:
            return None, None, None
        H, g, start = 0.0, 0.0, 0
        for J, T in blocks:
            ri = r[start : start + J.shape[0]]
            start += J.shape[0]
            Hi, gi = eliminate_initial_state(T.T @ (J.T @ J) @ T, T.T @ (J.T @ ri))
            H, g = H + Hi, g + gi
        self._x, self._r, self._H = np.array(x, dtype=float), r, H
        self._blocks, self._stacked = blocks, None
        return r, H, g

    def projected_blocks(self):
        """Per run the weighted Jacobian (N L, m) at the last ``normal_equations`` point,
        its x0 columns projected out.

        Yields
        ------
        (N L, m) ndarray
            The run's rows of the projected Jacobian.
        """
        for J, T in self._blocks:
            Jt = J @ T
            Jm, Jx = Jt[:, :-4], Jt[:, -4:]
            yield Jm - Jx @ np.linalg.solve(Jx.T @ Jx, Jx.T @ Jm)

    @property
    def _J(self):
        """The stacked projected Jacobian at the last ``normal_equations`` point, or None."""
        if self._x is None:
            return None
        if self._stacked is None:
            self._stacked = np.vstack(list(self.projected_blocks()))
        return self._stacked

    def jacobian(self, x):
        """(residual, projected Jacobian) at x, or (None, None)."""
        r, H, _ = self.normal_equations(x)
        if r is None:
            return None, None
        return r, self._J

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
            self.normal_equations(x)

    def residuals(self) -> np.ndarray:
        """Unweighted prediction errors (N_total, L) at the last Jacobian point."""
        return self._r.reshape(-1, self.L) / self.w


def _least_squares_x0(Psi: np.ndarray, e0: np.ndarray) -> np.ndarray:
    """x0 minimizing |e0 + Psi x0| by the 4 x 4 normal equations (columns scaled; SVD
    least squares where they are ill-conditioned, condition above ~1e8)."""
    x0, ok = _normal_x0(Psi, e0)
    return x0 if ok else np.linalg.lstsq(Psi, -e0, rcond=None)[0]


@numba.njit(cache=True)
def _normal_x0(Psi, e0):
    """(x0, ok): Cholesky of the column-scaled Psi'Psi; ok False where a pivot falls below
    1e-8 (condition above ~1e8) or a column is zero."""
    n = Psi.shape[1]
    G = Psi.T @ Psi
    b = Psi.T @ e0
    d = np.sqrt(np.diag(G))
    x0 = np.zeros(n)
    if np.any(d <= 0.0):
        return x0, False
    Lc = np.zeros((n, n))
    for i in range(n):
        for j in range(i + 1):
            acc = G[i, j] / (d[i] * d[j])
            for k in range(j):
                acc -= Lc[i, k] * Lc[j, k]
            if i == j:
                if acc <= 1e-8:
                    return x0, False
                Lc[i, i] = np.sqrt(acc)
            else:
                Lc[i, j] = acc / Lc[j, j]
    z = np.zeros(n)
    for i in range(n):
        acc = -b[i] / d[i]
        for k in range(i):
            acc -= Lc[i, k] * z[k]
        z[i] = acc / Lc[i, i]
    for i in range(n - 1, -1, -1):
        acc = z[i]
        for k in range(i + 1, n):
            acc -= Lc[k, i] * x0[k]
        x0[i] = acc / Lc[i, i]
    return x0 / d, True


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
    if problem._H is None:
        raise UntrustworthyResult("the prediction-error fit ended at an unstable predictor")
    return sol


def sandwich_covariance(problem: PredictionProblem, n_extra: int) -> np.ndarray:
    """Sandwich covariance (J'J)^-1 (sum_t J_t' Lambda J_t) (J'J)^-1 of the estimate.

    J (N L x P) and r are the weighted Jacobian and residuals, J_t the L x P block of
    sample t and Lambda the L x L sample covariance of the weighted innovations (degrees of
    freedom N L - P - n_extra).  The per-output weights whiten each output but not the
    correlation between outputs; this sandwich accounts for it (a prediction-error
    estimate under a non-optimal weighting; Ljung 1999, Sec. 9.3) and equals
    sigma^2 (J'J)^-1 when Lambda = sigma^2 I.  The middle term is summed run by run as
    W'W, W_t = F' J_t with Lambda = F F'.

    Parameters
    ----------
    problem : PredictionProblem
        The problem at the optimum (its last ``normal_equations`` point is used).
    n_extra : int
        Parameters not in the Jacobian's columns (the projected initial states), for the
        degrees of freedom.

    Returns
    -------
    (P, P) ndarray
        Symmetric covariance of the Jacobian's parameters (their squared units).
    """
    H, r = problem._H, problem._r
    n_out, P = problem.L, H.shape[0]
    dof = max(r.size - P - n_extra, 1)
    R = r.reshape(-1, n_out)
    lam = (R.T @ R) / dof * n_out
    s, V = np.linalg.eigh(lam)
    F = V * np.sqrt(np.clip(s, 0.0, None))
    meat = np.zeros((P, P))
    for Jp in problem.projected_blocks():
        W = np.tensordot(F, Jp.reshape(-1, n_out, P), axes=([0], [1])).reshape(-1, P)
        meat += W.T @ W
    inv = np.linalg.pinv(H)
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


