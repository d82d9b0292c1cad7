"""Matplotlib figures shared by commands and reports (radians inside, degrees in plots).

A figure file's suffix names its format (:data:`FIGURE_FORMATS`, :func:`figure_format`):
PNG, PDF, SVG, EPS or PS; the reports' own figures are PNG.

Angles are drawn in degrees (the design's convention: radians inside, degrees only in plots
and reports) unless the user's own logs were in radians (:func:`angle_unit` reads the
import settings a run or model file stores).  Bode phases of several curves are put on one
360-degree branch (:func:`phase_deg`, :func:`phases_on_one_branch`,
:func:`points_on_branch`).  :func:`layout_problems` checks a rendered figure for text
outside it and for labels of neighbouring axes that overlap.
"""

from __future__ import annotations

import textwrap
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import matplotlib
from matplotlib.text import Text

from bikeid.sim.linear import eigenvalues, eigenvalues_vs_speed

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from bikeid.dataset.files import atomic_path  # noqa: E402
from bikeid.sim.errors import InputError  # noqa: E402

MODE_STYLE = {"weave": "tab:blue", "capsize": "tab:red", "caster": "tab:green"}
#: Formats a figure file may have, named by its suffix (case ignored): matplotlib's own
#: writers for raster PNG and vector PDF, SVG, EPS and PS.
FIGURE_FORMATS = ("png", "pdf", "svg", "eps", "ps")


def figure_format(path: str | Path, option: str = "figure file") -> str:
    """The format of a figure file, named by its suffix.

    Parameters
    ----------
    path : str or path-like
        The figure file.
    option : str, optional
        How the file was given (a command-line option such as ``--plot``), for the message.

    Returns
    -------
    str
        One of :data:`FIGURE_FORMATS` (lower case).

    Raises
    ------
    InputError
        If the suffix is none of :data:`FIGURE_FORMATS` (one line naming the supported ones).
    """
    suffix = Path(path).suffix.lower().lstrip(".")
    if suffix not in FIGURE_FORMATS:
        what = f"unsupported figure format '.{suffix}'" if suffix else "no suffix naming a format"
        endings = ", ".join(f".{f}" for f in FIGURE_FORMATS[:-1]) + f" or .{FIGURE_FORMATS[-1]}"
        raise InputError(f"{option} {path}: {what}; give a file name ending in {endings}")
    return suffix


def save(fig, path: str | Path) -> Path:
    """Save a figure atomically (:func:`dataset.files.atomic_path`) and close it.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        The figure (closed afterwards, also on error).
    path : str or path-like
        The figure file, in the format its suffix names (:func:`figure_format`: .png,
        .pdf, .svg, .eps, .ps; rasters at 130 dpi); its folder is created if missing.  A
        symlink or device there is refused (ValueError).

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    InputError
        If the suffix names no supported format (nothing is written).
    """
    path = Path(path)
    try:
        fmt = figure_format(path)
        with atomic_path(path) as tmp:
            fig.savefig(tmp, format=fmt, dpi=130, bbox_inches="tight")
    finally:
        plt.close(fig)
    return path


def phase_deg(response, low: float = -270.0) -> np.ndarray:
    """Phase of a frequency response [deg], unwrapped along frequency on one branch.

    ``np.unwrap`` along the (increasing) frequencies, then shifted by a multiple of 360 deg
    so that the lowest-frequency value lies in (``low``, ``low`` + 360]: every curve drawn
    with it starts on the same branch, whatever ``np.angle`` returned for its first point
    (e.g. -180 or +180 for a negative static gain).

    Parameters
    ----------
    response : (N,) array_like of complex
        Frequency response at increasing frequencies.
    low : float, optional
        Lower end of the starting branch [deg] (default -270: phases start in (-270, 90]).

    Returns
    -------
    (N,) ndarray
        Phase [deg].
    """
    ph = np.degrees(np.unwrap(np.angle(np.asarray(response, complex).ravel())))
    k = np.ceil((low - ph[0]) / 360.0)
    if ph[0] + 360.0 * k <= low:
        k += 1
    return ph + 360.0 * k


