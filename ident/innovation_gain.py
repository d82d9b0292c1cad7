"""Innovation gains from noise covariances: a one-step predictor stable by construction.

The prediction-error fits (:mod:`ident.pem`) predict with
``xhat[k+1] = Ad xhat[k] + Bd u[k] + K e[k]`` (:mod:`ident.predictor`).  Estimating the
entries of K freely lets a fit on a short record lower its cost by moving the predictor's
poles (eig(Ad - K C)) onto the unit circle, where it stops: not at an optimum, so its
covariance describes nothing.  Here K is instead the steady-state Kalman gain of the model
for a noise model whose covariances are the parameters (Ljung 1999, sec. 4.3, the
"innovations form" from process and measurement noise):

- process noise: white noise in the roll and steer accelerations held over each sample,
  ``Q = G L L' G'`` (G the zero-order-hold sampling of :data:`NOISE_INPUT`, L a lower
  triangular factor relative to reference standard deviations ``ref``, its logs and
  off-diagonal entry ``eta[:3]``);
- sensor noise: diag(``rdiag``), held (the fixed-speed fit takes each output's one-step
  prediction-error variance, the speed model its per-speed fits'; K is unchanged when Q and
  R scale together, and the three entries of L carry the scale).

The stabilizing solution of the discrete Riccati equation makes Ad - K C stable for every
parameter value, also where the bicycle itself is unstable (an unstable mode's predictor
pole is its mirror image inside the unit circle as the process noise vanishes).  The fits
solve for the model parameters and eta together, then alternate between the two
(:func:`alternate`), because where the process noise is negligible K hardly depends on
eta, and on those near-zero Jacobian columns a joint Levenberg-Marquardt step can stall
short of the optimum (a low-noise two-speed set, docs/performance.md), while alternating
alone converges only linearly.
A noise standard deviation whose lower bound (:data:`NOISE_LOG_RANGE`) the data cannot
reject is put on it and the covariance is taken conditional on it (:func:`settle_bounds`).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from bikeid.ident.canonical import canonical_ab
from bikeid.ident.predictor import (
    PredictionProblem,
    discretize_with_derivatives,
    prediction_kernel,
    solve,
    stabilizing_riccati,
)
from bikeid.sim.sampling import zoh

__all__ = [
    "BOUND_CHI2",
    "FIXED_NOISE_STARTS",
    "JOINT_ROUNDS",
    "JOINT_TOL",
    "KalmanGainProblem",
    "NOISE_INPUT",
    "NOISE_LOG_RANGE",
    "NOISE_STARTS",
    "NOISE_STRUCTURES",
    "SENSOR_LOG_RANGE",
    "alternate",
    "filter_riccati",
    "gain_derivative",
    "kalman_gain_of",
    "noise_input",
    "sensor_variances",
    "settle_bounds",
]

#: Continuous-time process-noise input of the joint fit's Kalman gains: white noise in the
#: roll and steer accelerations (rows phidot and deltadot of Chen & Dao's state order).
NOISE_INPUT = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 0.0], [0.0, 1.0]])
#: The noise structures, by the length of eta: 3, the roll and steer acceleration noise of
#: :data:`NOISE_INPUT` ([log s1, s21, log s2]; the speed model's joint gains); 5 and more,
#: that plus independent white noise in the roll and steer angle rows ([log s3, log s4]: an
#: angle signal that is not the integral of its logged rate) and then the log sensor-noise
#: ratios of outputs 1.. (the fixed-speed fit, where measured logs need them:
#: docs/uncertainty.md).
NOISE_STRUCTURES = {"acceleration": 3, "acceleration+angle(+sensor ratios)": 5}
#: Range of the log sensor-noise standard-deviation ratios (eta[5:], relative to each
#: output's one-step prediction-error standard deviation, the first output's held at 1).
SENSOR_LOG_RANGE = (-20.0, 20.0)
#: Range of the log standard deviations of that noise relative to its reference
#: (the input's std times |b1|, |b2|); beyond it the gain no longer changes.
NOISE_LOG_RANGE = (-40.0, 5.0)
#: Start values [log s1, s21, log s2] of that noise tried by the joint fit (best kept).
NOISE_STARTS = ((math.log(1e-3), 0.0, math.log(1e-3)), (math.log(1e-1), 0.0, math.log(1e-1)))
#: Start values of eta tried by the fixed-speed fit (five parameters): the acceleration
#: noise of :data:`NOISE_STARTS` and none (both standard deviations on the lower bound, the
#: optimum of a loop without it), each with no angle-row noise and with 10 % of the angles'
#: RMS rates.
FIXED_NOISE_STARTS = tuple(
    (*acc, *angle)
    for angle in ((NOISE_LOG_RANGE[0],) * 2, (math.log(1e-1),) * 2)
    for acc in (*NOISE_STARTS, (NOISE_LOG_RANGE[0], 0.0, NOISE_LOG_RANGE[0]))
)
#: Rounds of the joint fit's alternation (speed parameters, then the noise's eta) per
#: weighting pass; a round whose eta step lowers the cost by less than :data:`JOINT_TOL`
#: (in residual variances: moves the estimate by about 0.1 standard error or less) ends it.
JOINT_ROUNDS = 6
JOINT_TOL = 1e-2
#: Most doubling steps of the Riccati solution (each squares the horizon: 2^64 samples), a
#: numpy integer rather than a literal, so that the compiled caller and Python calls share
#: one machine-code version of :func:`_doubling` (a literal 64 compiles a second).
DOUBLING_STEPS = np.int64(64)


def kalman_gain_of(theta, dt, C, rdiag, eta, ref) -> np.ndarray:
    """Steady-state Kalman gain of the canonical model ``theta`` for acceleration noise.

    Process noise: white noise in the roll and steer accelerations, held over each sample
    (``Q = G L L' G'``, G the zero-order-hold sampling of :func:`noise_input`, L =
    diag(ref) [[exp(eta0), 0], [eta1, exp(eta2)]]), and with five ``eta`` also in the roll
    and steer angle rows (exp(eta3) ref[2], exp(eta4) ref[3]); sensor noise
    diag(``rdiag``), outputs 1.. scaled by exp(2 eta[5:]).  The predictor Ad - K C is stable
    for every ``eta`` (the stabilizing Riccati solution).

    Parameters
    ----------
    theta : (10,) ndarray
        Canonical parameters [a1, ..., a8, b1, b2].
    dt : float
        Sample period [s].
    C : (L, 4) ndarray
        Output matrix.
    rdiag : (L,) ndarray
        Sensor-noise variances (squared output units).
    eta : (3,) or (5 + k,) ndarray
        [log s1, s21, log s2] of the acceleration noise's Cholesky factor, then [log s3,
        log s4] of the angle-row noise, relative to ``ref`` (logs clipped to
        :data:`NOISE_LOG_RANGE`), then k <= L - 1 log sensor-noise standard-deviation
        ratios of outputs 1.. (clipped to :data:`SENSOR_LOG_RANGE`).
    ref : (2,) or (4,) ndarray
        Reference standard deviations of the roll and steer acceleration noise
        [rad/s^2], then of the roll and steer angle-row noise [rad/s].

    Returns
    -------
    (4, L) ndarray
        K of xhat[k+1] = Ad xhat[k] + Bd u[k] + K e[k] (Chen & Dao's state order).
    """
    A, _ = canonical_ab(theta)
    Ad, G = zoh(A, noise_input(len(eta)), dt)
    return _gain(Ad, G, C, rdiag, eta, ref)[0]


def noise_input(n_eta: int) -> np.ndarray:
    """The continuous-time process-noise input of a noise structure with ``n_eta``
    parameters (:data:`NOISE_STRUCTURES`): :data:`NOISE_INPUT` (4 x 2) for 3, the identity
    (every state row) for 5.

    Parameters
    ----------
    n_eta : int
        3, or 5 and more (the entries after the fifth scale the sensor noise).

    Returns
    -------
    (4, 2) or (4, 4) ndarray
        The input columns, in Chen & Dao's state order.
    """
    if n_eta != 3 and n_eta < 5:
        raise ValueError(f"{n_eta} noise parameters: a noise structure has 3, or 5 and more")
    return NOISE_INPUT if n_eta == 3 else np.eye(4)


def _noise_factor(eta, ref) -> tuple[np.ndarray, np.ndarray]:
    """L (:func:`kalman_gain_of`; logs clipped to :data:`NOISE_LOG_RANGE`) and dL/deta
    (n_eta, rows, columns), zero for a clipped log."""
    lo, hi = NOISE_LOG_RANGE
    ref = np.asarray(ref, float)

    def scale(e: float, r: float) -> tuple[float, float]:  # exp(e) r and its derivative
        s = math.exp(min(max(e, lo), hi)) * r
        return s, (s if lo < e < hi else 0.0)

    (s1, d1), (s2, d2) = scale(eta[0], ref[0]), scale(eta[2], ref[1])
    if len(eta) == 3:
        Lf = np.array([[s1, 0.0], [eta[1] * ref[1], s2]])
        dL = np.zeros((3, 2, 2))
        dL[0, 0, 0], dL[1, 1, 0], dL[2, 1, 1] = d1, ref[1], d2
        return Lf, dL
    (s3, d3), (s4, d4) = scale(eta[3], ref[2]), scale(eta[4], ref[3])
    Lf = np.zeros((4, 4))
    Lf[1, 1], Lf[3, 1], Lf[3, 3], Lf[0, 0], Lf[2, 2] = s1, eta[1] * ref[1], s2, s3, s4
    dL = np.zeros((len(eta), 4, 4))  # none in the sensor ratios
    dL[0, 1, 1], dL[1, 3, 1], dL[2, 3, 3], dL[3, 0, 0], dL[4, 2, 2] = d1, ref[1], d2, d3, d4
    return Lf, dL


def _sensor(eta, rdiag) -> tuple[np.ndarray, np.ndarray]:
    """The sensor-noise variances R (``rdiag``, with eta[5:] scaling outputs 1.. by
    exp(2 eta), clipped to :data:`SENSOR_LOG_RANGE`) and dR/deta (n_eta, L), zero for the
    process-noise entries and a clipped ratio."""
    rdiag = np.asarray(rdiag, dtype=float)
    dR = np.zeros((len(eta), rdiag.size))
    if len(eta) <= 5:
        return rdiag, dR
    lo, hi = SENSOR_LOG_RANGE
    rho = np.asarray(eta[5:], dtype=float)
    R = rdiag.copy()
    R[1 : 1 + rho.size] *= np.exp(2.0 * np.clip(rho, lo, hi))
    for j, e in enumerate(rho):
        if lo < e < hi:
            dR[5 + j, 1 + j] = 2.0 * R[1 + j]
    return R, dR


def _gain(Ad, G, C, rdiag, eta, ref):
    """K, the Riccati solution P, (C P C' + R)^-1, the noise factor of :func:`kalman_gain_of`
    and its derivatives, the predictor's spectral radius, and dR/deta, from the sampled
    model (Ad, G)."""
    Lf, dL = _noise_factor(eta, ref)
    rdiag, dR = _sensor(eta, rdiag)
    rdiag = np.ascontiguousarray(rdiag, dtype=float)
    f = np.ascontiguousarray
    K, P, Sinv, rho, ok = _gain_core(f(Ad, dtype=float), f(G), f(C, dtype=float), rdiag, Lf)
    if not ok:  # doubling did not converge: the QZ fallback of filter_riccati
        GL = G @ Lf
        R = np.diag(rdiag)
        P = filter_riccati(Ad, C, GL @ GL.T + 1e-12 * np.eye(4), R)
        Sinv = np.linalg.inv(C @ P @ C.T + R)
        K = Ad @ P @ C.T @ Sinv
        rho = float(np.max(np.abs(np.linalg.eigvals(Ad - K @ C))))
    return K, P, Sinv, Lf, dL, rho, dR


@numba.njit(cache=True)
def _gain_core(Ad, G, C, rdiag, Lf):
    """(K, P, (C P C' + R)^-1, spectral radius of Ad - K C, converged) by doubling
    (:func:`filter_riccati` without its fallback)."""
    L = C.shape[0]
    Ct = np.ascontiguousarray(C.T)
    GL = G @ Lf
    Q = GL @ np.ascontiguousarray(GL.T) + 1e-12 * np.eye(4)
    Gm = Ct @ np.diag(1.0 / rdiag) @ C
    P, ok = _doubling(np.ascontiguousarray(Ad.T), 0.5 * (Gm + Gm.T), Q, DOUBLING_STEPS, 1e-14)
    if not ok or not np.all(np.isfinite(P)):
        return np.zeros((4, L)), P, np.zeros((L, L)), np.inf, False
    Sinv = np.linalg.inv(C @ P @ Ct + np.diag(rdiag))
    K = Ad @ P @ Ct @ Sinv
    rho = np.max(np.abs(np.linalg.eigvals((Ad - K @ C).astype(np.complex128))))
    return K, P, Sinv, rho, True


def gain_derivative(Ad, G, C, K, P, Sinv, Lf, dL, dAd, dG, dR=None) -> np.ndarray:
    """Exact derivatives of the steady-state Kalman gain K (:func:`kalman_gain_of`).

    Differentiating the filter Riccati equation at its stabilizing solution gives a Stein
    equation for each direction, dP = Abar dP Abar' + dAd P Abar' + Abar P dAd' + dQ
    + K dR K' with Abar = Ad - K C, and dK = (dAd P C' + Abar dP C' - K dR) (C P C' + R)^-1.

    Parameters
    ----------
    Ad, G, C, K, P, Sinv : ndarray
        The sampled model, its noise input, the output matrix and :func:`_gain`'s K, P and
        (C P C' + R)^-1.
    Lf, dL : ndarray
        The noise factor (q, q) and its derivatives in eta (n_eta, q, q).
    dAd, dG : ndarray
        Derivatives of Ad (n, 4, 4) and G (n, 4, 2) in the model parameters (n may be 0).
    dR : (n_eta, L) ndarray, optional
        Derivatives of the sensor-noise variances in eta (default none).

    Returns
    -------
    (n + n_eta, 4, L) ndarray
        dK in the model parameters, then in eta.
    """
    f = np.ascontiguousarray
    dR = np.zeros((dL.shape[0], C.shape[0])) if dR is None else dR
    return _gain_derivative_core(f(Ad), f(G), f(C), f(K), f(P), f(Sinv), f(Lf), f(dL), f(dAd),
                                 f(dG), f(dR, dtype=float))  # fmt: skip


@numba.njit(cache=True)
def _gain_derivative_core(Ad, G, C, K, P, Sinv, Lf, dL, dAd, dG, dR):
    """:func:`gain_derivative` compiled: one LU of I - Abar (x) Abar for all directions."""
    n = dAd.shape[0]
    m = n + dL.shape[0]
    GL = G @ Lf
    Abar = Ad - K @ C
    APt = P @ np.ascontiguousarray(Abar.T)
    PCt = P @ np.ascontiguousarray(C.T)
    Wm = np.empty((16, m))
    D = np.zeros((4, 4))
    for j in range(m):
        if j < n:
            D = dAd[j]
            dGL = dG[j] @ Lf
        else:
            D = np.zeros((4, 4))
            dGL = G @ dL[j - n]
        dQ = dGL @ np.ascontiguousarray(GL.T)
        W = D @ APt
        W = W + W.T + dQ + dQ.T
        if j >= n and np.any(dR[j - n]):  # a sensor ratio's direction
            W = W + K @ np.diag(dR[j - n]) @ np.ascontiguousarray(K.T)
        Wm[:, j] = W.ravel()
    dPm = np.linalg.solve(np.eye(16) - np.kron(Abar, Abar), Wm)
    out = np.empty((m, 4, C.shape[0]))
    Ct = np.ascontiguousarray(C.T)
    for j in range(m):
        D = dAd[j] if j < n else np.zeros((4, 4))
        dP = np.ascontiguousarray(dPm[:, j]).reshape(4, 4)
        dK = D @ PCt + Abar @ (dP @ Ct)
        if j >= n and np.any(dR[j - n]):
            dK = dK - K @ np.diag(dR[j - n])
        out[j] = dK @ Sinv
    return out


@numba.njit(cache=True)
def _doubling(A, G, H, max_iter, tol):
    """Structure-preserving doubling for X = A' X A - A' X G-part ... (see filter_riccati).

    Returns (X, converged).
    """
    n = A.shape[0]
    eye = np.eye(n)
    for _ in range(max_iter):
        W = np.linalg.inv(eye + G @ H)
        AW = A @ W
        G1 = G + AW @ G @ A.T
        H1 = H + A.T @ H @ W @ A
        A = AW @ A
        G = 0.5 * (G1 + G1.T)
        dH = np.max(np.abs(H1 - H))
        H = 0.5 * (H1 + H1.T)
        if dH <= tol * max(np.max(np.abs(H)), 1e-300):
            return H, True
    return H, False


def filter_riccati(Ad, C, Q, R) -> np.ndarray:
    """Stabilizing solution P of the filter Riccati equation
    P = Ad P Ad' - Ad P C' (C P C' + R)^-1 C P Ad' + Q.

    Structure-preserving doubling (Chu, Fan & Lin 2005: A0 = Ad', G0 = C' R^-1 C, H0 = Q;
    quadratic convergence, error ~ rho^(2^k) for the predictor's spectral radius rho), a
    few tens of microseconds for 4 states against milliseconds for the QZ method of
    ``scipy.linalg.solve_discrete_are``, which is the fallback where doubling does not
    converge in 64 steps (a predictor pole within ~1e-15 of the unit circle).

    Parameters
    ----------
    Ad : (n, n) ndarray
        Discrete state matrix.
    C : (L, n) ndarray
        Output matrix.
    Q : (n, n) ndarray
        Process-noise covariance (symmetric, positive semi-definite).
    R : (L, L) ndarray
        Sensor-noise covariance (symmetric, positive definite).

    Returns
    -------
    (n, n) ndarray
        P (the one-step prediction covariance of the state).

    Raises
    ------
    ValueError
        Where no stabilizing solution exists (from the fallback,
        :func:`bikeid.ident.predictor.stabilizing_riccati`).
    """
    G = C.T @ np.linalg.solve(R, C)
    try:
        P, ok = _doubling(np.ascontiguousarray(Ad.T), 0.5 * (G + G.T), np.ascontiguousarray(Q),
                          DOUBLING_STEPS, 1e-14)  # fmt: skip
    except np.linalg.LinAlgError:  # the iterates overflowed (no stabilizing solution)
        ok = False
    if ok and np.all(np.isfinite(P)):
        return P
    return stabilizing_riccati(Ad, C, Q, R)


def sensor_variances(model) -> np.ndarray:
    """The sensor-noise variances a joint fit's Kalman gains use at a fitted speed.

    Parameters
    ----------
    model : CanonicalModel
        The per-speed fit.

    Returns
    -------
    (L,) ndarray
        The diagonal of its ``noise_covariance`` (squared output units), raised to at
        least 1e-12 of its largest entry and to 1e-30 (noise-free data: a solvable
        Riccati equation).
    """
    r = np.diag(np.atleast_2d(model.noise_covariance)).astype(float)
    return np.maximum(r, max(1e-12 * float(np.max(r)), 1e-30))


class KalmanGainProblem(PredictionProblem):
    """Prediction errors with each run's K the Kalman gain of the model at its speed.

    z = [model parameters (14 over speed, or 10 at one speed), eta (3 or 5)]: the innovation
    gains follow the model (and a shared acceleration-noise covariance), so the predictor
    is stable at every point and
    the fit cannot stop on its stability boundary.  The Jacobian adds dE/dK dK/dz to the
    kernel's dE/dtheta (dK by central differences of the Riccati solution).  Only the
    entries ``free`` of z are the minimizer's x (the others held at ``z``): the fits
    solve for all of z, then alternate between the model parameters and eta (module
    docstring).

    Parameters
    ----------
    data, mapping, weights, outputs
        As :class:`bikeid.ident.predictor.PredictionProblem`.
    rdiag : ndarray
        Sensor noise variances of the outputs.
    ref : ndarray
        Reference model parameters of the noise scaling.
    z : ndarray
        The full parameter vector (model parameters, then eta).
    free : ndarray of int
        Indices of z the minimizer moves.
    """

    def __init__(self, data, mapping, rdiag, weights, outputs, ref, z, free):
        super().__init__(data, mapping, [None] * len(data), False, weights, outputs)
        self.rdiag, self.ref = rdiag, np.asarray(ref, float)
        self.z, self.free = np.asarray(z, float).copy(), np.asarray(free)
        self.n_eta = self.z.size - self.mapping[0].shape[1]
        self.noise_input = noise_input(self.n_eta)

    def full(self, x) -> np.ndarray:
        """z with the free entries set to x.

        Parameters
        ----------
        x : ndarray
            Values of the free entries.

        Returns
        -------
        ndarray
            The full parameter vector.
        """
        z = self.z.copy()
        z[self.free] = x
        return z

    def split(self, z):
        """The model parameters of z and no free gains (the gains follow the model).

        Parameters
        ----------
        z : ndarray
            The full parameter vector.

        Returns
        -------
        tuple
            (model parameters, None).
        """
        return z[: self.mapping[0].shape[1]], None

    def residual(self, x):
        """The stacked weighted prediction errors at the free entries x.

        Parameters
        ----------
        x : ndarray
            Values of the free entries.

        Returns
        -------
        ndarray or None
            The residual vector (None where a model cannot be evaluated).
        """
        return super().residual(self.full(x))

    def _needs(self) -> tuple[bool, bool]:
        """Whether speed parameters, and whether noise parameters, are free."""
        P = self.mapping[0].shape[1]
        return bool(np.any(self.free < P)), bool(np.any(self.free >= P))

    def _models(self, x, derivatives: bool):
        P = self.mapping[0].shape[1]
        p, eta = x[:P], x[P:]
        need_theta, need_eta = self._needs()
        ne = self.n_eta
        rows = [*(range(10) if need_theta else ()), *(range(10, 10 + ne) if need_eta else ())]
        out, cache = [], {}
        for i, d in enumerate(self.data):
            S = self.mapping[i]
            theta = S @ p
            key = (d.dt, theta.tobytes(), self.rdiag[i].tobytes())
            if key not in cache:
                Ad, Bd, dAd, dBd, G, dG = discretize_with_derivatives(
                    theta, d.dt, self.noise_input, derivatives=derivatives and need_theta
                )
                try:
                    K, Pr, Sinv, Lf, dL, rho, dR = _gain(Ad, G, self.C, self.rdiag[i], eta,
                                                         self.ref)  # fmt: skip
                except (ValueError, np.linalg.LinAlgError):
                    return None
                if not rho < 1.0:
                    return None
                dK = None
                if derivatives:
                    dK = np.zeros((10 + ne, 4, self.L))
                    pick = rows if need_theta else list(range(ne))
                    dK[rows] = gain_derivative(Ad, G, self.C, K, Pr, Sinv, Lf, dL, dAd,
                                               dG, dR)[pick]  # fmt: skip
                    dK = dK.reshape(10 + ne, -1)
                cache[key] = (Ad, Bd, dAd, dBd, K, dK)
            Ad, Bd, dAd, dBd, K, dK = cache[key]
            out.append((Ad, Bd, dAd, dBd, K, S, dK))
        return out

    def _jacobian_blocks(self, x):
        """Per run the weighted raw Jacobian in [theta, eta] (the blocks needed) and x0, with
        dK/d[theta, eta] chained inside the kernel, and its map to the free entries then x0."""
        z = self.full(x)
        models = self._models(z, derivatives=True)
        if models is None:
            return None
        need_theta, need_eta = self._needs()
        P, ne = self.mapping[0].shape[1], self.n_eta
        rows = [*(range(10) if need_theta else ()), *(range(10, 10 + ne) if need_eta else ())]
        m = self.free.size
        blocks = []
        for d, x0, (Ad, Bd, dAd, dBd, K, S, dK) in zip(self.data, self.x0s, models, strict=True):
            dKr = np.ascontiguousarray(dK[rows].reshape(len(rows), 4, self.L))
            _, J = prediction_kernel(Ad, Bd, K, dAd, dBd, dKr, d.u, d.y, self.idx, x0, False,
                                     self.w)  # fmt: skip
            J = J.reshape(-1, J.shape[2])
            Tz = np.zeros((len(rows), P + ne))  # raw columns -> entries of z
            if need_theta:
                Tz[:10, :P] = S
            if need_eta:
                Tz[len(rows) - ne :, P:] = np.eye(ne)
            T = np.zeros((J.shape[1], m + 4))
            T[: len(rows), :m] = Tz[:, self.free]
            T[len(rows) :, m:] = np.eye(4)
            blocks.append((J, T))
        return blocks


def alternate(problem, z: np.ndarray, n: int, max_nfev: int, method: str, passes: int,
              reweight, settle: bool = False
              ) -> tuple[np.ndarray, int, str | None, tuple[int, ...]]:  # fmt: skip
    """Fit z = [model parameters (n), eta] by alternating the two blocks.

    Parameters
    ----------
    problem : callable
        ``problem(z, free) -> KalmanGainProblem`` with the current output weights.
    z : ndarray
        Start (modified in place and returned).
    n : int
        Number of model parameters (the first n entries of z).
    max_nfev : int
        Residual evaluations per Levenberg-Marquardt solve.
    method : {"lm", "scipy"}
        Minimizer (:func:`bikeid.ident.predictor.solve`).
    passes : int
        Weighting passes; after each, ``reweight(prob)`` sets new output weights.
    reweight : callable
        Receives the last problem at the end of each pass.
    settle : bool, optional
        After each noise step, put the process-noise standard deviations the data do not
        hold off their lower bound on it and hold them there (:func:`settle_bounds`).

    Returns
    -------
    z : ndarray
        The fitted parameters.
    nfev : int
        Residual evaluations in all.
    stopped : str or None
        The minimizer's message when its last model-parameter solve did not converge.
    held : tuple of int
        Indices into z of the noise parameters held on their bound (``settle``).
    """
    par = np.arange(n)
    nfev, stopped, held = 0, None, ()
    for _ in range(max(1, passes)):
        for _ in range(JOINT_ROUNDS):
            prob = problem(z, par)
            sol = solve(prob, z[par], max_nfev, method)
            z[par], nfev = sol.x, nfev + sol.nfev
            stopped = None if sol.success else str(sol.message)
            before = float(prob._r @ prob._r)
            noise = np.array([i for i in range(n, z.size) if i not in held], dtype=int)
            if noise.size == 0:
                break
            prob = problem(z, noise)
            sol_n = solve(prob, z[noise], max_nfev, method)
            z[noise], nfev = sol_n.x, nfev + sol_n.nfev
            after = float(prob._r @ prob._r)
            if settle:
                z, newly, k = settle_bounds(problem, z, n)
                nfev += k
                if newly and set(newly) != set(held):
                    held = newly
                    continue  # refit the model parameters at the bound
            if before - after < JOINT_TOL:
                break
        reweight(prob)
    return z, nfev, stopped, held


#: A noise standard deviation is put on its lower bound when that raises the cost (squared
#: whitened prediction errors: -2 log-likelihood for Gaussian innovations of the weights'
#: variances) by less than chi^2_1(0.95) = 3.84 with the model parameters held (refitting
#: them could only lower it), i.e. when a likelihood-ratio test at 5 % does not reject the
#: bound.  The estimate of such a parameter is then the bound, and the other parameters'
#: covariance is conditional on it (a near-flat direction towards a bound has no quadratic
#: likelihood to give a marginal covariance).
BOUND_CHI2 = 3.841458820694124


def settle_bounds(problem, z: np.ndarray, n: int) -> tuple[np.ndarray, tuple[int, ...], int]:
    """Put the noise standard deviations the data do not hold off their bound on it.

    Tries, in turn, both acceleration-noise standard deviations (s1, s2) at the lower end
    of :data:`NOISE_LOG_RANGE`, then each alone; the first whose cost is within
    :data:`BOUND_CHI2` of the cost at ``z`` is kept.  With s1 on its bound s21 and s2
    describe one steer-noise variance (s21^2 + s2^2): s21 is folded into s2 and held at 0.
    With five noise parameters the angle-row standard deviations (s3, s4) are then tried
    the same way (both, then each), against the cost after the first step.

    Parameters
    ----------
    problem : callable
        ``problem(z, free) -> KalmanGainProblem``.
    z : ndarray
        [model parameters (n), eta].
    n : int
        Number of model parameters.

    Returns
    -------
    z : ndarray
        The parameters with the settled entries on their bound (a copy when changed).
    held : tuple of int
        Indices into z of the noise parameters held (on their bound, or s21 folded away),
        empty when none is; the covariance is to be taken without them.
    nfev : int
        Residual evaluations used.
    """
    lo, hi = NOISE_LOG_RANGE
    i1, i21, i2 = n, n + 1, n + 2

    def acceleration(zb: np.ndarray, held: tuple[int, ...]) -> None:
        if i1 in held:
            zb[i2] = (
                lo
                if i2 in held
                else 0.5 * math.log(zb[i21] ** 2 + math.exp(2.0 * min(max(zb[i2], lo), hi)))
            )
            zb[i21], zb[i1] = 0.0, lo
        else:
            zb[i2] = lo

    def angle(zb: np.ndarray, held: tuple[int, ...]) -> None:
        zb[list(held)] = lo

    steps = [(((i1, i21, i2), (i1, i21), (i2,)), acceleration)]
    if z.size - n >= 5:
        steps.append((((n + 3, n + 4), (n + 3,), (n + 4,)), angle))
    every = np.arange(z.size)
    base = problem(z, every).residual(z)
    if base is None:
        return z, (), 1
    cost0, nfev = float(base @ base), 1
    held_all: tuple[int, ...] = ()
    for candidates, put in steps:
        for held in candidates:
            zb = z.copy()
            put(zb, held)
            r = problem(zb, every).residual(zb)
            nfev += 1
            if r is not None and float(r @ r) - cost0 < BOUND_CHI2:  # the next step's
                z, held_all, cost0 = zb, held_all + held, float(r @ r)  # test from here
                break
    return z, held_all, nfev
