"""Checks of a run's units and signs before any fit: sample period and rates vs angles.

:func:`bikeid.dataset.run.check_plausible` (every loader runs it) refuses values no bicycle
shows.  A log in the wrong unit often stays inside those bounds and fits a confident wrong
model (a time column in ms read as s makes a 74 s ride last 20 hours and every eigenvalue
100x too small).  :func:`check_run` catches the usual mistakes from the data themselves,
each refused with a one-line :class:`~bikeid.sim.errors.InputError` (exit 3) naming the
likely mistake and the option that fixes it:

``sample-period``
    The median sample period lies in :data:`~bikeid.sim.conventions.SAMPLE_PERIOD`
    (0.1 ms to 0.1 s).
``rate-derivative``
    Each rate agrees with the time derivative of its angle (phidot with d(phi)/dt, deltadot
    with d(delta)/dt, psidot with d(psi)/dt when both are logged).  Both signals are
    smoothed by a centred moving average over :data:`SMOOTHING` s, the derivative is the
    central difference, and the factor is the least-squares slope of the rate on the
    derivative over the run.  When the two correlate (|r| >= :data:`MIN_CORRELATION`, so
    noise or a quiet channel cannot trigger it) and the slope lies within a factor
    :data:`FACTOR_BAND` of 1000, 1/1000 (the time unit), 57.3, 1/57.3 (degrees declared as
    radians or the reverse) or -1 (one of the two signals flipped), the run is refused
    with the measured factor.  The steer-by-wire logs give slopes 1.00-1.09 at r >= 0.98.

The range checks the readers run on import (:func:`bikeid.dataset.run.check_plausible`, one
name per unit: ``angle-bounds``, ``rate-bounds``, ``speed-bounds``, ``torque-bounds``,
``force-bounds``, :data:`bikeid.dataset.run.BOUND_CHECKS`) and the informativity check of the
fit (:mod:`bikeid.ident.informativity`) share this vocabulary (:data:`CHECKS`).

Every check is skipped by name (``skip``; ``bikeid identify --skip-check NAME`` or
``--no-checks``), never silently: :func:`check_runs` returns a note for every skipped check
of this module, :func:`bounds_notes` one for every skipped range check.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from bikeid.sim.conventions import PLAUSIBLE, SAMPLE_PERIOD, UNITS
from bikeid.sim.errors import InputError

from .check_names import BOUND_CHECKS, SKIPPABLE_CHECKS

__all__ = [
    "CHECKS",
    "FACTOR_BAND",
    "MIN_CORRELATION",
    "RATE_PAIRS",
    "SMOOTHING",
    "bounds_notes",
    "check_run",
    "check_runs",
    "rate_factor",
]

#: Checks run before a fit, by the name ``--skip-check`` takes: the range checks of the
#: import (:data:`bikeid.dataset.run.BOUND_CHECKS`), this module's two, informativity.
CHECKS = SKIPPABLE_CHECKS
#: Rate and the angle it is the derivative of.
RATE_PAIRS = (("phidot", "phi"), ("deltadot", "delta"), ("psidot", "psi"))
#: Width of the moving average applied to angle and rate before comparing them [s]
#: (the bicycle's modes lie below ~3 Hz; 0.1 s removes encoder steps and gyro noise).
SMOOTHING = 0.1
#: Smallest |correlation| of rate and derivative for a verdict [-].
MIN_CORRELATION = 0.9
#: A slope within this factor of a named one is taken as that mistake [-].
FACTOR_BAND = 2.0

_DEG = 180.0 / math.pi
#: (factor of rate over derivative, the likely mistake, the fix).
_MISTAKES = (
    (1000.0, "the time column is in milliseconds but read as seconds",
     "give its unit: --units t=ms, units={{'t': 'ms'}} in Python (or, if the time is right, "
     "check both signals' units)"),
    (1e-3, "the time column is in seconds but declared as milliseconds",
     "drop t=ms from --units (units= in Python)"),
    (_DEG, "{rate} is in deg/s declared as rad/s, or {angle} in rad declared as deg",
     "give --units {rate}=deg/s, units={{'{rate}': 'deg/s'}} in Python (or remove {angle}=deg)"),
    (1.0 / _DEG, "{angle} is in degrees declared as radians, or {rate} in rad/s declared as "
     "deg/s", "give --units {angle}=deg, units={{'{angle}': 'deg'}} in Python (or remove "
     "{rate}=deg/s)"),
    (-1.0, "one of {rate} and {angle} has the opposite sign",
     "--flip the one logged positive to the left, flip=[...] in Python (bikeid: positive to "
     "the right)"),
)  # fmt: skip


def _smooth(x: np.ndarray, w: int) -> np.ndarray:
    if w <= 1:
        return x
    return np.convolve(x, np.ones(w) / w, mode="valid")


def rate_factor(angle: np.ndarray, rate: np.ndarray, dt: float) -> tuple[float, float]:
    """Least-squares factor of a rate on the derivative of its angle, and their correlation.

    Parameters
    ----------
    angle : (N,) array_like
        The angle [rad], as read.
    rate : (N,) array_like
        The rate [rad/s], as read.
    dt : float
        Sample period [s].

    Returns
    -------
    factor : float
        Slope of ``rate`` on d(angle)/dt (1 for consistent signals) [-]; NaN when the
        angle does not move.
    correlation : float
        Their correlation coefficient [-]; NaN when either does not move.
    """
    n = np.asarray(angle).size
    w = max(1, int(round(SMOOTHING / dt))) if dt > 0 else 1
    w = w if 3 * w <= n else 1  # a run shorter than three smoothing windows: unsmoothed
    a = _smooth(np.asarray(angle, float), w)
    r = _smooth(np.asarray(rate, float), w)
    if a.size < 3:
        return math.nan, math.nan
    d = np.gradient(a, dt)
    d, r = d - d.mean(), r - r.mean()
    dd, rr = float(d @ d), float(r @ r)
    if dd == 0.0 or rr == 0.0:
        return math.nan, math.nan
    return float(r @ d) / dd, float(r @ d) / math.sqrt(dd * rr)


def _mistake(factor: float) -> tuple[float, str, str] | None:
    for f, what, fix in _MISTAKES:
        if f * factor > 0 and abs(math.log(factor / f)) <= math.log(FACTOR_BAND):
            return f, what, fix
    return None


def check_run(run: Any, source: str, skip: Iterable[str] = ()) -> None:
    """Refuse a run whose sample period or rates show a unit or sign mistake.

    Parameters
    ----------
    run : Run
        The run, in bikeid's units (after the importer's conversions).
    source : str
        What the run came from, for the message (a file name).
    skip : iterable of str, optional
        Names of :data:`CHECKS` not to run.

    Raises
    ------
    InputError
        ``<source>: sample period ... s is outside ...`` or ``<source>: <rate> is <factor>
        x d(<angle>)/dt ...``, naming the likely mistake and the option that fixes it.
    """
    skip = set(skip)
    lo, hi = SAMPLE_PERIOD
    dt = run.dt
    # (a relative 1e-9 for the round-off of a time base t = k dt)
    if "sample-period" not in skip and not (lo * (1 - 1e-9) <= dt <= hi * (1 + 1e-9)):
        duration = dt * (run.n - 1)
        hint = ("the time column is probably in milliseconds read as seconds: give --units "
                "t=ms, units={'t': 'ms'} in Python" if dt > hi else "the time column is "
                "probably in seconds declared as milliseconds (drop t=ms), or in microseconds: "
                "resample or rescale it")  # fmt: skip
        raise InputError(
            f"{source}: sample period {dt:.6g} s ({duration:.6g} s for {run.n} samples) is "
            f"outside the {lo:g}..{hi:g} s a bicycle logger produces "
            f"(sim.conventions.SAMPLE_PERIOD); {hint} (or --skip-check sample-period, "
            "skip=['sample-period'], for a log you know is sampled so)"
        )  # fmt: skip
    if "rate-derivative" in skip:
        return
    for rate, angle in RATE_PAIRS:
        if rate not in run.signals or angle not in run.signals:
            continue
        factor, corr = rate_factor(run.signals[angle], run.signals[rate], dt)
        if not (math.isfinite(corr) and abs(corr) >= MIN_CORRELATION):
            continue
        found = _mistake(factor)
        if found is None:
            continue
        _, what, fix = found
        raise InputError(
            f"{source}: {rate} is {factor:.4g} x d({angle})/dt (correlation {corr:.3f}; 1 "
            f"expected): {what.format(rate=rate, angle=angle)}; "
            f"{fix.format(rate=rate, angle=angle)} (or --skip-check rate-derivative, "
            "skip=['rate-derivative'])"
        )


def check_runs(
    runs: Sequence[Any], sources: Sequence[str], skip: Iterable[str] = ()
) -> list[str]:
    """:func:`check_run` on every run; the notes that say which checks were skipped.

    Parameters
    ----------
    runs : sequence of Run
        The runs.
    sources : sequence of str
        What each run came from (same length as ``runs``).
    skip : iterable of str, optional
        Names of :data:`CHECKS` not to run.

    Returns
    -------
    list of str
        One note per skipped data check (empty when all ran).

    Raises
    ------
    InputError
        On an unknown check name, or the first run that fails a check.
    """
    skip = list(dict.fromkeys(skip))
    bad = [s for s in skip if s not in CHECKS]
    if bad:
        raise InputError(f"--skip-check {','.join(bad)}: unknown check; choose from "
                         f"{', '.join(CHECKS)}")  # fmt: skip
    for run, src in zip(runs, sources, strict=True):
        check_run(run, src, skip)
    return [f"check {s} skipped on request: its mistakes are not caught" for s in skip
            if s in ("sample-period", "rate-derivative", "signs")]  # fmt: skip


def bounds_notes(skip: Iterable[str]) -> list[str]:
    """The notes that say which range checks of the import were skipped.

    Parameters
    ----------
    skip : iterable of str
        Names of :data:`CHECKS` skipped (names that are not range checks are ignored).

    Returns
    -------
    list of str
        One note per skipped range check (:data:`bikeid.dataset.run.BOUND_CHECKS`), naming
        the signals it bounds and their range, in the order of :data:`CHECKS`.
    """
    skip = set(skip)
    out = []
    for name, unit in BOUND_CHECKS.items():
        if name not in skip:
            continue
        ranges = ", ".join(f"{k} {lo:g}..{hi:g}" for k, (lo, hi) in PLAUSIBLE.items()
                           if UNITS.get(k) == unit)  # fmt: skip
        out.append(f"check {name} skipped on request: values beyond the physical range "
                   f"({ranges} {unit}) are kept")  # fmt: skip
    return out
