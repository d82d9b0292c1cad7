"""Figures of a model validation (:class:`bikeid.ident.validation_report.ValidationReport`).

Three PNG figures, written atomically (:func:`bikeid.experiments.plots.save`):

- :func:`plot_compare`: per output, measured, simulated and k-step-predicted signals of one
  run against time, with MATLAB ``compare``'s fit [%] in the legend;
- :func:`plot_resid`: per output, the residual autocorrelation (lags 1..M; lag 0 is 1) and
  the residual-T_delta cross-correlation against lag, one line per speed, with the 99 %
  band and the verdicts of :mod:`bikeid.ident.structure`'s tests over the speeds;
- :func:`plot_bode`: one figure per speed (:func:`bode_names`), per output the model's Bode
  plot (sampled response) with
  its 95 % band (when the model has a parameter covariance; calibrated on the linear plant
  only) under the nonparametric estimate and its error bars at the frequencies the
  coherence allows, and the coherence itself.

Angles and angular rates are drawn in degrees, or in radians when the user's logs were
(``angle``, :func:`bikeid.experiments.plots.angle_unit` of the runs); the Bode phases of
the model, its band and the estimate lie on one 360-degree branch
(:func:`bikeid.experiments.plots.phase_deg`, :func:`~bikeid.experiments.plots.points_on_branch`).
Every figure uses matplotlib's constrained layout and wraps long titles, so no text is
clipped and no labels of neighbouring axes overlap
(:func:`bikeid.experiments.plots.layout_problems`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bikeid.experiments.plots import (
    display_scale,
    phase_deg,
    plt,
    points_on_branch,
    save,
    wrap_title,
)
from bikeid.ident.validation_report import ValidationReport

__all__ = ["bode_names", "plot_bode", "plot_compare", "plot_resid", "write_figures"]

#: Characters of a 9-point title per inch of axes width (wrapping width).
CHARS_PER_INCH = 12


def _pct(x: float | None) -> str:
    return "n/a" if x is None or not np.isfinite(x) else f"{x:.1f} %"


def plot_compare(
    report: ValidationReport, path: str | Path, run: int = 0, angle: str = "deg"
) -> Path:
    """Measured vs simulated vs k-step-predicted outputs of one run.

    Parameters
    ----------
    report : ValidationReport
        The validation.
    path : str or Path
        PNG file to write.
    run : int, optional
        Index of the run to show.
    angle : {"deg", "rad"}, optional
        Unit of angles and angular rates on the plot (default degrees).

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    p = len(report.outputs)
    fig, axes = plt.subplots(p, 1, figsize=(8, 2.2 * p + 0.6), sharex=True, squeeze=False,
                             layout="constrained")  # fmt: skip
    s = report.series[run]
    for j, o in enumerate(report.outputs):
        ax = axes[j, 0]
        c, unit = display_scale(o, angle)
        ax.plot(s.t, c * s.measured[:, j], color="0.2", lw=0.8, label="measured")
        if s.simulated is not None:
            ax.plot(s.t, c * s.simulated[:, j], color="tab:blue", lw=0.9,
                    label=f"simulated (fit {_pct(s.fit['simulation'][o])})")  # fmt: skip
        kfit = _pct(s.fit["k_step"][o])
        ax.plot(s.t, c * s.predicted[:, j], color="tab:orange", lw=0.9, ls="--",
                label=f"{report.k_step}-step predicted (fit {kfit})")  # fmt: skip
        ax.set_ylabel(f"{o} [{unit}]")
        ax.grid(alpha=0.3)
        ax.legend(loc="upper right", fontsize=7)
    axes[-1, 0].set_xlabel("time [s]")
    title = f"compare: {s.label} (v = {s.speed:g} m/s)"
    if s.simulated is None:
        title += "\n" + report.simulation_note
    axes[0, 0].set_title(wrap_title(title, 8 * CHARS_PER_INCH), fontsize=9)
    return save(fig, path)


def _verdict_text(report: ValidationReport, output: str, kind: str) -> str:
    """``whiteness: rejected at 2 of 8 speeds`` from the structure check's tests."""
    rows = [t for tests in report.structure.tests.values() for t in tests
            if t["kind"] == kind and t["output"] == output]  # fmt: skip
    if not rows:
        return f"{kind}: not tested (K = 0)" if kind == "whiteness" else f"{kind}: not tested"
    bad = sum(t["rejected"] for t in rows)
    if len(rows) == 1:
        return f"{kind}: {'rejected' if bad else 'passed'} (p = {rows[0]['p_value']:.2g})"
    return f"{kind}: {f'rejected at {bad}' if bad else 'passed at all'} of {len(rows)} speeds"


