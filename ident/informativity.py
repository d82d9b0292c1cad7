"""Can the data determine the model?  Feedback share and order of excitation of the input.

Closed-loop data identify a plant only when the input carries something the loop's own
feedback does not put there: an external dither, a reference, a push measured as an
input.  A steer torque that a law of the measured states reproduces is feedback, and a
fit to it returns whatever model makes the closed loop's equations hold (the issue's
example: three unstable real poles from push logs under the steer-by-wire bicycle's own
balance controller).  MATLAB's System Identification Toolbox has ``feedback`` and
``pexcit`` for this; :func:`assess` does both, and :func:`check` refuses
(:class:`~bikeid.sim.errors.UntrustworthyResult`, exit 4) before any estimator returns a
model from data that cannot determine it: every estimator (``pem.fit``,
``pem.fit_speed_model``, ``greybox.fit``, ``direct.identify`` and the fit functions of
``ident.methods.METHODS``) runs :func:`guard` before it fits, whose ``informativity``
keyword (:data:`INFORMATIVITY`) can instead report the cause or skip the check, both
recorded with the model.

1. **Feedback share.**  Per run, the steer torque T is regressed by least squares on a
   low-order linear law of the measured states: a constant, phi, delta, phidot,
   deltadot, their products with the speed's deviation from its mean (a gain scheduled on
   the speed, e.g. ``K (V - v) phidot`` of the steer-by-wire logs), and the running
   integrals of phi and delta (the integral action of a PI/PID law).  R^2 is the share of
   T's variance the law reproduces; a run with R^2 >= :data:`FEEDBACK_R2` carries feedback
   only, no excitation.  The law has no lagged states on purpose: two consecutive samples
   of the full state give the held input between them through the plant's own equation
   (x_k = A x_{k-1} + B T_{k-1}), so a lagged law would "explain" any slowly varying
   external input and refuse good data.
2. **Order of excitation** of the part of T the law does not reproduce (the residual):
   the number of distinct frequencies in its Hann-windowed periodogram whose power is
   within :data:`LINE_LEVEL` (30 dB) of the strongest, pooled over runs on a common
   frequency grid: each band of adjacent excited bins counts as one frequency, or as
   several when it is wider than the bins one pure tone covers at that level
   (:func:`tone_bins`); the order is 2 per frequency (a sinusoid is persistently exciting of
   order 2, MATLAB's ``pexcit``).  The input itself is counted the same way first, so a
   single sinusoid is named as such, not as feedback.
3. **Verdict.**  The data determine a model of ``n_params`` free parameters when some run
   is not feedback-only and the order of excitation of the residual is at least
   ``n_params`` (:data:`ORDER_PER_PARAMETER` = 1: a sufficient condition for a SISO model
   with as many numerator and denominator parameters).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bikeid.sim.errors import InputError, UntrustworthyResult

__all__ = [
    "FEEDBACK_R2",
    "INFORMATIVITY",
    "LINE_LEVEL",
    "ORDER_PER_PARAMETER",
    "SKIPPED_NOTE",
    "Informativity",
    "assess",
    "check",
    "excited_frequencies",
    "feedback_share",
    "guard",
    "tone_bins",
]

#: R^2 of the state law above which a run's steer torque counts as feedback only [-].
#: The rule: a run is feedback-only when the static law of point 1 (in-sample least squares)
#: reproduces >= 98 % of its torque's variance.  Measured (:func:`feedback_share`; the
#: steer-by-wire logs through ``dataset.sbw_logs.settled``, ``T_delta`` = ``command_fork``;
#: ``benchmarks/feedback_share.py`` prints every number below):
#:
#: - refused, as they must be: the testbed's loops without dither or reference (PID, pole
#:   placement at 2, 4, 6 m/s: 1.0000; fuzzy: 0.995, its nonlinear law) and the push logs
#:   at 1.5, 3.5, 4.5 m/s (1.0000, 0.9987, 0.9951: the balance law K (V - v) phidot);
#: - passed, as they must be: the testbed's dithered sweep runs (defaults, fuzzy / PID /
#:   pole at 1-10 m/s, seeds 0-1, 48 runs: 0.29-0.78) and the linear loop with a white dither
#:   held 1-20 samples (0.33-0.83);
#: - a single sinusoid is not refused here (0.82-0.95: a sinusoid is reproduced by two
#:   states in quadrature whatever the loop) but by its order of excitation (point 2).
#:
#: The 9 km/h push log (2.5 m/s) gives 0.8994 and passes, and no threshold on this share
#: can refuse it without refusing data that determine the model: its ``command_fork`` holds,
#: beside the balance law (reproduced to 1.0000 when ``sil_command`` is the input), the
#: relayed handlebar torque (``command_fork - sil_command``, std 0.28 N m, nonzero in 13 %
#: of the samples, correlation 0.91 with ``hand_torque``), an input no state law
#: reproduces, while its PEM model is wrong (-1150, -1.10, +0.18, +5.93 1/s against the
#: Whipple model's -9.31, -3.41, +2.15 +- 1.91j).  A PID loop at 2.5 m/s with a 0.3 N m
#: dither and no reference gives 0.968 and a PEM model within 0.5 1/s of the truth (0.15
#: N m: 0.992, also within 0.5 1/s); the bode-4mps logs, each a person's sinusoidal
#: handlebar torque relayed to the fork, give 0.75-0.97, and pooled (docs/tutorial.md)
#: give -8.3, -2.9, +0.64 +- 2.93j 1/s, the Whipple model's pattern at 4 m/s (-12.8, -1.2,
#: +0.27 +- 3.35j).  So the 9 km/h log's failure is not a small external share (an
#: unmeasured push acting with the relayed torque would explain it; the share cannot see it).
#: Low-order dynamic laws do not separate it either (least squares fitted on one half of
#: the run, R^2 judged on the other, both ways): with the four states lagged 1-3 samples
#: added, 0.68-0.81 on the 9 km/h log but 0.33-0.98 on the 48 dithered sweep runs (pole
#: placement at 1-2 m/s: 0.93-0.98) and 0.84-0.996 on the sweep's runs with their roll
#: chirp but no dither (static law 0.29-0.87: the chirp is an external reference; the lags
#: reconstruct the held input from the plant's own equation); with the states filtered by
#: first-order lags of 0.02-0.2 s added, 0.73-0.81 on the 9 km/h log but up to 0.95 on the
#: dithered runs (0.98 in sample).  Such a law would refuse the testbed's own dithered runs
#: before the 9 km/h log.
FEEDBACK_R2 = 0.98
#: Power of a periodogram bin relative to the strongest bin above which the bin counts as
#: excited [-] (1e-3: 30 dB, an amplitude 3 % of the strongest component).
LINE_LEVEL = 1e-3
#: Order of persistent excitation required per free parameter of the model [-].
ORDER_PER_PARAMETER = 1

_STATES = ("phi", "delta", "phidot", "deltadot")


def _law(run: Any, name: str) -> np.ndarray:
    """Regressors of the state law (module docstring, point 1), one column each."""
    cols = [np.ones(run.n)] + [np.asarray(run[s], float) for s in _STATES]
    v = np.asarray(run["v"], float)
    dv = v - v.mean()
    if np.ptp(dv) > 0:
        cols += [dv] + [dv * np.asarray(run[s], float) for s in _STATES]
    dt = run.dt
    for s in ("phi", "delta"):
        integral = np.cumsum(np.asarray(run[s], float)) * dt
        cols.append(integral - integral.mean())
    X = np.column_stack(cols)
    scale = np.linalg.norm(X, axis=0)
    scale[scale == 0] = 1.0
    return X / scale


def feedback_share(run: Any, input_name: str = "T_delta") -> tuple[float, np.ndarray]:
    """R^2 of the steer torque reproduced by the state law, and the unexplained part.

    Parameters
    ----------
    run : Run
        One run (``phi``, ``delta``, ``phidot``, ``deltadot``, ``v`` and the input).
    input_name : str, optional
        The input signal [N m] (default ``T_delta``).

    Returns
    -------
    r2 : float
        Share of the input's variance (about its mean) the law reproduces, 0..1 [-];
        1.0 for an input without variance.
    residual : (N,) ndarray
        The input minus the law's least-squares fit [N m].
    """
    u = np.asarray(run[input_name], float)
    X = _law(run, input_name)
    coef, *_ = np.linalg.lstsq(X, u, rcond=None)
    res = u - X @ coef
    tot = float(np.sum((u - u.mean()) ** 2))
    if tot == 0.0:
        return 1.0, res
    return float(max(0.0, 1.0 - np.sum(res**2) / tot)), res


def _periodogram(u: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    from scipy.signal import periodogram

    f, p = periodogram(np.asarray(u, float), fs=1.0 / dt, window="hann", detrend="constant")
    return f[1:], p[1:]  # DC (a constant input, order 1) is not a frequency that excites


def tone_bins(n: int, level: float = LINE_LEVEL) -> int:
    """Bins one pure tone covers in an ``n``-sample Hann periodogram at ``level``.

    Parameters
    ----------
    n : int
        Record length [samples], >= 16.
    level : float, optional
        Relative power threshold [-] (:data:`LINE_LEVEL`).

    Returns
    -------
    int
        The largest count over tones on a bin and half-way between bins (>= 1).
    """
    k = np.arange(n)
    best = 1
    for cycles in (n / 8.0, n / 8.0 + 0.5, n / 8.0 + 0.25):
        _, p = _periodogram(np.sin(2 * np.pi * cycles * k / n), 1.0)
        best = max(best, int(np.sum(p >= level * p.max())))
    return best


def excited_frequencies(u: np.ndarray, dt: float, level: float = LINE_LEVEL) -> np.ndarray:
    """Frequencies of the periodogram bins of ``u`` within ``level`` of its strongest bin.

    Parameters
    ----------
    u : (N,) array_like
        The signal (mean removed here).
    dt : float
        Sample period [s].
    level : float, optional
        Relative power threshold [-].

    Returns
    -------
    ndarray
        Frequencies [Hz] of the excited bins (DC excluded); empty for a constant signal.
    """
    f, p = _periodogram(u, dt)
    if p.size == 0 or not np.any(p > 0):
        return np.empty(0)
    return f[p >= level * p.max()]


def _distinct(speeds: Sequence[float], tolerance: float) -> list[float]:
    """Speeds more than ``tolerance`` apart (the lowest of each cluster)."""
    out: list[float] = []
    for v in sorted(speeds):
        if not out or v - out[-1] > tolerance:
            out.append(round(float(v), 6))
    return out


def _order(freqs: Sequence[np.ndarray], resolutions: Sequence[float], bins: int) -> int:
    """2 x distinct frequencies of the pooled excited bins (on the coarsest grid)."""
    if not freqs or all(len(f) == 0 for f in freqs):
        return 0
    df = max(resolutions)
    grid = np.unique(np.rint(np.concatenate([np.asarray(f, float) for f in freqs]) / df))
    # contiguous excited bins are one line, or several when wider than one tone
    ends = np.append(np.flatnonzero(np.diff(grid) != 1.0), grid.size - 1)
    widths = np.diff(np.concatenate([[-1], ends]))
    return 2 * int(np.sum(-(-widths // bins)))


@dataclass(frozen=True)
class Informativity:
    """What the data can determine: feedback share and order of excitation of the input.

    Attributes
    ----------
    n_params : int
        Free parameters of the model to be fitted.
    r2 : tuple of float
        Per run, the share of the input's variance a state law reproduces [-].
    feedback_only : tuple of int
        Indices of the runs with ``r2 >= threshold``.
    input_order : int
        Order of persistent excitation of the input itself, pooled over runs.
    order : int
        Order of persistent excitation of the input's part no state law reproduces,
        pooled over the runs that are not feedback-only (0 when all are).
    threshold : float
        The R^2 threshold used [-].
    cause : str or None
        Why the data cannot determine the model, with the fix; None when they can.
    """

    n_params: int
    r2: tuple[float, ...]
    feedback_only: tuple[int, ...]
    input_order: int
    order: int
    threshold: float = FEEDBACK_R2
    cause: str | None = field(default=None)

    @property
    def informative(self) -> bool:
        """bool: True when the data can determine the model (``cause`` is None)."""
        return self.cause is None

    def to_json(self) -> dict:
        """The assessment as JSON-ready values.

        Returns
        -------
        dict
            ``n_params``, ``r2`` (per run), ``feedback_only``, ``input_order``, ``order``,
            ``threshold``, ``informative``, ``cause``.
        """
        return {"n_params": self.n_params, "r2": list(self.r2),
                "feedback_only": list(self.feedback_only), "input_order": self.input_order,
                "order": self.order, "threshold": self.threshold,
                "informative": self.informative, "cause": self.cause}  # fmt: skip


#: What to do with feedback-only data: no choice of free parameters helps (the data show the
#: loop, not the plant); free decays after pushes are what ``bikeid measured fit`` fits.
_FEEDBACK_FIX = ("if the logs hold free decays after pushes, fit them with bikeid measured fit "
                 "(free decays under the known controller law); otherwise record with an "
                 "external steer-torque dither or reference (broadband, independent of the "
                 "states)")  # fmt: skip


def _fewer_fix(order: int, n_params: int) -> str:
    """The fix of too few excited frequencies: the parameters these data can carry, if any."""
    most = order // ORDER_PER_PARAMETER
    excite = "excite more frequencies (a broadband dither or a multisine)"
    if 0 < most < n_params:
        return (f"fit at most {most} free parameter{'s' if most > 1 else ''} (a grey-box model, "
                f"--method greybox --free with {most} entr{'ies' if most > 1 else 'y'}), or "
                f"{excite}")  # fmt: skip
    return excite


def assess(
    runs: Sequence[Any],
    n_params: int,
    *,
    input_name: str = "T_delta",
    threshold: float = FEEDBACK_R2,
    level: float = LINE_LEVEL,
    min_speeds: int = 1,
    speed_tolerance: float = 0.25,
) -> Informativity:
    """Whether ``runs`` can determine a model with ``n_params`` free parameters.

    Parameters
    ----------
    runs : sequence of Run
        The runs a model is to be fitted to (with phi, delta, phidot, deltadot, v and the
        input).
    n_params : int
        Free parameters of the model (e.g. 10 for the canonical PEM at one speed).
    input_name : str, optional
        The input signal [N m].
    threshold : float, optional
        R^2 at or above which a run's input counts as feedback only (0 < threshold <= 1).
    level : float, optional
        Relative periodogram power of an excited bin [-].
    min_speeds : int, optional
        Distinct speeds (``run.speed`` more than ``speed_tolerance`` apart) the runs that
        are not feedback-only must cover: 2 for a model over speed (its v and v^2 terms).
    speed_tolerance : float, optional
        Speeds closer than this count as one [m/s].

    Returns
    -------
    Informativity
        The assessment; ``cause`` names the problem and the fix when the data cannot
        determine the model.

    Raises
    ------
    InputError
        If there are no runs, ``n_params`` < 1, or ``threshold`` is outside (0, 1].
    """
    if not runs:
        raise InputError("no runs to assess")
    if int(n_params) < 1:
        raise InputError(f"n_params={n_params}: a model has at least one free parameter")
    if not (0.0 < threshold <= 1.0):
        raise InputError(f"threshold={threshold}: give an R^2 in (0, 1]")
    r2s, residuals, res_f, in_f, res_df = [], [], [], [], []
    bins = 1
    for r in runs:
        r2, res = feedback_share(r, input_name)
        r2s.append(r2)
        residuals.append(res)
        in_f.append(excited_frequencies(r[input_name], r.dt, level))
        res_df.append(1.0 / (r.n * r.dt))
        bins = max(bins, tone_bins(min(r.n, 4096), level))
    feedback = tuple(i for i, x in enumerate(r2s) if x >= threshold)
    for i, (r, res) in enumerate(zip(runs, residuals, strict=True)):
        if i not in feedback:
            res_f.append(excited_frequencies(res, r.dt, level))
    input_order = _order(in_f, res_df, bins)
    keep = [d for i, d in enumerate(res_df) if i not in feedback]
    order = _order(res_f, keep, bins) if res_f else 0
    need = ORDER_PER_PARAMETER * int(n_params)
    cause = None
    n = len(runs)
    if input_order < need:
        cause = (f"the input {input_name} excites {input_order // 2} distinct frequenc"
                 f"{'y' if input_order // 2 == 1 else 'ies'} (order of excitation "
                 f"{input_order}; a single sinusoid has 2), fewer than the model's {n_params} "
                 f"free parameters need; {_fewer_fix(input_order, n_params)}, or pool runs "
                 "at other frequencies")  # fmt: skip
    elif len(feedback) == n:
        worst = min(r2s)
        cause = (f"the input {input_name} is feedback only: a linear law of the measured "
                 f"states reproduces {100 * worst:.4g} % or more of its variance in "
                 f"{'the run' if n == 1 else f'all {n} runs'} (threshold {100 * threshold:g} "
                 f"%), so the data show the closed loop, not the plant; {_FEEDBACK_FIX}")
    elif len(_distinct([runs[i].speed for i in range(n) if i not in feedback],
                       speed_tolerance)) < min(min_speeds, len(_distinct([r.speed for r in runs],
                                                                          speed_tolerance))):
        excited = _distinct([runs[i].speed for i in range(n) if i not in feedback],
                            speed_tolerance)
        cause = (f"only the runs at {', '.join(f'{v:g}' for v in excited)} m/s carry "
                 f"excitation (the input of the others is feedback only: R^2 >= "
                 f"{100 * threshold:g} %), and a model over speed needs excited runs at "
                 f"{min_speeds} or more speeds; fit the excited speeds on their own (one "
                 "model per speed), or record dithered runs at more speeds")  # fmt: skip
    elif order < need:
        cause = (f"the part of the input {input_name} that no state law reproduces excites "
                 f"{order // 2} distinct frequenc{'y' if order // 2 == 1 else 'ies'} (order "
                 f"of excitation {order}), fewer than the model's {n_params} free parameters "
                 f"need; {_fewer_fix(order, n_params)}")  # fmt: skip
    return Informativity(int(n_params), tuple(r2s), feedback, input_order, order, threshold,
                         cause)  # fmt: skip


def check(
    runs: Sequence[Any],
    n_params: int,
    *,
    what: str = "the model",
    input_name: str = "T_delta",
    threshold: float = FEEDBACK_R2,
    min_speeds: int = 1,
) -> Informativity:
    """:func:`assess`, refusing data that cannot determine the model.

    Parameters
    ----------
    runs : sequence of Run
        The runs a model is to be fitted to.
    n_params : int
        Free parameters of the model.
    what : str, optional
        The model, for the message (e.g. ``"the canonical PEM model at 4.5 m/s"``).
    input_name : str, optional
        The input signal [N m].
    threshold : float, optional
        R^2 at or above which an input counts as feedback only.
    min_speeds : int, optional
        Distinct speeds the excited runs must cover (:func:`assess`).

    Returns
    -------
    Informativity
        The assessment (informative).

    Raises
    ------
    UntrustworthyResult
        ``the logs cannot determine <what>: <cause and fix>``.
    """
    info = assess(runs, n_params, input_name=input_name, threshold=threshold,
                  min_speeds=min_speeds)
    if info.cause is not None:
        raise UntrustworthyResult(f"the logs cannot determine {what}: {info.cause}")
    return info


#: What an estimator does about data that cannot determine its model (the ``informativity``
#: keyword of every fit function): ``"refuse"`` (default) raises
#: :class:`~bikeid.sim.errors.UntrustworthyResult` before fitting, ``"report"`` fits and
#: records the cause, ``"skip"`` does not assess and records that it did not.
INFORMATIVITY = ("refuse", "report", "skip")
#: The record of a check skipped on request (never silent).
SKIPPED_NOTE = ("check informativity skipped on request: the model may be determined by "
                "feedback, not by the data")  # fmt: skip


def guard(
    runs: Sequence[Any],
    n_params: int,
    *,
    what: str,
    informativity: str = "refuse",
    input_name: str = "T_delta",
    min_speeds: int = 1,
) -> tuple[dict, str | None]:
    """What every estimator runs before it fits: :func:`check`, :func:`assess` or nothing.

    Parameters
    ----------
    runs : sequence of Run
        The runs a model is to be fitted to.
    n_params : int
        Free parameters of the model.
    what : str
        The model, for messages (e.g. ``"the canonical PEM model at 4.5 m/s"``).
    informativity : {"refuse", "report", "skip"}, optional
        :data:`INFORMATIVITY`.
    input_name : str, optional
        The input signal [N m].
    min_speeds : int, optional
        Distinct speeds the excited runs must cover (:func:`assess`).

    Returns
    -------
    record : dict
        :meth:`Informativity.to_json`, or ``{"skipped": True, "note": SKIPPED_NOTE}``.
    note : str or None
        A line for the model's notes: :data:`SKIPPED_NOTE`, or ``the logs cannot determine
        <what>: <cause>`` for reported data that cannot; None when the data can.

    Raises
    ------
    UntrustworthyResult
        With ``"refuse"``, when the data cannot determine the model (:func:`check`).
    InputError
        If ``informativity`` is not one of :data:`INFORMATIVITY`.
    """
    if informativity not in INFORMATIVITY:
        raise InputError(f"informativity={informativity!r}: choose one of "
                         f"{', '.join(INFORMATIVITY)}")  # fmt: skip
    if informativity == "skip":
        return {"skipped": True, "note": SKIPPED_NOTE}, SKIPPED_NOTE
    info = assess(runs, n_params, input_name=input_name, min_speeds=min_speeds)
    note = None if info.cause is None else f"the logs cannot determine {what}: {info.cause}"
    if note is not None and informativity == "refuse":
        raise UntrustworthyResult(note)
    return info.to_json(), note
