"""Figures of a model validation (:class:`bikeid.ident.validation_report.ValidationReport`).

Three PNG figures, written atomically (:func:`bikeid.experiments.plots.save`):

- :func:`plot_compare`: per output, measured, simulated and k-step-predicted signals of one
  run against time, with MATLAB ``compare``'s fit [%] in the legend;
- :func:`plot_resid`: per output, the residual autocorrelation (lags 1..M; lag 0 is 1) and
  the residual-input cross-correlation against lag with the 99 % band and the chi-squared
  test verdicts;
- :func:`plot_bode`: per output and speed, the model's Bode plot (sampled response) with
  its 95 % band (when the model has a parameter covariance; calibrated on the linear plant
  only) under the nonparametric estimate and its error bars at the frequencies the
  coherence allows, and the coherence itself.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bikeid.experiments.plots import plt, save
from bikeid.ident.validation_report import ValidationReport

__all__ = ["plot_bode", "plot_compare", "plot_resid", "write_figures"]

UNIT = {"phi": "rad", "delta": "rad", "phidot": "rad/s", "deltadot": "rad/s"}


def _pct(x: float | None) -> str:
    return "n/a" if x is None or not np.isfinite(x) else f"{x:.1f} %"


def plot_compare(report: ValidationReport, path: str | Path, run: int = 0) -> Path:
    """Measured vs simulated vs k-step-predicted outputs of one run.

    Parameters
    ----------
    report : ValidationReport
        The validation.
    path : str or Path
        PNG file to write.
    run : int, optional
        Index of the run to show.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    p = len(report.outputs)
    fig, axes = plt.subplots(p, 1, figsize=(8, 2.2 * p + 0.6), sharex=True, squeeze=False)
    t = report.t[run]
    fits = report.fit_per_run[run]
    for j, o in enumerate(report.outputs):
        ax = axes[j, 0]
        ax.plot(t, report.measured[run][:, j], color="0.2", lw=0.8, label="measured")
        if report.simulation is not None:
            ax.plot(t, report.simulation.yhat[run][:, j], color="tab:blue", lw=0.9,
                    label=f"simulated (fit {_pct(fits['simulation'][o])})")  # fmt: skip
        kfit = _pct(fits["k_step"][o])
        ax.plot(t, report.prediction.yhat[run][:, j], color="tab:orange", lw=0.9, ls="--",
                label=f"{report.k_step}-step predicted (fit {kfit})")  # fmt: skip
        ax.set_ylabel(f"{o} [{UNIT.get(o, '-')}]")
        ax.grid(alpha=0.3)
        ax.legend(loc="upper right", fontsize=7)
    axes[-1, 0].set_xlabel("time [s]")
    title = f"compare: {report.runs[run]} (v = {report.speeds[run]:g} m/s)"
    if report.simulation is None:
        title += "\n" + report.simulation_note[:110]
    axes[0, 0].set_title(title, fontsize=9)
    return save(fig, path)