def phases_on_one_branch(
    curves: Sequence[tuple[Any, Any]], low: float = -270.0
) -> list[np.ndarray]:
    """Phases [deg] of several frequency responses on one 360-degree branch.

    The first curve is placed by :func:`phase_deg` (its lowest-frequency value in
    (``low``, ``low`` + 360]); every further curve is unwrapped along its own frequencies
    and shifted by the multiple of 360 deg that brings its lowest-frequency value nearest
    to the first curve's phase there (interpolated linearly, held at the ends).
    Curves that agree at their lowest frequency are thus drawn on top of each other, even
    when ``np.angle`` put their first points on opposite sides of the branch cut at
    +-180 deg.

    Parameters
    ----------
    curves : sequence of (f, H)
        Per curve the increasing frequencies (any unit, the same for all curves)
        and the complex response there.
    low : float, optional
        Lower end of the first curve's starting branch [deg] (default -270).

    Returns
    -------
    list of ndarray
        Phase [deg] of each curve, in the order given.
    """
    out: list[np.ndarray] = []
    ref_f = ref_ph = None
    for f, H in curves:
        f = np.asarray(f, float).ravel()
        if ref_ph is None:
            ph = phase_deg(H, low)
            ref_f, ref_ph = f, ph
        else:
            ph = np.degrees(np.unwrap(np.angle(np.asarray(H, complex).ravel())))
            target = np.interp(f[0], ref_f, ref_ph)
            ph = ph + 360.0 * np.round((target - ph[0]) / 360.0)
        out.append(ph)
    return out


def points_on_branch(f, H, ref_f, ref_phase: np.ndarray) -> np.ndarray:
    """Phases [deg] of scattered response points, each on the branch of a reference curve.

    A nonparametric estimate at a few frequencies cannot be unwrapped by itself; each point
    is given the phase within 180 deg of the reference curve (interpolated linearly) at its
    frequency: the angle of ``H`` relative to the curve, added to the curve's phase.

    Parameters
    ----------
    f : (M,) array_like
        Frequencies of the points (the unit of ``ref_f``).
    H : (M,) array_like of complex
        Response at the points.
    ref_f : (N,) array_like
        Increasing frequencies of the reference curve.
    ref_phase : (N,) array_like
        The reference curve's phase [deg] (e.g. from :func:`phases_on_one_branch`).

    Returns
    -------
    (M,) ndarray
        Phase [deg] of each point, within (-180, 180] of the reference at its frequency.
    """
    f = np.asarray(f, float).ravel()
    ref = np.interp(f, np.asarray(ref_f, float), np.asarray(ref_phase, float))
    rel = np.degrees(np.angle(np.asarray(H, complex).ravel() * np.exp(-1j * np.radians(ref))))
    return ref + rel


#: The angle signals of a run and their SI units (drawn in degrees or radians).
ANGLE_SIGNALS = {"phi": "rad", "delta": "rad", "phidot": "rad/s", "deltadot": "rad/s"}


def _declared_units(source: Any) -> list[str]:
    """The units in which a source says the user's angle signals were logged."""
    if source is None or isinstance(source, str):
        return []
    if hasattr(source, "meta"):  # a Run
        source = source.meta
    if isinstance(source, Mapping):
        imp = source.get("import")
        if isinstance(imp, Mapping):  # a run's meta: the importer's conversions
            conv = imp.get("units") or {}
            return [str(c.get("from")) for k, c in conv.items()
                    if k in ANGLE_SIGNALS and isinstance(c, Mapping)]  # fmt: skip
        if source.get("format") in ("csv", "hdf5"):  # a model file's settings
            units = source.get("units") or {}
            mapped = [k for k in (source.get("columns") or {}) if k in ANGLE_SIGNALS]
            return [str(units.get(k, ANGLE_SIGNALS[k])) for k in mapped]
        return []
    if isinstance(source, Sequence):
        return [u for item in source for u in _declared_units(item)]
    return []


