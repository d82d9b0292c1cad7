"""Relative signs of roll, steer and steer torque, checked against a bicycle's own equations.

A log whose roll axis is mirrored (roll and roll rate logged positive to the left, bikeid's
``--flip phi,phidot`` forgotten) passes every unit check: each rate still agrees with the
derivative of its angle.  A black-box model cannot see it either (the sign change is a
similarity transform of the state: the eigenvalues stay, the coupling coefficients flip).
The bicycle's own equations of motion do see it (Meijaard 2007, eq. A1, with
``q = [phi, delta]``):

roll equation (no input but disturbances)
    ``P + D = T_phi ~ 0`` with ``P = M_pp phi'' + (g K0_pp + v^2 K2_pp) phi`` (the roll
    terms) and ``D = M_pd delta'' + v C1_pd delta' + (g K0_pd + v^2 K2_pd) delta`` (the
    steer terms);
steer equation
    ``Q = M_dp phi'' + v C1_dp phi' + (g K0_dp + v^2 K2_dp) phi + M_dd delta''
    + v C1_dd delta' + (g K0_dd + v^2 K2_dd) delta = T_delta``.

The coefficient ``s`` of ``D = -s P + c + e`` is +1 for bikeid's signs and -1 for a
mirrored roll axis; the coefficient ``b`` of ``T_delta = b Q + c + e`` is +1 when the torque's
sign agrees with the angles'.  Each is a least-squares slope with a heteroscedasticity- and
autocorrelation-consistent (Bartlett, :data:`HAC_BANDWIDTH` s) standard error pooled over
the runs, so a nominal bicycle that differs from the real one changes the slope's size, not
its sign.  A sign is **mirrored** when the two-sided ``level`` interval of its coefficient
lies below zero, **confirmed** when above, and **undecided** when it holds zero: the data do
not excite the equation enough (|t| below the normal quantile of ``1 - level / 2``, 2.58 at
the default 0.01).

Mirror symmetry makes only the relative signs decidable: "roll mirrored" is the same data
as "steer and torque mirrored", so a refusal names both equivalent fixes.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from bikeid.sim.errors import InputError

__all__ = [
    "HAC_BANDWIDTH",
    "LEVEL",
    "SMOOTHING",
    "SignCheck",
    "check_signs",
    "nominal_bicycle",
    "sign_evidence",
]

#: Level of the sign decision: a sign is decided when its two-sided 99 % interval excludes 0.
LEVEL = 0.01
#: Savitzky-Golay window (cubic) for the smoothed signals and the accelerations [s]: wide
#: enough to tame gyro and encoder noise in a differentiated rate, short against the
#: bicycle's modes (below ~3 Hz).
SMOOTHING = 0.25
#: Bartlett bandwidth of the autocorrelation-consistent variance [s]: a few periods of the
#: weave (~0.3-0.5 s) and the smoothing window.
HAC_BANDWIDTH = 2.0
#: The two equivalent fixes of a mirrored roll axis.
FIXES = ("--flip phi,phidot (flip=['phi', 'phidot'] in Python), or equivalently --flip "
         "delta,deltadot,T_delta")


@dataclass(frozen=True)
class SignCheck:
    """The evidence for one relative sign.

    Attributes
    ----------
    equation : str
        ``"roll"`` (roll vs steer angles) or ``"steer"`` (steer torque vs the angles).
    coefficient : float
        The fitted sign coefficient (+1 for consistent signs, -1 for mirrored) [-].
    std_error : float
        Its autocorrelation-consistent standard error [-].
    verdict : str
        ``"confirmed"``, ``"mirrored"`` or ``"undecided"``.
    """

    equation: str
    coefficient: float
    std_error: float
    verdict: str

    @property
    def t(self) -> float:
        """The coefficient over its standard error [-]."""
        return self.coefficient / self.std_error if self.std_error > 0 else math.nan


def nominal_bicycle(bicycle: Any) -> Any:
    """The parameters of a bicycle given by name, file or parameter set.

    Parameters
    ----------
    bicycle : str, path, BicycleParameters or None
        A name of :func:`bikeid.sim.parameters.by_name`, a parameter file, or the set.

    Returns
    -------
    BicycleParameters or None
        None when ``bicycle`` is None.
    """
    if bicycle is None:
        return None
    from bikeid.sim.parameters import BicycleParameters, by_name

    return bicycle if isinstance(bicycle, BicycleParameters) else by_name(str(bicycle))


def _smoothed(x: np.ndarray, dt: float, deriv: int = 0) -> np.ndarray:
    from scipy.signal import savgol_filter  # (lazy: the command line starts without scipy)

    n = x.size
    w = int(round(SMOOTHING / dt)) | 1
    w = min(w, n - 1 if n % 2 == 0 else n)
    if w < 5:
        return np.gradient(x, dt) if deriv else x
    return savgol_filter(x, w, 3, deriv=deriv, delta=dt)


def _terms(run: Any, cm: Any) -> dict[str, np.ndarray] | None:
    """The roll, steer-angle and steer-equation terms of one run (None: a signal missing)."""
    sig = run.signals
    if not {"phi", "delta", "phidot", "deltadot"} <= set(sig):
        return None
    dt = run.dt
    phi, delta = _smoothed(sig["phi"], dt), _smoothed(sig["delta"], dt)
    phid, deltad = _smoothed(sig["phidot"], dt), _smoothed(sig["deltadot"], dt)
    phidd, deltadd = _smoothed(sig["phidot"], dt, 1), _smoothed(sig["deltadot"], dt, 1)
    v = np.asarray(sig["v"], float) if "v" in sig else np.full(phi.size, run.speed)
    g, M, C1, K0, K2 = cm.g, cm.M, cm.C1, cm.K0, cm.K2
    k = [[g * K0[i, j] + v**2 * K2[i, j] for j in range(2)] for i in range(2)]
    out = {
        "P": M[0, 0] * phidd + v * C1[0, 0] * phid + k[0][0] * phi,
        "D": M[0, 1] * deltadd + v * C1[0, 1] * deltad + k[0][1] * delta,
        "Q": (M[1, 0] * phidd + v * C1[1, 0] * phid + k[1][0] * phi
              + M[1, 1] * deltadd + v * C1[1, 1] * deltad + k[1][1] * delta),
    }  # fmt: skip
    if "T_delta" in sig:
        out["T"] = _smoothed(np.asarray(sig["T_delta"], float), dt)
    return out


def _hac(u: np.ndarray, lags: int) -> float:
    """Bartlett-weighted long-run variance of the sum of ``u`` (mean zero)."""
    var = float(u @ u)
    for lag in range(1, min(lags, u.size - 1) + 1):
        var += 2.0 * (1.0 - lag / (lags + 1)) * float(u[lag:] @ u[:-lag])
    return max(var, 0.0)


def _slope(pairs: list[tuple[np.ndarray, np.ndarray, int]]) -> tuple[float, float]:
    """Pooled slope of y on x (each run centred) and its autocorrelation-consistent SE."""
    xs = [(x - x.mean(), y - y.mean(), lags) for x, y, lags in pairs]
    den = sum(float(x @ x) for x, _, _ in xs)
    if den <= 0.0:
        return math.nan, math.nan
    b = sum(float(x @ y) for x, y, _ in xs) / den
    var = sum(_hac(x * (y - b * x), lags) for x, y, lags in xs)
    return b, math.sqrt(var) / den


def _verdict(equation: str, b: float, se: float, level: float) -> SignCheck:
    from scipy.stats import norm

    z = float(norm.ppf(1.0 - level / 2.0))
    if not (math.isfinite(b) and math.isfinite(se) and se > 0) or abs(b) < z * se:
        verdict = "undecided"
    else:
        verdict = "confirmed" if b > 0 else "mirrored"
    return SignCheck(equation, float(b), float(se), verdict)


def sign_evidence(runs: Sequence[Any], p: Any, level: float = LEVEL) -> list[SignCheck]:
    """The roll-equation and steer-equation sign coefficients of ``runs`` on bicycle ``p``.

    Parameters
    ----------
    runs : sequence of Run
        The runs in bikeid's units and signs as read (phi, delta, phidot, deltadot [rad,
        rad/s], v [m/s] or the run's speed, T_delta [N m] if logged).
    p : bikeid.sim.parameters.BicycleParameters
        The nominal bicycle whose equations the signals must satisfy.
    level : float, optional
        Level of each sign decision (default :data:`LEVEL`).

    Returns
    -------
    list of SignCheck
        The roll equation's (always) and the steer equation's (when T_delta is logged).
    """
    from bikeid.sim.linear import canonical_matrices

    cm = canonical_matrices(p)
    roll, steer = [], []
    for run in runs:
        terms = _terms(run, cm)
        if terms is None or run.n < 10:
            continue
        lags = max(1, int(round(HAC_BANDWIDTH / run.dt)))
        roll.append((terms["P"], -terms["D"], lags))
        if "T" in terms:
            steer.append((terms["Q"], terms["T"], lags))
    out = [_verdict("roll", *_slope(roll), level)]
    if steer:
        out.append(_verdict("steer", *_slope(steer), level))
    return out


def check_signs(
    runs: Sequence[Any], p: Any, source: str = "the logs", level: float = LEVEL
) -> list[str]:
    """Refuse runs whose roll, steer and torque signs contradict bicycle ``p``'s equations.

    Parameters
    ----------
    runs : sequence of Run
        The runs (see :func:`sign_evidence`).
    p : bikeid.sim.parameters.BicycleParameters
        The nominal bicycle.
    source : str, optional
        What the runs came from, for the messages.
    level : float, optional
        Level of each decision (default :data:`LEVEL`).

    Returns
    -------
    list of str
        Notes: one per sign the data cannot decide (too little excitation), naming what it
        means.

    Raises
    ------
    InputError
        A mirrored roll axis or steer torque, with the coefficient, its standard error and
        the fixes (``--flip ...``, or ``--skip-check signs`` for data you know are right).
    """
    from scipy.stats import norm

    notes = []
    for c in sign_evidence(runs, p, level):
        if c.verdict == "mirrored" and c.equation == "roll":
            raise InputError(
                f"{source}: roll and steer have opposite signs to {p.name}'s roll equation "
                f"(sign coefficient {c.coefficient:.3g} +- {c.std_error:.2g}, +1 expected): "
                f"the roll axis is probably logged positive to the left; fix with {FIXES} "
                "(or --skip-check signs, skip=['signs'])"
            )
        if c.verdict == "mirrored":
            raise InputError(
                f"{source}: the steer torque has the opposite sign to {p.name}'s steer "
                f"equation (sign coefficient {c.coefficient:.3g} +- {c.std_error:.2g}, +1 "
                "expected): fix with --flip T_delta, flip=['T_delta'] in Python (or --skip-check "
                "signs, skip=['signs'])"
            )
        if c.verdict == "undecided":
            what = ("roll vs steer" if c.equation == "roll" else "steer torque vs angles")
            notes.append(
                f"{source}: the {what} sign cannot be decided from these data against "
                f"{p.name}'s {c.equation} equation (coefficient {c.coefficient:.3g} +- "
                f"{c.std_error:.2g}, |t| {abs(c.t):.2g} < {norm.ppf(1 - level / 2):.3g}): "
                "too little excitation; a mirrored axis would go unnoticed"
            )
    return notes