def plot_resid(report: ValidationReport, path: str | Path) -> Path:
    """Residual autocorrelation and residual-input cross-correlation with the 99 % band.

    Parameters
    ----------
    report : ValidationReport
        The validation.
    path : str or Path
        PNG file to write.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    rr = report.residuals
    p = len(report.outputs)
    fig, axes = plt.subplots(p, 2, figsize=(9, 2.4 * p + 0.6), squeeze=False,
                             layout="constrained")  # fmt: skip
    m = int(rr.lags[-1])
    for j, o in enumerate(report.outputs):
        a, c = axes[j, 0], axes[j, 1]
        w, ind = rr.whiteness_test[o], rr.independence_test[o]
        a.stem(np.arange(1, m + 1), rr.autocorr[o][1:], basefmt=" ")  # lag 0 is 1
        a.set_title(f"{o} residual: whiteness {'passed' if w['passed'] else 'FAILED'} "
                    f"(p = {w['p_value']:.2g}, lags 1..{m})", fontsize=8)  # fmt: skip
        c.stem(rr.lags, rr.crosscorr[o], basefmt=" ")
        c.set_title(f"{o} vs {rr.input}: independence {'passed' if ind['passed'] else 'FAILED'} "
                    f"(p = {ind['p_value']:.2g}, lags 1..{m})", fontsize=8)  # fmt: skip
        for ax in (a, c):
            ax.axhspan(-rr.band, rr.band, color="tab:blue", alpha=0.15, lw=0)
            ax.axhline(0, color="k", lw=0.5)
            ax.grid(alpha=0.3)
        a.set_ylabel("correlation [-]")
    axes[-1, 0].set_xlabel("lag [samples]")
    axes[-1, 1].set_xlabel(f"lag [samples] (residual at k vs {rr.input} at k - lag)")
    return save(fig, path)


def plot_bode(report: ValidationReport, path: str | Path) -> Path:
    """Model Bode plots with the nonparametric estimate where the coherence allows.

    Parameters
    ----------
    report : ValidationReport
        The validation.
    path : str or Path
        PNG file to write.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    ests = report.frequency_responses
    fig, axes = plt.subplots(3, len(ests), figsize=(4.2 * len(ests), 7.5), squeeze=False,
                             sharex="col", gridspec_kw={"height_ratios": [3, 2, 1.3]})  # fmt: skip
    for k, e in enumerate(ests):
        mag, ph, co = axes[0, k], axes[1, k], axes[2, k]
        curve_ph = np.unwrap(np.angle(e.model_curve))
        mag.loglog(e.model_f, np.abs(e.model_curve), color="tab:blue", label="model (sampled)")
        ph.semilogx(e.model_f, np.degrees(curve_ph), color="tab:blue")
        if e.curve_band_db.size:  # the model's 95 % band, under the estimate
            k_db = 10.0 ** (e.curve_band_db / 20.0)
            mag.fill_between(e.model_f, np.abs(e.model_curve) / k_db,
                             np.abs(e.model_curve) * k_db, color="tab:blue", alpha=0.2, lw=0,
                             label="model 95 % band (linear-plant calibrated)")  # fmt: skip
            ph.fill_between(e.model_f, np.degrees(curve_ph) - e.curve_band_deg,
                            np.degrees(curve_ph) + e.curve_band_deg, color="tab:blue",
                            alpha=0.2, lw=0)  # fmt: skip
        v = e.valid
        if v.any():
            err = e.rel_error[v] * np.abs(e.H[v])
            inside = e.in_band
            where = "" if inside is None else (
                f", {int(inside.sum())}/{int(v.sum())} in band, "
                f"{int(e.consistent.sum())} with own error")  # fmt: skip
            mag.errorbar(e.f[v], np.abs(e.H[v]), yerr=err, fmt="o", ms=3, color="tab:red",
                         lw=0.8, label=f"estimate ({e.reference}{where})")  # fmt: skip
            # phase of the estimate on the model curve's branch (same unwrapping offset)
            d = np.angle(e.H[v] / e.model[v])
            model_ph = np.interp(e.f[v], e.model_f, curve_ph)
            ph.errorbar(e.f[v], np.degrees(model_ph + d), yerr=np.degrees(e.rel_error[v]),
                        fmt="o", ms=3, color="tab:red", lw=0.8)  # fmt: skip
        else:
            mag.text(0.5, 0.5, "not enough excitation", transform=mag.transAxes,
                     ha="center", color="tab:red")  # fmt: skip
        if np.isfinite(e.coherence).any():
            co.semilogx(e.f, e.coherence, color="0.3")
        co.axhline(e.coherence_min, color="tab:red", ls="--", lw=0.8)
        co.set_ylim(0, 1.05)
        mag.set_title(f"{e.input} -> {e.output}, v = {e.speed:g} m/s", fontsize=9)
        mag.set_ylabel(f"|H| [{UNIT.get(e.output, '-')}/(N m)]")
        ph.set_ylabel("phase [deg]")
        co.set_ylabel("coherence [-]")
        co.set_xlabel("frequency [Hz]")
        mag.legend(fontsize=7)
        for ax in (mag, ph, co):
            ax.grid(alpha=0.3, which="both")
    return save(fig, path)


def write_figures(report: ValidationReport, out: str | Path, max_runs: int = 6) -> list[Path]:
    """Write compare (one per run, at most ``max_runs``), resid and Bode figures.

    Parameters
    ----------
    report : ValidationReport
        The validation.
    out : str or Path
        Folder (created if missing).
    max_runs : int, optional
        At most this many compare figures (the first runs).

    Returns
    -------
    list of pathlib.Path
        The files written: ``compare_1.png``..., ``resid.png``, ``bode.png``.
    """
    out = Path(out)
    paths = [plot_compare(report, out / f"compare_{i + 1}.png", i)
             for i in range(min(len(report.runs), max_runs))]  # fmt: skip
    paths.append(plot_resid(report, out / "resid.png"))
    paths.append(plot_bode(report, out / "bode.png"))
    return paths