def angle_unit(source: Any = None) -> str:
    """The unit angles are drawn in: the user's, degrees by default.

    Parameters
    ----------
    source : Run, run meta dict, model-file settings dict, sequence of them, or None
        Where the user's units are stated: a run's ``meta["import"]["units"]``
        (:mod:`bikeid.dataset.importers`), or the ``settings`` of a model file written by
        ``bikeid identify`` (``format`` csv/hdf5 with ``columns`` and ``units``; a mapped
        angle signal without a unit was logged in SI units, radians).

    Returns
    -------
    str
        ``"rad"`` when every angle signal the source states was logged in radians (rad or
        rad/s), else ``"deg"`` (also for bikeid's own data, which state nothing: the
        design's convention, degrees in plots and reports).
    """
    units = _declared_units(source)
    return "rad" if units and all(u in ("rad", "rad/s") for u in units) else "deg"


def display_scale(signal: str, angle: str = "deg") -> tuple[float, str]:
    """Factor from bikeid's SI value of a signal to the plotted value, and its unit.

    Parameters
    ----------
    signal : str
        bikeid signal name (``phi``, ``delta``, ``phidot``, ``deltadot``, ``T_delta``...).
    angle : {"deg", "rad"}, optional
        The unit angles are drawn in (:func:`angle_unit`).

    Returns
    -------
    factor : float
        Multiply the SI value by this (180/pi for an angle or rate in degrees, else 1).
    unit : str
        The plotted unit ("deg", "deg/s", "rad", "rad/s", "N m", "m/s", "N" or "-").
    """
    if angle not in ("deg", "rad"):
        raise ValueError(f"angle unit {angle!r}: give 'deg' or 'rad'")
    si = ANGLE_SIGNALS.get(signal)
    if si is not None:
        if angle == "rad":
            return 1.0, si
        return float(np.degrees(1.0)), si.replace("rad", "deg")
    return 1.0, {"T_delta": "N m", "v": "m/s", "F": "N"}.get(signal, "-")


def wrap_title(text: str, width: int) -> str:
    """A title wrapped at ``width`` characters per line (existing line breaks kept).

    Parameters
    ----------
    text : str
        The title.
    width : int
        Most characters per line (e.g. about 13 per inch of axes at 9 pt).

    Returns
    -------
    str
        The wrapped title.
    """
    return "\n".join(textwrap.fill(line, width) if line else line for line in text.split("\n"))


def _drawn_tick_labels(axis) -> list:
    """Tick labels an axis draws: visible, non-empty and inside the view interval."""
    lo, hi = sorted(axis.get_view_interval())
    span = (hi - lo) * 1e-9
    out = []
    for ticks in (axis.get_major_ticks(), axis.get_minor_ticks()):
        for tick in ticks:
            loc = tick.get_loc()
            if loc is None or not lo - span <= loc <= hi + span:
                continue
            for lab in (tick.label1, tick.label2):
                if lab.get_visible() and lab.get_text().strip():
                    out.append(lab)
    return out


