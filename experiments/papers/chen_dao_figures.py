"""Chen & Dao (2010) reproduction, the figures: Figs. 2, 3, 4-5 and 7 as PNG files.

Each function runs the numerics of :mod:`experiments.papers.chen_dao` (which has the
settings, the identification runs and every number of ``summary.json``), draws the figure
into the output folder and returns the numbers with the figure's file name added.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bikeid.experiments.papers import chen_dao as cd
from bikeid.experiments.papers import limit_cycles as lc
from bikeid.experiments.parallel import map_jobs
from bikeid.experiments.plots import MODE_STYLE, plt, save, wrap_title
from bikeid.sim.linear import critical_speeds, eigenvalues, eigenvalues_vs_speed
from bikeid.sim.parameters import BicycleParameters

__all__ = ["fig2", "fig3", "fig7", "limit_cycle_study"]


def fig2(p: BicycleParameters, out: Path, duration: float = 50.0) -> dict[str, Any]:
    """Fig. 2 analogue: :func:`~bikeid.experiments.papers.chen_dao.fig2_identification` and its
    figure.

    Parameters
    ----------
    p : BicycleParameters
        The simulated bicycle.
    out : Path
        Folder for ``cd_fig2_identification.png``.
    duration : float
        Length of the identification run [s].

    Returns
    -------
    dict
        The numbers of :func:`~bikeid.experiments.papers.chen_dao.fig2_identification` (without the
        time
        series) and ``figure``, the PNG's file name.
    """

    res = cd.fig2_identification(p, duration)
    ser = res.pop("_series")
    run_t, u, y, shown, err = (ser[k] for k in ("t", "u", "y", "shown", "err"))
    stable, v = ser["stable"], ser["speed"]
    fig, ax = plt.subplots(3, 1, figsize=(9, 8), sharex=True)
    ax[0].plot(run_t, u, lw=0.6, color="k", label="steer torque T_delta (incl. dither)")
    ax[0].set_ylabel("torque [N m]")
    ax[1].plot(run_t, np.degrees(y[:, 0]), color="tab:blue", lw=0.8, label="roll angle data")
    ax[1].plot(run_t, np.degrees(y[:, 1]), color="tab:red", lw=0.8, label="steer angle data")
    ax[1].plot(
        run_t,
        np.degrees(shown[:, 0]),
        "--",
        color="tab:cyan",
        lw=0.8,
        label="identified model, roll",
    )
    ax[1].plot(
        run_t,
        np.degrees(shown[:, 1]),
        "--",
        color="tab:orange",
        lw=0.8,
        label="identified model, steer",
    )
    ax[1].set_ylabel("angle [deg]")
    ax[2].plot(run_t, np.degrees(err[:, 0]), color="tab:blue", lw=0.6, label="roll angle error")
    ax[2].plot(run_t, np.degrees(err[:, 1]), color="tab:red", lw=0.6, label="steer angle error")
    ax[2].set_ylabel("error [deg]")
    ax[2].set_xlabel("time [s]")
    for a in ax:
        a.grid(alpha=0.3)
        a.legend(fontsize=7, loc="upper right", ncol=2)
    ax[0].set_title(
        f"Chen & Dao Fig. 2 analogue: identification at {v} m/s (fuzzy control, "
        "chirp + 1 N m dither)\nmodel: "
        + (
            "open-loop simulation"
            if stable
            else f"{cd.PREDICTION_HORIZON:g} s-ahead prediction (identified model unstable)"
        ),
        fontsize=9,
    )
    save(fig, out / "cd_fig2_identification.png")
    res["figure"] = "cd_fig2_identification.png"
    return res


def fig3(
    p: BicycleParameters,
    grid: list[dict[str, Any]],
    out: Path,
    zoom: list[dict[str, Any]] | None = None,
) -> dict[str, Any]:
    """Identified eigenvalues (PEM) against speed over the true linearization, ranges marked.

    Parameters
    ----------
    p : BicycleParameters
        The simulated bicycle.
    grid, zoom : list of dict
        As :func:`~bikeid.experiments.papers.chen_dao.fig3_summary`.
    out : Path
        Folder for ``cd_fig3a_eigenvalues.png`` (and ``cd_fig3b_zoom.png``).

    Returns
    -------
    dict
        :func:`~bikeid.experiments.papers.chen_dao.fig3_summary` and ``figures``, the PNG file
        names.
    """

    res = cd.fig3_summary(p, grid, zoom)
    ok, zoom_ok = res.pop("_ok"), res.pop("_zoom")
    speeds = np.array([g["speed"] for g in ok])
    crit_true, crit_id = res["critical_true"], res["critical_identified"]
    fine = np.linspace(min(1.0, speeds.min()), max(15.0, speeds.max()), 600)
    sw = eigenvalues_vs_speed(p, fine)

    def panel(axs, lo, hi, runs_sel, title):
        a1, a2 = axs
        seen = set()
        for j, lab in enumerate(sw.labels):
            c = MODE_STYLE.get(lab, "0.4")
            nm = f"true {lab}" if lab not in seen else None
            seen.add(lab)
            a1.plot(sw.speeds, sw.values[:, j].real, color=c, lw=1.0, label=nm)
            a2.plot(sw.speeds, np.abs(sw.values[:, j].imag), color=c, lw=1.0, label=nm)
        sp = np.array([g["speed"] for g in runs_sel])
        ev = np.array([g["methods"]["pem"]["eig"] for g in runs_sel])
        # 95 % intervals: 1.96 standard errors of the real and imaginary parts (first-order
        # propagation of the PEM covariance, chen_dao.eigen_stderr); NaN: no bar
        se = np.full((len(runs_sel), 4, 2), np.nan)
        for i, g in enumerate(runs_sel):
            if g["methods"]["pem"].get("stderr") is not None:
                se[i] = np.asarray(g["methods"]["pem"]["stderr"], float).reshape(4, 2)
        a1.errorbar(np.repeat(sp, 4), ev.real.ravel(), yerr=1.96 * se[:, :, 0].ravel(),
                    fmt="kx", ms=4, elinewidth=0.8, capsize=2,
                    label="identified (PEM), real part, 95 % interval")  # fmt: skip
        a2.errorbar(np.repeat(sp, 4), np.abs(ev.imag).ravel(), yerr=1.96 * se[:, :, 1].ravel(),
                    fmt="k*", ms=4, elinewidth=0.8, capsize=2,
                    label="identified (PEM), |imag part|, 95 % interval")  # fmt: skip
        for a in (a1, a2):
            a.axhline(0, color="k", lw=0.5)
            a.set_xlim(lo - 0.02 * (hi - lo), hi + 0.02 * (hi - lo))
            a.grid(alpha=0.3)
            for key in ("v_d", "v_w", "v_c"):
                val = crit_true[key]
                if val is not None and lo <= val <= hi:
                    a.axvline(val, color="0.4", ls="--", lw=0.8)
            for val in crit_id.values():
                if val is not None and lo <= val <= hi:
                    a.axvline(val, color="m", ls=":", lw=1.0)
            # the paper's boundaries (Chen & Dao p. 3, Sec. III.B; cd.PAPER)
            for key, val in cd.PAPER["critical"].items():
                if lo <= val <= hi:
                    a.axvline(val, color="tab:orange", ls="-.", lw=0.9)
                    if a is a1:
                        a1.annotate(f"paper {key}", (val, -1), fontsize=6, rotation=90,
                                    color="tab:orange", ha="right", va="top")  # fmt: skip
        an = cd.PAPER["anomaly"]
        pts = [an["dip"], an["recovered"]]
        if any(lo <= x <= hi for x, _ in pts):
            a1.plot(*zip(*pts, strict=True), "D", color="tab:orange", ms=6, mfc="none",
                    label="paper: capsize root (p. 3)")  # fmt: skip
            zc = [an["stable_from"], an["unstable_from"]]
            a1.plot(zc, [0, 0], "o", color="tab:orange", ms=5, mfc="none",
                    label="paper: capsize sign changes")  # fmt: skip
        ymin = max(-40.0, float(np.nanmin(ev.real)) - 2)
        a1.set_ylim(ymin, 8)
        a2.set_ylim(0, max(20.0, float(np.nanmax(np.abs(ev.imag))) + 1))
        for key in ("v_d", "v_w", "v_c"):
            val = crit_true[key]
            if val is not None and lo <= val <= hi:
                a1.annotate(
                    f"{key}={val:.3f}",
                    (val, 8),
                    fontsize=7,
                    ha="left",
                    va="top",
                    rotation=90,
                    color="0.3",
                )
        # ranges A-D of the truth
        edges = [lo] + [crit_true[k] for k in ("v_d", "v_w", "v_c")] + [hi]
        for name, a_, b_ in zip("ABCD", edges[:-1], edges[1:], strict=True):
            a_, b_ = max(a_, lo), min(b_, hi)
            if b_ > a_:
                a2.annotate(
                    name,
                    (0.5 * (a_ + b_), a2.get_ylim()[1] * 0.93),
                    ha="center",
                    fontsize=9,
                    color="0.3",
                )
        a1.set_ylabel("real part [1/s]")
        a2.set_ylabel("|imag part| [rad/s]")
        a2.set_xlabel(
            "speed v [m/s]\n(grey dashed: true v_d, v_w, v_c; magenta dotted: identified; "
            "orange dash-dot: the paper's)"
        )
        a1.set_title(wrap_title(title, 100), fontsize=9)  # 9 in wide: ~100 characters
        a1.legend(fontsize=6, loc="lower left", ncol=2)

    fig, axs = plt.subplots(2, 1, figsize=(9, 7.5), sharex=True)
    panel(
        axs,
        float(min(1.0, speeds.min())),
        float(max(15.0, speeds.max())),
        ok,
        "Chen & Dao Fig. 3(a) analogue: identified eigenvalues vs the true linearization "
        "(benchmark)",
    )
    save(fig, out / "cd_fig3a_eigenvalues.png")
    if zoom_ok:
        fig, axs = plt.subplots(2, 1, figsize=(9, 7.5), sharex=True)
        an = res["anomaly"]
        panel(
            axs,
            3.0,
            4.2,
            zoom_ok,
            "Chen & Dao Fig. 3(b) analogue: zoom 3-4.2 m/s; capsize anomaly "
            f"{an['verdict']} in our data ({an['reason']})",
        )
        axs[0].set_ylim(-16, 4)
        axs[0].title.set_fontsize(7)
        save(fig, out / "cd_fig3b_zoom.png")
    res["figures"] = ["cd_fig3a_eigenvalues.png"] + (["cd_fig3b_zoom.png"] if zoom_ok else [])
    return res


def fig7(
    p: BicycleParameters,
    model,
    out: Path,
    duration: float = 50.0,
    poles: Sequence[complex] | None = None,
) -> dict[str, Any]:
    """Fig. 7 analogue: :func:`~bikeid.experiments.papers.chen_dao.fig7_tracking` and its figure.

    Parameters
    ----------
    p, model, duration, poles
        As :func:`~bikeid.experiments.papers.chen_dao.fig7_tracking`.
    out : Path
        Folder for ``cd_fig7_tracking.png``.

    Returns
    -------
    dict
        The numbers of :func:`~bikeid.experiments.papers.chen_dao.fig7_tracking` and ``figure``.
    """

    res = cd.fig7_tracking(p, model, duration, poles)
    run = res.pop("_run")
    poles = res["poles_requested"]
    phi, r = run.true("phi"), run.reference
    e = r - phi
    fig, ax = plt.subplots(3, 1, figsize=(9, 7.5), sharex=True)
    ax[0].plot(run.t, np.degrees(r), "k--", lw=0.9, label="reference")
    ax[0].plot(run.t, np.degrees(phi), color="tab:blue", lw=0.9, label="response (roll angle)")
    ax[0].plot(run.t, np.degrees(e), color="tab:red", lw=0.7, label="error")
    ax[0].set_ylabel("roll angle [deg]")
    ax[1].plot(run.t, np.degrees(run.true("delta")), color="tab:green", lw=0.8)
    ax[1].set_ylabel("steer angle [deg]")
    ax[2].plot(run.t, run.true("T_delta"), color="k", lw=0.7)
    ax[2].set_ylabel("steer torque [N m]")
    ax[2].set_xlabel("time [s]")
    for a in ax:
        a.grid(alpha=0.3)
    ax[0].legend(fontsize=7, loc="upper left", ncol=3)
    ax[0].set_title(
        f"Chen & Dao Fig. 7 analogue: roll tracking at 15 km/h, nonlinear plant, "
        f"poles {[round(float(np.real(z)), 2) for z in poles]} placed on the model identified at "
        f"{model.speed} m/s",
        fontsize=9,
    )
    save(fig, out / "cd_fig7_tracking.png")
    res["figure"] = "cd_fig7_tracking.png"
    return res


def _coast_entry(args: tuple) -> tuple[dict, dict, Any]:
    """One coasting run's analysis, summary entry (with its Floquet multipliers when
    periodic) and, when asked, the run itself (for the figures); picklable worker:
    (parameters, initial condition, duration [s], keep the run)."""

    p, ic, duration, keep = args
    traj = lc.coast(p, ic, duration)
    r = lc.periodicity(traj, ic.label)
    return r.as_dict(), lc.summary_entry(p, ic, r), traj if keep else None


def limit_cycle_study(
    p: BicycleParameters,
    out: Path,
    duration: float,
    log: Callable[[str], None] = lambda s: None,
    workers: int = 1,
    dask: str | None = None,
) -> dict[str, Any]:
    """Figs. 4-5: coasting runs from the paper's initial conditions + periodicity check.

    Parameters
    ----------
    p : BicycleParameters
        The simulated bicycle.
    out : Path
        Folder for the phase-portrait and energy/speed PNGs.
    duration : float
        Length of each coasting run [s].
    log : callable
        Progress lines.
    workers : int, optional
        Worker processes for the runs and their Floquet multipliers (1: in this process).
    dask : str or None, optional
        ``"local"`` or a Dask scheduler address (:mod:`bikeid.experiments.parallel`).

    Returns
    -------
    dict
        Per figure the verdicts of :func:`experiments.papers.limit_cycles.periodicity`;
        ``limit_cycles``: one :func:`experiments.papers.limit_cycles.summary_entry` per initial
        condition (class, period, Floquet multipliers); ``mirror_checks``: the exactly
        mirrored runs of the periodic cases and their multipliers;
        the linear eigenvalues at 3.5 m/s [1/s], the true critical speeds [m/s] and the
        figure file names.
    """

    res: dict[str, Any] = {
        "speed": lc.SPEED,
        "duration": duration,
        "figures": [],
        "limit_cycles": [],
    }
    figs = (("fig4", lc.FIG4_CONDITIONS), ("fig5", lc.FIG5_CONDITIONS))
    conds = [ic for _, cs in figs for ic in cs]
    # every run and its exact mirror image in one pool (a mirror is only kept for a
    # periodic original; the mirrors of falls are short runs)
    mirrors = [lc.mirrored(ic) for ic in conds]
    jobs = [(p, ic, duration, True) for ic in conds] + [(p, ic, duration, False) for ic in mirrors]
    done = map_jobs(_coast_entry, jobs, workers, dask)
    by_label = {ic.label: d for ic, d in zip(conds + mirrors, done, strict=True)}
    for name, cs in figs:
        res[name] = [by_label[ic.label][0] for ic in cs]
        res["limit_cycles"] += [dict(by_label[ic.label][1], figure=name) for ic in cs]
        trajs = [by_label[ic.label][2] for ic in cs]  # the runs the pool analysed
        labels = [ic.label for ic in cs]
        lc.plot_phase_portraits(
            trajs,
            labels,
            out / f"cd_{name}_phase.png",
            f"Chen & Dao {name[:3].title()}. {name[3]} analogue: coasting at "
            f"3.5 m/s, no steer torque, {duration:g} s (benchmark)",
        )
        lc.plot_energy_speed(
            trajs,
            labels,
            out / f"cd_{name}_energy_speed.png",
            f"{name[:3].title()}. {name[3]} runs: energy conservation and speed",
        )
        res["figures"] += [f"cd_{name}_phase.png", f"cd_{name}_energy_speed.png"]
        log(f"  {name}: " + ", ".join(f"{r['label']}: {r['verdict']}" for r in res[name]))
    res["mirror_checks"] = _mirror_checks(res["limit_cycles"], by_label)
    ev = np.sort_complex(eigenvalues(p, lc.SPEED))
    res["linear_eigenvalues"] = ev
    cs = critical_speeds(p)
    res["critical_true"] = {k: cs[k] for k in ("v_d", "v_w", "v_c")}
    return res


def _mirror_checks(entries: list[dict], by_label: dict[str, tuple[dict, dict]]) -> list[dict]:
    """The exact mirror image of every periodic case (``by_label``: label -> the
    :func:`_coast_entry` result, mirrors included); its multipliers must agree."""

    conds = {ic.label: ic for ic in lc.FIG4_CONDITIONS + lc.FIG5_CONDITIONS}
    out = []
    for e in entries:
        if e["outcome"] != "periodic":
            continue
        m = by_label[lc.mirrored(conds[e["label"]]).label][1]
        d = None
        if m["floquet_multipliers"] is not None and e["floquet_multipliers"] is not None:
            a = np.array([complex(*z) for z in e["floquet_multipliers"]])
            b = np.array([complex(*z) for z in m["floquet_multipliers"]])
            d = float(np.max(np.abs(a - b))) if a.size == b.size else None
        out.append({"of": e["label"], "mirror": m, "max_multiplier_difference": d})
    return out
