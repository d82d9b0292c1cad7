"""``bikeid reproduce``: every figure and table of Chen & Dao (2010) and Moore & Hubbard, redone
on the testbed with paper | bikeid identified | ground truth side by side.

:func:`reproduce` runs all stages (progress: one line per stage on stderr), writes PNG figures,
``report.md`` and ``summary.json`` into ``out``.  Ground truth = the linearization of the
simulated plant (:mod:`sim.linear`) unless a table says otherwise.  :data:`QUICK` and
:data:`FULL` hold every setting (speeds, durations); the report lists the ones used.
This module runs the studies (numerics in :mod:`experiments.papers.chen_dao` and
:mod:`experiments.papers.moore_hubbard`, Chen & Dao's figures in
:mod:`experiments.papers.chen_dao_figures`); :mod:`experiments.papers.report`
renders ``report.md``.
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bikeid.controllers.registry import STUDY_CONTROLLERS
from bikeid.experiments.papers import chen_dao as cd
from bikeid.experiments.papers import chen_dao_figures as cdf
from bikeid.experiments.papers import limit_cycles as lcm
from bikeid.experiments.papers import moore_hubbard as mh
from bikeid.experiments.papers.chen_dao import ANOMALY_SPEEDS
from bikeid.experiments.papers.report import build_report
from bikeid.experiments.plots import plt, save
from bikeid.experiments.report import write
from bikeid.sim.linear import critical_speeds, eigenvalues_vs_speed
from bikeid.sim.parameters import benchmark, by_name

__all__ = ["FULL", "QUICK", "Settings", "reproduce"]


@dataclass(frozen=True)
class Settings:
    """What a reproduction computes (speeds in m/s, durations in s).

    Attributes
    ----------
    name : str
        ``"full"`` or ``"quick"``.
    fig3_speeds : tuple of float
        Speeds [m/s] of the fuzzy-controller identifications for Chen & Dao Fig. 3.
    zoom_speeds : tuple of float
        Extra PEM-only speeds [m/s] of Fig. 3(b): the paper's anomaly speeds and a grid over
        3.1-4.0 m/s, where the capsize-anomaly verdict is computed.
    sweep_speeds : tuple of float
        Speeds [m/s] of the controller sweep summary.
    id_duration : float
        Length of each identification run [s].
    fig2_duration : float
        Length of the Fig. 2 run at 4.2 m/s [s].
    fig7_duration : float
        Length of the Fig. 7 roll-tracking run [s].
    limit_cycle_duration : float
        Length of each coasting run of Figs. 4-5 and of the speed scan [s].
    scan_speeds : tuple of float
        Initial speeds [m/s] of the coasting speed scan (a uniform grid over 3.2-4.3 m/s).
    scan_step : float
        Step of that grid [m/s] (the windows' resolution).
    scan_duration : float
        Length of each run of the speed scan [s].
    mh_speeds : tuple of float
        Speeds [m/s] of the Moore & Hubbard reproduction.
    mh_duration : float
        Length of each Moore & Hubbard run [s].
    """

    name: str
    fig3_speeds: tuple[float, ...]
    zoom_speeds: tuple[float, ...]
    sweep_speeds: tuple[float, ...]
    id_duration: float
    fig2_duration: float
    fig7_duration: float
    limit_cycle_duration: float
    scan_speeds: tuple[float, ...]
    scan_step: float
    scan_duration: float
    mh_speeds: tuple[float, ...]
    mh_duration: float


def _speed(v: float | None) -> str:
    """A critical speed [m/s] to 3 decimals, or "none" (not in the identified range)."""
    return "none" if v is None else f"{v:.3f}"


def _grid(lo: float, hi: float, step: float) -> tuple[float, ...]:
    return tuple(float(round(v, 6)) for v in np.arange(lo, hi + step / 2, step))


#: The coasting speed scan: 3.2-4.3 m/s (below Chen & Dao's 3.152 every run falls; above
#: v_w = 4.29 m/s upright coasting is stable) at 0.01 m/s (full) / 0.04 m/s (quick), runs
#: capped at T_max = 300 s in both (the irregular windows stay irregular at 300 s); a run
#: still growing or periodic at T_max is decided by Newton on the Poincare map from its end
#: (:mod:`experiments.papers.orbit_convergence`).
SCAN_RANGE = (3.2, 4.3)
FULL = Settings(
    name="full",
    fig3_speeds=tuple(float(v) for v in np.arange(1.0, 15.01, 0.5)),
    zoom_speeds=ANOMALY_SPEEDS + _grid(3.1, 4.0, 0.05),
    sweep_speeds=tuple(float(v) for v in range(1, 16)),
    id_duration=50.0,
    fig2_duration=50.0,
    fig7_duration=50.0,
    limit_cycle_duration=300.0,
    scan_speeds=_grid(*SCAN_RANGE, 0.01),
    scan_step=0.01,
    scan_duration=300.0,
    mh_speeds=(2.5, 4.5, 7.0),
    mh_duration=30.0,
)
QUICK = Settings(
    name="quick",
    fig3_speeds=(1.0, 2.0, 3.0, 4.0, 4.5, 5.0, 6.0, 7.0, 8.0, 10.0, 12.0, 15.0),
    zoom_speeds=ANOMALY_SPEEDS + _grid(3.1, 4.0, 0.1),
    sweep_speeds=(2.0, 5.0, 10.0),
    id_duration=30.0,
    fig2_duration=50.0,
    fig7_duration=50.0,
    limit_cycle_duration=100.0,
    scan_speeds=_grid(*SCAN_RANGE, 0.04),
    scan_step=0.04,
    scan_duration=300.0,
    mh_speeds=(3.0, 6.0),
    mh_duration=20.0,
)

#: Controllers studied, by their stored names (``controllers.registry``).
CONTROLLERS = STUDY_CONTROLLERS
#: Stages of a reproduction (Fig. 2, the identification runs, Fig. 3, Figs. 4-5, the speed
#: scan, Fig. 7, Moore & Hubbard, the sweep summary), announced 0/8 .. 7/8, then the report.
STAGES = 8
#: Controllers identified only for the sweep summary (Fig. 3's fuzzy runs are reused there).
SWEEP_ONLY = tuple(c for c in CONTROLLERS if c != "fuzzy")
METHODS = ("pem", "direct")


def _stderr_log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def default_workers() -> int:
    """Worker processes by default: the CPU count, at most 2."""
    return max(1, min(2, os.cpu_count() or 1))


def stage_announcer(
    log: Callable[[str], None],
    progress: Callable[[int, int, str], None] | None,
    total: int,
) -> Callable[[str], float]:
    """The function that announces each stage once and returns its start time.

    Parameters
    ----------
    log : callable
        Log lines; a stage goes here (``[reproduce] name ...``) only without ``progress``.
    progress : callable or None
        ``progress(done, total, name)``: the bar or stage lines of the command, which
        announce the stage themselves (so it is said once, not by both).
    total : int
        Number of stages.

    Returns
    -------
    callable
        ``stage(name) -> time.perf_counter()`` at the stage's start.
    """
    done = 0

    def stage(name: str) -> float:
        nonlocal done
        if progress:
            progress(done, total, name)
        else:
            log(f"[reproduce] {name} ...")
        done += 1
        return time.perf_counter()

    return stage


def reproduce(
    out: str | Path,
    quick: bool = False,
    workers: int | None = None,
    log: Callable[[str], None] = _stderr_log,
    bicycle: str = "benchmark",
    progress: Callable[[int, int, str], None] | None = None,
    dask: str | None = None,
) -> dict[str, Any]:
    """Run every study into ``out``: figures, ``report.md`` and ``summary.json``.

    Parameters
    ----------
    out : str or path-like
        Output folder (created if missing).
    quick : bool
        :data:`QUICK` settings instead of :data:`FULL`.
    workers : int, optional
        Worker processes for the identification runs (default :func:`default_workers`).
    log : callable
        Progress lines (default: stderr).
    bicycle : str
        ``sim.parameters.by_name`` name of the simulated bicycle.
    progress : callable, optional
        ``progress(done, 8, label)`` before each of the 8 stages and at the end
        (:mod:`bikeid.experiments.progress`).
    dask : str or None, optional
        ``"local"`` or a Dask scheduler address for the batch jobs
        (:mod:`bikeid.experiments.parallel`); the numbers do not depend on it.

    Returns
    -------
    dict
        The summary (numbers; speeds [m/s], eigenvalues [1/s], times [s]) as written to
        ``summary.json``, with private keys (``_model``) that the file leaves out.
    """

    st = QUICK if quick else FULL
    workers = default_workers() if workers is None else int(workers)
    if workers < 1:
        raise ValueError(f"workers={workers}: need at least 1 process")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    p = by_name(bicycle)
    times: dict[str, float] = {}
    t_all = time.perf_counter()

    stage = stage_announcer(log, progress, STAGES)
    t0 = stage("Chen & Dao Fig. 2 / eqs. 5-6 (identification at 4.2 m/s)")
    f2 = cdf.fig2(p, out, st.fig2_duration)
    times["fig2"] = time.perf_counter() - t0
    t0 = stage(
        f"identification runs (one process pool): fuzzy at {len(st.fig3_speeds)} speeds for "
        f"Fig. 3 (speed held, and free from its initial value), pid and pole placement at "
        f"{len(st.sweep_speeds)} speeds for the sweep summary"
    )
    zoom_speeds = sorted({v for v in st.zoom_speeds if v not in st.fig3_speeds})
    jobs = [("fuzzy", float(v), st.id_duration, bicycle, METHODS) for v in st.fig3_speeds]
    jobs += [("fuzzy", float(v), st.id_duration, bicycle, ("pem",)) for v in zoom_speeds]
    jobs += [
        (c, float(v), st.id_duration, bicycle, METHODS) for c in SWEEP_ONLY for v in st.sweep_speeds
    ]
    n_rest = len(jobs) - len(st.fig3_speeds) - len(zoom_speeds)
    # Chen & Dao's runs start at a speed ("initial forward speed"): the same fits with the
    # speed free (the rear wheel coasting), for the free-speed experiment
    free_speeds = [float(v) for v in st.fig3_speeds] + [float(v) for v in zoom_speeds]
    jobs += [("fuzzy", v, st.id_duration, bicycle, ("pem",), "coast") for v in free_speeds]
    results = cd.run_jobs(jobs, workers, dask)
    n3 = len(st.fig3_speeds)
    grid, zoom = results[:n3], results[n3 : n3 + len(zoom_speeds)]
    rest = results[n3 + len(zoom_speeds) : n3 + len(zoom_speeds) + n_rest]
    free = results[n3 + len(zoom_speeds) + n_rest :]
    # the direct method: one regression over all speeds of a controller (K0dd vs K2dd)
    direct = {"fuzzy": cd.direct_stacked(grid, p)}
    for c in SWEEP_ONLY:
        direct[c] = cd.direct_stacked([g for g in rest if g["controller"] == c], p)
    times["identification_runs"] = time.perf_counter() - t0
    t0 = stage("Chen & Dao Fig. 3: eigenvalues against speed")
    f3 = cdf.fig3(p, grid, out, zoom)
    log(
        f"  identified v_w={_speed(f3['critical_identified']['v_w'])}, v_c="
        f"{_speed(f3['critical_identified']['v_c'])} m/s (true {f3['critical_true']['v_w']:.4f}, "
        f"{f3['critical_true']['v_c']:.4f})"
    )
    fs = cd.fig3_summary(p, free[:n3], free[n3:])
    free_speed = {
        "critical_identified": fs["critical_identified"],
        "anomaly": {k: v for k, v in fs["anomaly"].items() if k != "at_paper_speeds"},
        "rows": fs["rows"],
        "speed_ranges": [{"speed": g["speed"], "speed_range": g["speed_range"]} for g in free],
        "failed": fs["failed"],
    }
    free_speed["comparison"] = cd.free_speed_verdict(f3, fs)
    log(f"  speed free from the initial speed: {free_speed['comparison']['verdict']} the "
        f"paper's shifts ({free_speed['comparison']['reason']})")  # fmt: skip
    times["fig3"] = time.perf_counter() - t0
    t0 = stage("Chen & Dao Figs. 4-5: coasting at 3.5 m/s, periodicity")
    lc = cdf.limit_cycle_study(p, out, st.limit_cycle_duration, log, workers, dask)
    times["figs4_5"] = time.perf_counter() - t0
    coarser = ""
    if st.scan_step > FULL.scan_step:
        coarser = f", coarser than the full run's {FULL.scan_step:g} m/s"
    t0 = stage(
        f"Chen & Dao v_l..v_w: coasting speed scan ({len(st.scan_speeds)} initial speeds "
        f"{st.scan_speeds[0]:g}-{st.scan_speeds[-1]:g} m/s, step {st.scan_step:g} m/s{coarser}, "
        f"{st.scan_duration:g} s runs)"
    )

    scan = lcm.speed_scan(p, st.scan_speeds, st.scan_duration, workers=workers, dask=dask)
    scan["paper"] = cd.PAPER["periodic_range"]
    scan["grid_note"] = f"grid step {st.scan_step:g} m/s" + (f" ({coarser[2:]})" if coarser else "")
    log(
        "  periodic windows (initial speed, family): "
        + ("; ".join(f"{a:.2f}-{b:.2f} {f}" for a, b, f in scan["periodic_windows"]) or "none")
        + f" m/s ({scan['grid_note']}; paper: 3.152-3.994, the band v_l..v_w of its "
        "identified linear models, not a scan)"
    )
    times["speed_scan"] = time.perf_counter() - t0
    t0 = stage("Chen & Dao Fig. 7: pole-placement roll tracking at 15 km/h")
    f7 = cdf.fig7(p, f2["_model"], out, st.fig7_duration)
    times["fig7"] = time.perf_counter() - t0
    t0 = stage("Moore & Hubbard: 3 riders x 2 environments, Tables 2-5, Figs. 2-4")
    mhr = mh.reproduce(out, st.mh_speeds, st.mh_duration, workers, log, dask)
    times["moore_hubbard"] = time.perf_counter() - t0
    t0 = stage("sweep summary")
    sweep = {"fuzzy": [g for g in grid if g["speed"] in st.sweep_speeds]}
    for c in SWEEP_ONLY:
        sweep[c] = [g for g in rest if g["controller"] == c]
    sw = _sweep_summary(sweep, out, direct)
    times["sweep"] = time.perf_counter() - t0
    if progress:
        progress(STAGES, STAGES, "report")
    times["total"] = time.perf_counter() - t_all
    crit = critical_speeds(p)
    summary = {
        "settings": asdict(st),
        "bicycle": bicycle,
        "workers": workers,
        "seconds": times,
        "truth": {
            "critical_speeds": {k: crit[k] for k in ("v_d", "v_w", "v_c")},
            "weave_frequency_at_v_w": crit["weave_frequency"],
        },
        "chen_dao": {
            "fig2": f2,
            "fig3": f3,
            "free_speed": free_speed,
            "figs4_5": lc,
            "periodic_windows": scan["periodic_windows"],
            "speed_scan": {k: v for k, v in scan.items() if k != "points"},
            "fig7": f7,
        },
        "limit_cycles": lc["limit_cycles"],
        "speed_scan": scan["points"],
        "moore_hubbard": mhr,
        "sweep": sw,
    }
    rep = build_report(summary)
    md, js = write(out, rep, summary)
    log(f"[reproduce] done in {times['total']:.1f} s: {md} and {js}")
    return summary


# -- sweep summary -------------------------------------------------------------------------------
def _sweep_summary(
    sweep: dict[str, list[dict]], out: Path, direct: dict[str, dict] | None = None
) -> dict[str, Any]:
    """Identified vs true eigenvalues per controller and method, and their figure; the
    direct method's entry carries its one stacked regression (``direct[controller]``,
    :func:`experiments.papers.chen_dao.direct_stacked`) as ``stacked``."""

    res: dict[str, Any] = {}
    fig, axs = plt.subplots(2, 3, figsize=(13, 7), sharex=True)
    for j, c in enumerate(CONTROLLERS):
        rows = sweep.get(c, [])
        for m, mk in zip(METHODS, ("x", "+"), strict=True):
            errs, per = [], []
            for g in rows:
                r = g["methods"].get(m, {})
                if r.get("error") is not None or "eig" not in r:
                    per.append({"speed": g["speed"], "error": r.get("error", "not run")})
                    continue
                d = np.abs(np.asarray(r["eig"]) - g["truth"])
                errs.append(float(d.max()))
                per.append(
                    {
                        "speed": g["speed"],
                        "max_abs_error": float(d.max()),
                        "max_rel_error": float(np.max(d / np.abs(g["truth"]))),
                        "identified": r["eig"],
                        "true": g["truth"],
                        "fell_at": g["fell_at"],
                        "max_abs_deg": g.get("max_abs_deg"),
                    }
                )
                axs[0, j].plot(
                    [g["speed"]] * 4,
                    np.real(r["eig"]),
                    mk,
                    ms=5,
                    color="tab:blue" if m == "pem" else "tab:red",
                )
                axs[1, j].plot(
                    [g["speed"]] * 4,
                    np.abs(np.imag(r["eig"])),
                    mk,
                    ms=5,
                    color="tab:blue" if m == "pem" else "tab:red",
                )
            res[f"{c}/{m}"] = {
                "controller": c,
                "method": m,
                "n_ok": len(errs),
                "n": len(rows),
                "median_max_abs_error": float(np.median(errs)) if errs else None,
                "worst": max(errs) if errs else None,
                "per_speed": per,
            }
            if m == "direct" and direct is not None:
                res[f"{c}/{m}"]["stacked"] = direct.get(c)
        sp = [g["speed"] for g in rows]
        if sp:
            fine = np.linspace(min(sp), max(sp), 300)
            ev = eigenvalues_vs_speed(benchmark(), fine).values
            axs[0, j].plot(fine, ev.real, color="0.5", lw=0.8)
            axs[1, j].plot(fine, np.abs(ev.imag), color="0.5", lw=0.8)
        axs[0, j].set_title(f"{c}: x PEM, + direct", fontsize=9)
        axs[0, j].set_ylim(-30, 8)
        axs[1, j].set_xlabel("speed v [m/s]")
        for a in axs[:, j]:
            a.grid(alpha=0.3)
            a.axhline(0, color="k", lw=0.5)
    axs[0, 0].set_ylabel("real part [1/s]")
    axs[1, 0].set_ylabel("|imag part| [rad/s]")
    fig.suptitle(
        "Sweep summary: identified vs true eigenvalues (benchmark, nonlinear plant)\n"
        "x PEM: one model per speed; + direct: one regression over all speeds; grey: truth",
        fontsize=10,
    )
    save(fig, out / "sweep_eigenvalues.png")
    res["figure"] = "sweep_eigenvalues.png"
    return res
