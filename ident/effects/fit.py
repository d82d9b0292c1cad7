"""Output-error fits of named effects to free decays, with clustered standard errors.

The residuals (:func:`output_residuals`) are the simulated minus the measured roll rate and
steer angle of each decay, divided per window and channel by ||y - mean y||, so that their
sum of squares is a sum of NRMSE^2 (dimensionless).  :func:`fit_effects` fits named effects
by least squares on them (optionally with the weave term of :mod:`bikeid.ident.effects.weave`);
:func:`joint_fit` adds the nonlinear plant through the defect correction
(:func:`bikeid.ident.effects.experiment_model.with_nonlinear_correction`), returning the windows
corrected at the fit (windows are values: nothing is changed in place).  Standard errors are
clustered by window (:func:`effect_std`), with the degrees of freedom of :func:`effect_dof`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import least_squares

from bikeid.dataset.windows import Window
from bikeid.ident.effects.experiment_model import ExperimentModel, with_nonlinear_correction
from bikeid.ident.effects.library import LIBRARY, Candidate
from bikeid.ident.effects.nominal_uncertainty import Calibration
from bikeid.ident.effects.weave import WeaveTerm

__all__ = [
    "EffectEstimate",
    "FitResult",
    "corrected",
    "effect_dof",
    "effect_std",
    "fit_effects",
    "joint_fit",
    "noise_floor",
    "noise_variance_coloured",
    "coloured_noise",
    "residual_noise_floor",
    "output_residuals",
    "trial_residuals",
]

#: Residual [dimensionless, ~O(1) per sample] given to every sample at a trial point the
#: model cannot take, and the clip of every residual (a diverging loop must not overflow
#: the Jacobian).
TRIAL_FAILURE = 1e3


def trial_residuals(fun: Callable[[np.ndarray], np.ndarray]) -> Callable[[np.ndarray], np.ndarray]:
    """``fun`` made safe for a least-squares search over trial points.

    Residuals are clipped to +-:data:`TRIAL_FAILURE` and non-finite ones set to it.  A trial
    point after the first at which ``fun`` raises ``ValueError`` or ``LinAlgError`` (values
    the model cannot take, e.g. a parameter correction leaving a frame without mass, or a
    sampled model so far outside the unit circle that the k-step error's Kalman filter has
    no stabilizing solution, seen on a torque-only no-effect log) gets :data:`TRIAL_FAILURE`
    everywhere, so the optimizer steps back from it; at the first call (the start) the
    error is raised, since there it is the data's or the caller's.

    Parameters
    ----------
    fun : callable
        x -> residuals (1-d ndarray).

    Returns
    -------
    callable
        x -> residuals, as above.
    """
    size: list[int] = []

    def wrapped(x):
        try:
            r = np.asarray(fun(x), dtype=float)
        except (ValueError, np.linalg.LinAlgError):
            if not size:
                raise
            return np.full(size[0], TRIAL_FAILURE)
        size[:] = [r.size]
        return np.where(np.isfinite(r), np.clip(r, -TRIAL_FAILURE, TRIAL_FAILURE), TRIAL_FAILURE)

    return wrapped


def _norms(windows, channels=("phidot", "delta")):
    return [
        [max(np.linalg.norm(getattr(w, c) - getattr(w, c).mean()), 1e-12) for c in channels]
        for w in windows
    ]


def output_residuals(model: ExperimentModel, windows: list[Window], norms=None) -> np.ndarray:
    """Stacked residuals (sim - measured) of roll rate and steer angle, each window and
    channel divided by ||y - mean y|| so the sum of squares is a sum of NRMSE^2.

    Parameters
    ----------
    model : ExperimentModel
        The model simulated on each window (:meth:`ExperimentModel.simulate`).
    windows : list of Window
        Measured free decays.
    norms : list of [float, float], optional
        ||y - mean y|| of roll rate [rad/s] and steer angle [rad] per window (computed when
        not given).

    Returns
    -------
    ndarray
        Dimensionless residuals, window by window (roll rate, then steer angle).
    """
    norms = norms or _norms(windows)
    sims = model.simulate(windows)
    parts = []
    for w, s, nr in zip(windows, sims, norms, strict=True):
        parts.append((s["phidot"] - w.phidot) / nr[0])
        parts.append((s["delta"] - w.delta) / nr[1])
    return np.concatenate(parts)


def noise_floor(windows: list[Window], method: str = "second_difference") -> float:
    """Expected normalized cost of a perfect model: sum n sigma^2 / ||y - ybar||^2.

    Parameters
    ----------
    windows : list of Window
        The decays; sigma^2 of each channel and window is estimated from the measured signal.
    method : str, optional
        ``"second_difference"`` (default): sigma^2 = mean((y[k+1] - 2 y[k] + y[k-1])^2) / 6,
        exact for white noise on a locally linear signal, but an AR(1) noise of coefficient
        a puts only (1 - a)(3 - a) / 3 of its variance there (0.23 at a = 0.7).
        ``"coloured"``: :func:`noise_variance_coloured`, which also fits the noise's
        lag-one correlation (AR(1), 0 <= a <= 0.95).

    Returns
    -------
    float
        Dimensionless cost (comparable with the sum of squares of :func:`output_residuals`).

    Raises
    ------
    ValueError
        If ``method`` is unknown.
    """
    if method not in ("second_difference", "coloured"):
        raise ValueError(f"unknown noise-floor method {method!r}; use 'second_difference' or "
                         "'coloured'")  # fmt: skip
    tot = 0.0
    for w, nr in zip(windows, _norms(windows), strict=True):
        for y, ni in ((w.phidot, nr[0]), (w.delta, nr[1])):
            if method == "coloured":
                s2 = noise_variance_coloured(y)
            else:
                s2 = np.mean(np.diff(y, 2) ** 2) / 6.0
            tot += y.size * s2 / ni**2
    return float(tot)


def noise_variance_coloured(y: np.ndarray, spacings: int = 4) -> float:
    """Variance of AR(1)-coloured noise on a smooth signal, from spaced second differences.

    The second difference at spacing m, y[k+m] - 2 y[k] + y[k-m], has the variance
    2 s2 (3 - 4 a^m + a^2m) for AR(1) noise of variance s2 and coefficient a, and about
    (ydd m^2)^2 for a smooth signal.  v(1..spacings) is fitted by these two terms with
    s2, d >= 0 (non-negative least squares in relative error at each a of a 0.05 grid on
    [0, 0.95], the best a kept).  a = 0 and no signal term is the second-difference floor.

    Parameters
    ----------
    y : ndarray
        One channel of one window (any unit u; at least ``2 spacings + 2`` samples).
    spacings : int, optional
        Largest spacing m [samples].

    Returns
    -------
    float
        The noise variance s2 [u^2].
    """
    return coloured_noise(y, spacings)[0]


def coloured_noise(y: np.ndarray, spacings: int = 4) -> tuple[float, float]:
    """Variance and lag-one coefficient of AR(1) noise on a smooth signal
    (:func:`noise_variance_coloured`'s fit, both numbers).

    Parameters
    ----------
    y : ndarray
        One channel of one window (any unit u).
    spacings : int, optional
        Largest spacing m [samples].

    Returns
    -------
    s2 : float
        Noise variance [u^2] (0 when a spaced difference vanishes).
    a : float
        Lag-one coefficient in [0, 0.95].
    """
    from scipy.optimize import nnls

    y = np.asarray(y, dtype=float)
    m = np.arange(1, min(spacings, (y.size - 2) // 2) + 1)
    v = np.array([np.mean((y[2 * k :] - 2 * y[k:-k] + y[: -2 * k]) ** 2) for k in m])
    if not np.all(v > 0):
        return 0.0, 0.0
    best = (np.inf, 0.0, 0.0)
    for a in np.arange(0.0, 0.951, 0.05):
        A = np.column_stack([2 * (3 - 4 * a**m + a ** (2 * m)), m.astype(float) ** 4])
        x, rn = nnls(A / v[:, None], np.ones(m.size))
        if rn < best[0]:
            best = (rn, float(x[0]), float(a))
    return best[1], best[2]


def residual_noise_floor(r: np.ndarray, sizes: list[int], lags: int = 8) -> float:
    """Noise part of a residual's cost, from the variogram of each window's residual.

    The residual of a good model is noise plus a small smooth error; its semivariogram
    g(h) = mean((r[k+h] - r[k])^2) / 2 is fitted by s2 (1 - a^h) + c h^2 (AR(1) noise of
    variance s2 and coefficient a on a grid of 0.05 in [0, 0.95], smooth error c h^2;
    s2, c >= 0), and n s2 summed over the pieces.

    Parameters
    ----------
    r : ndarray
        Stacked normalized residuals (:func:`output_residuals`).
    sizes : list of int
        Length of each piece (one window's channel) in order.
    lags : int, optional
        Largest lag h [samples].

    Returns
    -------
    float
        The noise floor in the cost's units (dimensionless).
    """
    from scipy.optimize import nnls

    tot, i = 0.0, 0
    for n in sizes:
        y = r[i : i + n]
        i += n
        h = np.arange(1, min(lags, n - 2) + 1)
        g = np.array([np.mean((y[k:] - y[:-k]) ** 2) / 2 for k in h])
        best = (np.inf, 0.0)
        for a in np.arange(0.0, 0.951, 0.05):
            x, rn = nnls(np.column_stack([1 - a**h, h.astype(float) ** 2]), g)
            if rn < best[0]:
                best = (rn, float(x[0]))
        tot += n * best[1]
    return float(tot)


@dataclass
class EffectEstimate:
    """One effect's estimate.

    ``value`` and ``std`` (clustered standard error) in ``unit``; ``t`` = |value - absent| /
    std; ``explained``: fraction of the nominal cost removed; ``accepted``: selected.

    Attributes
    ----------
    name : str
        Effect name (a key of :data:`bikeid.ident.effects.library.LIBRARY`).
    value : float
        Estimated value, in ``unit``.
    std : float
        Window-clustered standard error, in ``unit``.
    unit : str
        The effect's SI unit as text (e.g. ``"N m s/rad"``).
    t : float
        |value - absent value| / std (dimensionless).
    explained : float
        Fraction of the cost removed when the effect is added: in a selection round's
        ranking, of that round's starting cost on the fit windows (weave term included);
        for the accepted effects of :class:`bikeid.ident.effects.selection.Identification`,
        the final model's explained fraction (the same for all of them).
    accepted : bool
        Whether the selection kept the effect.
    p_value : float
        Two-sided p-value of ``t`` against Student's t with ``dof`` degrees of freedom
        (:func:`bikeid.ident.effects.acceptance.t_p_value`; nan when not tested).
    dof : float
        Degrees of freedom of the standard error (:func:`effect_dof`).
    """

    name: str
    value: float
    std: float
    unit: str
    t: float
    explained: float = 0.0  # fraction of the nominal cost removed when added
    accepted: bool = False
    p_value: float = float("nan")
    dof: float = float("inf")

    def as_dict(self) -> dict:
        """The estimate as a JSON-able dict (the keys of the attributes).

        Returns
        -------
        dict
            ``name``, ``value``, ``std``, ``unit``, ``t``, ``explained``, ``accepted``,
            ``p_value``, ``dof``.
        """
        return {
            "name": self.name, "value": self.value, "std": self.std, "unit": self.unit,
            "t": self.t, "explained": self.explained, "accepted": self.accepted,
            "p_value": self.p_value, "dof": self.dof,
        }  # fmt: skip


@dataclass
class FitResult:
    """A fit: the fitted ``model``, the fitted ``values`` and their standard errors ``std``
    (effect units) and the final ``cost`` (sum of squared normalized residuals, with the
    weave term when one was given).

    Attributes
    ----------
    model : ExperimentModel
        The model with the fitted effect values.
    values : dict of str to float
        Fitted value of each named effect (the effect's unit).
    std : dict of str to float
        Window-clustered standard error of each value (same unit).
    cost : float
        Final sum of squared normalized residuals (dimensionless).
    calibration : Calibration or None
        The nominal parameters' offsets fitted with the effects (``calibration=`` of
        :func:`fit_effects`), None when they were not fitted.
    windows : list of Window or None
        The windows the fit ran on, with the defect correction it used (for
        :func:`joint_fit` with ``nonlinear``: taken at the fit before the last refit).
    dof : float
        Degrees of freedom of the standard errors (:func:`effect_dof`; inf when none were
        computed).
    """

    model: ExperimentModel
    values: dict[str, float]
    std: dict[str, float]
    cost: float
    calibration: Calibration | None = None
    windows: list[Window] | None = None
    dof: float = float("inf")


def fit_effects(
    model: ExperimentModel,
    windows: list[Window],
    names: list[str],
    start: dict | None = None,
    weave: WeaveTerm | None = None,
    calibration: Calibration | None = None,
) -> FitResult:
    """Output-error least squares of the named effects (others kept as in ``model``);
    with ``weave``, the weave-eigenvalue residuals are appended (one more cluster for the
    standard errors) and ``cost`` includes them; with ``calibration``, the nominal
    parameters' offsets are fitted too, within their uncertainty's box
    (:mod:`bikeid.ident.effects.nominal_uncertainty`; the model's parameters become
    ``calibration``'s at the fitted offsets).

    Parameters
    ----------
    model : ExperimentModel
        Start model; effects not in ``names`` stay as they are.
    windows : list of Window
        The decays.
    names : list of str
        Registry names to fit (library settings :data:`bikeid.ident.effects.library.LIBRARY`;
        other names: additive, scale 0.1, unbounded).
    start : dict, optional
        Start values by name [effect units] (default: those of ``model``).
    weave : WeaveTerm, optional
        Weave-eigenvalue residuals to append.
    calibration : Calibration, optional
        Start offsets of the nominal parameters and their box (bounds +-1 half-width).

    Returns
    -------
    FitResult
        Fitted model, values and window-clustered standard errors [effect units; infinite
        for a value held on its bound], final cost (dimensionless), and the fitted
        ``calibration`` (when one was given).
    """
    extra = weave is not None and weave.weight > 0 and bool(weave.targets)
    ncal = len(calibration.offsets) if calibration is not None else 0
    if not names and not ncal:
        r = output_residuals(model, windows)
        if extra:
            r = np.concatenate([r, weave.residuals(model)])
        return FitResult(model, {}, {}, float(r @ r), windows=windows)
    norms = _norms(windows)
    cands = [LIBRARY[n] if n in LIBRARY else Candidate(n, "additive", 0.1) for n in names]
    start = start or {}
    x0 = np.array([(start.get(c.name, model.e(c.name)) - c.absent) / c.scale for c in cands])
    lo = np.array([(c.lower - c.absent) / c.scale if c.lower > -np.inf else -np.inf for c in cands])
    hi = np.array([(c.upper - c.absent) / c.scale if c.upper < np.inf else np.inf for c in cands])
    lo = np.where(np.isfinite(lo), lo, -np.inf)
    if ncal:  # the nominal offsets, in half-widths, bounded by the box
        x0 = np.concatenate([x0, np.clip(calibration.offsets, -1 + 1e-9, 1 - 1e-9)])
        lo, hi = np.concatenate([lo, -np.ones(ncal)]), np.concatenate([hi, np.ones(ncal)])
    x0 = np.clip(x0, lo + 1e-9, hi - 1e-9)
    k = len(cands)

    def mk(x):
        m = model.with_effects(
            **{c.name: c.absent + c.scale * xi for c, xi in zip(cands, x[:k], strict=True)}
        )
        return replace(m, p=calibration.params(x[k:])) if ncal else m

    def fun(x):
        m = mk(x)
        r = output_residuals(m, windows, norms)  # ~O(1) per sample (normalized)
        if extra:
            try:
                r = np.concatenate([r, weave.residuals(m)])
            except ValueError:  # a trial value the loop roots cannot take
                r = np.concatenate([r, np.full(2 * len(weave.targets), TRIAL_FAILURE)])
        return r

    sol = least_squares(trial_residuals(fun), x0, bounds=(lo, hi), x_scale=1.0,
                        diff_step=1e-3, max_nfev=60)  # fmt: skip
    r = sol.fun
    sizes = [2 * w.n for w in windows] + ([2 * len(weave.targets)] if extra else [])
    # a value on its bound (an active constraint: an effect at a plausibility bound or at
    # absent = bound, an offset on its box's edge) is held there, not estimated: an effect on
    # its bound gets an infinite standard error (t = 0: no evidence), an offset on the edge 0.
    # The offsets inside the box stay in the covariance, so an effect's standard error counts
    # what they can mimic; their box enters as prior information (uniform on [-1, 1]:
    # variance 1/3 half-widths^2), so a direction the decays do not resolve cannot dilute it
    # beyond what the box allows
    std, dof = bounded_std(sol, lo, hi, k, sizes)
    vals = {c.name: c.absent + c.scale * xi for c, xi in zip(cands, sol.x[:k], strict=True)}
    stds = {c.name: c.scale * si for c, si in zip(cands, std[:k], strict=True)}
    cal = replace(calibration, offsets=sol.x[k:].copy(), std=std[k:]) if ncal else None
    return FitResult(mk(sol.x), vals, stds, float(r @ r), cal, windows, dof)


def joint_fit(
    model: ExperimentModel,
    windows: list[Window],
    names: list[str],
    start: dict | None = None,
    nonlinear: bool = False,
    weave: WeaveTerm | None = None,
    calibration: Calibration | None = None,
) -> FitResult:
    """Fit the named effects jointly on all windows (and ``weave``, see
    :func:`fit_effects`); with ``nonlinear`` the defect
    correction is taken at ``model`` first (unless a window already carries one) and again
    at the fitted model twice (each moves the linearization point of the correction to the
    fit).  The windows given are not changed; the result's ``windows`` are those of the last
    refit (corrected at the fit before it).

    Parameters
    ----------
    model, windows, names, start, weave, calibration
        As for :func:`fit_effects` (the calibration's offsets are refitted each time).
    nonlinear : bool, optional
        Nonlinear plant by defect correction.

    Returns
    -------
    FitResult
        As :func:`fit_effects`, of the last refit, with the windows it ran on.
    """
    if nonlinear and all(w.correction is None for w in windows):
        windows = corrected(windows, model, True)
    res = fit_effects(model, windows, names, start, weave, calibration)
    for _ in range(2 if nonlinear and (names or calibration) else 0):
        windows = corrected(windows, res.model, True)
        res = fit_effects(model, windows, names, res.values, weave, res.calibration)
    return res


def bounded_std(sol, lo: np.ndarray, hi: np.ndarray, k: int,
                sizes: list[int]) -> tuple[np.ndarray, float]:  # fmt: skip
    """Standard errors and degrees of freedom of a bounded fit of k effects then offsets.

    A value on its bound is held there, not estimated: an effect (the first ``k``) on its
    bound gets an infinite standard error (t = 0: no evidence), an offset on its box's edge
    0.  The offsets inside the box stay in the covariance with the box as prior information
    (uniform on [-1, 1]: variance 1/3 half-widths^2, :func:`effect_std`'s ``prior`` 3).

    Parameters
    ----------
    sol : scipy.optimize.OptimizeResult
        ``least_squares``' result (``x``, ``jac``, ``fun``).
    lo, hi : ndarray
        The bounds of ``sol.x``.
    k : int
        Number of effects (the rest are calibration offsets in half-widths).
    sizes : list of int
        Residual count of each cluster (window).

    Returns
    -------
    std : ndarray
        Standard errors in the fit's (scaled) units.
    dof : float
        Their degrees of freedom (:func:`effect_dof`; infinite with nothing free).
    """
    free = (sol.x - lo > 1e-6) & (hi - sol.x > 1e-6)
    is_effect = np.arange(sol.x.size) < k
    std = np.where(is_effect, np.inf, 0.0)
    dof = float("inf")
    if free.any():
        r = sol.fun
        std[free] = effect_std(sol.jac[:, free], r, sizes, np.where(is_effect, 0.0, 3.0)[free])
        dof = effect_dof(r, sizes, int(free.sum()))
    return std, dof


def effect_dof(r: np.ndarray, sizes: list[int], p: int) -> float:
    """Degrees of freedom of :func:`effect_std`'s standard errors.

    The cluster-robust sandwich over G clusters has G - 1 degrees of freedom (the
    small-cluster reference distribution of Cameron, Gelbach & Miller 2008 is Student's t
    with G - 1); the fallback of fewer than p + 2 clusters has N_eff - p, N_eff the sample
    count reduced for the residual's lag-one autocorrelation (as :func:`effect_std`).

    Parameters
    ----------
    r : (n,) ndarray
        Residuals at the estimate.
    sizes : list of int
        Residual count of each cluster, in order.
    p : int
        Number of estimated parameters.

    Returns
    -------
    float
        Degrees of freedom (> 0).
    """
    n, g = r.size, len(sizes)
    if g >= p + 2 and sum(sizes) == n:
        return float(g - 1)
    r1 = float(np.clip(np.corrcoef(r[:-1], r[1:])[0, 1], 0.0, 0.99)) if n > 3 else 0.0
    neff = max(n * (1 - r1) / (1 + r1), p + 1)
    return float(neff - p)


def effect_std(
    J: np.ndarray, r: np.ndarray, sizes: list[int], prior: np.ndarray | None = None
) -> np.ndarray:
    """Standard errors of output-error estimates, clustered by window.

    The residual of one decay is smooth and mostly model error, so its samples are far
    from independent, while separate pushes are: the covariance is the cluster-robust
    sandwich (J^T J)^-1 (sum_g J_g^T r_g r_g^T J_g) (J^T J)^-1 G / (G - 1) over the G
    windows (Liang & Zeger 1986).  With fewer than p + 2 windows it falls back to
    s^2 (J^T J)^-1 with the sample count reduced for the lag-1 autocorrelation r1,
    N_eff = N (1 - r1) / (1 + r1).

    Parameters
    ----------
    J : (n, p) ndarray
        Jacobian of the residuals with respect to the (scaled) parameters.
    r : (n,) ndarray
        Residuals at the estimate.
    sizes : list of int
        Residual count of each cluster (window), in order.
    prior : (p,) ndarray, optional
        Prior information of each parameter [1 / its scaled unit^2] (0: none), combined with
        the data's covariance C as (C^-1 + diag(prior))^-1 (e.g. 3 for an offset uniform on
        [-1, 1], variance 1/3).

    Returns
    -------
    (p,) ndarray
        Standard errors in the parameters' (scaled) units.
    """
    n, p = J.shape
    try:
        bread = np.linalg.pinv(J.T @ J)
    except np.linalg.LinAlgError:
        return np.full(p, np.inf)
    g = len(sizes)
    if g >= p + 2 and sum(sizes) == n:
        meat = np.zeros((p, p))
        i = 0
        for m in sizes:
            u = J[i : i + m].T @ r[i : i + m]
            meat += np.outer(u, u)
            i += m
        cov = bread @ meat @ bread * g / (g - 1)
    else:
        r1 = float(np.clip(np.corrcoef(r[:-1], r[1:])[0, 1], 0.0, 0.99)) if n > 3 else 0.0
        neff = max(n * (1 - r1) / (1 + r1), p + 1)
        cov = float(r @ r) / (neff - p) * bread
    if prior is not None and np.any(prior > 0):
        cov = np.linalg.pinv(np.linalg.pinv(cov) + np.diag(prior))
    return np.sqrt(np.maximum(np.diag(cov), 0.0))


def corrected(windows: list[Window], model: ExperimentModel, nonlinear: bool) -> list[Window]:
    """The windows with the nonlinear plant's defect correction at ``model`` when ``nonlinear``.

    Parameters
    ----------
    windows : list of Window
        The windows (not changed).
    model : ExperimentModel
        The linearization point of the correction.
    nonlinear : bool
        False: the windows are returned as they are (in a new list).

    Returns
    -------
    list of Window
        New windows (:func:`bikeid.ident.effects.experiment_model.with_nonlinear_correction`)
        or the same ones.
    """
    return with_nonlinear_correction(windows, model) if nonlinear else list(windows)
