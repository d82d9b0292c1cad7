"""Signal preparation for identification: mean removal, zero-phase low-pass, differentiation.

Moore & Hubbard's processing (paper §4, "Data processing"; reference §1.1): subtract
the time mean of every signal that is symmetric about zero (all but speed v and
lateral force F), low-pass all signals with a 2nd-order 15 Hz Butterworth, and
estimate roll and steer accelerations by numerically differentiating the
*measured rates* (central differences).

Differentiation pitfall (reference T9).  With a zero-order-hold input (dither or
controller output held over each sample), q'' jumps at every switching instant.
A central difference (x[k+1] - x[k-1]) / (2 dt) averages the acceleration over
[t_k-1, t_k+1] and so straddles the jump at t_k: the estimate is off by half the
jump at every switch, an error that does not shrink with dt (sim: up to 13 % on
C1dp).  A forward difference (x[k+1] - x[k]) / dt is the exact mean of q'' over
the hold interval [t_k, t_k+1), whose value at t_k+ is what the equation of motion
holds with u[k]; its error is O(dt) (sim: up to 5 % on Mdd at 5 ms).  So:
``method="forward"`` for ZOH data sampled at the controller instants, ``"central"``
(Moore's choice, second order for smooth signals) for continuous signals such as
measured data with filtered inputs.  Neither is exact; tests of the direct method
use simulator accelerations or tolerances that shrink with dt.

``derivative="interval"`` (for ZOH data sampled at the controller instants) goes one step
further and writes the equation of motion *averaged over each hold interval*
[t_k, t_k+1), where the torque is the constant T[k]: the mean of q'' is exactly
(q'[k+1] - q'[k]) / dt, and the means of q' and q are the trapezoids (x[k] + x[k+1]) / 2
(error O(dt^2), against O(dt) for point values at t_k, which matters for the fast caster
mode: -25 1/s at 10 m/s moves q' by ~25 % within one 10 ms sample).  The relation between
the averaged sequences is linear and exact up to that O(dt^2), so the *same* discrete
zero-phase filter may then be applied to every sequence (``cutoff``) to cut the sensor
noise without breaking it.  The last sample is dropped (no interval after it).

Sampling contract (:func:`check_sampling`, called by every estimator: ``pem.fit``,
``pem.fit_speed_model``, ``direct.identify``, ``tailored_iv.identify_tailored``).  A run
logs the steer torque once per sample period; PEM's ZOH predictor, the direct method's
interval and forward differences and the tailored instruments all take the logged value
as the torque the plant held over the whole sample [t_k, t_k+1).  That is true only if
everything that changes the applied torque (the controller and the dither) changes at
the sample instants: its period must be a whole multiple of the run's sample period.  A
1 ms controller logged at 100 Hz breaks it (the applied torque changes 10 times per
logged value) and gave PEM an unstable weave (+0.066 +- 4.313j 1/s) for the benchmark's
stable one (-0.775 +- 4.465j) at 5 m/s, without a warning; such runs are refused.

Complete runs only (:func:`check_complete`, called by :func:`check_sampling`, so by every
estimator above).  A simulated run that ended early (``meta["stop"]``: a fall, |steer|
over 90 deg, or a numerical failure such as a step too coarse) is refused with its name
and cause: its last samples run into the limit or the blow-up, far outside the linear
model the estimators fit.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from scipy.signal import butter, sosfiltfilt

from bikeid.dataset.run import Run, run_stop
from bikeid.sim.errors import InputError, UntrustworthyResult

__all__ = [
    "NO_MEAN_REMOVAL",
    "check_complete",
    "check_sampling",
    "differentiate",
    "input_periods",
    "lowpass",
    "prepare",
    "remove_means",
]

#: Signals whose mean is physical and must not be removed (Moore & Hubbard §4).
NO_MEAN_REMOVAL = ("v", "F", "thetaRdot")

_METHODS = ("central", "forward", "backward")
_PREPARE = (*_METHODS, "interval")


def input_periods(run: Run) -> dict[str, float]:
    """The periods [s] at which the run's applied steer torque could change, from its meta.

    Parameters
    ----------
    run : Run
        A run; its ``meta["sampling"]`` (written by both closed-loop engines,
        ``dataset.closed_loop`` and ``dataset.linear_loop``) gives ``controller_period``
        and ``dither_hold``.  Runs written before that key existed fall back on
        ``meta["controller"]["sample_time"]`` and a uniform dither's ``meta["dither"]["hold"]``.

    Returns
    -------
    dict
        ``{"controller": Ts, "dither": hold}`` [s], each only when known (measured runs: {}).
    """
    meta = run.meta or {}
    out: dict[str, float] = {}
    sampling = meta.get("sampling")
    if isinstance(sampling, dict):
        for key, name in (("controller_period", "controller"), ("dither_hold", "dither")):
            if sampling.get(key) is not None:
                out[name] = float(sampling[key])
        return out
    ctrl = meta.get("controller")
    if isinstance(ctrl, dict) and ctrl.get("sample_time") is not None:
        out["controller"] = float(ctrl["sample_time"])
    dither = meta.get("dither")
    if isinstance(dither, dict) and dither.get("name") == "uniform" and dither.get("hold"):
        out["dither"] = float(dither["hold"])
    return out


def _run_label(run: Run, i: int) -> str:
    name = run.meta.get("name") or run.meta.get("run")
    if name:
        return f"run {i} ({name})"
    if "speed" in run.meta:
        return f"run {i} ({run.meta['speed']:g} m/s, seed {run.meta.get('seed', '?')})"
    return f"run {i}"


def check_complete(runs: Run | Sequence[Run], estimator: str) -> None:
    """Refuse runs that ended early (``meta["stop"]``, :func:`dataset.run.run_stop`).

    Parameters
    ----------
    runs : Run or sequence of Run
        The estimator's runs.
    estimator : str
        The estimator's name, for the message.

    Raises
    ------
    ValueError
        If a run records a stop (physical or numerical); the message names the run, the
        cause, the time and the fix.  Measured runs and complete simulated runs pass.
    """
    runs = [runs] if isinstance(runs, Run) else list(runs)
    for i, run in enumerate(runs):
        stop = run_stop(run)
        if stop is None:
            continue
        kind = "a fall" if stop.get("physical") else "a numerical failure, not a fall"
        raise UntrustworthyResult(
            f"{estimator}: {_run_label(run, i)} ended early at t={float(stop['time']):.3f} s "
            f"on {stop['cause']} ({kind}: {stop['message']}); its last samples are not "
            f"the upright bicycle the estimator models.  Fix: leave the run out (or "
            f"re-simulate it so it completes: a stabilizing controller, or a smaller step "
            f"for a numerical cause)"
        )


def check_sampling(runs: Run | Sequence[Run], estimator: str) -> None:
    """Refuse runs whose logged steer torque is not what the plant held (module docstring).

    Parameters
    ----------
    runs : Run or sequence of Run
        The estimator's runs.
    estimator : str
        The estimator's name, for the message (e.g. ``"pem.fit"``).

    Raises
    ------
    ValueError
        If a run's controller period or dither hold [s] (from :func:`input_periods`) is
        not a whole multiple (>= 1, to 1e-6 relative) of the run's sample period
        ``run.dt``.  The message names both periods and the fix.  Runs without that
        metadata (measured data) pass.  Also if a run ended early
        (:func:`check_complete`).
    """
    runs = [runs] if isinstance(runs, Run) else list(runs)
    check_complete(runs, estimator)
    for i, run in enumerate(runs):
        dt = run.dt
        for what, period in input_periods(run).items():
            ratio = period / dt
            k = round(ratio)
            if k >= 1 and math.isclose(ratio, k, rel_tol=1e-6):
                continue
            label = "controller period" if what == "controller" else "dither hold"
            raise InputError(
                f"{estimator}: run {i} logs T_delta every {dt * 1e3:g} ms (logging period "
                f"{dt:g} s) but its {label} is {period * 1e3:g} ms ({period:g} s), so the "
                f"plant's steer torque changed within the logged samples; {estimator} assumes "
                f"each logged torque was held over its whole sample and would return wrong "
                f"estimates (e.g. an unstable weave for a stable one).  Fix: simulate with the "
                f"controller at the logging period (sample_time={dt:g}, the default "
                f"controllers.DEFAULT_SAMPLE_TIME for 100 Hz sensors) and a dither hold that "
                f"is a whole multiple of it (e.g. UniformDither(hold={dt:g}))"
            )


def lowpass(x: np.ndarray, dt: float, cutoff: float = 15.0, order: int = 2) -> np.ndarray:
    """Zero-phase Butterworth low-pass (``scipy.signal.sosfiltfilt``) along the last axis.

    ``cutoff`` [Hz] must lie below the Nyquist frequency 1 / (2 dt).  Forward-backward
    filtering squares the magnitude response (-6 dB at ``cutoff``) and has no phase lag.

    Parameters
    ----------
    x : (..., N) array_like
        Uniformly sampled signal(s), any unit; filtered along the last axis.
    dt : float
        Sample period [s].
    cutoff : float, optional
        Cut-off frequency [Hz] of the Butterworth design (-3 dB one way, -6 dB after
        forward-backward filtering); default 15 Hz (Moore & Hubbard).
    order : int, optional
        Butterworth order of the one-way filter (the zero-phase result has twice it).

    Returns
    -------
    (..., N) ndarray
        The filtered signal, same shape and unit as ``x``.

    Raises
    ------
    ValueError
        If ``cutoff`` is not in (0, 1 / (2 dt)) Hz or ``order`` < 1.
    """
    nyq = 0.5 / dt
    if not (0 < cutoff < nyq):
        raise ValueError(
            f"cutoff {cutoff} Hz must lie in (0, {nyq:g}) Hz, the Nyquist frequency at dt={dt} s"
        )
    if order < 1:
        raise ValueError(f"filter order {order}: need an integer >= 1")
    sos = butter(order, cutoff / nyq, output="sos")
    x = np.asarray(x, dtype=float)
    # sosfiltfilt's default edge padding (its "padlen"), which the signal must exceed
    pad = 3 * (2 * len(sos) + 1 - min((sos[:, 2] == 0).sum(), (sos[:, 5] == 0).sum()))
    if x.shape[-1] <= pad:
        raise InputError(
            f"a run of {x.shape[-1]} samples is too short to low-pass filter at {cutoff:g} Hz "
            f"(zero-phase filtering needs more than {pad}); use longer runs or no filter "
            "(cutoff 0)"
        )
    return sosfiltfilt(sos, x, axis=-1)


def differentiate(x: np.ndarray, dt: float, method: str = "central") -> np.ndarray:
    """Numerical derivative of a uniformly sampled signal [units/s].

    ``central``: (x[k+1] - x[k-1]) / 2dt, one-sided at the ends (``np.gradient``);
    ``forward``: (x[k+1] - x[k]) / dt, backward at the last sample;
    ``backward``: (x[k] - x[k-1]) / dt, forward at the first sample.
    See the module docstring for which to choose.

    Parameters
    ----------
    x : (..., N) array_like
        Uniformly sampled signal(s), differentiated along the last axis; at least 3
        samples.
    dt : float
        Sample period [s].
    method : {"central", "forward", "backward"}, optional
        Difference scheme.

    Returns
    -------
    (..., N) ndarray
        The derivative, unit of ``x`` per second (e.g. rad/s -> rad/s^2), same shape.

    Raises
    ------
    ValueError
        If ``x`` has fewer than 3 samples or ``method`` is unknown.
    """
    x = np.asarray(x, dtype=float)
    if x.shape[-1] < 3:
        raise ValueError("need at least 3 samples to differentiate")
    if method == "central":
        return np.gradient(x, dt, axis=-1)
    d = np.diff(x, axis=-1) / dt
    if method == "forward":
        return np.concatenate([d, d[..., -1:]], axis=-1)
    if method == "backward":
        return np.concatenate([d[..., :1], d], axis=-1)
    raise ValueError(f"unknown differentiation method {method!r}; choose from {list(_METHODS)}")


def remove_means(signals: dict[str, np.ndarray], keep=NO_MEAN_REMOVAL) -> dict[str, np.ndarray]:
    """A copy with each signal's time mean subtracted, except those named in ``keep``.

    Parameters
    ----------
    signals : dict of str to (N,) ndarray
        Named signals (any units).
    keep : collection of str, optional
        Names whose mean is physical and is kept; default :data:`NO_MEAN_REMOVAL`
        (speed ``v``, lateral force ``F``, rear wheel rate ``thetaRdot``).

    Returns
    -------
    dict of str to (N,) ndarray
        New arrays, same keys and units; the inputs are not modified.
    """
    return {k: (v.copy() if k in keep else v - v.mean()) for k, v in signals.items()}


def prepare(
    run: Run,
    cutoff: float | None = 15.0,
    order: int = 2,
    subtract_mean: bool = True,
    derivative: str = "central",
    source: str = "signals",
) -> Run:
    """Moore & Hubbard preprocessing; returns a new run with ``phiddot``, ``deltaddot``.

    Order: low-pass every signal (``cutoff=None`` skips it), differentiate the
    (filtered) rates phidot, deltadot with ``derivative``, then remove means (not from
    v, F, thetaRdot).  ``derivative="interval"``: interval-averaged equation first, then
    the low-pass (module docstring); the run loses its last sample.  ``source="truth"``
    processes the noise-free signals of a simulated run instead of the measured ones.  The
    dither and reference are kept.

    Parameters
    ----------
    run : Run
        The run to process (not modified).
    cutoff : float or None, optional
        Low-pass cut-off [Hz] of :func:`lowpass` (default 15 Hz, Moore & Hubbard's);
        ``None`` or 0 skips filtering.
    order : int, optional
        Butterworth order of :func:`lowpass`.
    subtract_mean : bool, optional
        Remove each signal's time mean, except :data:`NO_MEAN_REMOVAL`.
    derivative : {"central", "forward", "backward", "interval"}, optional
        How the accelerations are formed (module docstring).
    source : {"signals", "truth"}, optional
        Process the measured signals or the simulator's noise-free ones.

    Returns
    -------
    Run
        A new run whose signals are the processed ones plus ``phiddot`` and ``deltaddot``
        [rad/s^2]; ``meta["preprocessing"]`` records the options.  With
        ``derivative="interval"`` it has one sample fewer and its signals are interval
        means (held inputs T_phi, T_delta, F at their value over the interval).

    Raises
    ------
    ValueError
        If ``source`` or ``derivative`` is not one of its choices, ``source="truth"`` for
        a run without noise-free signals, or the filter settings are invalid
        (:func:`lowpass`).
    """
    if source not in ("signals", "truth"):
        raise ValueError(f"source {source!r}: choose 'signals' or 'truth'")
    sig = run.signals if source == "signals" else run.truth
    if sig is None:
        raise ValueError("this run has no noise-free signals; use source='signals'")
    if derivative not in _PREPARE:
        raise ValueError(f"unknown derivative {derivative!r}; choose from {list(_PREPARE)}")
    dt = run.dt
    t, dither, reference = run.t, run.dither, run.reference
    if derivative == "interval":
        held = ("T_delta", "T_phi", "F")  # ZOH inputs: constant over the interval
        sig = {k: (np.asarray(v, float)[:-1] if k in held else
                   0.5 * (np.asarray(v, float)[:-1] + np.asarray(v, float)[1:]))
               for k, v in sig.items()}  # fmt: skip
        raw = run.signals if source == "signals" else run.truth
        sig["phiddot"] = np.diff(np.asarray(raw["phidot"], float)) / dt
        sig["deltaddot"] = np.diff(np.asarray(raw["deltadot"], float)) / dt
        t = t[:-1]
        dither = None if dither is None else dither[:-1]
        reference = None if reference is None else reference[:-1]
    out = {k: (lowpass(v, dt, cutoff, order) if cutoff else v.copy()) for k, v in sig.items()}
    if derivative != "interval":
        out["phiddot"] = differentiate(out["phidot"], dt, derivative)
        out["deltaddot"] = differentiate(out["deltadot"], dt, derivative)
    if subtract_mean:
        out = remove_means(out)
    meta = dict(run.meta)
    meta["preprocessing"] = {
        "lowpass_hz": cutoff, "order": order, "subtract_mean": subtract_mean,
        "derivative": derivative, "source": source,
    }  # fmt: skip
    truth = run.truth
    if derivative == "interval" and truth is not None:
        truth = {k: np.asarray(v)[:-1] for k, v in truth.items()}
    return Run(t=t, signals=out, truth=truth, dither=dither, reference=reference,
               meta=meta)  # fmt: skip
