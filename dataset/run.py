"""One experiment run: time series of the Moore & Hubbard Table 1 signals + metadata.

Simulated and measured data both become a :class:`Run`, so identification never
knows where the data came from.  Signal names, units and signs are those of
:mod:`sim.conventions`.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bikeid.sim.conventions import INPUTS, MEASURED, NOMINAL_SPEED, PLAUSIBLE, UNITS

__all__ = [
    "CONSTANT_CHECKED",
    "SPEED_TOLERANCE",
    "Run",
    "check_finite",
    "check_plausible",
    "run_stop",
    "split_by_speed",
]

REQUIRED = ("phi", "delta", "phidot", "deltadot", "v", "T_delta")

#: Signals that must not be constant over a run: the states and the steer torque of a
#: closed loop move whenever anything is measured (v may be constant: a treadmill or a
#: simulated ideal drive; other extras, e.g. a locked handlebar angle, may be too).
CONSTANT_CHECKED = ("phi", "delta", "phidot", "deltadot", "T_delta")

#: Largest accepted |mean(v) - meta speed| [m/s]: max(absolute, relative * speed).  A run's
#: own speed signal must agree with its nominal speed.  The simulated speed sensor has
#: 0.01 m/s noise on a held (exact) or coasting (drifting by centimetres per second) speed;
#: the TU Delft sensor speed is compared with its own plateau (``meta["speed_sensor"]``) over
#: the settled rows, which lie within 5 % of it by construction.  0.5 m/s or 15 % is 10x above
#: those and catches metadata of another run or a mistyped speed (e.g. 4.5 for 2.5 m/s).
SPEED_TOLERANCE = (0.5, 0.15)


@dataclass
class Run:
    """A run sampled on a uniform time base.

    Every array is converted to ``float`` and checked on construction.  Units and
    signs are those of :mod:`sim.conventions` (:data:`~sim.conventions.UNITS`):
    angles rad, rates rad/s, v m/s, torques N m, force N, positive to the right.

    Attributes
    ----------
    t : (N,) ndarray
        Time [s], uniform, strictly increasing, N >= 2.  Uniformity is assumed,
        not checked (:attr:`dt` is the median spacing).
    signals : dict of str to (N,) ndarray
        Measured signals by name (see ``sim.conventions.MEASURED`` and ``INPUTS``);
        at least phi, delta, phidot, deltadot, v and T_delta.  Optional extras (pitch
        ``theta``, contact positions ``x``, ``y``, ...) are allowed.  For measured data
        these are what the sensors reported.
    truth : dict of str to (N,) ndarray or None
        The same signals without sensor effects (simulated runs only).
    dither : (N,) ndarray or None
        Steer-torque dither [N m] (part of T_delta), or None.
    reference : (N,) ndarray or None
        Roll-angle reference [rad], or None.
    meta : dict
        JSON-serializable metadata: bicycle parameters, controller and gains,
        effects, noise, seed, speed, source ("simulated" or "measured"),
        ``fell_at`` [s] if the bicycle fell, ``stop`` (why a simulated run ended
        early, see :func:`run_stop`), package version, ...

    Raises
    ------
    ValueError
        On construction, if ``t`` is not 1-D with at least 2 finite, strictly
        increasing samples, a required signal is missing, an array does not have
        shape (N,) or holds non-finite samples, or ``meta`` is not JSON-serializable.
    """

    t: np.ndarray
    signals: dict[str, np.ndarray]
    truth: dict[str, np.ndarray] | None = None
    dither: np.ndarray | None = None
    reference: np.ndarray | None = None
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.t = np.asarray(self.t, dtype=float)
        n = self.t.size
        if self.t.ndim != 1 or n < 2:
            raise ValueError(f"run time base must be 1-D with at least 2 samples, got {n}")
        if not np.all(np.isfinite(self.t)) or np.any(np.diff(self.t) <= 0):
            raise ValueError("run time base must be finite and strictly increasing")
        missing = [k for k in REQUIRED if k not in self.signals]
        if missing:
            raise ValueError(f"run is missing signals {missing}; required are {list(REQUIRED)}")
        self.signals = {k: self._check(k, v, n) for k, v in self.signals.items()}
        if self.truth is not None:
            self.truth = {k: self._check(f"truth/{k}", v, n) for k, v in self.truth.items()}
        for name in ("dither", "reference"):
            arr = getattr(self, name)
            if arr is not None:
                setattr(self, name, self._check(name, arr, n))
        try:
            json.dumps(self.meta)
        except TypeError as exc:
            raise ValueError(f"run metadata must be JSON-serializable: {exc}") from None

    @staticmethod
    def _check(name: str, arr, n: int) -> np.ndarray:
        arr = np.asarray(arr, dtype=float)
        if arr.shape != (n,):
            raise ValueError(f"signal {name!r} has shape {arr.shape}, expected ({n},)")
        check_finite(arr, "run", name)
        return arr

    # -- convenience ---------------------------------------------------------------
    @property
    def n(self) -> int:
        """Number of samples N."""
        return self.t.size

    @property
    def dt(self) -> float:
        """Sample period [s] (median spacing)."""
        return float(np.median(np.diff(self.t)))

    @property
    def speed(self) -> float:
        """Nominal speed [m/s]: ``meta['speed']`` if set, else the mean of v."""
        return float(self.meta.get("speed", np.mean(self.signals["v"])))

    def __getitem__(self, name: str) -> np.ndarray:
        """A measured signal by name: ``run["phi"]``.

        Parameters
        ----------
        name : str
            Signal name (a key of :attr:`signals`, or an input of
            ``sim.conventions.INPUTS``).

        Returns
        -------
        (N,) ndarray
            The signal; T_phi and F default to zeros when not recorded.

        Raises
        ------
        KeyError
            If the run has no such signal and it is not an input.
        """
        if name in self.signals:
            return self.signals[name]
        if name in INPUTS:
            return np.zeros(self.n)
        raise KeyError(
            f"run has no signal {name!r}; it has {sorted(self.signals)} "
            f"(known names: {list(MEASURED) + list(INPUTS)})"
        )

    def true(self, name: str) -> np.ndarray:
        """A noise-free signal (simulated runs only).

        Parameters
        ----------
        name : str
            Signal name (a key of :attr:`truth`, or an input of
            ``sim.conventions.INPUTS``).

        Returns
        -------
        (N,) ndarray
            The true signal; an input not stored in :attr:`truth` is zeros.

        Raises
        ------
        ValueError
            If the run has no noise-free signals (measured data).
        KeyError
            If :attr:`truth` has no such signal and it is not an input.
        """
        if self.truth is None:
            raise ValueError("this run has no noise-free signals (measured data)")
        if name not in self.truth:
            if name in INPUTS:
                return np.zeros(self.n)
            raise KeyError(f"run has no true signal {name!r}; it has {sorted(self.truth)}")
        return self.truth[name]

    def window(self, t0: float, t1: float) -> Run:
        """The samples with t0 <= t < t1, as a new run (metadata copied).

        Parameters
        ----------
        t0, t1 : float
            Start (included) and end (excluded) of the window [s], on the run's own
            time base (not shifted to zero).

        Returns
        -------
        Run
            Signals, truth, dither and reference cut to the window; a shallow copy of
            ``meta``.

        Raises
        ------
        ValueError
            If the window holds fewer than 2 samples.
        """
        sel = (self.t >= t0) & (self.t < t1)
        if sel.sum() < 2:
            raise ValueError(f"window [{t0}, {t1}) s holds fewer than 2 samples")

        def cut(d):
            return None if d is None else {k: v[sel] for k, v in d.items()}

        return Run(
            t=self.t[sel],
            signals=cut(self.signals),
            truth=cut(self.truth),
            dither=None if self.dither is None else self.dither[sel],
            reference=None if self.reference is None else self.reference[sel],
            meta=dict(self.meta),
        )

    # -- the data object, to python-control (from arrays, frames, responses: importers) ----
    def to_timeresponse(
        self,
        inputs: Sequence[str] = ("T_delta",),
        outputs: Sequence[str] = ("phi", "delta", "phidot", "deltadot"),
    ) -> Any:
        """The run as python-control's ``TimeResponseData``, with names, units and speed.

        Parameters
        ----------
        inputs : sequence of str, optional
            Signals taken as inputs (default the steer torque T_delta [N m]).
        outputs : sequence of str, optional
            Signals taken as outputs (default the states in bikeid's order [rad, rad/s]);
            add ``"v"`` to carry the measured speed.

        Returns
        -------
        control.TimeResponseData
            ``time`` [s], ``inputs`` and ``outputs`` (n, N) in SI units, labelled with
            bikeid's names; ``params`` holds ``units`` (SI unit per label), ``dt`` [s] and
            ``speed`` [m/s] (what :func:`bikeid.dataset.importers.from_timeresponse` reads
            back).

        Raises
        ------
        KeyError
            If the run has no such signal.
        """
        import control  # python-control is a dependency, loaded only when converting

        names = [*inputs, *outputs]
        return control.TimeResponseData(
            self.t, np.array([self[o] for o in outputs]), inputs=np.array([self[i] for i in
            inputs]), output_labels=list(outputs), input_labels=list(inputs),
            params={"units": {k: UNITS.get(k, "") for k in names}, "dt": self.dt,
                    "speed": self.speed}, title="bikeid run",
        )  # fmt: skip



def _where(i: int, rows) -> str:
    """'row R' when file rows are known (array, or a function of the index giving the
    whole phrase), else 'sample i'."""
    if rows is None:
        return f"sample {i}"
    return str(rows(i)) if callable(rows) else f"row {int(rows[i])}"


def _count(bad: np.ndarray) -> str:
    """'1 such sample' / 'k such samples'."""
    k = int(bad.sum())
    return f"{k} such sample" + ("" if k == 1 else "s")


def _at(i: int, t) -> str:
    """' at t = ... s' when the time base is known."""
    return "" if t is None else f" at t = {float(t[i]):.3f} s"


#: The usual wrong unit of a column in each SI unit (the importers' name for it).
_OTHER_UNIT = {"rad": "deg", "rad/s": "deg/s", "m/s": "km/h", "N m": "N cm"}


def _unit_hint(key: str, unit: str) -> str:
    """'check the unit first: ...; ' for a signal whose column may be in another unit."""
    other = _OTHER_UNIT.get(unit)
    if other is None:
        return "check the column's unit and sign first; "
    return (f"check the column's unit first (in {other}? give --units {key}={other}, "
            f"units={{{key!r}: {other!r}}}); ")


def check_finite(arr: np.ndarray, source: str, column: str, rows=None, t=None) -> None:
    """Refuse NaN or infinite samples, naming the source, column and first bad row.

    Parameters
    ----------
    arr : (N,) array_like
        The samples.
    source : str
        What the samples came from (a file name, ``file: run 'name'``), for the message.
    column : str
        The column or dataset name, for the message.
    rows : (N,) array_like of int or callable, optional
        The file row (line number) of each sample, or a function of the sample index
        returning the phrase naming it (e.g. ``"line 12"``), for the message.
    t : (N,) array_like, optional
        Time of each sample [s], for the message when ``rows`` is not given.

    Raises
    ------
    ValueError
        ``<source>: row R, column '<column>': non-finite value nan at t = ... s (k such
        samples); ...`` at the first non-finite sample.
    """
    arr = np.asarray(arr, dtype=float)
    bad = ~np.isfinite(arr)
    if bad.any():
        i = int(np.argmax(bad))
        raise ValueError(
            f"{source}: {_where(i, rows)}, column {column!r}: non-finite value "
            f"{float(arr[i])!r}{_at(i, t)} ({_count(bad)}); clean or cut the data"
        )


def check_plausible(
    run: Run,
    source: str,
    rows=None,
    columns: dict[str, str] | None = None,
    bounds_as: dict[str, str] | None = None,
) -> Run:
    """Refuse a run whose numbers are not physical: the one check every loader runs.

    Checks, in this order:

    1. every measured (and noise-free) signal with a bound in
       ``sim.conventions.PLAUSIBLE`` lies inside it (or inside the bound of the name
       ``bounds_as`` maps it to);
    2. none of :data:`CONSTANT_CHECKED` is constant over the run (an all-zero or dead
       channel);
    3. ``meta["speed"]``, if present, is a number in ``sim.conventions.NOMINAL_SPEED``
       (0 < speed <= 30 m/s), and the mean of the run's own ``v`` over its settled rows
       (``meta["ramp_end_index"]`` .. ``meta["settled_end_index"]`` when known) agrees with
       ``meta["speed_sensor"]`` (measured logs) or ``meta["speed"]`` within
       :data:`SPEED_TOLERANCE`.

    Non-finite samples cannot occur: :class:`Run` refuses them (:func:`check_finite`).

    A simulated run whose metadata records a *numerical* stop (:func:`run_stop` with
    ``physical`` False: the integration blew up, e.g. a controller asked for 1e299 N m)
    is flagged as non-physical by its own record: checks 1 and 2 are skipped for it (its
    last samples are the blow-up, the sweep stores and reports it as failed) and only
    check 3 applies.  Such a run never reaches an estimate: every estimator refuses
    runs that stopped (``ident.signals.check_complete``).

    Parameters
    ----------
    run : Run
        The run to check.
    source : str
        What the run came from (file name, ``file: run 'name'``), for the messages.
    rows : (N,) array_like of int or callable, optional
        File row (line number) of each sample, or a function of the sample index returning
        the phrase naming it, for the messages; default: sample index and time.
    columns : dict of str to str, optional
        Column name in the source of each signal name, for the messages (default: the
        signal name).
    bounds_as : dict of str to str, optional
        Signal names checked against the bound of another name (e.g. a logged handlebar
        torque against ``T_delta``).

    Returns
    -------
    Run
        ``run`` itself, unchanged.

    Raises
    ------
    ValueError
        Naming the source, column and row of the first sample out of bounds, the constant
        channel, or the nominal and the measured speed.
    """
    columns = columns or {}
    bounds_as = bounds_as or {}
    stop = run_stop(run)
    failed = stop is not None and not stop.get("physical", True)
    groups = [("", run.signals)] + ([("truth/", run.truth)] if run.truth is not None else [])
    if failed:  # flagged non-physical by its own stop record: see the docstring
        groups = []
    for prefix, sig in groups:
        for name, arr in sig.items():
            key = bounds_as.get(name, name)
            if key not in PLAUSIBLE:
                continue
            lo, hi = PLAUSIBLE[key]
            bad = (arr < lo) | (arr > hi)
            if bad.any():
                i = int(np.argmax(bad))
                col = prefix + name if prefix else columns.get(name, name)
                label = f"{col!r}" if col == prefix + name else f"{col!r} ({name})"
                unit = UNITS.get(key, "")
                raise ValueError(
                    f"{source}: {_where(i, rows)}, column {label}: value {arr[i]:.6g} {unit}"
                    f"{_at(i, run.t)} is outside the physical range {lo:g}..{hi:g} {unit} of {key} "
                    f"(sim.conventions.PLAUSIBLE; {_count(bad)}); {_unit_hint(key, unit)}"
                    "otherwise the data is corrupt: fix or cut these rows"
                )
    for name in () if failed else CONSTANT_CHECKED:
        if name in run.signals and np.ptp(run.signals[name]) == 0.0:
            col = columns.get(name, name)
            raise ValueError(
                f"{source}: column {col!r} ({name}) is constant ({run.signals[name][0]:g}) over "
                f"all {run.n} samples: a dead sensor or an empty record; drop this run"
            )
    if "speed" in run.meta:
        speed = run.meta["speed"]
        lo, hi = NOMINAL_SPEED
        if (
            not isinstance(speed, (int, float))
            or isinstance(speed, bool)
            or not (np.isfinite(speed) and lo < speed <= hi)
        ):
            raise ValueError(
                f"{source}: nominal speed meta['speed'] = {speed!r} is not a speed in "
                f"({lo:g}, {hi:g}] m/s; fix the run's metadata"
            )
        ref_key = "speed_sensor" if "speed_sensor" in run.meta else "speed"
        ref = float(run.meta[ref_key])
        first = int(run.meta.get("first_index", 0))
        a = max(int(run.meta.get("ramp_end_index", first)) - first, 0)
        b = min(int(run.meta.get("settled_end_index", first + run.n)) - first, run.n)
        if b - a < 1:
            a, b = 0, run.n
        mean_v = float(np.mean(run.signals["v"][a:b]))
        tol = max(SPEED_TOLERANCE[0], SPEED_TOLERANCE[1] * abs(ref))
        if abs(mean_v - ref) > tol:
            where = "" if (a, b) == (0, run.n) else f" over samples {a}..{b}"
            raise ValueError(
                f"{source}: meta[{ref_key!r}] = {ref:.3f} m/s but the mean of its own speed signal "
                f"{columns.get('v', 'v')!r}{where} is {mean_v:.3f} m/s (tolerance {tol:.3g} m/s, "
                "dataset.run.SPEED_TOLERANCE); the metadata belongs to another run or is wrong"
            )
    return run


def run_stop(run: Run) -> dict[str, Any] | None:
    """Why a run ended early, from its metadata, or None if it is complete.

    Parameters
    ----------
    run : Run
        Any run.  Simulated runs record ``meta["stop"]`` (``dataset.closed_loop``);
        runs written before that field existed record only ``meta["fell_at"]``, read
        here as a ``roll_limit`` stop.

    Returns
    -------
    dict or None
        ``{"cause", "time" [s], "message", "physical"}`` (``sim.integrate.STOP_CAUSES``),
        or None for a complete run (and for measured data).
    """
    stop = run.meta.get("stop")
    if stop:
        return dict(stop)
    fell = run.meta.get("fell_at")
    if fell is not None:
        return {
            "cause": "roll_limit",
            "time": float(fell),
            "message": f"fell at t={float(fell):.3f} s",
            "physical": True,
        }
    return None


def split_by_speed(
    run: Run,
    tolerance: float = 0.25,
    min_duration: float = 10.0,
    min_speed: float = 0.5,
    smoothing: float = 1.0,
) -> list[Run]:
    """A run whose speed varies, cut into its constant-speed stretches.

    The speed is smoothed by a centred moving average over ``smoothing`` s (sensor noise is
    not a change of speed); walking forward from the first sample, a stretch grows while the
    smoothed speed's range within it stays at most ``tolerance``.  Stretches shorter than
    ``min_duration`` or slower (mean of the logged v) than ``min_speed`` are dropped.

    Parameters
    ----------
    run : Run
        The run; its signal ``v`` [m/s] is the speed.
    tolerance : float, optional
        Largest range of the smoothed speed within a stretch [m/s].
    min_duration : float, optional
        Shortest stretch kept [s].
    min_speed : float, optional
        Slowest mean speed of a stretch kept [m/s].
    smoothing : float, optional
        Width of the moving average applied to v first [s].

    Returns
    -------
    list of Run
        The stretches in time order (:meth:`Run.window`), each with ``meta["speed"]`` the
        mean of its v [m/s] and ``meta["stretch"]`` its [start, stop) [s]; empty when none
        qualifies.
    """
    v = run.signals["v"]
    w = max(1, min(run.n, int(round(smoothing / run.dt))))
    pad = np.concatenate([np.full(w // 2, v[0]), v, np.full(w - 1 - w // 2, v[-1])])
    vs = np.convolve(pad, np.ones(w) / w, mode="valid")
    out: list[Run] = []
    i = 0
    while i < run.n:
        lo = hi = vs[i]
        j = i + 1
        while j < run.n and max(hi, vs[j]) - min(lo, vs[j]) <= tolerance:
            lo, hi = min(lo, vs[j]), max(hi, vs[j])
            j += 1
        mean = float(np.mean(v[i:j]))
        if (j - i) * run.dt >= min_duration and mean >= min_speed and j - i >= 3:
            t0, t1 = float(run.t[i]), float(run.t[j - 1] + 0.5 * run.dt)
            part = run.window(t0, t1)
            part.meta.update(speed=mean, stretch=[t0, t1])
            out.append(part)
        i = j
    return out
