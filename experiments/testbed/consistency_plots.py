"""Figures of the consistency study: RMSE against N with the 1/sqrt(N) reference, coverage.

:func:`plot_consistency` draws, per study (controller), one panel of each estimator's RMSE
(all components and speeds, [1/s]) against the number of samples N on log axes with a line
of slope -1/2 through the first point of the estimator with the smallest first RMSE, and one
panel of the fraction of the estimator's own intervals containing the truth per length,
with the nominal level; saved atomically by :func:`bikeid.experiments.plots.save`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["plot_consistency"]


def plot_consistency(studies: list[dict[str, Any]], path: str | Path) -> Path:
    """Draw the consistency figures of one or more studies.

    Parameters
    ----------
    studies : list of dict
        :func:`bikeid.experiments.testbed.consistency.run_consistency` results, each with
        ``controller``.
    path : str or Path
        Figure file (format from its suffix).

    Returns
    -------
    Path
        The file written.
    """
    from matplotlib.ticker import NullFormatter

    from bikeid.experiments.plots import plt, save

    fig, axes = plt.subplots(len(studies), 2, figsize=(10, 3.6 * len(studies)), squeeze=False)
    for (ax, axc), st in zip(axes, studies, strict=True):
        dt = st["scenario"]["sample_time"]
        starts = []
        for name, m in st["methods"].items():
            n = np.array(m["durations"]) / dt
            r = np.array([np.nan if x is None else x for x in m["rmse"]], float)
            ax.loglog(n, r, "o-", label=f"{name}: {m['verdict']}")
            if np.isfinite(r[0]):
                starts.append((r[0], n))
            if m["coverage"]:
                f = [np.nan if c is None else c["fraction"] for c in m["coverage"]]
                axc.semilogx(n, f, "o-", label=name)
        if starts:
            r0, n = min(starts, key=lambda s: s[0])
            ax.loglog(n, r0 * np.sqrt(n[0] / n), "k--", label="slope -1/2")
        n_all = np.array(st["scenario"]["durations"]) / dt
        for a in (ax, axc):  # ticks at the lengths studied, no crowded minor labels
            a.set_xticks(n_all, [f"{x:g}" for x in n_all])
            a.xaxis.set_minor_formatter(NullFormatter())
        ax.set_xlabel("samples N")
        ax.set_ylabel("RMSE of the eigenvalue errors [1/s]")
        ax.set_title(f"{st.get('controller', '')}: against {st['against']}")
        ax.legend(fontsize=7)
        axc.axhline(st["level"], color="k", ls="--", label=f"nominal {st['level']:g}")
        axc.set_ylim(0, 1.02)
        axc.set_xlabel("samples N")
        axc.set_ylabel("coverage of own intervals")
        axc.legend(fontsize=7)
    fig.tight_layout()
    return save(fig, path)
