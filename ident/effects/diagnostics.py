"""Diagnostics of the experiment model's misfit: equation error, ranking, spectra, symmetry,
and the before/after evaluation of an augmented model.

* :func:`equation_error`: roll- and steer-row equation errors in Moore & Hubbard's form
  ``M q'' + v C1 q' + (g K0 + v^2 K2) q = [0, T]`` and the additive candidates' regressors;
  :func:`err_ranking` ranks those by the orthogonal error-reduction ratio (FROLS).
* :func:`spectrum` (Welch) and :func:`push_asymmetry` (does the error depend on the push
  direction?).  Residual whiteness and cross-correlation: :func:`bikeid.ident.validate.whiteness`
  and :func:`bikeid.ident.validate.cross_correlation`.
* :func:`evaluate`: decay error and weave error before (nominal) and after (augmented), per
  file and overall.
"""

from __future__ import annotations

import numpy as np
from scipy import signal

from bikeid.dataset.windows import Window
from bikeid.ident.effects.before_after import before_after, zero_motion_error
from bikeid.ident.effects.experiment_model import COULOMB_EPS, ExperimentModel, window_errors
from bikeid.ident.effects.fit import corrected
from bikeid.ident.effects.weave import (
    decay_eigenvalue,
    median_complex,
    simulated_weave,
    weave_uncertainty,
)
from bikeid.sim.blas import single_threaded_blas
from bikeid.sim.effect_registry import EFFECTS, V_FLOOR

__all__ = [
    "before_after_summary",
    "equation_error",
    "err_ranking",
    "evaluate",
    "evaluate_windows",
    "push_asymmetry",
    "spectrum",
]


def _deriv(y: np.ndarray, dt: float = 0.01, fc: float = 15.0) -> np.ndarray:
    b, a = signal.butter(2, fc / (0.5 / dt))
    pad = min(3 * max(len(a), len(b)), y.size - 1)
    return np.gradient(signal.filtfilt(b, a, y, padlen=pad), dt)


def equation_error(model: ExperimentModel, windows: list[Window]) -> dict[str, np.ndarray]:
    """Roll- and steer-row equation errors and additive candidate regressors.

    r = [0, T] - (M q'' + v C1 q' + (g K0 + v^2 K2) q), with q'' from filtered central
    differences of the measured rates (2nd-order 15 Hz Butterworth, zero phase) and T the
    logged command.  Regressors (per unit of effect): for the steer row, the law of every
    library entry on the steer equation (:mod:`bikeid.sim.effect_registry`, e.g.
    steer_viscous_damping -deltadot, steer_coulomb_friction -tanh(deltadot/0.1),
    tire_scrub_torque -deltadot/v, steer_torque_bias 1, steer_inertia -deltaddot,
    steer_stiffness -delta, and a user's library effects) and command_gain T (an input
    entry: its code); for the roll row: roll_viscous_damping -phidot (outside the library,
    used only to show the residual pattern).

    Parameters
    ----------
    model : ExperimentModel
        The model whose canonical matrices, speed calibration and command law are used.
    windows : list of Window
        Measured free decays (10 ms samples).

    Returns
    -------
    dict of str to ndarray
        ``roll``, ``steer`` [N m], ``T`` [N m], ``v`` [m/s] stacked over the windows, and
        ``reg:<name>`` the regressor of each candidate per unit of the effect.
    """
    cm = model.canonical()
    rows = {k: [] for k in ("roll", "steer", "T", "v")}
    laws = {n: e.law for n, e in EFFECTS.items()
            if e.law is not None and e.in_library and e.law.equation == "steer"}  # fmt: skip
    laws["roll_viscous_damping"] = EFFECTS["roll_viscous_damping"].law
    reg = {k: [] for k in (*laws, "command_gain")}
    sims = model.simulate(windows)
    for w, s in zip(windows, sims, strict=True):
        v = model.true_speed(float(np.mean(w.v_sensor)))
        q = np.vstack([w.phi, w.delta])
        qd = np.vstack([w.phidot, w.deltadot])
        dt = float(w.meta.get("dt", 0.01))  # the log's sample period (decays_from_runs)
        qdd = np.vstack([_deriv(w.phidot, dt), _deriv(w.deltadot, dt)])
        T = s["T"]  # the applied command the model reconstructs (= logged law)
        lhs = cm.M @ qdd + v * cm.C1 @ qd + cm.stiffness(v) @ q
        rows["roll"].append(-lhs[0])
        rows["steer"].append(T - lhs[1])
        rows["T"].append(T)
        rows["v"].append(np.full(w.n, v))
        signals = {"1": np.ones(w.n), "phi": w.phi, "delta": w.delta, "phidot": w.phidot,
                   "deltadot": w.deltadot, "phiddot": qdd[0], "deltaddot": qdd[1],
                   "sign(phidot)": np.tanh(w.phidot / COULOMB_EPS),
                   "sign(deltadot)": np.tanh(w.deltadot / COULOMB_EPS)}  # fmt: skip
        for n, law in laws.items():  # the law's force per unit of the effect
            reg[n].append(law.coefficient(signals[law.signal], v, V_FLOOR))
        reg["command_gain"].append(T)
    out = {k: np.concatenate(v) for k, v in rows.items()}
    out.update({f"reg:{k}": np.concatenate(v) for k, v in reg.items()})
    return out


