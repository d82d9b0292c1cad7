"""Matplotlib figures shared by commands and reports (PNG, SI units, degrees only in labels)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from bikeid.dataset.files import atomic_path  # noqa: E402

MODE_STYLE = {"weave": "tab:blue", "capsize": "tab:red", "caster": "tab:green"}


def save(fig, path: str | Path) -> Path:
    """Save a figure as PNG atomically (:func:`dataset.files.atomic_path`) and close it.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        The figure (closed afterwards, also on error).
    path : str or path-like
        The PNG file; its folder is created if missing.  A symlink or device there is
        refused (ValueError).

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    path = Path(path)
    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, format="png", dpi=130, bbox_inches="tight")
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


def plot_eigenvalues(sweep, path: str | Path, title: str = "", critical: dict | None = None):
    """Real and imaginary parts of tracked eigenvalues against speed.

    Parameters
    ----------
    sweep : EigenSweep
        Eigenvalues [1/s] against speed [m/s] with mode labels
        (:func:`bikeid.sim.linear.eigenvalues_vs_speed`).
    path : str or Path
        PNG file to write (atomically, :func:`save`).
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
