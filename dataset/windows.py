"""Windows of an experiment: the stretches of a measured log a model is compared with.

A :class:`Window` is a free decay (:func:`decay_windows`, from the rows of
:mod:`bikeid.dataset.decays`) or the settled stretch of a Bode run (:func:`bode_window`),
with the measured signals, the sensor and treadmill speeds and the logged steer commands
before its start (for a model's delay buffer).  Both builders check the run first
(:func:`bikeid.dataset.run.check_plausible`), and a decay window outside the settled speed
(inside the start-up ramp or in the run-down) is refused by name.  Sample time 0.01 s (one
control loop, :data:`bikeid.dataset.sbw_logs.DT`); units SI (rad, rad/s, m/s, N m).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field, replace

import numpy as np

from bikeid.dataset.run import Run, check_plausible
from bikeid.dataset.sbw_logs import BOUNDS_AS, DT, SIGNAL_COLUMNS, treadmill_speed

__all__ = ["Window", "bode_window", "decay_windows"]


@dataclass(frozen=True)
class Window:
    """One stretch of an experiment to simulate: a free decay or a Bode record.

    A value: frozen, so a variant (another drive, the nonlinear plant's defect correction of
    :func:`bikeid.ident.effects.experiment_model.with_nonlinear_correction`) is a new window
    made with :func:`dataclasses.replace`, and fitting twice on the same windows sees the
    same data.

    Measured arrays (length n, sample time 0.01 s): phi, delta, phidot, deltadot,
    v_sensor, T_ext (external steer torque relayed to the motor), T_phi (roll torque,
    simulation only).  ``hist`` holds the logged steer commands before the window
    start (oldest first) for the delay buffer.  ``speed`` is the treadmill speed [m/s].

    Windows of one fit may differ in length (detected decays last 1 to 3 s,
    :func:`bikeid.dataset.decays.detect_decays`).  Each counts as one decay: the fit divides
    a window's residual by that window's own ||y - mean y|| (its cost term is its NRMSE^2,
    :func:`bikeid.ident.effects.fit.output_residuals`, not a sum that grows with n), the
    standard errors take each window as one cluster of its own size, and the weave term
    takes one eigenvalue fit per window (the median per speed).

    Attributes
    ----------
    file : str
        Log file name.
    speed : float
        Treadmill speed [m/s].
    start : int
        File row index of the first sample.
    phi, delta : (n,) ndarray
        Measured roll and steer angles [rad] (positive to the right).
    phidot, deltadot : (n,) ndarray
        Measured roll and steer rates [rad/s].
    v_sensor : (n,) ndarray
        Speed from the bicycle's own sensor [m/s].
    T_ext : (n,) ndarray
        External steer torque relayed to the motor [N m] (zero if the log has none).
    hist : (m,) ndarray
        Logged steer commands T_delta [N m] before ``start``, oldest first (m = 20 from
        :func:`decay_windows` and :func:`bode_window`).
    kind : str
        ``"decay"`` or ``"bode"``.
    freq : float or None
        Excitation frequency of a Bode window [Hz]; None for a decay.
    T_phi : (n,) ndarray or None
        Roll torque [N m] (simulation only; None for measured data).
    meta : dict
        Free-form metadata.
    correction : dict or None
        Nonlinear minus linear outputs at the model the correction was taken at
        (:func:`bikeid.ident.effects.experiment_model.with_nonlinear_correction`), or None.
    T_logged : (n,) ndarray or None
        Logged total steer-motor command over the window [N m] (the plant input; None when
        unknown).
    drive : str
        What drives a model simulated over the window: ``"loop"`` (default: the known
        steer-into-lean law on the simulated roll rate, plus ``T_ext``) or ``"logged"``
        (``T_logged`` replayed open loop: no controller needed).
    """

    file: str
    speed: float
    start: int
    phi: np.ndarray
    delta: np.ndarray
    phidot: np.ndarray
    deltadot: np.ndarray
    v_sensor: np.ndarray
    T_ext: np.ndarray
    hist: np.ndarray
    kind: str = "decay"
    freq: float | None = None
    T_phi: np.ndarray | None = None
    meta: dict = field(default_factory=dict)
    # nonlinear - linear nominal outputs (ident.effects.experiment_model)
    correction: dict | None = None
    T_logged: np.ndarray | None = None
    drive: str = "loop"

    @property
    def n(self) -> int:
        """Number of samples."""
        return self.phi.size

    def state0(self) -> np.ndarray:
        """Measured state at the start: quadratic fit over the first 5 samples at t=0.

        Returns
        -------
        (4,) ndarray
            phi [rad], delta [rad], phidot [rad/s], deltadot [rad/s] at the first sample.
        """
        k = min(5, self.n)
        tt = np.arange(k) * DT
        out = []
        for y in (self.phi, self.delta, self.phidot, self.deltadot):
            c = np.polyfit(tt, y[:k], 2 if k >= 4 else 0)
            out.append(np.polyval(c, 0.0))
        return np.array(out)

    def command_history(self, length: int) -> np.ndarray:
        """The last ``length`` logged commands before the start, oldest first.

        Parameters
        ----------
        length : int
            Number of samples.

        Returns
        -------
        (length,) ndarray
            Steer commands [N m]; a shorter history is padded at the front with its oldest
            value (zero when there is none).
        """
        h = np.asarray(self.hist, dtype=float)
        if h.size >= length:
            return h[-length:]
        return np.concatenate([np.full(length - h.size, h[0] if h.size else 0.0), h])


def _window(run: Run, i0: int, i1: int, kind: str, freq=None, hist_len: int = 20) -> Window:
    first = int(run.meta.get("first_index", 0))
    a, b = i0 - first, i1 - first
    if a < 0 or b > run.n or b - a < 10:
        raise ValueError(
            f"{run.meta.get('file', 'run')}: window rows {i0}..{i1} outside the file "
            f"(rows {first}..{first + run.n})"
        )
    sl = slice(a, b)
    h = run["T_delta"][max(0, a - hist_len) : a]
    h = np.concatenate([np.full(hist_len - h.size, h[0] if h.size else 0.0), h])
    ext = run.signals.get("T_ext", np.zeros(run.n))
    return Window(
        file=str(run.meta.get("file", "run")),
        speed=float(treadmill_speed(np.mean(run["v"][sl]))),
        start=i0,
        phi=run["phi"][sl].copy(),
        delta=run["delta"][sl].copy(),
        phidot=run["phidot"][sl].copy(),
        deltadot=run["deltadot"][sl].copy(),
        v_sensor=run["v"][sl].copy(),
        T_ext=ext[sl].copy(),
        hist=h,
        kind=kind,
        freq=freq,
        T_logged=run["T_delta"][sl].copy(),
    )


def _check_run(run: Run) -> None:
    """The loaders' plausibility check (bounds, dead channels, speed against v)."""
    check_plausible(
        run, str(run.meta.get("file", "run")), columns=SIGNAL_COLUMNS, bounds_as=BOUNDS_AS
    )


