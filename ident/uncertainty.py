"""Confidence intervals on what is derived from a fitted canonical model.

A PEM fit (:mod:`ident.pem`) gives parameters p with covariance P_p: ``theta`` (10) of a
:class:`~bikeid.ident.pem.CanonicalModel`, or ``params`` (14) of a
:class:`~bikeid.ident.pem.SpeedCanonicalModel` with theta(v) = S(v) p
(:func:`ident.canonical.speed_map`).  A derived quantity q(p) gets the first-order
(delta-method) covariance J P_p J' with J = dq/dp, and the interval q +- z sd with
z = Phi^-1((1 + level) / 2) (1.96 at the default level 0.95).

- Eigenvalues (:func:`eigenvalue_intervals`): analytic perturbation of a simple eigenvalue,
  d lambda = w^H dA x / (w^H x) with right and left eigenvectors x, w
  (``scipy.linalg.eig(left=True)``); dA/da_j is one unit entry of A, b1 and b2 do not
  enter.  The derivative grows without bound where two eigenvalues meet (a double root,
  e.g. the weave pair at v_d): :attr:`EigenIntervals.condition` (|w| |x| / |w^H x|) says
  how close that is, and the first-order interval is then not to be trusted.
- Critical speeds of a speed-parameterized model (:func:`critical_speed_intervals`): v_w is
  a root of h(p, v) = b c d - a d^2 - b^2 e (third Hurwitz determinant of the quartic
  a s^4 + ... + e; :func:`bikeid.sim.linear.critical_speeds`), v_c of h = e; by the implicit
  function theorem dv/dp = -(dh/dp) / (dh/dv).  dh/dp is exact (complex step: h is a
  polynomial in p), dh/dv a central difference with step 1e-4 m/s (relative error ~1e-8).
- Bode bands (:func:`bode_bands`): G(jw) = C (jw I - A)^-1 B; dG = C R dA R B + C R dB with
  R = (jw I - A)^-1, propagated to log-magnitude (dB, d ln|G| = Re(dG / G)) and phase
  (d angle = Im(dG / G)).

The first-order interval is symmetric and assumes q linear in p over the interval.  Where it
is not (eigenvalue real parts whose standard error is a sizeable fraction of their distance
to the other modes), :func:`profile_interval` gives the interval the quadratic
log-likelihood implies without linearizing q: the least and greatest q(p') over the
ellipsoid (p' - p)' P_p^-1 (p' - p) <= z^2, found by projected gradient ascent on its
surface.  It equals the first-order interval when q is linear and follows q's curvature
otherwise; :func:`eigenvalue_intervals` and :func:`critical_speed_intervals` use it by
default (``method="profile"``; ``"delta"`` gives the symmetric interval), and
docs/uncertainty.md measures both against the truth.

:func:`monte_carlo` draws p from N(p, P_p) and recomputes the same quantities (eigenvalues
paired with the nominal ones by :func:`bikeid.sim.linear.match_eigenvalues`), the check of
the first-order propagation (tests/ident/test_uncertainty.py).  These intervals are only as good
as P_p: docs/uncertainty.md reports how often they contain the truth on the linear plant,
where it is known exactly, and why that calibration does not carry over to the nonlinear
plant or measured data.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from bikeid.ident.canonical import A_POS, B_POS, canonical_ab, matrices_from_speed_params, speed_map
from bikeid.ident.linear_model import mode_names
from bikeid.ident.predictor import output_matrix
from bikeid.ident.trust import (
    PREDICTOR_BOUNDARY_TOL,
    WithheldIntervals,
    check_predictor_interior,
    check_trust,
    predictor_radius,
)
from bikeid.sim.errors import InputError, UntrustworthyResult
from bikeid.sim.linear import (
    CanonicalMatrices,
    constant_term,
    critical_speeds,
    hurwitz3,
    match_eigenvalues,
    quartic_coefficients,
)
from bikeid.sim.textformats import to_jsonable

__all__ = [
    "BodeBand",
    "CriticalSpeedIntervals",
    "EigenIntervals",
    "INTERVAL_METHODS",
    "MonteCarloDraws",
    "bode_bands",
    "critical_speed_intervals",
    "eigenvalue_intervals",
    "eigenvalue_jacobian",
    "monte_carlo",
    "PREDICTOR_BOUNDARY_TOL",
    "WithheldIntervals",
    "check_predictor_interior",
    "check_trust",
    "predictor_radius",
    "profile_interval",
    "z_value",
]

#: Step [m/s] of the central difference dh/dv in :func:`critical_speed_intervals`.
SPEED_STEP = 1e-4


#: Interval methods: the quadratic-likelihood profile (default) and the first-order one
#: (not the identification methods, which are :data:`bikeid.ident.methods.METHODS`).
INTERVAL_METHODS = ("profile", "delta")


def z_value(level: float) -> float:
    """Two-sided normal quantile of a confidence level.

    Parameters
    ----------
    level : float
        Confidence level in (0, 1), e.g. 0.95.

    Returns
    -------
    float
        z = Phi^-1((1 + level) / 2) (1.959964 for 0.95), the half-width of the interval in
        standard errors.

    Raises
    ------
    InputError
        If ``level`` is not strictly between 0 and 1.
    """
    from scipy.stats import norm

    if not (isinstance(level, (int, float)) and 0.0 < level < 1.0):
        raise InputError(f"level={level!r}: need a confidence level strictly between 0 and 1")
    return float(norm.ppf(0.5 + 0.5 * level))


def _parameters(model, v: float | None) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """(p, P_p, S, speed) of a canonical model: theta(speed) = S @ p."""
    if hasattr(model, "params") and hasattr(model, "per_speed"):  # SpeedCanonicalModel
        if v is None or not math.isfinite(v):
            raise InputError("a speed-parameterized model needs the speed: pass v=... [m/s]")
        p, cov, S = np.asarray(model.params, float), np.asarray(model.covariance, float), None
        S = speed_map(float(v))
        speed = float(v)
    elif hasattr(model, "theta") and hasattr(model, "covariance"):  # CanonicalModel
        p, cov, S = np.asarray(model.theta, float), np.asarray(model.covariance, float), None
        S = np.eye(10)
        speed = float(model.speed)
        if v is not None and abs(float(v) - speed) > 1e-6:
            raise InputError(
                f"v={v} m/s: this fixed-speed model was fitted at {speed} m/s; use a "
                "speed-parameterized model for other speeds"
            )
    else:
        raise InputError(
            f"{type(model).__name__} has no parameter covariance: pass a CanonicalModel or "
            "SpeedCanonicalModel (ident.pem.fit, fit_speed_model)"
        )
    n = p.size
    if cov.shape != (n, n) or not np.all(np.isfinite(cov)) or not np.all(np.isfinite(p)):
        raise InputError(
            f"the model's covariance must be a finite {n}x{n} matrix (got shape {cov.shape}); "
            "refit the model"
        )
    return p, 0.5 * (cov + cov.T), S, speed


def _check_method(method: str) -> None:
    if method not in INTERVAL_METHODS:
        raise InputError(f"method={method!r}: choose one of {', '.join(INTERVAL_METHODS)}")


def _sqrt_cov(cov: np.ndarray) -> np.ndarray:
    """L with L L' = cov (eigendecomposition: a singular covariance is allowed)."""
    evals, evecs = np.linalg.eigh(cov)
    return evecs * np.sqrt(np.maximum(evals, 0.0))


