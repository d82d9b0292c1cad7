"""The weave eigenvalue of free decays: its fit, its uncertainty, and a fit term for it.

The measured weave of a speed is the median (real and imaginary parts separately) of the
damped-oscillation fits :func:`decay_eigenvalue` to its decays; :func:`weave_uncertainty`
is its bootstrap standard error.  A model is compared with it through the *same* estimator
applied to the model's simulated decays (:func:`simulated_weave`, :func:`weave_error`), so
the estimator's bias on large nonlinear decays cancels.  :class:`WeaveTerm` adds the
measured weave of each speed as extra data of an output-error fit
(:func:`bikeid.ident.effects.fit.fit_effects`).

Eigenvalues are in 1/s (sigma + i omega, omega in rad/s).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numba
import numpy as np
from scipy.optimize import least_squares

from bikeid.dataset.windows import Window
from bikeid.ident.effects.experiment_model import ExperimentModel

__all__ = [
    "WeaveTerm",
    "decay_eigenvalue",
    "median_complex",
    "simulated_weave",
    "weave_error",
    "weave_targets",
    "weave_uncertainty",
]


@dataclass(frozen=True)
class WeaveTerm:
    """The measured weave eigenvalues as extra data of an output-error fit.

    ``targets``: per speed (speed key, mean sensor speed [m/s], measured weave [1/s], its
    standard error [1/s]) from :func:`weave_targets`; ``weight``: the factor on the
    residuals (lambda_model + offset - lambda_data) / standard error (real and imaginary
    parts), lambda_model the loop root nearest to the data (:meth:`ExperimentModel.weave`).
    ``offsets`` (see :meth:`at`) carry the difference between the estimator used on the data
    (damped-oscillation fit of nonlinear decays) and the linear loop root.

    Attributes
    ----------
    weight : float
        Factor on the normalized weave residuals (dimensionless; 0 switches the term off).
    targets : tuple of (float, float, complex, float)
        Per speed: speed key, mean sensor speed [m/s], measured weave eigenvalue [1/s]
        and its standard error [1/s].
    offsets : tuple of complex
        Per target: estimator offset [1/s] added to the model's loop root (empty: none).
    """

    weight: float
    targets: tuple[tuple[float, float, complex, float], ...]
    offsets: tuple[complex, ...] = ()

    def residuals(self, model: ExperimentModel) -> np.ndarray:
        """The weighted weave residuals of ``model``.

        Parameters
        ----------
        model : ExperimentModel
            The model whose loop roots (:meth:`ExperimentModel.weave`) are compared.

        Returns
        -------
        (2 * len(targets),) ndarray
            ``weight`` (lambda_model + offset - lambda_data) / standard error, real parts then
            imaginary parts (dimensionless).
        """
        off = self.offsets or (0j,) * len(self.targets)
        d = [(model.weave(vs, lam) + o - lam) / unc
             for (_k, vs, lam, unc), o in zip(self.targets, off, strict=True)]  # fmt: skip
        return self.weight * np.concatenate([np.real(d), np.imag(d)])

    def at(self, model: ExperimentModel, windows: list[Window]) -> WeaveTerm:
        """Offsets at ``model``: per speed, the median decay fit of the model's simulated
        decays (windows corrected at ``model`` when the plant is nonlinear) minus the loop
        root, so that the term compares like with like at ``model`` and to first order near
        it (the defect correction of the signals, applied to the eigenvalue estimator).

        Parameters
        ----------
        model : ExperimentModel
            Where the offsets are taken.
        windows : list of Window
            The decays the targets came from.

        Returns
        -------
        WeaveTerm
            A copy with ``offsets`` [1/s], one per target.
        """
        sims = model.simulate(windows)
        off = []
        for key, vs, lam, _unc in self.targets:
            idx = [i for i, w in enumerate(windows) if w.kind == "decay" and _key(w) == key]
            fitted = simulated_weave([windows[i] for i in idx], [sims[i] for i in idx])
            off.append(fitted - model.weave(vs, lam))
        return replace(self, offsets=tuple(off))


def _key(w: Window) -> float:
    return round(w.speed, 1)


def weave_targets(
    windows: list[Window], lams: list[complex] | None = None
) -> tuple[tuple[float, float, complex, float], ...]:
    """(speed key, mean sensor speed, measured weave, standard error) of each speed with
    >= 3 decays: the median of :func:`decay_eigenvalue` over the decays and
    :func:`weave_uncertainty`.  ``lams``: the windows' decay fits if already computed.

    Parameters
    ----------
    windows : list of Window
        Decays (other kinds are ignored), grouped by speed to 0.1 m/s.
    lams : list of complex, optional
        :func:`decay_eigenvalue` of each window [1/s].

    Returns
    -------
    tuple of (float, float, complex, float)
        Speed key [m/s], mean sensor speed [m/s], measured weave [1/s], standard error [1/s].
    """
    if lams is None:
        lams = [decay_eigenvalue(w) if w.kind == "decay" else 0j for w in windows]
    groups: dict[float, list[int]] = {}
    for i, w in enumerate(windows):
        if w.kind == "decay":
            groups.setdefault(_key(w), []).append(i)
    out = []
    for key, idx in groups.items():
        if len(idx) >= 3:
            g = [lams[i] for i in idx]
            lam = median_complex(g)
            vs = float(np.mean([np.mean(windows[i].v_sensor) for i in idx]))
            out.append((key, vs, lam, weave_uncertainty(g) * abs(lam)))
    return tuple(out)


def decay_eigenvalue(w: Window) -> complex:
    """Weave eigenvalue sigma + i omega fitted to one free decay.

    Model (both channels share sigma, omega): y_c(t) = e^{sigma t}(a_c cos wt + b_c sin wt)
    + d_c e^{-p t} + o_c; sigma, omega, p by nonlinear LS, the rest linear (variable
    projection).  Start: omega from the steer-angle zero crossings.

    Parameters
    ----------
    w : Window
        A free decay (roll rate [rad/s] and steer angle [rad]; sample period
        ``w.meta["dt"]`` [s], 0.01 s, the steer-by-wire logs', when it has none).

    Returns
    -------
    complex
        sigma + i omega [1/s].

    Raises
    ------
    ValueError
        If the steer angle or roll rate of the window is non-finite, overflows in its
        standard deviation, or is constant (the fit would be nan), naming the file and the
        window.
    """
    t = np.arange(w.n) * float(w.meta.get("dt", 0.01))
    for name in ("delta", "phidot"):
        y = np.asarray(getattr(w, name), dtype=float)
        sd = float(np.std(y)) if np.all(np.isfinite(y)) else float("nan")
        if not (np.isfinite(sd) and sd > 0):
            what = "no variation" if sd == 0 else "non-finite samples or spread (overflow)"
            raise ValueError(
                f"decay_eigenvalue: {w.file}: window at row {w.start}: {name!r} has {what}; "
                "no weave can be fitted (load windows through bikeid.dataset)"
            )
    ys = np.column_stack([w.delta / np.std(w.delta), w.phidot / np.std(w.phidot)]).astype(float)

    last: list[np.ndarray] = []  # [th, residuals] of the last evaluation

    def fun(th):
        f = _projected_residuals(th, t, ys)
        last[:] = [th.copy(), f]
        return f

    def jac(th):  # scipy asks for the Jacobian where it has just evaluated the residuals
        f0 = last[1] if last and np.array_equal(last[0], th) else _projected_residuals(th, t, ys)
        return _projected_jacobian(th, t, ys, f0)

    best = None
    for om0 in (5.0, 7.5, 10.0, 12.5):
        sol = least_squares(fun, [-2.0, om0, 1.0], jac=jac, bounds=(_LOWER, _UPPER))
        if best is None or sol.cost < best.cost:
            best = sol
    return complex(best.x[0], best.x[1])


#: Bounds of (sigma [1/s], omega [rad/s], p [1/s]) in :func:`decay_eigenvalue`.
_LOWER = np.array([-30.0, 1.0, 0.0])
_UPPER = np.array([10.0, 40.0, 60.0])
#: scipy's relative step of a forward difference, sqrt of the float64 machine epsilon
#: (``scipy.optimize._numdiff``, method '2-point').
_FORWARD_STEP = float(np.finfo(np.float64).eps ** 0.5)


@numba.njit(cache=True)
def _projected_jacobian(th, t, ys, f0):  # pragma: no cover - compiled
    """Forward-difference Jacobian of :func:`_projected_residuals` at th (``f0``: the
    residuals there, which scipy has just evaluated), computed as
    ``least_squares(jac='2-point')`` computes it (scipy 1.17's step, sqrt(eps) max(1,
    |th_i|) with the sign of th_i, turned back where it would cross a bound of
    :data:`_LOWER`, :data:`_UPPER` (always wider than the step); the same differences and
    quotients), so the fit's iterates are bit-identical while scipy's Python
    finite-difference machinery is skipped: the decay fits of ``measured fit`` 27 % less
    CPU, and a further evaluation of the residuals per Jacobian less by taking ``f0``
    (tests/ident/effects/test_weave_fit.py checks the identity)."""
    n = th.shape[0]
    jt = np.empty((n, f0.shape[0]))
    for i in range(n):
        sign = 1.0 if th[i] >= 0 else -1.0
        h = _FORWARD_STEP * sign * max(1.0, abs(th[i]))
        x = th[i] + h
        if x < _LOWER[i] or x > _UPPER[i]:
            h = -h
        th1 = th.copy()
        th1[i] = th[i] + h
        dx = (th[i] + h) - th[i]
        f1 = _projected_residuals(th1, t, ys)
        for k in range(f0.shape[0]):
            jt[i, k] = (f1[k] - f0[k]) / dx
    return jt.T


@numba.njit(cache=True)
def _projected_residuals(th, t, ys):  # pragma: no cover - compiled
    """Residuals (channel 0 then 1) of the linear least-squares fit of the basis
    [e^{sigma t} cos wt, e^{sigma t} sin wt, e^{-p t}, 1] to each column of ``ys``, at
    th = (sigma, omega, p) (variable projection; LAPACK gelsd as numpy's lstsq, with its
    default cutoff eps * max(n, 4), so the fits are bit-identical): 0.04 ms per call on a
    1 s decay against 0.21 ms in numpy (cProfile of ``measured fit``, 147,600 calls)."""
    sg, om, pp = th[0], th[1], th[2]
    n = t.shape[0]
    basis = np.empty((n, 4))
    for i in range(n):
        e = np.exp(sg * t[i])
        basis[i, 0] = e * np.cos(om * t[i])
        basis[i, 1] = e * np.sin(om * t[i])
        basis[i, 2] = np.exp(-pp * t[i])
        basis[i, 3] = 1.0
    out = np.empty(2 * n)
    for c in range(ys.shape[1]):
        y = np.ascontiguousarray(ys[:, c])
        coef = np.linalg.lstsq(basis, y, rcond=2.220446049250313e-16 * max(n, 4))[0]
        fit = basis @ coef
        for i in range(n):
            out[c * n + i] = fit[i] - y[i]
    return out


def weave_error(windows: list[Window], sims, lam_data) -> float:
    """Mean relative weave-eigenvalue error of simulated decays against measured ones.

    Windows are grouped by (file, speed to 0.1 m/s); per group the weave of the data is
    the median (real, imaginary parts) of ``lam_data`` (:func:`decay_eigenvalue` of each
    measured window) and that of the model the median of the same fit applied to the
    simulated decays ``sims`` from the same initial states.  Returns the mean over groups
    of |lambda_model - lambda_data| / |lambda_data| (the ``weave_error`` of
    :func:`bikeid.ident.effects.diagnostics.evaluate`).

    Parameters
    ----------
    windows : list of Window
        The measured decays.
    sims : list of dict
        :meth:`ExperimentModel.simulate` of each window.
    lam_data : list of complex
        :func:`decay_eigenvalue` of each window [1/s].

    Returns
    -------
    float
        Mean relative error (dimensionless).
    """
    groups: dict[tuple, list[int]] = {}
    for i, w in enumerate(windows):
        groups.setdefault((w.file, round(w.speed, 1)), []).append(i)
    errs = []
    for idx in groups.values():
        lam_d = median_complex([lam_data[i] for i in idx])
        lam_m = simulated_weave([windows[i] for i in idx], [sims[i] for i in idx])
        errs.append(abs(lam_m - lam_d) / abs(lam_d))
    return float(np.mean(errs))


def simulated_weave(windows: list[Window], sims: list[dict[str, np.ndarray]]) -> complex:
    """Median weave of the damped-oscillation fits to simulated decays.

    The same estimator as for the measured ones (:func:`decay_eigenvalue`).

    Parameters
    ----------
    windows : list of Window
        The decays (their timing and speed; the signals are replaced).
    sims : list of dict
        :meth:`ExperimentModel.simulate` output per window (``phidot`` [rad/s], ``delta``
        [rad]).

    Returns
    -------
    complex
        Median (real, imaginary parts) of the fitted weave eigenvalues [1/s].
    """
    return median_complex(
        [decay_eigenvalue(replace(w, phidot=s["phidot"], delta=s["delta"]))
         for w, s in zip(windows, sims, strict=True)]
    )  # fmt: skip


def weave_uncertainty(lams, resamples: int = 2000, seed: int = 0) -> float:
    """Relative standard error of the measured weave (the median of the per-decay fits
    ``lams``): rms of |median(resample) - median| / |median| over bootstrap resamples of
    the decays (fixed seed).  A model equal to the truth would still show a weave error
    of about this size; nan with fewer than 3 decays.

    Parameters
    ----------
    lams : array_like of complex
        Per-decay weave fits [1/s].
    resamples : int, optional
        Bootstrap resamples.
    seed : int, optional
        Generator seed.

    Returns
    -------
    float
        Relative standard error (dimensionless), nan with fewer than 3 decays.
    """
    lams = np.asarray(lams, complex)
    if lams.size < 3:
        return float("nan")
    med = median_complex(lams)
    idx = np.random.default_rng(seed).integers(0, lams.size, (resamples, lams.size))
    res = lams[idx]
    bs = np.median(res.real, axis=1) + 1j * np.median(res.imag, axis=1)
    return float(np.sqrt(np.mean(np.abs(bs - med) ** 2)) / abs(med))


def median_complex(lams) -> complex:
    """Median of the real and of the imaginary parts, separately.

    Parameters
    ----------
    lams : array_like of complex
        Eigenvalues [1/s].

    Returns
    -------
    complex
        median(Re) + i median(Im) [1/s].

    Raises
    ------
    ValueError
        If ``lams`` is empty or holds a non-finite eigenvalue.
    """
    lams = np.asarray(lams, dtype=complex)
    if lams.size == 0 or not np.all(np.isfinite(lams)):
        raise ValueError(
            f"median_complex: need finite eigenvalues, got {lams.size} values with "
            f"{int((~np.isfinite(lams)).sum())} non-finite"
        )
    return complex(np.median(np.real(lams)), np.median(np.imag(lams)))