def layout_problems(fig, tol: float = 1.0) -> list[str]:
    """Texts a rendered figure clips or that overlap a neighbouring axes' labels.

    The figure is drawn with its own layout engine (Agg).  Checked: every visible,
    non-empty text of the figure (titles, axis and tick labels, legends, annotations)
    lies inside the figure; no two tick labels of one axis overlap; the title, axis
    labels and tick labels of one axes do not overlap those of another axes nor the other
    axes' plotting area.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        The figure (not saved, not closed).
    tol : float, optional
        Overlap or overhang tolerated [pixels] (default 1).

    Returns
    -------
    list of str
        One line per problem (empty when the figure fits).
    """

    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    box = fig.bbox
    problems = []

    def overlap(a, b) -> bool:
        return (min(a.x1, b.x1) - max(a.x0, b.x0) > tol
                and min(a.y1, b.y1) - max(a.y0, b.y0) > tol)  # fmt: skip

    texts = [t for t in fig.findobj(Text)
             if t.get_visible() and t.get_text().strip() and t.figure is not None]  # fmt: skip
    axes = [a for a in fig.axes if a.get_visible()]
    drawn = {id(t) for a in axes for ax_ in (a.xaxis, a.yaxis) for t in _drawn_tick_labels(ax_)}
    ticks = {id(t) for a in axes for ax_ in (a.xaxis, a.yaxis)
             for t in (*ax_.get_majorticklabels(), *ax_.get_minorticklabels())}  # fmt: skip
    for t in texts:
        if id(t) in ticks and id(t) not in drawn:
            continue
        e = t.get_window_extent(renderer)
        if (e.x0 < box.x0 - tol or e.y0 < box.y0 - tol or e.x1 > box.x1 + tol
                or e.y1 > box.y1 + tol):  # fmt: skip
            problems.append(f"text {t.get_text()[:40]!r} extends outside the figure")
    parts = {}
    for i, a in enumerate(axes):
        own = []
        for axis, name in ((a.xaxis, "x"), (a.yaxis, "y")):
            labels = _drawn_tick_labels(axis)
            ext = [lab.get_window_extent(renderer) for lab in labels]
            for k in range(len(ext)):
                for m in range(k + 1, len(ext)):
                    if overlap(ext[k], ext[m]):
                        problems.append(f"axes {i}: {name} tick labels "
                                        f"{labels[k].get_text()!r} and {labels[m].get_text()!r} "
                                        "overlap")  # fmt: skip
            own += [(f"{name} tick label {lab.get_text()!r}", e)
                    for lab, e in zip(labels, ext, strict=True)]  # fmt: skip
            if axis.label.get_visible() and axis.label.get_text().strip():
                own.append((f"{name} label {axis.label.get_text()!r}",
                            axis.label.get_window_extent(renderer)))  # fmt: skip
        for title in (a.title, a._left_title, a._right_title):
            if title.get_visible() and title.get_text().strip():
                own.append((f"title {title.get_text()[:40]!r}", title.get_window_extent(renderer)))
        parts[i] = own
    for i in range(len(axes)):
        for j, b in enumerate(axes):
            if i == j:
                continue
            area = b.get_window_extent(renderer)
            for what, e in parts[i]:
                if overlap(e, area):
                    problems.append(f"axes {i}: {what} overlaps the plotting area of axes {j}")
                if j > i:
                    for what_b, e_b in parts[j]:
                        if overlap(e, e_b):
                            problems.append(f"axes {i}: {what} overlaps axes {j}: {what_b}")
    return problems