#: Iterations and relative tolerance (of u, and of q against the first-order half-width)
#: of :func:`profile_interval`'s ascent.
PROFILE_MAX_ITER = 60
PROFILE_TOL = 1e-9


def profile_interval(
    func: Callable[[np.ndarray, Any], tuple[float, np.ndarray, Any]],
    p: np.ndarray,
    cov: np.ndarray,
    state: Any = None,
    level: float = 0.95,
) -> tuple[float, float, bool]:
    """Least and greatest q(p') over the confidence ellipsoid of p (profile interval).

    Under a quadratic log-likelihood in p (the asymptotic one of a prediction-error fit)
    the likelihood-ratio interval of a scalar q = q(p) is {q(p') : (p' - p)' P^-1 (p' - p)
    <= z^2}, z = Phi^-1((1 + level) / 2).  Each end is found on the ellipsoid's surface
    p' = p + L u, |u| = z, L L' = P, by the fixed point u = z grad_u q / |grad_u q| of the
    Lagrange condition, each step halved until q does not get worse (a monotone ascent).
    For q linear in p the ends are q(p) -+ z sd, the first-order interval.

    Parameters
    ----------
    func : callable
        ``func(p_prime, state) -> (q, dq_dp, new_state)``: the quantity, its gradient with
        respect to p and a state passed to the next call (e.g. the eigenvalues to track a
        mode by); must accept the start ``state``.
    p : (P,) ndarray
        Estimate.
    cov : (P, P) ndarray
        Its covariance (positive semi-definite).
    state : object, optional
        Initial state for ``func``.
    level : float, optional
        Confidence level (default 0.95).

    Returns
    -------
    lower, upper : float
        Ends of the interval (units of q); NaN where the ascent towards that end met points
        at which ``func`` returns a non-finite q (q undefined there: the interval is open
        on that side within the ellipsoid).
    converged : bool
        Both ascents stopped within :data:`PROFILE_MAX_ITER` iterations because a step
        moved u by less than :data:`PROFILE_TOL` z or raised q by less than
        :data:`PROFILE_TOL` times the first-order half-width; if not, the ends are the best
        points found (too narrow by about the last steps' change in q).

    Raises
    ------
    InputError
        If ``level`` is not in (0, 1).
    """
    z = z_value(level)
    L = _sqrt_cov(np.asarray(cov, float))
    p = np.asarray(p, float)
    q0, g0, s0 = func(p, state)
    gu0 = L.T @ g0
    if not np.any(gu0):  # q does not depend on p within the covariance's range
        return float(q0), float(q0), True
    half = z * float(np.linalg.norm(gu0))  # first-order half-width: the scale of q's changes
    ends, ok = [], True
    for sign in (-1.0, 1.0):
        u = sign * z * gu0 / np.linalg.norm(gu0)
        q, g, st = func(p + L @ u, s0)
        f, gu = sign * q, sign * (L.T @ g)
        done, undefined = False, not math.isfinite(q)
        for _ in range(PROFILE_MAX_ITER):
            norm = np.linalg.norm(gu)
            if norm == 0.0:
                done = True
                break
            target, step = z * gu / norm, 1.0
            while True:
                cand = u + step * (target - u)
                cand = z * cand / np.linalg.norm(cand)
                qc, gc, sc = func(p + L @ cand, st)
                undefined = undefined or not math.isfinite(qc)
                if sign * qc >= f or step < 1.0 / 64:
                    break
                step *= 0.5
            moved, gain = np.linalg.norm(cand - u), sign * qc - f
            if not gain >= 0.0:  # no ascent along the surface at 1/64 of a step: a maximum
                done = True
                break
            u, f, gu, st = cand, sign * qc, sign * (L.T @ gc), sc
            if moved <= PROFILE_TOL * z or gain <= PROFILE_TOL * half:
                done = True
                break
        ok = ok and done
        ends.append(math.nan if undefined else sign * f)
    return float(ends[0]), float(ends[1]), ok