def decay_windows(run: Run, segments) -> list[Window]:
    """Free-decay windows of a run from ``bikeid.dataset.decays.Segment`` rows.

    Parameters
    ----------
    run : Run
        A log read by :func:`bikeid.dataset.sbw_logs.load_log`.
    segments : iterable of Segment
        Rows start..end-1 (file row indices).

    Returns
    -------
    list of Window
        With the file's settled treadmill speed [m/s] when the run knows it.

    Raises
    ------
    ValueError
        If the run is not plausible (:func:`bikeid.dataset.run.check_plausible`); a
        window starts before the speed settled (``meta["ramp_end_index"]``: inside the
        start-up ramp) or ends after it stopped being settled (``meta["settled_end_index"]``),
        naming the file and the window's rows; or a segment's rows fall outside the log or
        span fewer than 10 samples.
    """
    _check_run(run)
    segments = list(segments)
    first = int(run.meta.get("first_index", 0))
    lo = int(run.meta.get("ramp_end_index", first))
    hi = int(run.meta.get("settled_end_index", first + run.n))
    for s in segments:
        if s.start < lo or s.end > hi:
            part = "start-up speed ramp" if s.start < lo else "run-down after the settled speed"
            raise ValueError(
                f"{run.meta.get('file', 'run')}: decay window rows {s.start}..{s.end} lies in the "
                f"{part} (speed settled over rows {lo}..{hi}): the model assumes a constant "
                "speed; drop or move this window (eigen/segments.csv)"
            )
    out = [_window(run, s.start, s.end, "decay") for s in segments]
    if "speed" in run.meta:  # one treadmill speed per file (settled plateau)
        out = [replace(w, speed=float(run.meta["speed"])) for w in out]
    return out


def bode_window(run: Run, freq: float | None = None, max_len: float = 20.0) -> Window:
    """The settled-speed stretch of a Bode run (at most ``max_len`` s, skipping 1 s).

    Parameters
    ----------
    run : Run
        A Bode log.
    freq : float, optional
        Excitation frequency [Hz] (default: read from the file name, ``_<f>Hz``).
    max_len : float, optional
        Longest window [s].

    Returns
    -------
    Window
        ``kind="bode"``, rows from the end of the speed ramp + 100 (1 s) to the end of the
        settled plateau or ``max_len`` s later, whichever is first.

    Raises
    ------
    ValueError
        If the run is not plausible (:func:`bikeid.dataset.run.check_plausible`), ``freq``
        is None and the file name has no ``_<f>Hz``, or the window rows fall outside the log
        or span fewer than 10 samples.
    """
    _check_run(run)
    first = int(run.meta.get("first_index", 0))
    i0 = int(run.meta.get("ramp_end_index", first)) + 100
    i1 = min(int(run.meta.get("settled_end_index", first + run.n)), i0 + int(max_len / DT))
    if freq is None:
        m = re.search(r"_([0-9.]+)Hz", str(run.meta.get("file", "")))
        if not m:
            raise ValueError(f"cannot read the excitation frequency from {run.meta.get('file')}")
        freq = float(m.group(1))
    return _window(run, i0, i1, "bode", freq=freq)