def plot_eigenvalues(sweep, path: str | Path, title: str = "", critical: dict | None = None):
    """Real and imaginary parts of tracked eigenvalues against speed.

    Parameters
    ----------
    sweep : EigenSweep
        Eigenvalues [1/s] against speed [m/s] with mode labels
        (:func:`bikeid.sim.linear.eigenvalues_vs_speed`).
    path : str or Path
        Figure file to write (atomically, :func:`save`; format from its suffix).
    title : str, optional
        Figure title.
    critical : dict of str to float or None, optional
        Speeds [m/s] to mark with a dashed line and their names (e.g. ``v_w``, ``v_c``);
        None values are skipped.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(7, 6), sharex=True)
    seen = set()
    for j, lab in enumerate(sweep.labels):
        color = MODE_STYLE.get(lab, "0.4")
        name = lab if lab not in seen else None
        seen.add(lab)
        ax1.plot(sweep.speeds, sweep.values[:, j].real, color=color, label=name)
        ax2.plot(sweep.speeds, np.abs(sweep.values[:, j].imag), color=color, label=name)
    for ax in (ax1, ax2):
        ax.axhline(0, color="k", lw=0.6)
        ax.grid(alpha=0.3)
        if critical:
            for key, val in critical.items():
                if val is not None:
                    ax.axvline(val, color="0.5", ls="--", lw=0.8)
                    if ax is ax1:
                        ax.annotate(key, (val, ax1.get_ylim()[1]), fontsize=8, ha="center",
                                    va="bottom")  # fmt: skip
    ax1.set_ylabel("real part [1/s]")
    ax2.set_ylabel("|imaginary part| [rad/s]")
    ax2.set_xlabel("speed v [m/s]")
    ax1.legend(loc="lower left")
    ax1.set_title(title)
    return save(fig, path)


def _interval_rows(identified: Sequence[Any]) -> list[tuple[float, np.ndarray, Any]]:
    """(speed, eigenvalues, (4, 4) [re lo, re hi, im lo, im hi] or None) per speed."""

    def cplx(z: Any) -> complex:
        return complex(z["re"], z["im"]) if isinstance(z, Mapping) else complex(z)

    def num(x: Any) -> float:
        return np.nan if x is None else float(x)

    rows = []
    for item in identified:
        if hasattr(item, "real_lower"):  # an EigenIntervals
            bounds = np.column_stack([item.real_lower, item.real_upper, item.imag_lower,
                                      item.imag_upper])  # fmt: skip
            rows.append((float(item.speed), np.asarray(item.values, complex), bounds))
            continue
        ei = item.get("eigenvalue_intervals")
        if ei:
            vals = np.array([cplx(r["value"]) for r in ei["eigenvalues"]])
            bounds = np.array([[num(r["real"][0]), num(r["real"][1]), num(r["imag"][0]),
                                num(r["imag"][1])] for r in ei["eigenvalues"]])  # fmt: skip
        else:
            vals, bounds = np.array([cplx(z) for z in item["eigenvalues"]]), None
        rows.append((float(item["speed"]), vals, bounds))
    return rows


def _bars_title(rows: Sequence[tuple[float, np.ndarray, Any]]) -> str:
    """The complex plane's title, saying whether the points carry interval bars: at every
    speed, at some (naming them), or at none (withheld or not computed)."""
    drawn = [v for v, _, b in rows if b is not None and np.isfinite(b).any()]
    if len(drawn) == len(rows):
        return "eigenvalues with 95 % intervals (bars) vs nominal (squares)"
    if not drawn:
        return ("eigenvalues (no 95 % intervals: withheld or not computed) vs nominal "
                "(squares)")  # fmt: skip
    at = f"{len(drawn)} of {len(rows)} speeds"
    if len(drawn) <= 4:
        at = f"{', '.join(f'{v:g}' for v in drawn)} m/s only"
    return f"eigenvalues, 95 % intervals (bars) at {at}, vs nominal (squares)"


def _errorbars(ax, x, y, xlo, xhi, ylo, yhi, **kw) -> None:
    """Points with (asymmetric) error bars; a missing or non-finite end draws no bar."""

    def err(c, lo, hi):
        if lo is None:
            return None
        e = np.vstack([c - lo, hi - c])
        return np.where(np.isfinite(e), np.abs(e), 0.0)

    ax.errorbar(x, y, xerr=err(x, xlo, xhi), yerr=err(y, ylo, yhi), fmt="o", ms=4,
                capsize=2, lw=0.9, **kw)  # fmt: skip


def plot_identified_eigenvalues(
    identified: Sequence[Any],
    nominal,
    path: str | Path,
    nominal_label: str = "nominal bicycle",
    speed_model: Any = None,
    title: str = "",
) -> Path:
    """Identified eigenvalues with their confidence intervals against a nominal bicycle's.

    Left: the complex plane, per fitted speed the identified eigenvalues (filled dots) with
    the intervals of their real and imaginary parts as error bars, and the nominal
    bicycle's Whipple eigenvalues at that speed (open squares, same colour).  For a fit at
    several speeds or a model over speed, right: real and imaginary parts against speed,
    the nominal bicycle's branches (solid; :func:`bikeid.sim.linear.eigenvalues_vs_speed`),
    the model over speed (dashed, when given) and the per-speed identified values with
    their intervals.

    Parameters
    ----------
    identified : sequence of EigenIntervals or dict
        Per fitted speed an :class:`bikeid.ident.uncertainty.EigenIntervals`, or a dict
        with ``speed`` [m/s], ``eigenvalues`` ((4,) complex [1/s], or ``{"re", "im"}``
        dicts) and optionally ``eigenvalue_intervals`` (``EigenIntervals.to_json()``;
        None: no interval, drawn without bars), as ``bikeid identify --json``'s
        ``per_speed`` rows.
    nominal : BicycleParameters or CanonicalMatrices
        The nominal bicycle (its linearized Whipple model).
    path : str or Path
        Figure file to write (atomically, :func:`save`; format from its suffix).
    nominal_label : str, optional
        Name of the nominal bicycle in the legend.
    speed_model : model with ``canonical_matrices()`` or None, optional
        A model over speed (e.g. :class:`bikeid.ident.pem.SpeedCanonicalModel`) whose
        eigenvalues are drawn against speed.
    title : str, optional
        Figure title (wrapped to fit).

    Returns
    -------
    pathlib.Path
        ``path``.
    """

    rows = _interval_rows(identified)
    if not rows:
        raise ValueError("no identified eigenvalues to plot")
    speeds = [v for v, _, _ in rows]
    over_speed = speed_model is not None or len(set(speeds)) > 1
    if over_speed:
        fig = plt.figure(figsize=(12, 6), layout="constrained")
        axd = fig.subplot_mosaic("AB;AC")
        plane, re_ax, im_ax = axd["A"], axd["B"], axd["C"]
    else:
        fig, plane = plt.subplots(figsize=(7, 6), layout="constrained")
        re_ax = im_ax = None
    for k, (v, vals, b) in enumerate(rows):
        c = f"C{k % 10}"
        nom = eigenvalues(nominal, v)
        lo = (None,) * 4 if b is None else (b[:, 0], b[:, 1], b[:, 2], b[:, 3])
        _errorbars(plane, vals.real, vals.imag, *lo, color=c,
                   label=f"identified, {v:g} m/s")  # fmt: skip
        plane.plot(nom.real, nom.imag, "s", mfc="none", color=c, ms=7,
                   label=f"{nominal_label}, {v:g} m/s")  # fmt: skip
        if over_speed:
            x = np.full(vals.size, v)
            _errorbars(re_ax, x, vals.real, None, None, lo[0], lo[1], color=c)
            im_lo = None if lo[2] is None else np.abs(lo[2])
            im_hi = None if lo[3] is None else np.abs(lo[3])
            if im_lo is not None:  # |Im|: the conjugate's interval mirrored
                im_lo, im_hi = np.minimum(im_lo, im_hi), np.maximum(im_lo, im_hi)
            _errorbars(im_ax, x, np.abs(vals.imag), None, None, im_lo, im_hi, color=c)
    plane.axhline(0, color="k", lw=0.5)
    plane.axvline(0, color="k", lw=0.5)
    plane.set_xlabel("real part [1/s]")
    plane.set_ylabel("imaginary part [rad/s]")
    plane.grid(alpha=0.3)
    plane.legend(fontsize=7, loc="best")
    plane.set_title(_bars_title(rows), fontsize=9)
    if over_speed:
        grid = np.linspace(max(0.2, min(speeds) - 1.0), max(speeds) + 1.0, 120)
        curves = [(eigenvalues_vs_speed(nominal, grid).values, "-", nominal_label)]
        if speed_model is not None:
            sweep = eigenvalues_vs_speed(speed_model.canonical_matrices(), grid)
            curves.append((sweep.values, "--", "identified model over speed"))
        for vals, ls, name in curves:
            for j in range(vals.shape[1]):
                lab = name if j == 0 else None
                re_ax.plot(grid, vals[:, j].real, color="0.3", ls=ls, lw=1.0, label=lab)
                im_ax.plot(grid, np.abs(vals[:, j].imag), color="0.3", ls=ls, lw=1.0)
        re_ax.axhline(0, color="k", lw=0.5)
        re_ax.set_ylabel("real part [1/s]")
        im_ax.set_ylabel("|imaginary part| [rad/s]")
        im_ax.set_xlabel("speed v [m/s]")
        re_ax.legend(fontsize=7, loc="best")
        for ax in (re_ax, im_ax):
            ax.grid(alpha=0.3)
    if title:
        fig.suptitle(wrap_title(title, 150 if over_speed else 85), fontsize=10)
    return save(fig, path)
