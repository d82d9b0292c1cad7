"""Prediction-error identification of Chen & Dao's canonical model (C&D §II, Ljung ch. 7).

Predictor.  The continuous-time canonical model (``ident.canonical``) is sampled
exactly with a zero-order hold at the data's dt (Ad, Bd = blocks of
expm([[A, B], [0, 0]] dt)), and the one-step prediction error comes from the
innovations (steady-state Kalman) predictor::

    yhat[k] = C xhat[k],  e[k] = y[k] - yhat[k],
    xhat[k+1] = Ad xhat[k] + Bd u[k] + K e[k]

``noise_model="free"`` (default): the noise model is estimated with the plant (the model
set then contains any plant-input and sensor noise of the true loop, which makes direct PEM
consistent in closed loop, reference F1), by :data:`FREE_NOISE_MODEL` ("kalman").
``"kalman"``: K is the Kalman gain of the model for fitted noise covariances (roll and
steer acceleration noise, and angle-row noise for angle signals that are not the integrals
of their logged rates; :mod:`ident.innovation_gain`), so Ad - K C is stable for every
parameter value, also where the bicycle is open-loop unstable, and the fit cannot stop on
the predictor's stability boundary.  ``noise_model="gain"``: the discrete-time innovation
gain K (4 x L) has free entries (on short records it ends on that boundary, where
its covariance describes no optimum: docs/uncertainty.md), started from the Kalman gain of
the start model with Q = Bd Bd' var(u), R = diag(var(y)) 1e-2.  ``noise_model="none"``:
K = 0, output error (biased in closed loop, and for an open-loop unstable plant it
simulates an unstable plant: the interval functions refuse it there,
:mod:`ident.trust`).

Initial state.  Estimated per run by variable projection: e is affine in x0, so
x0 is solved by least squares at each evaluation and the Jacobian is projected
(Kaufman).  Jacobian: exact sensitivities, the derivative of expm by
``scipy.linalg.expm_frechet`` and a compiled recursion for d xhat / d theta.
Minimizer: ``scipy.optimize.least_squares(method="lm")`` (Levenberg-Marquardt,
MINPACK).  A trial step whose predictor is unstable gets a large finite residual
and is rejected.  Outputs are weighted by the inverse residual standard deviation
(two passes); the covariance is the sandwich of ``sandwich_covariance``, which accounts for the
correlation between the outputs' innovations that per-output weights leave.

Start.  ``ident.subspace.pbsid`` on decimated data (closed-loop safe), converted to
continuous time and to the canonical form; by default two past windows/decimations
(:data:`SUBSPACE_STARTS`) plus any ``starts`` given (a neighbouring speed's model, a
direct estimate) are scored by their one-step prediction cost and the best is refined.

Minimizer.  ``method="lm"`` (default): Levenberg-Marquardt on the P x P normal equations
with a statistical stopping rule (see ``_lm``); ``method="scipy"``: MINPACK through
``scipy.optimize.least_squares``.  Profiling showed MINPACK's QR of the full
(N l) x P Jacobian at every iteration, and a Jacobian at every trial point, dominating.

Speed-parameterized model (``fit_speed_model``): per-speed fits (warm-started from
the next lower speed, or reused via ``per_speed=``) give the start; then alpha, beta,
gamma, b are refined jointly over all runs.  Each run's innovation gain is the steady-state
Kalman gain of the joint model at its speed (:func:`kalman_gain_of`: white noise in the roll
and steer accelerations, one 2x2 covariance shared by all speeds and estimated with the
model, sensor noise the per-speed fit's innovation variances), so K follows the model and
the predictor is stable at every point.  Holding each speed's K at its per-speed fit's value
(``joint_gain="per_speed"``, the former fit) biased the model: on a loop without process
noise the optimal predictor's poles are the plant's slow poles, near the unit circle, and
short per-speed fits with a free K end on the predictor's stability boundary; with their K
the true parameters give an unstable predictor for some runs, so the joint fit could not
reach them (the README tour's sweep on the exact linear plant: v_c 6.0627 m/s, 85 standard
errors from Meijaard's 6.0243, eigenvalue real parts up to 95 standard errors off; with the
Kalman gains v_c 6.0240, 0.4 standard errors, eigenvalues within 1.7).  The runs' nominal
speed ``run.speed`` is used (per-sample speed variation is ignored here).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bikeid.dataset.run import Run
from bikeid.ident.canonical import (
    PERM,
    SPEED_NAMES,
    THETA_NAMES,
    canonical_ab,
    matrices_from_speed_params,
    speed_map,
    to_canonical_form,
)
from bikeid.ident.informativity import guard
from bikeid.ident.innovation_gain import (
    FIXED_NOISE_STARTS,
    NOISE_LOG_RANGE,
    NOISE_STARTS,
    SENSOR_LOG_RANGE,
    KalmanGainProblem,
    alternate,
    kalman_gain_of,
    sensor_variances,
)
from bikeid.ident.linear_model import LinearModel, SpeedDependentModel
from bikeid.ident.predictor import (
    DEFAULT_OUTPUTS,
    INPUT,
    PredictionProblem,
    discretize,
    initial_gain,
    output_matrix,
    run_data,
    sandwich_covariance,
    single_threaded_blas,
    solve,
)
from bikeid.ident.signals import check_sampling
from bikeid.ident.subspace import d2c, decimate, pbsid
from bikeid.ident.trust import PREDICTOR_BOUNDARY_TOL
from bikeid.sim.errors import UntrustworthyResult
from bikeid.sim.linear import CanonicalMatrices

__all__ = [
    "CanonicalModel",
    "SpeedCanonicalModel",
    "SUBSPACE_STARTS",
    "fit",
    "fit_speed_model",
    "output_matrix",
    "subspace_start",
]


class _ParamsDict(dict):
    """The parameters by name; calling it (the former ``params()`` method) warns."""

    def __call__(self) -> dict[str, float]:
        import warnings  # only on the deprecated path

        warnings.warn("CanonicalModel.params is an attribute now: drop the parentheses",
                      DeprecationWarning, stacklevel=2)  # fmt: skip
        return dict(self)


@dataclass(frozen=True)
class CanonicalModel(LinearModel):
    """A fixed-speed canonical model.

    ``A``, ``B``, ``C`` and :meth:`state_space` are in bikeid's state order [phi, delta,
    phidot, deltadot], as every bikeid model (:mod:`ident.linear_model`); Chen & Dao's
    order [phi, phidot, delta, deltadot] (the canonical form's) only by name:
    ``A_chen_dao``, ``B_chen_dao``, ``C_chen_dao``, ``state_space(order="chen_dao")``,
    and the predictor's ``K`` and :meth:`predictor`, which are stated in it.

    ``theta`` = [a1..a8, b1, b2] (:data:`ident.canonical.THETA_NAMES`), ``covariance``
    (10x10), ``outputs`` the measured states used, ``K`` the discrete innovation gain
    at ``dt`` (4 x len(outputs)), ``noise_covariance`` of the innovations, ``x0`` per
    run, ``speed`` [m/s].

    Attributes
    ----------
    theta : (10,) ndarray
        [a1, ..., a8, b1, b2]: a1, a3, a5, a7 [1/s^2], a2, a4, a6, a8 [1/s], b1, b2
        [1/(kg m^2)] = [rad/(N m s^2)] (:func:`ident.canonical.canonical_ab`).
    covariance : (10, 10) ndarray
        Covariance of ``theta`` (sigma^2 (J'J)^-1 of the whitened residuals), in the
        squared units of ``theta``.
    K : (4, L) ndarray
        Discrete-time innovation gain at ``dt`` (L = ``len(outputs)``), canonical state
        order; zeros for ``noise_model="none"``.
    dt : float
        Sample period [s] of the predictor.
    speed : float
        Forward speed [m/s] of the runs (their nominal ``run.speed``).
    noise_covariance : (L, L) ndarray
        Sample covariance of the one-step prediction errors, in the outputs' units
        (rad^2, rad^2/s^2, ...).
    outputs : tuple of str
        Measured states fitted, a subset of ``("phi", "phidot", "delta", "deltadot")``
        containing phi and delta.
    x0 : tuple of (4,) ndarray
        Estimated initial state of each run, canonical order [rad, rad/s, rad, rad/s].
    cost : float
        Sum of squared weighted prediction errors at the optimum (dimensionless).
    nfev : int
        Number of residual evaluations over all passes.
    notes : tuple of str
        Remarks, e.g. the start used and a minimizer message when it did not converge.
    noise_model : {"kalman", "gain", "none"}
        How K was fitted: the Kalman gain of fitted noise covariances (stable by
        construction), free entries (the former default; may end on the predictor's
        stability boundary), or K = 0 (output error).  "gain" for models made elsewhere.
    gain_noise : (5 + (L - 1) + 4 + L,) ndarray or None
        For ``"kalman"``: eta = [log s1, s21, log s2, log s3, log s4] (the acceleration
        noise's Cholesky factor, then the roll and steer angle-row noise, relative to the
        reference standard deviations [ref1, ref2] [rad/s^2] and [ref3, ref4] [rad/s] that
        follow the eta) and the log sensor-noise standard-deviation ratios of outputs 1..,
        then those references, then the outputs' one-step prediction-error variances
        (squared output units) the ratios scale
        (:func:`bikeid.ident.innovation_gain.kalman_gain_of`).
    noise_on_bound : tuple of str
        Noise parameters put on their lower bound (``"log_s1"``, ``"log_s2"``): the data do
        not reject zero process noise there, and ``covariance`` is conditional on it.
    structure : StructureCheck or None
        The residual tests of the fitted runs (:func:`bikeid.ident.structure.check_structure`),
        which the interval functions read (:mod:`bikeid.ident.trust`).
    unstable_plant : str
        For an output-error fit, why the plant is open-loop unstable (the fit on the
        plant's stability boundary, an unstable start, or an unstable default fit of the
        same runs), else "".
    roll_rms_deg : float
        RMS roll angle of the fitted runs [deg] (:func:`roll_rms_deg`), NaN for runs of a
        linear plant or when not recorded; the interval functions refuse above
        :data:`bikeid.ident.trust.AMPLITUDE_LIMIT_DEG` (amplitude bias).
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
    noise_model: str = "gain"
    gain_noise: np.ndarray | None = None
    noise_on_bound: tuple[str, ...] = ()
    structure: Any = None
    unstable_plant: str = ""
    roll_rms_deg: float = float("nan")

    @property
    def A_chen_dao(self) -> np.ndarray:
        """(4, 4) ndarray: state matrix in Chen & Dao's order [phi, phidot, delta, deltadot].

        a1, a3, a5, a7 in 1/s^2, a2, a4, a6, a8 in 1/s (:func:`ident.canonical.canonical_ab`).
        """
        return canonical_ab(self.theta)[0]

    @property
    def B_chen_dao(self) -> np.ndarray:
        """(4, 1) ndarray: input matrix for T_delta in Chen & Dao's order, b1, b2 in rows 1, 3
        [1/(kg m^2)]."""
        return canonical_ab(self.theta)[1]

    @property
    def C_chen_dao(self) -> np.ndarray:
        """(L, 4) ndarray: 0/1 output matrix selecting ``outputs`` (rows in that order) from
        Chen & Dao's state [phi, phidot, delta, deltadot]."""
        return output_matrix(self.outputs)[0]

    @property
    def A(self) -> np.ndarray:
        """(4, 4) ndarray: state matrix for bikeid's state [phi, delta, phidot, deltadot]
        [1/s, 1/s^2 by position] (:attr:`A_chen_dao` permuted)."""
        return PERM @ self.A_chen_dao @ PERM.T

    @property
    def B(self) -> np.ndarray:
        """(4, 1) ndarray: input matrix for T_delta, bikeid's state order, b1, b2 in rows 2,
        3 [1/(kg m^2)]."""
        return PERM @ self.B_chen_dao

    @property
    def C(self) -> np.ndarray:
        """(L, 4) ndarray: 0/1 output matrix selecting ``outputs`` (rows in that order) from
        bikeid's state [phi, delta, phidot, deltadot]."""
        return self.C_chen_dao @ PERM.T

    @property
    def stderr(self) -> dict[str, float]:
        """dict of str to float: standard error of each theta entry, by name (units of theta)."""
        return dict(zip(THETA_NAMES, np.sqrt(np.diag(self.covariance)), strict=True))

    @property
    def params(self) -> dict[str, float]:
        """dict of str to float: the estimated parameters by name, ``{"a1": ..., "b2": ...}``
        in :data:`ident.canonical.THETA_NAMES` order (units as in ``theta``).  Calling it,
        ``params()``, the former method, still works and warns (deprecated)."""
        return _ParamsDict(zip(THETA_NAMES, self.theta, strict=True))

    def _matrices_at(self, speed: float) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        return self.A, {INPUT: self.B[:, 0]}

    def predictor(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(Ad, Bd, C, K) of the discrete innovations predictor at ``dt``.

        Returns
        -------
        Ad : (4, 4) ndarray
            Zero-order-hold state matrix at ``dt``, canonical order (maps xhat[k] to
            xhat[k+1]: entries in 1, s or 1/s by position).
        Bd : (4, 1) ndarray
            Zero-order-hold input matrix for T_delta [rad/(N m) in rows 0, 2; rad/(N m s)
            in rows 1, 3].
        C : (L, 4) ndarray
            Output matrix (:attr:`C_chen_dao`).
        K : (4, L) ndarray
            Innovation gain; xhat[k+1] = Ad xhat[k] + Bd u[k] + K (y[k] - C xhat[k]).
        """
        Ad, Bd = discretize(self.theta, self.dt)
        return Ad, Bd[:, None], self.C_chen_dao, self.K


@dataclass(frozen=True)
class SpeedCanonicalModel(SpeedDependentModel):
    """Speed-parameterized canonical model: a_odd = alpha + beta v^2, a_even = gamma v.

    ``params`` in :data:`ident.canonical.SPEED_NAMES` order with ``covariance``
    (14x14); ``per_speed`` holds the fixed-speed fits (start values and sensor-noise
    variances; each speed's innovation gain K with ``gain_noise`` None).

    Attributes
    ----------
    params : (14,) ndarray
        [alpha1, alpha3, alpha5, alpha7 [1/s^2], beta1 .. beta7 [1/m^2], gamma2 .. gamma8
        [1/m], b1, b2 [1/(kg m^2)]] (Chen & Dao eq. 4; :data:`ident.canonical.SPEED_NAMES`).
    covariance : (14, 14) ndarray
        Covariance of ``params`` (squared units of ``params``).
    per_speed : dict of float to CanonicalModel
        Fixed-speed fits keyed by speed [m/s] (rounded to 1e-6 m/s).
    dt : float
        Sample period [s] of the first run.
    g : float
        Gravitational acceleration [m/s^2] used to express alpha as K0 in
        :meth:`canonical_matrices` (does not enter the fit).
    outputs : tuple of str
        Measured states fitted.
    cost : float
        Sum of squared weighted prediction errors of the joint fit (dimensionless).
    nfev : int
        Number of residual evaluations of the joint fit.
    notes : tuple of str
        What the fit recorded (an informativity check skipped or failed, when asked to fit
        anyway).
    gain_noise : (5,) ndarray or None
        The joint fit's innovation-gain model: [log s1, s21, log s2] of the acceleration
        noise's Cholesky factor relative to [ref1, ref2] [rad/s^2], then ref1, ref2
        (:func:`kalman_gain_of`; the sensor-noise variances are the diagonal of each
        per-speed fit's ``noise_covariance``).  None when each speed's K was the per-speed
        fit's (``joint_gain="per_speed"`` or ``noise_model="none"``).
    structure : StructureCheck or None
        The residual tests of the runs against the model over speed
        (:func:`bikeid.ident.structure.check_structure` with ``speed_model``).
    unstable_plant : str
        For output-error per-speed fits, the speeds whose plant is open-loop unstable, else "".
    roll_rms_deg : float
        Largest RMS roll angle of the runs at one speed [deg], NaN for a linear plant.
    """

    params: np.ndarray
    covariance: np.ndarray
    per_speed: dict[float, CanonicalModel]
    dt: float
    g: float = 9.81
    outputs: tuple[str, ...] = DEFAULT_OUTPUTS
    cost: float = float("nan")
    nfev: int = 0
    notes: tuple[str, ...] = ()
    gain_noise: np.ndarray | None = None
    structure: Any = None
    unstable_plant: str = ""
    roll_rms_deg: float = float("nan")

    @property
    def stderr(self) -> dict[str, float]:
        """dict of str to float: standard error of each speed parameter, by name."""
        return dict(zip(SPEED_NAMES, np.sqrt(np.diag(self.covariance)), strict=True))

    def theta(self, v: float) -> np.ndarray:
        """Canonical parameters at one speed, S(v) @ params.

        Parameters
        ----------
        v : float
            Forward speed [m/s].

        Returns
        -------
        (10,) ndarray
            [a1, ..., a8, b1, b2] at ``v`` (units as :attr:`CanonicalModel.theta`).
        """
        return speed_map(v) @ self.params

    def at(self, v: float) -> CanonicalModel:
        """The fixed-speed model at v (covariance propagated, K of the joint model).

        Parameters
        ----------
        v : float
            Forward speed [m/s]; need not be one of the fitted speeds.

        Returns
        -------
        CanonicalModel
            theta = S(v) params, covariance S(v) cov S(v)', ``noise_covariance`` of the
            fitted speed nearest to ``v`` and K the Kalman gain of theta with the joint
            fit's noise model (:attr:`gain_noise`), or, without one (or without a
            stabilizing Riccati solution at ``v``), the K of that nearest fitted speed;
            ``structure``, ``unstable_plant`` and ``roll_rms_deg`` those of the model over
            speed; ``x0``, ``cost`` and ``nfev`` are left at their defaults.
        """
        S = speed_map(v)
        near = min(self.per_speed, key=lambda s: abs(s - v))
        K = self.per_speed[near].K
        if self.gain_noise is not None:
            C = output_matrix(self.outputs)[0]
            rdiag = sensor_variances(self.per_speed[near])
            try:
                K = kalman_gain_of(S @ self.params, self.dt, C, rdiag, self.gain_noise[:3],
                                   self.gain_noise[3:])  # fmt: skip
            except (ValueError, np.linalg.LinAlgError):  # no stabilizing Riccati solution
                K = self.per_speed[near].K
        return CanonicalModel(
            theta=S @ self.params, covariance=S @ self.covariance @ S.T,
            K=K, dt=self.dt, speed=v,
            noise_covariance=self.per_speed[near].noise_covariance, outputs=self.outputs,
            structure=self.structure, unstable_plant=self.unstable_plant,
            roll_rms_deg=self.roll_rms_deg,
        )  # fmt: skip

    def _matrices_at(self, speed: float) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        A, B = canonical_ab(self.theta(speed))
        return PERM @ A @ PERM.T, {INPUT: (PERM @ B)[:, 0]}

    def _speed_matrices(self) -> CanonicalMatrices:
        return self.canonical_matrices()

    def scaled_matrices(self) -> dict[str, np.ndarray]:
        """M^-1 g K0, M^-1 K2, M^-1 C1 (2x2 each) and the second column of M^-1.

        Returns
        -------
        dict of str to ndarray
            ``"Minv_gK0"`` (2, 2) = -alpha [1/s^2], ``"Minv_K2"`` (2, 2) = -beta [1/m^2],
            ``"Minv_C1"`` (2, 2) = -gamma [1/m], ``"Minv_col_delta"`` (2,) = [b1, b2]
            [1/(kg m^2)]; rows/columns [phi, delta].
        """
        cm = matrices_from_speed_params(self.params, self.g)
        return {"Minv_gK0": cm.K0 * self.g, "Minv_K2": cm.K2, "Minv_C1": cm.C1,
                "Minv_col_delta": self.params[12:14].copy()}  # fmt: skip

    def canonical_matrices(self) -> CanonicalMatrices:
        """Equivalent ``CanonicalMatrices`` with M = I (same A(v), same eigenvalues).

        Returns
        -------
        CanonicalMatrices
            :func:`ident.canonical.matrices_from_speed_params` of ``params`` and ``g``:
            M = I, K0 = -alpha / g, K2 = -beta, C1 = -gamma (its B is not the true one).
        """
        return matrices_from_speed_params(self.params, self.g)


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

    Parameters
    ----------
    runs : sequence of Run
        Runs at one speed and sample period with nonzero ``T_delta`` [N m] and ``phi``,
        ``delta`` [rad].
    outputs : sequence of str, optional
        Not used (the subspace step always uses phi and delta).
    p_seconds : float, optional
        VARX past window [s] (at least 8 decimated samples).
    coarse_dt : float, optional
        Target sample period [s] after decimation (a whole multiple of the runs' dt).

    Returns
    -------
    (10,) ndarray
        Canonical start [a1, ..., a8, b1, b2] (units as :attr:`CanonicalModel.theta`).

    Raises
    ------
    ValueError
        If ``T_delta`` is zero in a run or the subspace step (:func:`ident.subspace.pbsid`,
        :func:`ident.canonical.to_canonical_form`) refuses the data.  A discrete model
        without a real logarithm is not refused: the real part of the logarithm is used
        (``d2c(strict=False)``, good enough as a start).
    """
    data = run_data(runs, ("phi", "delta"))
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


#: Noise models of :func:`fit`: "free" (the noise model estimated, by
#: :data:`FREE_NOISE_MODEL`), "kalman" (K the Kalman gain of fitted noise covariances: a
#: stable predictor by construction), "gain" (K's entries free, the former default), "none"
#: (K = 0, output error).
NOISE_MODELS = ("free", "kalman", "gain", "none")
#: What ``noise_model="free"`` fits: the Kalman gain.  Measured better than the free gain
#: (docs/uncertainty.md, "A predictor stable by construction"): never on the predictor's
#: stability boundary on the README example (the free gain: 7-20 of 20 records at 30 s),
#: coverage 16-20 of 20 where the free gain's fell to 10-14, better held-out predictions on
#: the tutorial's measured runs, as consistent with process noise; 1.76x its CPU per fit.
FREE_NOISE_MODEL = "kalman"

#: Subspace starts tried by ``fit(..., multistart=True)``: (past window [s], coarse dt [s]).
SUBSPACE_STARTS = ((0.5, 0.01), (1.5, 0.02))


def _candidates(runs, theta0, starts, multistart) -> list[tuple[str, np.ndarray]]:
    cands: list[tuple[str, np.ndarray]] = []
    if theta0 is not None:
        cands.append(("theta0", np.asarray(theta0, float)))
    cands += [(f"start{i}", np.asarray(t, float)) for i, t in enumerate(starts or ())]
    if theta0 is None and (multistart or not cands):
        windows = SUBSPACE_STARTS if multistart else SUBSPACE_STARTS[:1]
        for p_s, cdt in windows:
            try:
                th = subspace_start(runs, p_seconds=p_s, coarse_dt=cdt)
            except (ValueError, np.linalg.LinAlgError):
                continue
            if np.all(np.isfinite(th)):
                cands.append((f"pbsid(p={p_s:g}s, dt={cdt:g}s)", th))
    bad = [n for n, t in cands if t.shape != (10,)]
    if bad:
        raise ValueError(f"start values {bad} must hold 10 canonical parameters a1..a8, b1, b2")
    if not cands:
        raise ValueError("no usable start: the subspace start failed; pass theta0=")
    return cands


@single_threaded_blas
def fit(
    runs: Run | Sequence[Run],
    *,
    outputs: Sequence[str] = DEFAULT_OUTPUTS,
    theta0: np.ndarray | None = None,
    noise_model: str = "free",
    max_nfev: int = 100,
    method: str = "lm",
    passes: int = 2,
    starts: Sequence[np.ndarray] = (),
    multistart: bool = True,
    informativity: str = "refuse",
    structure: bool = True,
    plant_check: bool = True,
) -> CanonicalModel:
    """Fixed-speed canonical PEM from one or more runs at the same speed and dt.

    ``outputs``: measured states fitted (default all four; see module docstring);
    ``theta0``: start (default: the subspace starts, see ``multistart``); ``starts``:
    further candidate starts (e.g. the model of a neighbouring speed or a direct
    estimate); ``multistart``: also try the PBSID starts of :data:`SUBSPACE_STARTS`.
    All candidates are scored by their one-step prediction cost (Kalman K of each
    candidate) and the best is refined, which avoids the local minima a single poor
    subspace start ran into.  ``noise_model`` "free" (the noise model estimated,
    :data:`FREE_NOISE_MODEL`), "kalman", "gain" or "none" (module docstring); ``method``
    "lm" (Levenberg-Marquardt on the normal equations, default) or
    "scipy" (``scipy.optimize.least_squares``, MINPACK; same optimum, slower);
    ``passes``: fits with re-estimated output weights (1 = weights from the output
    variances only).  Returns a :class:`CanonicalModel` (``notes`` names the start used).
    Runs whose logged torque was not held over each sample (controller or dither faster
    than the logging, ``ident.signals.check_sampling``) raise ValueError.

    Parameters
    ----------
    runs : Run or sequence of Run
        Runs at one speed (``run.speed`` [m/s], equal to 1e-6) and one sample period,
        with input ``T_delta`` [N m, positive to the right] and the ``outputs`` signals
        (``phi``, ``delta`` [rad], ``phidot``, ``deltadot`` [rad/s]).
    outputs : sequence of str, optional
        Measured states fitted; must include phi and delta.
    theta0 : (10,) array_like, optional
        Start [a1, ..., a8, b1, b2]; when given, the subspace starts are not tried.
    noise_model : {"free", "kalman", "gain", "none"}, optional
        "free" (default): the noise model estimated, as :data:`FREE_NOISE_MODEL`
        ("kalman"); "kalman": K the Kalman gain of fitted noise covariances (a stable
        predictor by construction); "gain": K's entries free; "none": K = 0 (output
        error).
    max_nfev : int, optional
        Residual evaluations allowed per pass.
    method : {"lm", "scipy"}, optional
        Minimizer (module docstring).
    passes : int, optional
        Number of fits with re-estimated output weights (at least 1).
    starts : sequence of (10,) array_like, optional
        Further candidate starts.
    multistart : bool, optional
        Try all :data:`SUBSPACE_STARTS` (else only the first) when ``theta0`` is None.
    informativity : {"refuse", "report", "skip"}, optional
        Before the fit, whether the runs can determine the 10 parameters
        (:func:`bikeid.ident.informativity.guard`): refuse when they cannot (default), or
        fit and say so in ``notes``, or skip the check (``notes`` says so).
    structure : bool, optional
        Attach the residual tests of the runs (``model.structure``,
        :func:`bikeid.ident.structure.check_structure`), which the interval functions of
        :mod:`bikeid.ident.uncertainty` read (default True).
    plant_check : bool, optional
        Output error only: fit the Kalman-gain model of the same runs to tell whether the
        nominal plant is open-loop unstable (``model.unstable_plant``, which the interval
        functions refuse); False skips that second fit and leaves it unchecked (default
        True).

    Returns
    -------
    CanonicalModel
        The fitted model at the runs' speed and dt.

    Raises
    ------
    ValueError
        If no runs are given, a run breaks the sampling contract, ``noise_model``,
        ``method`` or ``outputs`` is invalid, runs differ in sample period or speed,
        ``T_delta`` is zero in a run, a start does not hold 10 values, or no start gives
        a stable one-step predictor.
    UntrustworthyResult
        If the runs cannot determine the model (feedback-only input, too few excited
        frequencies) and ``informativity`` is ``"refuse"``.
    """
    runs = [runs] if isinstance(runs, Run) else list(runs)
    if not runs:
        raise ValueError("no runs given")
    check_sampling(runs, "pem.fit")
    if noise_model not in NOISE_MODELS:
        raise ValueError(f"noise_model {noise_model!r}: choose one of {', '.join(NOISE_MODELS)}")
    kind = FREE_NOISE_MODEL if noise_model == "free" else noise_model
    outputs = tuple(outputs)
    C, _ = output_matrix(outputs)
    data = run_data(runs, outputs)
    dts = {round(d.dt, 12) for d in data}
    if len(dts) > 1:
        raise ValueError(f"runs have different sample periods {sorted(dts)}; resample first")
    speeds = {round(d.v, 6) for d in data}
    if len(speeds) > 1:
        raise ValueError(
            f"runs at different speeds {sorted(speeds)}: use fit_speed_model for several speeds"
        )
    _, told = guard(runs, len(THETA_NAMES), what=f"the canonical PEM model at {data[0].v:g} m/s",
                    informativity=informativity)  # fmt: skip
    dt = data[0].dt
    free_k = kind == "gain"
    yvar = np.mean([np.var(d.y, axis=0) for d in data], axis=0)
    w = 1.0 / np.sqrt(yvar)
    mapping = [np.eye(10)] * len(data)
    best = None
    cands = _candidates(runs, theta0, starts, multistart)
    # the nominal plant of an output-error fit: the most unstable start (closed-loop-safe
    # subspace estimates, or the caller's), whose predictor K = 0 could not even be scored
    nominal = max(((float(np.max(np.linalg.eigvals(canonical_ab(t)[0]).real)), n)
                   for n, t in cands), key=lambda c: c[0])  # fmt: skip
    for name, theta in cands:
        K = initial_gain(theta, dt, C, data, yvar, kind != "none")
        if K is None:
            continue
        x = np.concatenate([theta, K.ravel()]) if free_k else theta
        prob = PredictionProblem(data, mapping, [K] * len(data), free_k, w, outputs)
        r = prob.residual(x)
        if r is not None and (best is None or float(r @ r) < best[0]):
            best = (float(r @ r), name, x, K, r)
    if best is None and kind == "none":
        raise ValueError(
            "no start gives a stable output-error predictor: output error simulates the "
            f"plant, and every start is open-loop unstable (most unstable eigenvalue real "
            f"part {nominal[0]:+.3f} 1/s); fit the Kalman gain (noise_model='kalman', a "
            "predictor stable by construction)"
        )
    if best is None:
        raise ValueError(
            "no start gives a stable one-step predictor; pass theta0= (e.g. a model at a "
            "neighbouring speed)"
        )
    _, start_name, x, K, r = best
    notes = [f"start: {start_name}"]
    if told:
        notes.append(told)
    if kind == "kalman":
        w = 1.0 / np.sqrt(np.mean((r.reshape(-1, len(outputs)) / w) ** 2, axis=0))
        model = _fit_kalman(data, x[:10], w, outputs, max_nfev, method, passes, notes)
        return _checked(runs, model) if structure else model
    nfev = 0
    for _ in range(max(1, passes)):
        prob = PredictionProblem(data, mapping, [K] * len(data), free_k, w, outputs)
        sol = solve(prob, x, max_nfev, method)
        nfev += sol.nfev
        x = sol.x
        w = 1.0 / np.sqrt(np.mean(prob.residuals() ** 2, axis=0))
    if not sol.success:
        notes.append(f"least_squares: {sol.message}")
    cov = sandwich_covariance(prob, 4 * len(data))
    theta, Kf = prob.split(x)
    model = CanonicalModel(
        theta=theta.copy(), covariance=cov[:10, :10], K=Kf.copy() if free_k else K, dt=dt,
        speed=data[0].v, noise_covariance=np.atleast_2d(np.cov(prob.residuals().T)),
        outputs=outputs, x0=tuple(prob.x0s), cost=float(prob._r @ prob._r), nfev=nfev,
        notes=tuple(notes), noise_model=kind,
    )  # fmt: skip
    if kind == "none":
        why = _unstable_plant(theta, dt, *nominal)
        if not why and plant_check:  # the nominal plant: the Kalman-gain fit's (consistent
            # in closed loop and never on its predictor's boundary; the free gain's fit can
            # end there with a spurious unstable root: +0.252 1/s on a stable 5 m/s loop)
            ref = fit(runs, outputs=outputs, theta0=theta0, noise_model="kalman",
                      max_nfev=max_nfev, method=method, passes=passes, starts=starts,
                      multistart=multistart, informativity="skip", structure=False)  # fmt: skip
            re = float(np.max(np.linalg.eigvals(ref.A).real))
            if re > 0.0:
                why = (f"the Kalman-gain fit of the same runs has an eigenvalue with real "
                       f"part {re:+.3f} 1/s")  # fmt: skip
        model = dataclasses.replace(model, unstable_plant=why)
    return _checked(runs, model) if structure else model


def _unstable_plant(theta, dt, start_re: float, start_name: str) -> str:
    """Why an output-error fit's plant is open-loop unstable, or "".

    The identified plant cannot be unstable (its predictor is the plant, kept stable), but a
    fit that ends on that stability boundary (spectral radius of Ad above 1 -
    :data:`bikeid.ident.trust.PREDICTOR_BOUNDARY_TOL`) wanted to be; the starts (closed-loop
    safe subspace estimates, or the caller's) and, failing them, the default fit of the same
    runs (:func:`fit`) are the nominal plant: an output-error fit of a plant that is unstable
    ends on a stable, wrong model (the README example at 4 m/s: weave real part -0.24 for a
    true +0.41, docs/uncertainty.md).
    """
    rho = float(np.max(np.abs(np.linalg.eigvals(discretize(theta, dt)[0]))))
    if rho > 1.0 - PREDICTOR_BOUNDARY_TOL:
        return f"the fit ended on the plant's stability boundary, spectral radius 1 - {1 - rho:.1e}"
    if start_re > 0.0:
        return f"a start ({start_name}) has an eigenvalue with real part {start_re:+.3f} 1/s"
    return ""


def _checked(runs, model):
    """The model with its structure check (:mod:`bikeid.ident.structure`) and roll RMS."""
    from bikeid.ident.structure import check_structure  # structure imports the intervals

    speeds = sorted({round(r.speed, 6) for r in runs})
    if hasattr(model, "per_speed"):
        check = check_structure(runs, {v: model.at(v) for v in speeds}, speed_model=model)
    else:
        check = check_structure(runs, {speeds[0]: model})
    rms = [roll_rms_deg([r for r in runs if round(r.speed, 6) == v]) for v in speeds]
    return dataclasses.replace(model, structure=check, roll_rms_deg=max(rms))


def roll_rms_deg(runs: Sequence[Run]) -> float:
    """RMS roll angle of runs from a nonlinear plant (measured or simulated).

    Parameters
    ----------
    runs : sequence of Run
        Runs with ``phi`` [rad].

    Returns
    -------
    float
        sqrt(mean(phi^2)) over all samples [deg]; NaN when every run comes from a linear
        plant (``meta["plant"]["model"] == "whipple-linear"`` or the ``linear_loop``
        simulator), where the amplitude causes no bias.
    """

    def linear(r) -> bool:
        meta = getattr(r, "meta", None) or {}
        plant = meta.get("plant") if isinstance(meta.get("plant"), dict) else {}
        return (plant.get("model") == "whipple-linear"
                or "linear_loop" in str(meta.get("simulator", "")))  # fmt: skip

    if all(linear(r) for r in runs):
        return float("nan")
    phi = np.concatenate([np.asarray(r["phi"], float) for r in runs])
    return float(np.degrees(np.sqrt(np.mean(phi**2))))


def _fit_kalman(data, theta, w, outputs, max_nfev, method, passes, notes) -> CanonicalModel:
    """The fixed-speed fit with K the Kalman gain of the model for a fitted noise covariance.

    eta = [log s1, s21, log s2] of the acceleration noise relative to |b| std(u), and
    [log s3, log s4] of the roll and steer angle-row noise relative to the angles' RMS
    rates, and the log sensor-noise ratios of outputs 1.. (the sensor variances are the
    one-step prediction errors', 1 / w^2, updated with the output weights after each pass,
    scaled by those ratios; the first output's held, as K does not change when all noise
    covariances scale together) (:func:`bikeid.ident.innovation_gain.kalman_gain_of`);
    fitted together with theta, then alternately
    (:func:`bikeid.ident.innovation_gain.alternate`); noise standard deviations the data
    cannot hold off their lower bound are put on it and the covariance of theta is
    conditional on them (:func:`bikeid.ident.innovation_gain.settle_bounds`).
    """
    dt = data[0].dt
    C = output_matrix(outputs)[0]
    uvar = float(np.mean([np.var(d.u) for d in data]))
    angle_rate = [  # RMS rate of each angle from its own samples [rad/s]
        math.sqrt(float(np.mean([np.mean((np.diff(d.y[:, outputs.index(a)]) / dt) ** 2)
                                 for d in data])))  # fmt: skip
        for a in ("phi", "delta")
    ]
    ref = np.concatenate([np.maximum(np.abs(theta[8:10]), 1e-6) * math.sqrt(uvar),
                          np.maximum(angle_rate, 1e-12)])  # fmt: skip
    mapping, weights = [np.eye(10)] * len(data), [w]

    def problem(z, free):
        r = 1.0 / weights[0] ** 2
        rd = np.maximum(r, max(1e-12 * float(np.max(r)), 1e-30))
        return KalmanGainProblem(data, mapping, [rd] * len(data), weights[0], outputs,
                                 ref, z, free)  # fmt: skip

    n_eta = 5 + len(outputs) - 1  # and the sensor ratios of outputs 1.. (start: none)
    z0 = _noise_start(problem, theta, n_eta, FIXED_NOISE_STARTS)
    if z0 is None:
        raise ValueError(
            "no start gives a stable one-step predictor; pass theta0= (e.g. a model at a "
            "neighbouring speed)"
        )

    # every entry together first, then alternately (settling the bounds): on the tutorial's
    # measured logs alternating alone from the subspace start stopped in a basin of nonsense
    # (a caster of about -3e4 1/s; docs/uncertainty.md)
    prob = problem(z0, np.arange(z0.size))
    sol = solve(prob, z0, max_nfev, method)
    joint_weights = weights[0]
    weights[0] = _weights(prob)
    try:
        z, nfev, stopped, held = alternate(
            problem, sol.x.copy(), 10, max_nfev, method, passes,
            lambda prob: weights.__setitem__(0, _weights(prob)), settle=True,
        )  # fmt: skip
    except UntrustworthyResult as exc:  # a noise bound or reweighting left no stable start
        # (measured: 1.5 m/s of an accuracy sweep, weave +3.1 1/s, the process noise put on
        # its lower bound): keep the joint fit, which ended with a stable predictor
        weights[0] = joint_weights
        z, nfev, stopped, held = sol.x.copy(), 0, None, ()
        notes.append(f"alternating refinement stopped ({exc}); the joint fit is kept")
    nfev += sol.nfev
    lo, hi = NOISE_LOG_RANGE
    logs = [10, 12, 13, 14]
    z[logs] = np.clip(z[logs], lo, hi)  # same gain, finite
    z[15:] = np.clip(z[15:], *SENSOR_LOG_RANGE)
    top = tuple(i for i in logs if z[i] >= hi and i not in held)  # the gain no longer moves
    free = np.array([i for i in range(z.size) if i not in held and i not in top])
    prob = problem(z, free)
    prob.normal_equations(z[free])
    cov = sandwich_covariance(prob, 4 * len(data))
    names = ("log_s1", "s21", "log_s2", "log_s_phi", "log_s_delta",
             *(f"log_r_{o}" for o in outputs[1:]))  # fmt: skip
    bound = tuple(names[i - 10] for i in held if i != 11)
    upper = tuple(names[i - 10] for i in top)
    eta = z[10:]
    notes.append(
        "innovation gain: Kalman gain of the model for fitted noise covariances (" +
        ", ".join(f"{k} {v:.3g}" for k, v in zip(names, eta, strict=True)) +
        (f"; on the lower bound: {', '.join(bound)}" if bound else "") +
        (f"; on the upper bound: {', '.join(upper)}" if upper else "") +
        ("; covariance conditional on them" if bound or upper else "") + ")"
    )  # fmt: skip
    if stopped:
        notes.append(f"least_squares: {stopped}")
    theta = z[:10].copy()
    return CanonicalModel(
        theta=theta, covariance=cov[:10, :10],
        K=kalman_gain_of(theta, dt, C, prob.rdiag[0], eta, ref),
        dt=dt, speed=data[0].v, noise_covariance=np.atleast_2d(np.cov(prob.residuals().T)),
        outputs=outputs, x0=tuple(prob.x0s), cost=float(prob._r @ prob._r),
        nfev=nfev, notes=tuple(notes), noise_model="kalman",
        gain_noise=np.concatenate([eta, ref, prob.rdiag[0]]),
        noise_on_bound=bound,
    )  # fmt: skip


@single_threaded_blas
def fit_speed_model(
    runs: Sequence[Run],
    *,
    outputs: Sequence[str] = DEFAULT_OUTPUTS,
    g: float = 9.81,
    noise_model: str = "free",
    max_nfev: int = 50,
    method: str = "lm",
    per_speed: dict[float, CanonicalModel] | None = None,
    passes: int = 2,
    informativity: str = "refuse",
    joint_gain: str = "kalman",
    structure: bool = True,
) -> SpeedCanonicalModel:
    """Speed-parameterized canonical PEM over runs at >= 2 distinct speeds (see module doc).

    Per-speed fits (one weighting pass each; speeds in increasing order, each also
    started from its lower neighbour's model) give the start and the sensor-noise
    variances; pass ``per_speed`` (speed rounded to 1e-6 m/s -> :class:`CanonicalModel`,
    e.g. from :func:`fit`) to reuse fits already made.  Then alpha, beta, gamma, b are
    refined jointly over all runs, each run's K the Kalman gain of the joint model at its
    speed, together with the acceleration-noise covariance that gain assumes (``passes``
    weighting passes), then in one pass alternating between the two (module docstring).
    Runs that break the sampling contract (``ident.signals.check_sampling``) raise ValueError.

    Parameters
    ----------
    runs : sequence of Run
        Runs at two or more nominal speeds ``run.speed`` [m/s], with ``T_delta`` [N m]
        and the ``outputs`` signals [rad, rad/s].
    outputs : sequence of str, optional
        Measured states fitted; must include phi and delta.
    g : float, optional
        Gravitational acceleration [m/s^2] stored in the result (for
        :meth:`SpeedCanonicalModel.canonical_matrices`); does not affect the fit.
    noise_model : {"free", "none"}, optional
        Noise model: "free" (the joint fit's Kalman gains; the per-speed start fits have
        free gains, ``fit(noise_model="gain")``) or "none" (output error throughout).
    max_nfev : int, optional
        Residual evaluations allowed per pass of the joint fit.
    method : {"lm", "scipy"}, optional
        Minimizer.
    per_speed : dict of float to CanonicalModel, optional
        Fixed-speed fits to reuse, keyed by speed [m/s].
    passes : int, optional
        Weighting passes of the joint fit (at least 1; with the Kalman gain, one
        alternating pass follows them).
    informativity : {"refuse", "report", "skip"}, optional
        Before the fit, whether the runs can determine the 14 parameters, with excited
        runs at two or more speeds (:func:`bikeid.ident.informativity.guard`; the
        per-speed fits, only starts here, report rather than refuse).
    joint_gain : {"kalman", "per_speed"}, optional
        Innovation gains of the joint fit (with ``noise_model="free"``): the joint model's
        Kalman gains (default), or each speed's K held at its per-speed fit's (the former
        fit, biased where those fits end on their predictor's stability boundary; kept for
        comparison).  With ``noise_model="none"`` K = 0 either way.
    structure : bool, optional
        Attach the residual tests of the runs against the model over speed
        (``model.structure``), which the interval functions read (default True).

    Returns
    -------
    SpeedCanonicalModel
        The jointly fitted speed parameters with the per-speed fits.

    Raises
    ------
    ValueError
        If a run breaks the sampling contract, the runs cover fewer than 2 distinct
        speeds, ``per_speed`` models used other outputs, no stable predictor exists for
        a run at the joint start, ``joint_gain`` is unknown, or a per-speed :func:`fit`
        raises.
    UntrustworthyResult
        If the runs cannot determine the model and ``informativity`` is ``"refuse"``.
    """
    runs = list(runs)
    check_sampling(runs, "pem.fit_speed_model")
    if joint_gain not in ("kalman", "per_speed"):
        raise ValueError(f"joint_gain {joint_gain!r}: choose 'kalman' or 'per_speed'")
    outputs = tuple(outputs)
    groups: dict[float, list[Run]] = {}
    for r in runs:
        groups.setdefault(round(r.speed, 6), []).append(r)
    if len(groups) < 2:
        raise ValueError(
            "the speed-parameterized model needs runs at >= 2 distinct speeds (alpha and beta "
            "are not separable at one speed, reference T3)"
        )
    _, told = guard(runs, len(SPEED_NAMES), what="the speed-parameterized PEM model",
                    informativity=informativity, min_speeds=2)  # fmt: skip
    starts_check = "skip" if informativity == "skip" else "report"
    per: dict[float, CanonicalModel] = {}
    given = {round(float(v), 6): m for v, m in (per_speed or {}).items()}
    prev = None
    for v in sorted(groups):
        if v in given:
            per[v] = given[v]
        else:
            per[v] = fit(groups[v], outputs=outputs, method=method,
                         noise_model="gain" if noise_model == "free" else noise_model,
                         structure=False,
                         passes=1, starts=() if prev is None else (prev.theta,),
                         informativity=starts_check)  # fmt: skip
        prev = per[v]
    if any(tuple(m.outputs) != outputs for m in per.values()):
        raise ValueError("per_speed models were fitted with other outputs than outputs=")
    Sstack = np.vstack([speed_map(v) for v in per])
    tstack = np.concatenate([m.theta for m in per.values()])
    params, *_ = np.linalg.lstsq(Sstack, tstack, rcond=None)
    data = run_data(runs, outputs)
    mapping = [speed_map(d.v) for d in data]
    w = 1.0 / np.sqrt(np.mean([np.var(d.y, axis=0) for d in data], axis=0))
    if noise_model == "free" and joint_gain == "kalman":
        model = _joint_kalman(runs, data, mapping, per, params, w, outputs, g, max_nfev,
                              method, passes, told)  # fmt: skip
        return _checked(runs, model) if structure else model
    Ks = [per[round(r.speed, 6)].K for r in runs]
    C = output_matrix(outputs)[0]
    for i, d in enumerate(data):  # a per-speed K may not stabilize the joint start
        Ad, Bd = discretize(mapping[i] @ params, d.dt)
        if not np.max(np.abs(np.linalg.eigvals(Ad - Ks[i] @ C))) < 1.0:
            K = initial_gain(mapping[i] @ params, d.dt, C, [d], np.var(d.y, axis=0), True)
            if K is None:
                raise ValueError(
                    f"no stable predictor for the run at {d.v} m/s from the joint start; "
                    "fit that speed separately and check its data"
                )
            Ks[i] = K
    nfev = 0
    for _ in range(max(1, passes)):
        prob = PredictionProblem(data, mapping, Ks, False, w, outputs)
        sol = solve(prob, params, max_nfev, method)
        nfev += sol.nfev
        params = sol.x
        w = 1.0 / np.sqrt(np.mean(prob.residuals() ** 2, axis=0))
    cov = sandwich_covariance(prob, 4 * len(data))
    unstable = [f"{v:g} m/s: {m.unstable_plant}" for v, m in per.items() if m.unstable_plant]
    model = SpeedCanonicalModel(
        params=params.copy(), covariance=cov, per_speed=per, dt=data[0].dt, g=g,
        outputs=outputs, cost=float(prob._r @ prob._r), nfev=nfev,
        notes=(told,) if told else (), unstable_plant="; ".join(unstable),
    )  # fmt: skip
    return _checked(runs, model) if structure else model


def _joint_kalman(runs, data, mapping, per, params, w, outputs, g, max_nfev, method, passes,
                  told) -> SpeedCanonicalModel:  # fmt: skip
    """The joint fit with the innovation gains from the joint model's Kalman filter."""
    rdiag = [sensor_variances(per[round(r.speed, 6)]) for r in runs]
    uvar = float(np.mean([np.var(d.u) for d in data]))
    ref = np.abs(params[12:14]) * math.sqrt(uvar)
    n = len(SPEED_NAMES)
    weights = [w]

    def problem(z, free):
        return KalmanGainProblem(data, mapping, rdiag, weights[0], outputs, ref, z, free)

    z = _noise_start(problem, params, 3)
    if z is None:
        raise ValueError(
            "no stable predictor from the joint start: fit each speed separately and check its data"
        )
    # every entry together, one solve per weighting pass, then one alternating pass, which
    # moves on where a joint step stalls on the near-flat noise columns (as the fixed-speed
    # fit, joint first then alternately): on benchmark 2 of bench_ident.py 28 residual
    # evaluations against 90-96 for alternating alone, and a likelihood as high or higher
    # on that and three smaller sets of runs (docs/performance.md)
    nfev, stopped = 0, None
    for _ in range(max(1, passes)):
        prob = problem(z, np.arange(z.size))
        sol = solve(prob, z, max_nfev, method)
        z, nfev = sol.x.copy(), nfev + sol.nfev
        weights[0] = _weights(prob)
    del prob  # its Jacobian blocks (N L x 17 per run) are not needed beside alternate's
    z, more, stopped, _ = alternate(
        problem, z, n, max_nfev, method, 1,
        lambda prob: weights.__setitem__(0, _weights(prob)),
    )  # fmt: skip
    nfev += more
    prob = problem(z, np.arange(z.size))
    prob.normal_equations(z)
    x = z
    cov = sandwich_covariance(prob, 4 * len(data))
    lo, hi = NOISE_LOG_RANGE
    x[n], x[n + 2] = (min(max(x[i], lo), hi) for i in (n, n + 2))  # same gain, finite
    notes = [f"innovation gains: Kalman gains of the joint model (acceleration noise "
             f"[log s1, s21, log s2] = {np.round(x[n:], 3).tolist()} relative to "
             f"{np.round(ref, 6).tolist()} rad/s^2)"]  # fmt: skip
    if stopped:
        notes.append(f"least_squares: {stopped}")
    if told:
        notes.append(told)
    return SpeedCanonicalModel(
        params=x[:n].copy(), covariance=cov[:n, :n], per_speed=per, dt=data[0].dt, g=g,
        outputs=outputs, cost=float(prob._r @ prob._r), nfev=nfev, notes=tuple(notes),
        gain_noise=np.concatenate([x[n:], ref]),
    )  # fmt: skip


def _weights(prob) -> np.ndarray:
    """Output weights: the inverse RMS of each output's prediction errors."""
    return 1.0 / np.sqrt(np.mean(prob.residuals() ** 2, axis=0))


def _noise_start(problem, params: np.ndarray, n_eta: int, starts=NOISE_STARTS
                 ) -> np.ndarray | None:  # fmt: skip
    """[params, eta] with the eta of ``starts`` (sensor ratios 0) of least cost, or None
    when none gives a stable predictor."""
    best = None
    for eta in starts:
        z = np.concatenate([params, eta, np.zeros(n_eta - len(eta))])
        r = problem(z, np.arange(z.size)).residual(z)
        if r is not None and (best is None or float(r @ r) < best[0]):
            best = (float(r @ r), z)
    return None if best is None else best[1]