def eigenvalue_jacobian(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Eigenvalues of the canonical A(theta) and their derivatives (analytic perturbation).

    Parameters
    ----------
    theta : (10,) array_like
        Canonical parameters [a1, ..., a8, b1, b2] (:data:`ident.canonical.THETA_NAMES`;
        a_odd [1/s^2], a_even [1/s], b [1/(kg m^2)]).

    Returns
    -------
    values : (4,) complex ndarray
        Eigenvalues [1/s], sorted by real then imaginary part (``numpy.sort_complex``,
        :data:`bikeid.ident.linear_model.EIGENVALUE_ORDER`).
    jacobian : (4, 10) complex ndarray
        d lambda_i / d theta_j = conj(w_i[r]) x_i[c] / (w_i^H x_i) for a_j at A[r, c]
        (units 1/s per unit of theta_j); zero for b1, b2.
    condition : (4,) ndarray
        Eigenvalue condition numbers |w_i| |x_i| / |w_i^H x_i| (1 for a normal matrix,
        infinite at a defective double root, where the derivative does not exist).
    """
    from scipy.linalg import eig

    A = canonical_ab(theta)[0]
    lam, W, X = eig(A, left=True, right=True)
    order = np.lexsort((lam.imag, lam.real))
    lam, W, X = lam[order], W[:, order], X[:, order]
    jac = np.zeros((4, 10), dtype=complex)
    cond = np.empty(4)
    for i in range(4):
        denom = np.vdot(W[:, i], X[:, i])
        cond[i] = np.linalg.norm(W[:, i]) * np.linalg.norm(X[:, i]) / max(abs(denom), 1e-300)
        for j, (r, c) in enumerate(A_POS):
            jac[i, j] = np.conj(W[r, i]) * X[c, i] / denom
    return lam.astype(complex), jac, cond


@dataclass(frozen=True)
class EigenIntervals:
    """Confidence intervals on the eigenvalues of a model at one speed.

    Attributes
    ----------
    speed : float
        Forward speed [m/s].
    level : float
        Confidence level of the intervals (e.g. 0.95).
    values : (4,) complex ndarray
        Eigenvalues [1/s] in bikeid's one order
        (:data:`bikeid.ident.linear_model.EIGENVALUE_ORDER`: real part, then imaginary
        part), the order of the models' ``eigenvalues``.
    std_real, std_imag : (4,) ndarray
        First-order standard errors of the real and imaginary parts [1/s] (zero
        imaginary-part error for a real eigenvalue of a real matrix).
    covariance : (8, 8) ndarray
        First-order covariance of [Re lambda_0..3, Im lambda_0..3] [1/s^2].
    condition : (4,) ndarray
        Eigenvalue condition numbers (:func:`eigenvalue_jacobian`); above ~1e3 the
        eigenvalue is near a double root and no interval of it is reliable.
    method : str
        ``"profile"`` (ends from :func:`profile_interval`, generally asymmetric) or
        ``"delta"`` (value -+ z std).
    real_bounds, imag_bounds : (4, 2) ndarray or None
        [lower, upper] of the real and imaginary parts [1/s] for ``method="profile"``.
    converged : (4, 2) bool ndarray or None
        Whether the profile ascents of the real and imaginary parts converged.
    modes : tuple of str
        Mode name of each eigenvalue (``weave``, ``weave (real)``, ``capsize``, ``caster``
        or ``""``; :func:`bikeid.ident.linear_model.mode_names`).
    predictor_radius : float or None
        Spectral radius of the fit's one-step predictor Ad - K C (:func:`predictor_radius`;
        None for a speed-parameterized model).  Above 1 - :data:`PREDICTOR_BOUNDARY_TOL`
        the fit ended on the predictor's stability boundary and the intervals are not to be
        trusted (:attr:`at_predictor_boundary`).
    notes : tuple of str
        What the intervals come with (:func:`bikeid.ident.trust.check_trust`: no structure
        check attached, or a refusal opted out of).
    """

    speed: float
    level: float
    values: np.ndarray
    std_real: np.ndarray
    std_imag: np.ndarray
    covariance: np.ndarray
    condition: np.ndarray
    method: str = "delta"
    real_bounds: np.ndarray | None = None
    imag_bounds: np.ndarray | None = None
    converged: np.ndarray | None = None
    modes: tuple[str, ...] = ()
    predictor_radius: float | None = None
    notes: tuple[str, ...] = ()

    @property
    def at_predictor_boundary(self) -> bool:
        """bool: the fit ended on its predictor's stability boundary (no trustworthy
        interval; :func:`check_predictor_interior`)."""
        r = self.predictor_radius
        return r is not None and r > 1.0 - PREDICTOR_BOUNDARY_TOL

    @property
    def z(self) -> float:
        """float: half-width of the first-order intervals in standard errors."""
        return z_value(self.level)

    @property
    def real_lower(self) -> np.ndarray:
        """(4,) ndarray: lower ends of the real-part intervals [1/s]."""
        if self.real_bounds is not None:
            return self.real_bounds[:, 0]
        return self.values.real - self.z * self.std_real

    @property
    def real_upper(self) -> np.ndarray:
        """(4,) ndarray: upper ends of the real-part intervals [1/s]."""
        if self.real_bounds is not None:
            return self.real_bounds[:, 1]
        return self.values.real + self.z * self.std_real

    @property
    def imag_lower(self) -> np.ndarray:
        """(4,) ndarray: lower ends of the imaginary-part intervals [1/s]."""
        if self.imag_bounds is not None:
            return self.imag_bounds[:, 0]
        return self.values.imag - self.z * self.std_imag

    @property
    def imag_upper(self) -> np.ndarray:
        """(4,) ndarray: upper ends of the imaginary-part intervals [1/s]."""
        if self.imag_bounds is not None:
            return self.imag_bounds[:, 1]
        return self.values.imag + self.z * self.std_imag

    def contains(self, truth: Sequence[complex]) -> tuple[np.ndarray, np.ndarray]:
        """Whether the intervals contain given eigenvalues, paired by minimum distance.

        Parameters
        ----------
        truth : (4,) array_like of complex
            Reference eigenvalues [1/s] (any order; paired with :attr:`values` by
            :func:`bikeid.sim.linear.match_eigenvalues`).

        Returns
        -------
        real : (4,) bool ndarray
            Real part of ``truth[i]`` inside its paired real-part interval.
        imag : (4,) bool ndarray
            The same for the imaginary part (a real pair counts as contained when both
            imaginary parts are zero).
        """
        _, col = match_eigenvalues(self.values, truth, return_index=True)
        t = np.asarray(truth, dtype=complex).ravel()
        lo_r, hi_r = self.real_lower[col], self.real_upper[col]
        lo_i, hi_i = self.imag_lower[col], self.imag_upper[col]
        return (lo_r <= t.real) & (t.real <= hi_r), (lo_i <= t.imag) & (t.imag <= hi_i)

    def to_json(self) -> dict[str, Any]:
        """The intervals as plain JSON types.

        Returns
        -------
        dict
            ``speed`` [m/s], ``level``, ``z``, ``method`` and per eigenvalue (in
            :attr:`values` order) ``mode`` (name or ""), ``value`` ({re, im} [1/s]),
            ``std`` ({re, im}, first order), ``real`` and ``imag`` ([lower, upper] [1/s]),
            ``condition`` and, for the profile, ``converged``.
        """
        modes = self.modes or ("",) * self.values.size
        rows = [
            {"mode": modes[i], "value": self.values[i],
             "std": {"re": self.std_real[i], "im": self.std_imag[i]},
             "real": [self.real_lower[i], self.real_upper[i]],
             "imag": [self.imag_lower[i], self.imag_upper[i]],
             "condition": self.condition[i]}
            for i in range(self.values.size)
        ]  # fmt: skip
        if self.converged is not None:
            for row, ok in zip(rows, self.converged, strict=True):
                row["converged"] = bool(np.all(ok))
        return to_jsonable({"speed": self.speed, "level": self.level, "z": self.z,
                          "method": self.method, "eigenvalues": rows})  # fmt: skip


def eigenvalue_intervals(
    model,
    v: float | None = None,
    level: float = 0.95,
    method: str = "profile",
    *,
    refuse_boundary: bool = True,
    refuse_structure: bool = True,
    refuse_output_error: bool = True,
    refuse_amplitude: bool = True,
) -> EigenIntervals:
    """Confidence intervals on the eigenvalues of a fitted model.

    Parameters
    ----------
    model : ident.pem.CanonicalModel or ident.pem.SpeedCanonicalModel
        Fitted model with its parameter covariance.
    v : float, optional
        Speed [m/s]; required for a speed-parameterized model, and must equal the fitted
        speed of a fixed-speed one if given.
    level : float, optional
        Confidence level (default 0.95).
    method : {"profile", "delta"}, optional
        ``"profile"`` (default): the ends of each real and imaginary part over the
        parameters' confidence ellipsoid (:func:`profile_interval`; the mode is followed
        by :func:`bikeid.sim.linear.match_eigenvalues`), which holds its coverage where an
        eigenvalue is curved in the parameters; ``"delta"``: value -+ z std.
    refuse_boundary, refuse_structure, refuse_output_error, refuse_amplitude : bool, optional
        Refuse (default) what ``bikeid identify`` withholds: a fit on its one-step
        predictor's stability boundary, a structure its attached check rejects, an
        output-error fit of an unstable plant, nonlinear-plant runs above the roll
        amplitude whose bias the intervals do not show (:func:`bikeid.ident.trust.check_trust`);
        False gives the intervals with that said in ``notes``.

    Returns
    -------
    EigenIntervals
        Eigenvalues in bikeid's one order (real part, then imaginary part, as the models'
        ``eigenvalues``) with their mode names, first-order standard errors and the
        intervals of their real and imaginary parts.

    Raises
    ------
    InputError
        If the model has no usable covariance, ``v`` is missing or inconsistent,
        ``level`` is not in (0, 1) or ``method`` is unknown.
    WithheldIntervals
        (an UntrustworthyResult) on a refusal not opted out of; its ``reason`` and
        ``remedy`` say why and what to do.
    """
    z_value(level)
    _check_method(method)
    p, cov, S, speed = _parameters(model, v)
    rho, notes = check_trust(model, speed, refuse_boundary=refuse_boundary,
                             refuse_structure=refuse_structure,
                             refuse_output_error=refuse_output_error,
                             refuse_amplitude=refuse_amplitude)  # fmt: skip
    lam, jac, cond = eigenvalue_jacobian(S @ p)
    Jp = jac @ S  # d lambda / d p
    J = np.vstack([Jp.real, Jp.imag])
    C = J @ cov @ J.T
    sd = np.sqrt(np.maximum(np.diag(C), 0.0))
    matrices = model.canonical_matrices() if hasattr(model, "per_speed") else None
    ei = EigenIntervals(speed=speed, level=level, values=lam, std_real=sd[:4],
                        std_imag=sd[4:], covariance=C, condition=cond,
                        modes=mode_names(lam, matrices, speed),
                        predictor_radius=rho, notes=notes)  # fmt: skip
    if method == "delta":
        return ei
    bounds = np.empty((2, 4, 2))
    ok = np.empty((4, 2), dtype=bool)
    for i in range(4):
        mirror = [k for k in range(i) if lam[i].imag != 0 and lam[k] == np.conj(lam[i])]
        if mirror:  # the conjugate of a pair profiled already: same real, mirrored imaginary
            k = mirror[0]
            bounds[0, i], bounds[1, i], ok[i] = bounds[0, k], -bounds[1, k, ::-1], ok[k]
            continue
        for k, part in enumerate(("real", "imag")):
            if part == "imag" and lam[i].imag == 0.0 and not np.any(Jp[i].imag):
                bounds[k, i], ok[i, k] = (0.0, 0.0), True  # a real root stays real nearby
                continue
            lo, hi, conv = profile_interval(_eigen_part(S, i, part), p, cov, lam, level)
            bounds[k, i], ok[i, k] = (lo, hi), conv
    return dataclasses.replace(ei, method="profile", real_bounds=bounds[0],
                               imag_bounds=bounds[1], converged=ok)  # fmt: skip


def _eigen_part(S: np.ndarray, i: int, part: str):
    """q(p) = Re or Im of the mode that was eigenvalue i, for :func:`profile_interval`.

    The state is the previous point's eigenvalues, to which the new ones are paired.
    """

    def func(pp: np.ndarray, ref: np.ndarray):
        lam, jac, _ = eigenvalue_jacobian(S @ pp)
        _, col = match_eigenvalues(lam, ref, return_index=True)
        lam, d = lam[col], jac[col[i]] @ S
        return (lam[i].real, d.real, lam) if part == "real" else (lam[i].imag, d.imag, lam)

    return func


@dataclass(frozen=True)
class CriticalSpeedIntervals:
    """First-order intervals on the weave and capsize speeds of a speed-parameterized model.

    Attributes
    ----------
    level : float
        Confidence level.
    v_w, v_c : float or None
        Weave and capsize speeds [m/s] of the model (:func:`bikeid.sim.linear.critical_speeds`),
        None where the model has none in (0, vmax].
    std_v_w, std_v_c : float or None
        Their standard errors [m/s] (None with the speed).
    gradient_v_w, gradient_v_c : (14,) ndarray or None
        dv/dp (implicit-function derivative) [m/s per unit of each parameter].
    method : str
        ``"profile"`` (:func:`profile_interval`) or ``"delta"`` (value -+ z std).
    bounds_v_w, bounds_v_c : (float, float) or None
        Profile interval [m/s]; None for the delta method.  Where the ascent towards one
        end reached parameters without that speed in (0, vmax], that end is the edge of
        the searched range (0 or ``vmax``) and ``open_v_w``/``open_v_c`` is True.  The
        v_c interval is found by test inversion (the speeds at which the characteristic
        polynomial's constant term vanishes for some parameters in the region), so it
        exists also when the estimate itself has no v_c in (0, vmax].
    open_v_w, open_v_c : bool
        The confidence ellipsoid holds parameters without the critical speed in (0, vmax].
    notes : tuple of str
        What the intervals come with (:func:`bikeid.ident.trust.check_trust`).
    """

    level: float
    v_w: float | None
    v_c: float | None
    std_v_w: float | None
    std_v_c: float | None
    gradient_v_w: np.ndarray | None
    gradient_v_c: np.ndarray | None
    method: str = "delta"
    bounds_v_w: tuple[float, float] | None = None
    bounds_v_c: tuple[float, float] | None = None
    open_v_w: bool = False
    open_v_c: bool = False
    notes: tuple[str, ...] = ()

    def interval(self, name: str) -> tuple[float, float] | None:
        """The confidence interval of one critical speed.

        Parameters
        ----------
        name : {"v_w", "v_c"}
            Which speed.

        Returns
        -------
        (float, float) or None
            (lower, upper) [m/s]: the profile interval (an open side at 0 or ``vmax``),
            or value -+ z std for the delta method; None when the model has no such speed
            (for v_c by the profile: when no parameters in the confidence region have one).

        Raises
        ------
        InputError
            If ``name`` is neither choice.
        """
        if name not in ("v_w", "v_c"):
            raise InputError(f"critical speed {name!r}: choose 'v_w' or 'v_c'")
        val, sd = getattr(self, name), getattr(self, f"std_{name}")
        if getattr(self, f"bounds_{name}") is not None:
            return tuple(getattr(self, f"bounds_{name}"))
        if val is None:
            return None
        z = z_value(self.level)
        return (val - z * sd, val + z * sd)

    def to_json(self) -> dict[str, Any]:
        """The intervals as plain JSON types.

        Returns
        -------
        dict
            ``level``, ``method`` and, for ``v_w`` and ``v_c``, ``value``, ``std``,
            ``interval`` [m/s] (None where the model has no such speed) and ``open``.
        """
        out: dict[str, Any] = {"level": self.level, "method": self.method}
        for name in ("v_w", "v_c"):
            out[name] = {"value": getattr(self, name), "std": getattr(self, f"std_{name}"),
                         "interval": self.interval(name),
                         "open": getattr(self, f"open_{name}")}  # fmt: skip
        return to_jsonable(out)


def _h(params: np.ndarray, g: float, v: float, func) -> complex:
    """h(p, v) of a critical-speed condition (complex parameters allowed: complex step)."""
    p = np.asarray(params)
    al, be, ga = (p[i : i + 4].reshape(2, 2) for i in (0, 4, 8))
    cm = CanonicalMatrices(M=np.eye(2), C1=-ga, K0=-al / g, K2=-be, g=g)
    return complex(func(*quartic_coefficients(cm, [v]))[0])


def _critical_gradient(p: np.ndarray, g: float, v0: float, func, name: str) -> np.ndarray:
    """dv/dp at a critical speed v0 by the implicit function theorem (module docstring)."""
    eps = 1e-30 * max(1.0, float(np.max(np.abs(p))))
    dh_dp = np.empty(p.size)
    for j in range(p.size):
        pc = p.astype(complex)
        pc[j] += 1j * eps
        dh_dp[j] = _h(pc, g, v0, func).imag / eps
    dh_dv = (_h(p, g, v0 + SPEED_STEP, func).real - _h(p, g, v0 - SPEED_STEP, func).real) / (
        2 * SPEED_STEP
    )
    if dh_dv == 0.0 or not math.isfinite(dh_dv):
        raise UntrustworthyResult(
            f"{name} = {v0:.4f} m/s is a tangential crossing (dh/dv = 0): no first-order "
            "interval; use monte_carlo"
        )
    return -dh_dp / dh_dv


def critical_speed_intervals(
    model,
    level: float = 0.95,
    vmax: float = 30.0,
    method: str = "profile",
    *,
    refuse_structure: bool = True,
    refuse_output_error: bool = True,
    refuse_amplitude: bool = True,
) -> CriticalSpeedIntervals:
    """Confidence intervals on v_w and v_c of a speed-parameterized model.

    Parameters
    ----------
    model : ident.pem.SpeedCanonicalModel
        Fitted speed-parameterized model (``params``, ``covariance`` 14x14, ``g``).
    level : float, optional
        Confidence level (default 0.95).
    vmax : float, optional
        Highest speed searched [m/s] (:func:`bikeid.sim.linear.critical_speeds`).
    method : {"profile", "delta"}, optional
        ``"profile"`` (default): the least and greatest speed over the parameters'
        confidence ellipsoid (:func:`profile_interval`); ``"delta"``: value -+ z std.
    refuse_structure, refuse_output_error, refuse_amplitude : bool, optional
        Refuse (default) a model over speed whose attached structure check rejects it, an
        output-error fit of an unstable plant, or runs above the roll amplitude whose bias
        the intervals do not show (:func:`bikeid.ident.trust.check_trust`);
        False gives the intervals with that said in ``notes``.

    Returns
    -------
    CriticalSpeedIntervals
        The speeds, their standard errors, gradients and intervals.

    Raises
    ------
    InputError
        If the model is not speed-parameterized or has no usable covariance, ``level`` is
        not in (0, 1) or ``method`` is unknown.
    UntrustworthyResult
        If h crosses zero tangentially (dh/dv = 0) at a critical speed, where the first-
        order derivative does not exist.
    WithheldIntervals
        (an UntrustworthyResult) on a refusal not opted out of; its ``reason`` and
        ``remedy`` say why and what to do.
    """
    z_value(level)
    _check_method(method)
    if not hasattr(model, "per_speed"):
        raise InputError(
            "critical speeds need a speed-parameterized model (ident.pem.fit_speed_model)"
        )
    p, cov, _, _ = _parameters(model, 1.0)
    _, notes = check_trust(model, None, refuse_structure=refuse_structure,
                           refuse_output_error=refuse_output_error,
                           refuse_amplitude=refuse_amplitude)  # fmt: skip
    g = float(model.g)
    crit = critical_speeds(matrices_from_speed_params(p, g), vmax)
    out: dict[str, Any] = {"method": method}
    for name, func in (("v_w", hurwitz3), ("v_c", constant_term)):
        v0 = crit[name]
        if v0 is None:
            out[name], out[f"std_{name}"], out[f"gradient_{name}"] = None, None, None
        else:
            grad = _critical_gradient(p, g, v0, func, name)
            out[name] = float(v0)
            out[f"std_{name}"] = float(math.sqrt(max(grad @ cov @ grad, 0.0)))
            out[f"gradient_{name}"] = grad
        if method != "profile":
            continue
        if name == "v_c":  # the speeds at which some parameters in the region have e = 0
            bounds, is_open = _capsize_speed_set(p, cov, level, vmax)
            out["bounds_v_c"], out["open_v_c"] = bounds, is_open
        elif v0 is not None:
            lo, hi, _ = profile_interval(_critical_speed(g, vmax, name, func), p, cov, v0, level)
            out[f"open_{name}"] = not (math.isfinite(lo) and math.isfinite(hi))
            out[f"bounds_{name}"] = (lo if math.isfinite(lo) else 0.0,
                                     hi if math.isfinite(hi) else float(vmax))  # fmt: skip
    return CriticalSpeedIntervals(level=level, notes=notes, **out)


#: Speed grid step [m/s] of :func:`_capsize_speed_set` (each end then bisected 12 times).
CAPSIZE_GRID_STEP = 0.05


def _capsize_constant(s: float):
    """q(p) = det(alpha + s beta), the characteristic polynomial's constant term at v^2 = s.

    alpha = p[0:4], beta = p[4:8] (2x2, row-major; A21 = alpha + v^2 beta); its gradient
    is adj(X)' = [[x11, -x10], [-x01, x00]] for alpha and s times that for beta.
    """

    def q(pp: np.ndarray, state):
        x = pp[0:4].reshape(2, 2) + s * pp[4:8].reshape(2, 2)
        adj_t = np.array([x[1, 1], -x[1, 0], -x[0, 1], x[0, 0]])
        grad = np.zeros(pp.size)
        grad[0:4], grad[4:8] = adj_t, s * adj_t
        return float(x[0, 0] * x[1, 1] - x[0, 1] * x[1, 0]), grad, state

    return q


def _capsize_speed_set(
    p: np.ndarray, cov: np.ndarray, level: float, vmax: float
) -> tuple[tuple[float, float] | None, bool]:
    """The v_c interval by test inversion: speeds v at which the constant term
    det(alpha + v^2 beta) changes sign for some parameters in the confidence ellipsoid.

    v belongs to the set when 0 lies within the profile interval (:func:`profile_interval`)
    of the constant term at v^2.  The set's hull on a grid of :data:`CAPSIZE_GRID_STEP`
    over (0, vmax], ends refined by bisection, is returned with ``open`` = True where it
    reaches the grid's first point or vmax.  This needs no v_c at the estimate, so a fit
    whose own capsize root never crosses zero still gets the speeds the data allow.
    """

    def inside(v: float) -> bool:
        lo, hi, _ = profile_interval(_capsize_constant(v * v), p, cov, None, level)
        return lo <= 0.0 <= hi

    grid = np.arange(CAPSIZE_GRID_STEP, vmax + CAPSIZE_GRID_STEP / 2, CAPSIZE_GRID_STEP)
    hit = np.array([inside(float(v)) for v in grid])
    if not hit.any():
        return None, False
    i, j = int(np.argmax(hit)), int(hit.size - 1 - np.argmax(hit[::-1]))
    ends = []
    for k, step in ((i, -1), (j, 1)):
        if not 0 <= k + step < grid.size:  # the set reaches the edge of the range
            ends.append(float(grid[k]))
            continue
        a, b = float(grid[k]), float(grid[k + step])  # a inside, b outside
        for _ in range(12):
            m = 0.5 * (a + b)
            a, b = (m, b) if inside(m) else (a, m)
        ends.append(a)
    lo, hi = sorted(ends)
    return (lo, hi), bool(hit[0] or hit[-1])


def _critical_speed(g: float, vmax: float, name: str, func):
    """q(p) = v_w or v_c for :func:`profile_interval` (NaN where p has none below vmax)."""

    def q(pp: np.ndarray, state):
        v = critical_speeds(matrices_from_speed_params(pp, g), vmax)[name]
        if v is None:
            return math.nan, np.zeros(pp.size), state
        try:
            return float(v), _critical_gradient(pp, g, v, func, name), v
        except UntrustworthyResult:
            return math.nan, np.zeros(pp.size), state

    return q


@dataclass(frozen=True)
class BodeBand:
    """Bode magnitude and phase of one channel with first-order confidence bands.

    Attributes
    ----------
    output, input : str
        Channel, e.g. ("phi", "T_delta").
    level : float
        Confidence level.
    frequencies : (F,) ndarray
        Angular frequencies [rad/s].
    magnitude_db, magnitude_lower_db, magnitude_upper_db : (F,) ndarray
        20 log10 |G(jw)| and its band [dB] (G in output units per N m).
    phase_deg, phase_lower_deg, phase_upper_deg : (F,) ndarray
        Unwrapped phase of G(jw) and its band [deg].
    std_magnitude_db, std_phase_deg : (F,) ndarray
        Standard errors [dB, deg].
    notes : tuple of str
        What the bands come with (:func:`bikeid.ident.trust.check_trust`).
    """

    output: str
    input: str
    level: float
    frequencies: np.ndarray
    magnitude_db: np.ndarray
    magnitude_lower_db: np.ndarray
    magnitude_upper_db: np.ndarray
    phase_deg: np.ndarray
    phase_lower_deg: np.ndarray
    phase_upper_deg: np.ndarray
    std_magnitude_db: np.ndarray
    std_phase_deg: np.ndarray
    notes: tuple[str, ...] = ()

    def to_json(self) -> dict[str, Any]:
        """The band as plain JSON types.

        Returns
        -------
        dict
            Every attribute, arrays as lists (frequencies [rad/s], dB, deg).
        """
        return to_jsonable({k: getattr(self, k) for k in self.__dataclass_fields__})


def _frequency_response(theta, C, w) -> tuple[np.ndarray, np.ndarray]:
    """G (L, F) and dG/dtheta (L, F, 10) of the canonical model at frequencies w [rad/s]."""
    A, B = canonical_ab(theta)
    L = C.shape[0]
    G = np.empty((L, w.size), dtype=complex)
    dG = np.zeros((L, w.size, 10), dtype=complex)
    for k, wk in enumerate(w):
        R = np.linalg.inv(1j * wk * np.eye(4) - A)
        CR, RB = C @ R, R @ B[:, 0]
        G[:, k] = CR @ B[:, 0]
        for j, (r, c) in enumerate(A_POS):
            dG[:, k, j] = CR[:, r] * RB[c]
        for j, r in enumerate(B_POS):
            dG[:, k, 8 + j] = CR[:, r]
    return G, dG


def _check_frequencies(frequencies) -> np.ndarray:
    w = np.asarray(frequencies, dtype=float)
    if w.ndim != 1 or w.size == 0 or not np.all(np.isfinite(w)) or np.any(w <= 0):
        raise InputError("frequencies must be a non-empty 1-D array of positive values [rad/s]")
    return w


def bode_bands(
    model,
    frequencies,
    v: float | None = None,
    level: float = 0.95,
    *,
    refuse_boundary: bool = True,
    refuse_structure: bool = True,
    refuse_output_error: bool = True,
    refuse_amplitude: bool = True,
) -> list[BodeBand]:
    """Delta-method bands on the Bode magnitude and phase of each output/T_delta channel.

    Parameters
    ----------
    model : ident.pem.CanonicalModel or ident.pem.SpeedCanonicalModel
        Fitted model (outputs ``model.outputs``, input T_delta [N m]).
    frequencies : (F,) array_like
        Angular frequencies [rad/s], positive.
    v : float, optional
        Speed [m/s] (required for a speed-parameterized model).
    level : float, optional
        Confidence level (default 0.95).
    refuse_boundary, refuse_structure, refuse_output_error, refuse_amplitude : bool, optional
        Refuse (default) what ``bikeid identify`` withholds: a fit on its one-step
        predictor's stability boundary, a structure its attached check rejects, an
        output-error fit of an unstable plant, nonlinear-plant runs above the roll
        amplitude whose bias the intervals do not show (:func:`bikeid.ident.trust.check_trust`);
        False gives the intervals with that said in ``notes``.

    Returns
    -------
    list of BodeBand
        One per output, in ``model.outputs`` order; ready for plotting
        (``ax.fill_between(b.frequencies, b.magnitude_lower_db, b.magnitude_upper_db)``).

    Raises
    ------
    InputError
        On a model without covariance, a missing speed, bad frequencies or level.
    WithheldIntervals
        (an UntrustworthyResult) on a refusal not opted out of; its ``reason`` and
        ``remedy`` say why and what to do.
    """
    z = z_value(level)
    w = _check_frequencies(frequencies)
    p, cov, S, speed = _parameters(model, v)
    _, notes = check_trust(model, speed, refuse_boundary=refuse_boundary,
                           refuse_structure=refuse_structure,
                           refuse_output_error=refuse_output_error,
                           refuse_amplitude=refuse_amplitude)  # fmt: skip
    C = output_matrix(model.outputs)[0]
    G, dG = _frequency_response(S @ p, C, w)
    rel = (dG / G[:, :, None]) @ S  # d ln G / dp  (L, F, P)
    out = []
    for i, o in enumerate(model.outputs):
        Jm = rel[i].real * (20.0 / math.log(10.0))
        Jp = rel[i].imag * (180.0 / math.pi)
        sm = np.sqrt(np.maximum(np.einsum("fp,pq,fq->f", Jm, cov, Jm), 0.0))
        sp = np.sqrt(np.maximum(np.einsum("fp,pq,fq->f", Jp, cov, Jp), 0.0))
        mag = 20.0 * np.log10(np.abs(G[i]))
        ph = np.degrees(np.unwrap(np.angle(G[i])))
        out.append(BodeBand(output=o, input="T_delta", level=level, frequencies=w,
                            magnitude_db=mag, magnitude_lower_db=mag - z * sm,
                            magnitude_upper_db=mag + z * sm, phase_deg=ph,
                            phase_lower_deg=ph - z * sp, phase_upper_deg=ph + z * sp,
                            std_magnitude_db=sm, std_phase_deg=sp, notes=notes))  # fmt: skip
    return out


@dataclass(frozen=True)
class MonteCarloDraws:
    """Quantities recomputed on parameter draws from N(p, P_p).

    Attributes
    ----------
    params : (D, P) ndarray
        The D parameter draws (units of ``theta`` or ``params``).
    speed : float
        Speed [m/s] of the eigenvalues and frequency responses.
    eigenvalues : (D, 4) complex ndarray
        Eigenvalues of each draw [1/s], column i paired with the nominal
        :attr:`EigenIntervals.values` [i] (minimum total distance).
    magnitude_db, phase_deg : (D, L, F) ndarray or None
        Bode magnitude [dB] and phase [deg] of each draw (phase = nominal unwrapped phase
        + angle(G_draw / G_nominal)), when frequencies were given.
    v_w, v_c : (D,) ndarray or None
        Critical speeds of each draw [m/s] (NaN where a draw has none), for a
        speed-parameterized model with ``critical=True``.
    """

    params: np.ndarray
    speed: float
    eigenvalues: np.ndarray
    magnitude_db: np.ndarray | None = None
    phase_deg: np.ndarray | None = None
    v_w: np.ndarray | None = None
    v_c: np.ndarray | None = None

    def to_json(self) -> dict[str, Any]:
        """Summary statistics of the draws as plain JSON types.

        Returns
        -------
        dict
            ``draws``, ``speed`` [m/s], per eigenvalue ``mean`` and ``std`` of the real and
            imaginary parts [1/s]; ``v_w``/``v_c`` mean, std [m/s] and the number of draws
            without that speed, when computed.
        """
        ev = self.eigenvalues
        out: dict[str, Any] = {
            "draws": int(self.params.shape[0]),
            "speed": self.speed,
            "eigenvalues": [
                {"mean": complex(np.mean(ev[:, i])),
                 "std": {"re": float(np.std(ev[:, i].real, ddof=1)),
                         "im": float(np.std(ev[:, i].imag, ddof=1))}}
                for i in range(ev.shape[1])
            ],
        }  # fmt: skip
        for name in ("v_w", "v_c"):
            x = getattr(self, name)
            if x is not None:
                ok = x[np.isfinite(x)]
                out[name] = {"mean": float(np.mean(ok)) if ok.size else None,
                             "std": float(np.std(ok, ddof=1)) if ok.size > 1 else None,
                             "missing": int(x.size - ok.size)}  # fmt: skip
        return to_jsonable(out)


def monte_carlo(
    model,
    draws: int,
    rng: np.random.Generator,
    *,
    v: float | None = None,
    frequencies=None,
    critical: bool = False,
    vmax: float = 30.0,
) -> MonteCarloDraws:
    """Recompute eigenvalues (and Bode responses, critical speeds) on parameter draws.

    Parameters
    ----------
    model : ident.pem.CanonicalModel or ident.pem.SpeedCanonicalModel
        Fitted model with its parameter covariance.
    draws : int
        Number of draws D (>= 2).
    rng : numpy.random.Generator
        Source of the draws (p + L z, L L' = P_p by eigendecomposition, so a singular
        covariance is allowed).
    v : float, optional
        Speed [m/s] (required for a speed-parameterized model).
    frequencies : (F,) array_like, optional
        Angular frequencies [rad/s] of the Bode responses; None for none.
    critical : bool, optional
        Also compute v_w and v_c per draw (speed-parameterized model only; ~10 ms a draw).
    vmax : float, optional
        Highest speed searched for critical speeds [m/s].

    Returns
    -------
    MonteCarloDraws
        The draws and the recomputed quantities.

    Raises
    ------
    InputError
        On fewer than 2 draws, a model without covariance, a missing speed, bad
        frequencies, or ``critical=True`` for a fixed-speed model.
    """
    if int(draws) != draws or draws < 2:
        raise InputError(f"draws={draws!r}: need a whole number >= 2")
    p, cov, S, speed = _parameters(model, v)
    if critical and not hasattr(model, "per_speed"):
        raise InputError("critical=True needs a speed-parameterized model (fit_speed_model)")
    P = p[None, :] + rng.standard_normal((int(draws), p.size)) @ _sqrt_cov(cov).T
    nominal = np.sort_complex(np.linalg.eigvals(canonical_ab(S @ p)[0]).astype(complex))
    ev = np.empty((P.shape[0], 4), dtype=complex)
    for k, pk in enumerate(P):
        ev[k] = match_eigenvalues(np.linalg.eigvals(canonical_ab(S @ pk)[0]), nominal)
    mag = phase = None
    if frequencies is not None:
        w = _check_frequencies(frequencies)
        C = output_matrix(model.outputs)[0]
        G0, _ = _frequency_response(S @ p, C, w)
        ph0 = np.degrees(np.unwrap(np.angle(G0), axis=1))
        G = _resp(P @ S.T, C, w)  # (D, L, F)
        mag = 20.0 * np.log10(np.abs(G))
        phase = ph0[None] + np.degrees(np.angle(G / G0[None]))
    vw = vc = None
    if critical:
        vw, vc = np.full(P.shape[0], np.nan), np.full(P.shape[0], np.nan)
        for k, pk in enumerate(P):
            c = critical_speeds(matrices_from_speed_params(pk, float(model.g)), vmax)
            vw[k] = np.nan if c["v_w"] is None else c["v_w"]
            vc[k] = np.nan if c["v_c"] is None else c["v_c"]
    return MonteCarloDraws(params=P, speed=speed, eigenvalues=ev, magnitude_db=mag,
                           phase_deg=phase, v_w=vw, v_c=vc)  # fmt: skip


def _resp(thetas: np.ndarray, C: np.ndarray, w: np.ndarray) -> np.ndarray:
    """G (D, L, F) = C (jw I - A)^-1 B of D canonical models at once (no derivatives)."""
    th = np.atleast_2d(thetas)
    A = np.zeros((th.shape[0], 4, 4))
    A[:, 0, 1] = A[:, 2, 3] = 1.0
    for j, (r, c) in enumerate(A_POS):
        A[:, r, c] = th[:, j]
    B = np.zeros((th.shape[0], 4))
    B[:, B_POS[0]], B[:, B_POS[1]] = th[:, 8], th[:, 9]
    M = 1j * w[None, :, None, None] * np.eye(4) - A[:, None]  # (D, F, 4, 4)
    X = np.linalg.solve(M, np.broadcast_to(B[:, None, :, None], M.shape[:3] + (1,)))[..., 0]
    return np.einsum("lk,dfk->dlf", C, X)