def err_ranking(model: ExperimentModel, windows: list[Window], steps: int = 4) -> list[dict]:
    """Forward orthogonal least squares (FROLS) on the steer-row equation error.

    ERR_i = (w_i . r)^2 / ((w_i . w_i)(r . r)) with w_i the candidate orthogonalised
    against those already chosen.  Also reports, for comparison, the share of the
    roll-row residual a roll damping term would explain (an effect outside the library:
    a large value there points to "unexplained").

    Parameters
    ----------
    model : ExperimentModel
        The model (:func:`equation_error`).
    windows : list of Window
        Measured free decays.
    steps : int, optional
        Number of FROLS steps.

    Returns
    -------
    list of dict
        ``name``, ``err`` (dimensionless, 0-1) and ``row`` per chosen regressor, then the
        roll-row pattern.
    """
    ee = equation_error(model, windows)
    r = ee["steer"]
    names = [k[4:] for k in ee if k.startswith("reg:") and k != "reg:roll_viscous_damping"]
    P = {n: ee[f"reg:{n}"].astype(float) for n in names}
    chosen, basis, out = [], [], []
    rr = float(r @ r)
    for _ in range(min(steps, len(names))):
        best = None
        for n in names:
            if n in chosen:
                continue
            wv = P[n].copy()
            for b in basis:
                wv -= (b @ wv) / (b @ b) * b
            den = float(wv @ wv)
            if den < 1e-12 * max(float(P[n] @ P[n]), 1e-300):
                continue
            err = float((wv @ r) ** 2 / (den * rr))
            if best is None or err > best[0]:
                best = (err, n, wv)
        if best is None:
            break
        chosen.append(best[1])
        basis.append(best[2])
        out.append({"name": best[1], "err": best[0], "row": "steer"})
    rl = ee["roll"]
    wv = ee["reg:roll_viscous_damping"]
    out.append(
        {"name": "roll_row:roll_damping_pattern", "row": "roll",
         "err": float((wv @ rl) ** 2 / ((wv @ wv) * (rl @ rl)))}
    )  # fmt: skip
    return out