def plot_resid(report: ValidationReport, path: str | Path) -> Path:
    """Residual autocorrelation and residual-input cross-correlation with the 99 % band.

    One line per speed (colour: speed), the band of the speed with the fewest samples (the
    widest); the titles give the verdicts of :mod:`bikeid.ident.structure`'s tests over the
    speeds (the tests :func:`~bikeid.ident.validation_report.validate_model` reports).

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
    cs = report.correlations
    p = len(report.outputs)
    fig, axes = plt.subplots(p, 2, figsize=(9, 2.4 * p + 0.6), squeeze=False,
                             layout="constrained")  # fmt: skip
    m = int(cs[0].lags[-1])
    band = max(c.band for c in cs)
    speeds = [c.speed for c in cs]
    lo, hi = min(speeds), max(speeds)
    cmap = plt.get_cmap("viridis")
    width = 64  # characters of an 8-point title over a column of ~4.2 in
    level = report.structure.per_test_level
    for j, o in enumerate(report.outputs):
        a, c = axes[j, 0], axes[j, 1]
        for k, cr in enumerate(cs):
            col = cmap(0.5 if hi == lo else (cr.speed - lo) / (hi - lo))
            kw = {"color": col, "lw": 0.9, "marker": "o", "ms": 2}
            if j == 0 and k in (0, len(cs) - 1):
                kw["label"] = f"{cr.speed:g} m/s"
            a.plot(np.arange(1, m + 1), cr.autocorr[o][1:], **kw)  # lag 0 is 1
            c.plot(cr.lags, cr.crosscorr[o], color=col, lw=0.9, marker="o", ms=2)
        a.set_title(wrap_title(f"{o} residual, lags 1..{m}: "
                               f"{_verdict_text(report, o, 'whiteness')}", width),
                    fontsize=8)  # fmt: skip
        c.set_title(wrap_title(f"{o} vs T_delta, lags 1..{m}: "
                               f"{_verdict_text(report, o, 'independence')}", width),
                    fontsize=8)  # fmt: skip
        for ax in (a, c):
            ax.axhspan(-band, band, color="tab:blue", alpha=0.15, lw=0)
            ax.axhline(0, color="k", lw=0.5)
            ax.grid(alpha=0.3)
        a.set_ylabel("correlation [-]")
    if len(cs) > 1:
        axes[0, 0].legend(fontsize=7, title="speed", title_fontsize=7, loc="upper right")
    axes[-1, 0].set_xlabel(wrap_title(f"lag [samples] (tests: ident.structure, each at p < "
                                      f"{level:.2g})", width))  # fmt: skip
    axes[-1, 1].set_xlabel(wrap_title("lag [samples] (residual at k vs T_delta at k - lag)",
                                      width))  # fmt: skip
    return save(fig, path)


#: Panels (outputs) per row of a Bode figure; each panel is BODE_PANEL_IN inches wide.
BODE_COLUMNS = 4
BODE_PANEL_IN = 3.4


def plot_bode(
    report: ValidationReport, path: str | Path, angle: str = "deg", speed: float | None = None
) -> Path:
    """Model Bode plots with the nonparametric estimate where the coherence allows.

    One speed per figure (``speed``; default the first), its outputs side by side, at most
    :data:`BODE_COLUMNS` per row (about 1,800 px wide at 130 dpi).  The model curve's phase
    is unwrapped and put on the branch whose lowest-frequency value lies in (-270, 90] deg
    (:func:`bikeid.experiments.plots.phase_deg`); its band and the estimate's points are
    drawn on that same branch (each point within 180 deg of the curve at its frequency).

    Parameters
    ----------
    report : ValidationReport
        The validation.
    path : str or Path
        PNG file to write.
    angle : {"deg", "rad"}, optional
        Unit of the outputs' angles and rates in the magnitude (default degrees); phases
        are always in degrees.
    speed : float, optional
        The speed group [m/s] (a :attr:`FrequencyResponseEstimate.speed`).

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    speeds = list(dict.fromkeys(e.speed for e in report.frequency_responses))
    v = speeds[0] if speed is None else speed
    ests = [e for e in report.frequency_responses if e.speed == v]
    if not ests:
        raise ValueError(f"speed={speed}: no frequency response at it; use one of {speeds}")
    ncol = min(len(ests), BODE_COLUMNS)
    nblk = -(-len(ests) // ncol)
    fig, axes = plt.subplots(3 * nblk, ncol, figsize=(BODE_PANEL_IN * ncol, 7.5 * nblk),
                             squeeze=False, sharex="col",
                             gridspec_kw={"height_ratios": [3, 2, 1.3] * nblk},
                             layout="constrained")  # fmt: skip
    width = int((BODE_PANEL_IN - 0.2) * CHARS_PER_INCH)
    for k, e in enumerate(ests):
        b, col = divmod(k, ncol)
        mag, ph, co = axes[3 * b, col], axes[3 * b + 1, col], axes[3 * b + 2, col]
        scale, unit = display_scale(e.output, angle)
        curve = scale * np.abs(e.model_curve)
        curve_ph = phase_deg(e.model_curve)
        mag.loglog(e.model_f, curve, color="tab:blue", label="model (sampled)")
        ph.semilogx(e.model_f, curve_ph, color="tab:blue")
        if e.curve_band_db.size:  # the model's 95 % band, under the estimate
            k_db = 10.0 ** (e.curve_band_db / 20.0)
            mag.fill_between(e.model_f, curve / k_db, curve * k_db, color="tab:blue",
                             alpha=0.2, lw=0,
                             label="model 95 % band (linear-plant calibrated)")  # fmt: skip
            ph.fill_between(e.model_f, curve_ph - e.curve_band_deg,
                            curve_ph + e.curve_band_deg, color="tab:blue",
                            alpha=0.2, lw=0)  # fmt: skip
        v = e.valid
        if v.any():
            err = scale * e.rel_error[v] * np.abs(e.H[v])
            inside = e.in_band
            where = "" if inside is None else (
                f", {int(inside.sum())}/{int(v.sum())} in band, "
                f"{int(e.consistent.sum())} with own error")  # fmt: skip
            mag.errorbar(e.f[v], scale * np.abs(e.H[v]), yerr=err, fmt="o", ms=3,
                         color="tab:red", lw=0.8,
                         label=f"estimate ({e.reference}{where})")  # fmt: skip
            # each point of the estimate on the model curve's branch
            ph.errorbar(e.f[v], points_on_branch(e.f[v], e.H[v], e.model_f, curve_ph),
                        yerr=np.degrees(e.rel_error[v]), fmt="o", ms=3, color="tab:red",
                        lw=0.8)  # fmt: skip
        else:
            mag.text(0.5, 0.5, "not enough excitation", transform=mag.transAxes,
                     ha="center", color="tab:red")  # fmt: skip
        if np.isfinite(e.coherence).any():
            co.semilogx(e.f, e.coherence, color="0.3")
        co.axhline(e.coherence_min, color="tab:red", ls="--", lw=0.8)
        co.set_ylim(0, 1.05)
        mag.set_title(wrap_title(f"{e.input} -> {e.output}, v = {e.speed:g} m/s", width),
                      fontsize=9)  # fmt: skip
        mag.set_ylabel(f"|H| [{unit}/(N m)]")
        ph.set_ylabel("phase [deg]")
        co.set_ylabel("coherence [-]")
        co.set_xlabel("frequency [Hz]")
        mag.legend(fontsize=7, loc="best")  # explicit: no timing warning on a busy machine
        for ax in (mag, ph, co):
            ax.grid(alpha=0.3, which="both")
    return save(fig, path)


def bode_names(report: ValidationReport) -> dict[float, str]:
    """File name of each speed's Bode figure.

    Parameters
    ----------
    report : ValidationReport
        The validation (its frequency responses' speeds).

    Returns
    -------
    dict of float to str
        ``bode.png`` for one speed, else ``bode_v<speed>.png`` (e.g. ``bode_v12.5.png``).
    """
    speeds = list(dict.fromkeys(e.speed for e in report.frequency_responses))
    if len(speeds) == 1:
        return {speeds[0]: "bode.png"}
    return {v: f"bode_v{v:g}.png" for v in speeds}


def write_figures(
    report: ValidationReport, out: str | Path, max_runs: int = 6, angle: str = "deg"
) -> list[Path]:
    """Write compare (one per run, at most ``max_runs``), resid and Bode figures.

    Each figure is drawn, written and closed before the next, one Bode figure per speed
    (:func:`bode_names`), so none is wider than about 1,800 px whatever the number of runs.

    Parameters
    ----------
    report : ValidationReport
        The validation.
    out : str or Path
        Folder (created if missing).
    max_runs : int, optional
        At most this many compare figures (the first runs whose series the report kept).
    angle : {"deg", "rad"}, optional
        Unit of angles and angular rates on the figures: degrees (default, bikeid's
        convention) or the user's radians (:func:`bikeid.experiments.plots.angle_unit`).

    Returns
    -------
    list of pathlib.Path
        The files written: ``compare_1.png``..., ``resid.png``, then the Bode figures.
    """
    out = Path(out)
    paths = [plot_compare(report, out / f"compare_{i + 1}.png", i, angle)
             for i in range(min(len(report.series), max_runs))]  # fmt: skip
    paths.append(plot_resid(report, out / "resid.png"))
    for v, name in bode_names(report).items():
        paths.append(plot_bode(report, out / name, angle, speed=v))
    return paths