def spectrum(e: np.ndarray, dt: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """Welch power spectral density (Hz, unit^2/Hz).

    Parameters
    ----------
    e : array_like
        A residual sequence.
    dt : float, optional
        Sample time [s].

    Returns
    -------
    f : ndarray
        Frequencies [Hz].
    psd : ndarray
        Power spectral density [unit^2/Hz].
    """
    return signal.welch(np.asarray(e, float), fs=1 / dt, nperseg=min(256, len(e)))


def push_asymmetry(windows: list[Window], errors) -> dict:
    """Does the error depend on the direction of the push?

    The Whipple model and the steer-into-lean loop are mirror-symmetric: a push to the left
    is the mirror image of one to the right.  A term that breaks the symmetry (a sensor
    zero offset, a constant torque, a lateral mass offset) makes the errors of the two
    directions differ, while symmetric errors (damping, stiffness, inertia, gains, delay)
    do not.  ``errors``: one number per window (e.g. the mean NRMSE of
    :func:`window_errors`).  Windows are split by the sign of the measured initial roll rate;
    returns the counts, the mean error of each side, their ratio (right / left) and the
    two-sided Mann-Whitney p-value of "same distribution" (nan with fewer than 2 per side).

    Parameters
    ----------
    windows : list of Window
        The decays; a positive initial roll rate counts as a push to the right.
    errors : array_like
        One error per window.

    Returns
    -------
    dict
        ``n_right``, ``n_left``, ``error_right``, ``error_left``, ``ratio``, ``p_value``.

    Raises
    ------
    ValueError
        If ``errors`` does not hold one number per window.
    """
    from scipy.stats import mannwhitneyu

    e = np.asarray(errors, float)
    if e.shape != (len(windows),):
        raise ValueError(f"need one error per window ({len(windows)}), got shape {e.shape}")
    right = np.array([w.state0()[2] > 0 for w in windows])
    a, b = e[right], e[~right]
    p = float(mannwhitneyu(a, b).pvalue) if min(a.size, b.size) >= 2 else float("nan")
    ea = float(a.mean()) if a.size else float("nan")
    eb = float(b.mean()) if b.size else float("nan")
    return {"n_right": int(a.size), "n_left": int(b.size), "error_right": ea,
            "error_left": eb, "ratio": ea / eb if b.size and eb > 0 else float("nan"),
            "p_value": p}  # fmt: skip


def _check_finite_windows(windows: list[Window]) -> None:
    """Refuse windows with non-finite samples (e.g. built by hand, not by a loader)."""
    if not windows:
        raise ValueError("evaluate: no windows given")
    for w in windows:
        for name in ("phi", "delta", "phidot", "deltadot", "v_sensor", "T_ext", "hist"):
            arr = np.asarray(getattr(w, name), dtype=float)
            bad = ~np.isfinite(arr)
            if bad.any():
                i = int(np.argmax(bad))
                raise ValueError(
                    f"evaluate: {w.file}: window at row {w.start}, column {name!r}, sample {i}: "
                    f"non-finite value {float(arr[i])!r}; load windows through bikeid.dataset "
                    "(check_plausible) or clean them"
                )


@single_threaded_blas
def evaluate(
    nominal: ExperimentModel,
    augmented: ExperimentModel,
    windows: list[Window],
    nonlinear: bool = False,
) -> dict:
    """Error before (nominal) and after (augmented), per file and overall.

    ``nonlinear``: both models simulate as the nonlinear plant (defect correction
    attached at each model in turn).

    Metric: mean over windows and the two channels (roll rate, steer angle) of the
    NRMSE ||y_sim - y|| / ||y - mean y|| of the free-decay simulation from the measured
    initial state.  Weave eigenvalue error |lambda_model - lambda_data| / |lambda_data|
    with lambda_data the median (real and imaginary parts) of the damped-oscillation fits
    to the measured decays (``decay_eigenvalue``) and lambda_model the median of the
    *same* fit applied to the model's simulated decays from the same initial states
    (``weave_error_*``: one estimator on both sides, so its bias on the large, nonlinear
    decays at low speed cancels).  ``weave_root_error_*``: lambda_model is instead the
    oscillatory root of the sampled *linear* loop nearest to lambda_data.

    Parameters
    ----------
    nominal, augmented : ExperimentModel
        The models before and after (e.g. the selected effects added).
    windows : list of Window
        The decays (not changed; :func:`evaluate_windows` also returns them corrected).
    nonlinear : bool, optional
        Simulate both as the nonlinear plant by defect correction.

    Returns
    -------
    dict
        ``files``: per file its speed [m/s], window count, errors (dimensionless) and weave
        eigenvalues [1/s]; ``summary``: their means, ratios and the push asymmetry.

    Raises
    ------
    ValueError
        If a window holds a non-finite sample (naming the file, window and column), or an
        error or weave value comes out non-finite (naming the file and the quantity), so that
        no "nan" is ever reported as a result.
    """
    return evaluate_windows(nominal, augmented, windows, nonlinear)[0]


def evaluate_windows(
    nominal: ExperimentModel,
    augmented: ExperimentModel,
    windows: list[Window],
    nonlinear: bool = False,
) -> tuple[dict, list[Window]]:
    """:func:`evaluate`, and the windows with the defect correction at ``augmented``.

    Parameters
    ----------
    nominal, augmented : ExperimentModel
        The models before and after.
    windows : list of Window
        The decays (not changed).
    nonlinear : bool, optional
        Simulate both as the nonlinear plant by defect correction.

    Returns
    -------
    result : dict
        As :func:`evaluate`.
    windows : list of Window
        The decays corrected at ``augmented`` when ``nonlinear`` (else as given), e.g. for
        the validation of the augmented model on them.

    Raises
    ------
    ValueError
        As :func:`evaluate`.
    """
    _check_finite_windows(windows)
    s0 = nominal.simulate(corrected(windows, nominal, nonlinear))
    e0 = window_errors(windows, s0)
    windows = corrected(windows, augmented, nonlinear)
    s1 = augmented.simulate(windows)
    e1 = window_errors(windows, s1)

    files = []
    for f in sorted({w.file for w in windows}):
        idx = [i for i, w in enumerate(windows) if w.file == f]
        ws = [windows[i] for i in idx]
        vs = float(np.mean([np.mean(w.v_sensor) for w in ws]))
        lams = [decay_eigenvalue(w) for w in ws]
        lam_data = median_complex(lams)
        r0, r1 = nominal.weave(vs, lam_data), augmented.weave(vs, lam_data)
        f0, f1 = (
            simulated_weave(ws, [s0[i] for i in idx]),
            simulated_weave(ws, [s1[i] for i in idx]),
        )
        files.append(
            {
                "file": f,
                "speed": float(np.mean([w.speed for w in ws])),
                "windows": len(ws),
                "error_before": float(e0[idx].mean()),
                "error_after": float(e1[idx].mean()),
                "error_before_channels": {"phidot": float(e0[idx, 0].mean()),
                                          "delta": float(e0[idx, 1].mean())},
                "error_after_channels": {"phidot": float(e1[idx, 0].mean()),
                                         "delta": float(e1[idx, 1].mean())},
                "weave_data": lam_data,
                "weave_data_rel_std": weave_uncertainty(lams),
                "weave_before": f0,
                "weave_after": f1,
                "weave_error_before": abs(f0 - lam_data) / abs(lam_data),
                "weave_error_after": abs(f1 - lam_data) / abs(lam_data),
                "weave_root_before": r0,
                "weave_root_after": r1,
                "weave_root_error_before": abs(r0 - lam_data) / abs(lam_data),
                "weave_root_error_after": abs(r1 - lam_data) / abs(lam_data),
            }
        )  # fmt: skip
    keys = ("error_before", "error_after", "weave_error_before", "weave_error_after",
            "weave_root_error_before", "weave_root_error_after")  # fmt: skip
    for f in files:
        bad = [k for k in keys if not np.isfinite(f[k])]
        bad += [f"{k}[{c}]" for k in ("error_before_channels", "error_after_channels")
                for c, x in f[k].items() if not np.isfinite(x)]  # fmt: skip
        if bad:
            raise ValueError(
                f"evaluate: {f['file']}: {', '.join(bad)} is not finite (a simulation diverged "
                "or a window is degenerate); check the model and the windows of this file"
            )
    summ = {k: float(np.mean([f[k] for f in files])) for k in keys}
    summ["ratio"] = summ["error_after"] / summ["error_before"]
    summ["weave_ratio"] = summ["weave_error_after"] / max(summ["weave_error_before"], 1e-12)
    unc = [f["weave_data_rel_std"] for f in files if np.isfinite(f["weave_data_rel_std"])]
    summ["weave_data_rel_std"] = float(np.mean(unc)) if unc else float("nan")  # files with >= 3
    summ["push_asymmetry_before"] = push_asymmetry(windows, e0.mean(axis=1))
    summ["push_asymmetry_after"] = push_asymmetry(windows, e1.mean(axis=1))
    summ.update(before_after_summary(windows, e0.mean(axis=1), e1.mean(axis=1)))
    return {"files": files, "summary": summ}, windows


def before_after_summary(windows: list[Window], before: np.ndarray, after: np.ndarray) -> dict:
    """The interval, paired test, verdict and trivial baselines of a before/after error.

    :func:`bikeid.ident.effects.before_after.before_after` on the per-window errors
    (decays resampled within their file), plus the absolute levels of two trivial
    predictions in the same metric: the mean of each signal (``baseline_mean``, exactly 1)
    and zero motion (``baseline_zero``, mean over files of the file means, >= 1).

    Parameters
    ----------
    windows : list of Window
        The decays (their ``file`` is the bootstrap's stratum).
    before, after : (len(windows),) ndarray
        Each window's error before and after (mean NRMSE of roll rate and steer angle).

    Returns
    -------
    dict
        ``ratio_ci`` [low, high], ``p_value``, ``verdict``, ``interval`` (what the interval
        covers), ``goal`` (0.5), ``level`` (the interval's confidence level),
        ``baseline_mean``, ``baseline_zero`` (dimensionless).
    """
    files = [w.file for w in windows]
    ba = before_after(before, after, files)
    zero = np.array([np.mean([zero_motion_error(getattr(w, c)) for c in ("phidot", "delta")])
                     for w in windows])  # fmt: skip
    per_file = [zero[[i for i, f in enumerate(files) if f == n]].mean() for n in set(files)]
    return {"ratio_ci": ba["ratio_ci"], "p_value": ba["p_value"], "verdict": ba["verdict"],
            "interval": ba["interval"], "goal": ba["goal"], "level": ba["level"],
            "baseline_mean": 1.0,
            "baseline_zero": float(np.mean(per_file))}  # fmt: skip
