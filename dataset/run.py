"""One experiment run: time series of the Moore & Hubbard Table 1 signals + metadata.

Simulated and measured data both become a :class:`Run`, so identification never
knows where the data came from.  Signal names, units and signs are those of
:mod:`sim.conventions`.

:class:`Run` is also the data object a user builds (as MATLAB's ``iddata``): from numpy arrays
with their own signal names, a mapping, units and signs (:meth:`Run.from_arrays`), from a
data frame (:meth:`Run.from_dataframe`), from python-control's ``TimeResponseData``
(:meth:`Run.from_timeresponse`) and back (:meth:`Run.to_timeresponse`); the file readers of
:mod:`bikeid.dataset.importers` end in the same :meth:`Run.from_table`.  Units are converted
to SI (:mod:`bikeid.dataset.units`), the sample time is checked, and the values are checked
against the physical ranges of :data:`bikeid.sim.conventions.PLAUSIBLE`
(:func:`check_plausible`); each range check has a name (:data:`BOUND_CHECKS`) by which a
caller who knows the data are odd skips it (``skip=``), which the run's provenance records.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from bikeid.sim.conventions import INPUTS, MEASURED, NOMINAL_SPEED, PLAUSIBLE, UNITS

from .check_names import BOUND_CHECKS, SKIPPABLE_CHECKS
from .tabular import (
    JITTER,
    REQUIRED,
    SIGNAL_UNITS,
    SPEED_RANGE,
    TIME,
    ArrayTable,
    Table,
    check_missing,
    check_request,
    frame_column,
    relative_path,
)
from .units import CONVERSIONS

__all__ = [
    "BOUND_CHECKS",
    "CONSTANT_CHECKED",
    "REQUIRED",
    "SPEED_TOLERANCE",
    "SKIPPABLE_CHECKS",
    "Run",
    "bound_check",
    "check_finite",
    "check_plausible",
    "run_stop",
    "split_by_speed",
]

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

def bound_check(signal: str) -> str | None:
    """The name of the range check that bounds a signal (:data:`BOUND_CHECKS`).

    Parameters
    ----------
    signal : str
        A bikeid signal name (``"phi"``, ``"T_delta"``).

    Returns
    -------
    str or None
        ``"angle-bounds"``, ...; None for a signal without a physical bound.
    """
    if signal not in PLAUSIBLE:
        return None
    unit = UNITS[signal]
    return next((name for name, u in BOUND_CHECKS.items() if u == unit), None)


def _check_skip(skip: Iterable[str]) -> set[str]:
    """The range checks named in ``skip``; a name no check has is refused (a misspelled skip
    must not leave the user believing a check is off)."""
    skip = {skip} if isinstance(skip, str) else set(skip)
    bad = sorted(s for s in skip if s not in SKIPPABLE_CHECKS)
    if bad:
        raise ValueError(f"skip={bad}: no such check; choose from {', '.join(SKIPPABLE_CHECKS)}")
    return {s for s in skip if s in BOUND_CHECKS}


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

    # -- the data object, to python-control ----------------------------------------------
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
            ``speed`` [m/s] (what :meth:`from_timeresponse` reads back).

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

    # -- the data object: built from a table, a data frame, arrays, a time response ---------
    @classmethod
    def from_table(
        cls,
        table: Table,
        columns: dict[str, str],
        units: dict[str, str],
        flip: set[str],
        *,
        time: str | None,
        speed: float | None,
        dt: float | None,
        meta: Mapping[str, Any] | None,
        jitter: float = JITTER,
        speed_range: float | None = SPEED_RANGE,
        extra: Mapping[str, str] | None = None,
        bounds_as: Mapping[str, str] | None = None,
        skip: Iterable[str] = (),
    ) -> Run:
        """A run from a reader's table: the one implementation behind every constructor.

        The samples are checked (finite, time strictly increasing, uniform within
        ``jitter``, ``dt`` if given, no constant channel, speed within ``speed_range``),
        converted to SI units (:data:`bikeid.dataset.units.CONVERSIONS`) and bikeid's signs
        (``flip``), and checked against the physical ranges (:func:`check_plausible`).

        Parameters
        ----------
        table : bikeid.dataset.tabular.Table
            The user's columns as read.
        columns : dict of str to str
            bikeid signal name -> column (checked by
            :func:`bikeid.dataset.tabular.check_request`).
        units : dict of str to str
            bikeid signal name (or ``"t"``) -> the column's unit, in the table's spelling.
        flip : set of str
            Signals logged with the opposite sign; negated.
        time : str or None
            The time column; None: one row per ``dt``, counted from the first data row.
        speed : float or None
            Constant nominal speed [m/s] when no column is mapped to ``v``.
        dt : float or None
            Expected sample period [s].
        meta : mapping or None
            Extra JSON-serializable metadata (``source`` and ``import`` are reserved).
        jitter : float, optional
            Largest relative deviation of a time step from the median step [-].
        speed_range : float or None, optional
            Largest speed range relative to the mean speed [-]; None: any.
        extra : mapping of str to str, optional
            Further signals kept as logged, name -> column.
        bounds_as : mapping of str to str, optional
            Extra signals checked against the bound of a bikeid signal.
        skip : iterable of str, optional
            Range checks not to run (:data:`BOUND_CHECKS` names; other check names are
            ignored here), recorded in ``meta["import"]["skipped_checks"]``.

        Returns
        -------
        Run
            ``meta["source"] == "imported"``, ``meta["speed"]`` [m/s], and
            ``meta["import"]``: file name, relative path, SHA-256, format, mapping, time
            column, unit conversions (user unit, SI unit, factor), flips, speed source,
            sample period [s], skipped checks.

        Raises
        ------
        ValueError
            Naming the source, the column and the row of the first bad sample, and the fix.
        """
        label, data, row = table.label, table.data, table.row
        extra = dict(extra or {})
        skipped = _check_skip(skip)
        for key, tol in (("jitter", jitter), ("speed_range", speed_range)):
            if tol is None and key == "speed_range":
                continue
            if isinstance(tol, bool) or not isinstance(tol, (int, float)) or not tol > 0:
                raise ValueError(f"{key} must be a positive relative tolerance, got {tol!r}")
        n = len(next(iter(data.values())))
        if n == 0:
            raise ValueError(f"{label}: the file holds no data rows; nothing to import")
        if n < 3:
            raise ValueError(f"{label}: only {n} data row(s); a run needs at least 3 samples")
        if time is None:  # one row per sample period, counted from the first data row
            t = (table.first + np.arange(n)) * dt
            used = list(dict.fromkeys([*columns.values(), *extra.values()]))
        else:
            check_finite(data[time], label, time, rows=row)
            t = data[time] * CONVERSIONS["s"][units.get(TIME, "s")]
            used = [c for c in dict.fromkeys([*columns.values(), *extra.values()]) if c != time]
        for col in used:
            check_finite(data[col], label, col, rows=row, t=t)
        step = np.diff(t)
        if time is not None and np.any(step <= 0):
            i = int(np.argmax(step <= 0)) + 1
            raise ValueError(
                f"{label}: column {time!r}, {row(i)}: time {data[time][i]!r} does not "
                f"increase (previous row: {data[time][i - 1]!r}); sort the log or split it there"
            )
        h = float(np.median(step))
        dev = np.abs(step - h) / h
        dev[~np.isfinite(dev)] = np.inf  # a step that overflows float64 is irregular too
        worst = int(np.argmax(dev))
        if time is not None and dev[worst] > jitter:
            raise ValueError(
                f"{label}: column {time!r}, {row(worst + 1)}: irregular sampling, the step "
                f"{step[worst]:.6g} s differs from the median {h:.6g} s by "
                f"{100 * dev[worst]:.3g} % (tolerance {100 * jitter:.3g} %); resample the log "
                "onto a uniform time base or cut out the gap"
            )
        if time is not None and dt is not None and abs(dt - h) > jitter * h:
            raise ValueError(
                f"{label}: column {time!r}: dt={dt!r} s given but the file is sampled every "
                f"{h:.9g} s (median step, {units.get(TIME, 's')} converted to s); fix dt or "
                "the time unit (units={'t': 'ms'})"
            )
        signals: dict[str, np.ndarray] = {}
        conversions: dict[str, dict[str, Any]] = {}
        for sig, col in columns.items():
            si = SIGNAL_UNITS[sig]
            user = units.get(sig, si)
            factor = CONVERSIONS[si][user]
            x = data[col] * factor
            if sig in flip:
                x = -x
            if sig != "v" and sig not in CONSTANT_CHECKED and np.ptp(data[col]) == 0:
                # (the states and the steer torque: check_plausible below, same wording)
                raise ValueError(
                    f"{label}: column {col!r} ({sig}) is constant ({data[col][0]:g}) over all "
                    f"{n} samples; it carries no information: check the mapping or leave it out"
                )
            signals[sig] = x
            conversions[sig] = {"from": user, "to": si, "factor": factor}
        if TIME in units:
            conversions[TIME] = {
                "from": units[TIME], "to": "s", "factor": CONVERSIONS["s"][units[TIME]]
            }  # fmt: skip
        if "v" in signals:
            v = signals["v"]
            mean = float(np.mean(v))
            if not (math.isfinite(mean) and mean > 0):
                raise ValueError(
                    f"{label}: column {columns['v']!r}: mean speed {mean:.6g} m/s is not "
                    "positive and finite; check the column, its unit or flip"
                )
            spread = float(np.ptp(v))
            if speed_range is not None and spread > speed_range * mean:
                lo, hi = int(np.argmin(v)), int(np.argmax(v))
                raise ValueError(
                    f"{label}: column {columns['v']!r}: speed ranges from {v[lo]:.4g} m/s "
                    f"({row(lo)}) to {v[hi]:.4g} m/s ({row(hi)}), {100 * spread / mean:.3g} % "
                    f"of its mean {mean:.4g} m/s (limit {100 * speed_range:.3g} %); a "
                    "constant-speed linear model does not fit: split the log into "
                    "constant-speed segments"
                )
            nominal, speed_source = mean, "column"
        else:
            nominal, speed_source = float(speed), "nominal"
            top = PLAUSIBLE["v"][1]
            if nominal > top and "speed-bounds" not in skipped:
                raise ValueError(
                    f"{label}: the nominal speed {nominal:g} m/s given (speed=, --speed) is "
                    f"outside the physical range 0..{top:g} m/s of v (sim.conventions."
                    f"PLAUSIBLE); check its unit first (in km/h? give --speed {nominal:g}km/h, "
                    f"speed={nominal:g} / 3.6); otherwise it is a typo (or, for a run you know "
                    "is that fast, --skip-check speed-bounds, skip=['speed-bounds'])"
                )
            signals["v"] = np.full(n, nominal)
        for name, col in extra.items():  # taken as logged: no unit conversion, no flip
            signals[name] = data[col]
        user_meta = dict(meta or {})
        clash = sorted({"source", "import"} & set(user_meta))
        if clash:
            raise ValueError(f"meta keys {clash} are set by the importer; rename them")
        out_meta: dict[str, Any] = {
            "speed": nominal,
            **user_meta,
            "source": "imported",
            "import": {
                "file": None if table.path is None else table.path.name,
                "path": None if table.path is None else relative_path(table.path),
                "sha256": table.digest,
                "format": table.fmt,
                "columns": dict(columns),
                "time": time,
                "units": conversions,
                "flip": sorted(flip),
                "speed_source": speed_source,
                "dt": h if time is not None else dt,
            },
        }
        if extra:
            out_meta["import"]["extra"] = extra
        if table.first:
            out_meta["import"]["leading_rows_skipped"] = table.first
        if skipped:
            out_meta["import"]["skipped_checks"] = sorted(skipped)
        try:
            run = cls(t=t, signals=signals, meta=out_meta, dither=signals.pop("dither", None))
        except ValueError as exc:
            raise ValueError(f"{label}: {exc}") from None
        return check_plausible(run, label, rows=row, columns={**extra, **columns},
                               bounds_as=bounds_as, skip=skipped,
                               units={k: units[k] for k in columns if k in units})  # fmt: skip

    @classmethod
    def from_dataframe(
        cls,
        df: Any,
        columns: Mapping[str, str],
        units: Mapping[str, str] | None = None,
        *,
        time: str = "t",
        speed: float | None = None,
        dt: float | None = None,
        meta: Mapping[str, Any] | None = None,
        flip: Iterable[str] = (),
        name: str = "data frame",
        jitter: float = JITTER,
        speed_range: float = SPEED_RANGE,
        skip: Iterable[str] = (),
        bicycle: Any = None,
    ) -> Run:
        """A run from a table in memory (a pandas DataFrame or any look-alike).

        Parameters
        ----------
        df : object
            Anything with ``.columns`` (iterable of column names) and ``df[name]`` returning
            a 1-D array-like of numbers; pandas itself is not imported.
        columns : mapping of str to str
            bikeid signal name -> column name (phi, delta, phidot, deltadot, T_delta and v,
            unless ``speed`` is given; optional others of
            :data:`bikeid.sim.conventions.UNITS` and ``dither``).
        units : mapping of str to str, optional
            bikeid signal name (or ``"t"``) -> the column's unit
            (:data:`bikeid.dataset.units.CONVERSIONS`: "deg", "deg/s", "km/h", "mph",
            "N cm", "ms"; case-insensitive where unambiguous); default SI.
        time : str, default "t"
            Name of the time column [s, or ``units["t"]``].
        speed : float, optional
            Constant nominal speed [m/s] when there is no speed column.
        dt : float, optional
            Expected sample period [s], checked against the data.
        meta : mapping, optional
            Extra JSON-serializable metadata.
        flip : iterable of str, optional
            Signals whose sign is opposite to bikeid's (Meijaard: positive to the right).
        name : str, default "data frame"
            What messages call the table (e.g. the file it was read from).
        jitter : float, default 0.01
            Largest allowed relative deviation of a time step from the median step [-].
        speed_range : float, default 0.10
            Largest allowed speed range relative to the mean speed [-].
        skip : iterable of str, optional
            Checks not to run (:data:`SKIPPABLE_CHECKS`: the range checks, ``sample-period``,
            ``rate-derivative``, ``signs``), for data you know are odd; recorded in
            ``meta["import"]["skipped_checks"]``.
        bicycle : str or BicycleParameters, optional
            The nominal bicycle: the relative signs of roll, steer and torque are checked
            against its equations of motion (:mod:`bikeid.dataset.signs`).

        Returns
        -------
        Run
            As :meth:`from_table`; ``meta["import"]["file"]`` is None and ``sha256`` is the
            digest of the used columns' float64 bytes (time first, then in mapping order).

        Raises
        ------
        ValueError
            On a bad mapping or unit, a table without ``.columns``, duplicated or missing
            column names, non-numeric cells or bad data; rows are numbered with the header
            as row 1 (position 0 is row 2).

        Examples
        --------
        >>> import pandas as pd  # doctest: +SKIP
        >>> df = pd.read_excel("ride.xlsx")  # doctest: +SKIP
        >>> run = Run.from_dataframe(df, {"phi": "roll", "delta": "steer", "phidot": "p",
        ...                          "deltadot": "d", "T_delta": "tq", "v": "speed"},
        ...                          units={"v": "km/h"}, time="time")  # doctest: +SKIP
        """
        label = str(name)
        columns, units, flipped = check_request(columns, units, time, speed, dt, flip,
                                                "columns")  # fmt: skip
        try:
            have = [str(c) if not isinstance(c, str) else c for c in list(df.columns)]
        except Exception:  # noqa: BLE001
            raise ValueError(
                f"{label}: a {type(df).__name__} has no usable .columns; pass a table such as "
                "a pandas DataFrame"
            ) from None
        dup = sorted({c for c in have if have.count(c) > 1})
        if dup:
            raise ValueError(f"{label}: duplicated column names {dup}; rename them")
        wanted = list(dict.fromkeys([time] + list(columns.values())))
        check_missing(label, wanted, have, "column")
        data = {c: frame_column(label, df, c) for c in wanted}
        sizes = {c: a.size for c, a in data.items()}
        if len(set(sizes.values())) > 1:
            raise ValueError(f"{label}: columns have different lengths {sizes}")
        h = hashlib.sha256()
        for c in wanted:
            h.update(np.ascontiguousarray(data[c], dtype="<f8").tobytes())
        table = Table(label, data, lambda i: f"row {i + 2}", "dataframe", None, h.hexdigest())
        run = cls.from_table(
            table, columns, units, flipped, time=time, speed=speed, dt=dt, meta=meta,
            jitter=jitter, speed_range=speed_range, skip=skip,
        )  # fmt: skip
        return _checked(run, label, skip, bicycle)

    @classmethod
    def from_arrays(
        cls,
        t: Any,
        signals: Mapping[str, Any],
        mapping: Mapping[str, str] | None = None,
        units: Mapping[str, str] | None = None,
        *,
        speed: float | None = None,
        dt: float | None = None,
        flip: Iterable[str] = (),
        meta: Mapping[str, Any] | None = None,
        name: str = "arrays",
        skip: Iterable[str] = (),
        bicycle: Any = None,
    ) -> Run:
        """A run from numpy arrays with your own signal names, units and signs.

        The arrays go through the checks of every import (:meth:`from_table`): uniform
        sampling (each step within 1 % of the median), ``dt`` if given, finite values, units
        converted to SI, ``flip`` signals negated, the physical ranges of
        :data:`bikeid.sim.conventions.PLAUSIBLE`; then the checks of the loader
        (:mod:`bikeid.dataset.plausibility`): the sample period (a time in ms given as s is
        refused) and each rate against the derivative of its angle (units, single flips);
        with ``bicycle``, the relative signs against its equations (a mirrored axis).

        Parameters
        ----------
        t : (N,) array_like
            Time, strictly increasing, uniformly sampled [s, or ``units["t"]``, e.g. "ms"].
        signals : mapping of str to (N,) array_like
            Your signals by your names.
        mapping : mapping of str to str, optional
            bikeid signal name -> your name (phi, delta, phidot, deltadot, T_delta and v,
            unless ``speed`` is given; see :data:`bikeid.sim.conventions.UNITS`); default:
            your names are bikeid's.
        units : mapping of str to str, optional
            bikeid signal name -> the unit of your array
            (:data:`bikeid.dataset.units.CONVERSIONS`: "deg", "deg/s", "km/h", "mph",
            "N cm"; ``"t"`` for the time: "ms"); default SI.
        speed : float, optional
            Constant nominal speed [m/s] when there is no speed signal.
        dt : float, optional
            Expected sample period [s], checked against ``t``.
        flip : iterable of str, optional
            bikeid names of signals logged positive to the left (bikeid: to the right).
        meta : mapping, optional
            Extra JSON-serializable metadata.
        name : str, optional
            What messages call the data.
        skip : iterable of str, optional
            Checks not to run (:data:`SKIPPABLE_CHECKS`), recorded in
            ``meta["import"]["skipped_checks"]``.
        bicycle : str or BicycleParameters, optional
            The nominal bicycle whose equations check the signs (default: not checked).

        Returns
        -------
        Run
            In SI units and bikeid's signs; ``meta["import"]`` records the mapping, the unit
            conversions, the flips and the sample period.

        Raises
        ------
        ValueError
            Naming the signal and the fix: a missing or unknown signal, an unknown unit,
            arrays of different lengths, irregular sampling, a ``dt`` that disagrees,
            implausible values.
        """
        names = dict(signals)
        time = TIME if TIME not in names else "__time__"
        columns = dict(mapping) if mapping is not None else {k: k for k in names}
        return cls.from_dataframe(ArrayTable({time: t, **names}), columns, units, time=time,
                                  speed=speed, dt=dt, meta=meta, flip=flip, name=name,
                                  skip=skip, bicycle=bicycle)  # fmt: skip

    @classmethod
    def from_timeresponse(
        cls,
        response: Any,
        mapping: Mapping[str, str] | None = None,
        units: Mapping[str, str] | None = None,
        *,
        speed: float | None = None,
        flip: Iterable[str] = (),
        meta: Mapping[str, Any] | None = None,
        skip: Iterable[str] = (),
        bicycle: Any = None,
    ) -> Run:
        """A run from python-control's ``TimeResponseData`` (one trace).

        Its input and output labels are the signal names; a response made by
        :meth:`to_timeresponse` carries bikeid's names, units, sample period and speed
        (``params``), which are used and checked.

        Parameters
        ----------
        response : control.TimeResponseData
            A single-trace response: ``time`` (N,), ``inputs`` and ``outputs`` (n, N) with
            their labels.
        mapping : mapping of str to str, optional
            bikeid signal name -> label (default: the labels are bikeid's names).
        units : mapping of str to str, optional
            Units of the signals by bikeid name; default ``response.params["units"]`` if
            present, else SI.
        speed : float, optional
            Constant nominal speed [m/s] when there is no speed signal (default
            ``response.params["speed"]``).
        flip : iterable of str, optional
            bikeid names of signals with the opposite sign.
        meta : mapping, optional
            Extra JSON-serializable metadata.
        skip : iterable of str, optional
            Checks not to run (:data:`SKIPPABLE_CHECKS`).
        bicycle : str or BicycleParameters, optional
            The nominal bicycle whose equations check the signs (default: not checked).

        Returns
        -------
        Run
            As :meth:`from_arrays`.

        Raises
        ------
        ValueError
            If the response holds several traces, a label repeats, or as :meth:`from_arrays`.
        """
        params = dict(getattr(response, "params", None) or {})
        t = np.asarray(response.time, dtype=float)
        signals: dict[str, np.ndarray] = {}
        for kind in ("outputs", "inputs"):
            data = getattr(response, kind, None)
            labels = list(getattr(response, f"{kind[:-1]}_labels", None) or [])
            if data is None or not labels:
                continue
            arr = np.asarray(data, dtype=float).reshape(len(labels), -1)
            if arr.shape[1] != t.size:
                raise ValueError(
                    f"time response {kind} have {arr.shape[1]} samples per signal, time has "
                    f"{t.size}: pass a single-trace response"
                )
            for label, row in zip(labels, arr, strict=True):
                if label in signals:
                    raise ValueError(f"time response label {label!r} repeats; rename it")
                signals[label] = row
        if speed is None and "v" not in (mapping or signals):
            speed = params.get("speed")
        if units is None:
            units = {k: u for k, u in (params.get("units") or {}).items()
                     if k in (mapping or signals)}  # fmt: skip
        return cls.from_arrays(t, signals, mapping, units, speed=speed, dt=params.get("dt"),
                               flip=flip, meta=meta, name="time response",
                               skip=skip, bicycle=bicycle)  # fmt: skip


def _checked(run: Run, source: str, skip: Iterable[str], bicycle: Any) -> Run:
    """The loader's data checks on a run built in Python (:meth:`Run.from_dataframe` and the
    constructors on it), as ``bikeid identify`` runs them on files: sample period, rates vs
    angles, and with ``bicycle`` the relative signs; skipped ones recorded in the meta."""
    import warnings

    from .plausibility import check_run

    skip = {skip} if isinstance(skip, str) else set(skip)
    check_run(run, source, skip)
    notes = []
    if bicycle is not None and "signs" not in skip:
        from .signs import check_signs, nominal_bicycle

        notes = check_signs([run], nominal_bicycle(bicycle), source)
        for msg in notes:
            warnings.warn(msg, UserWarning, stacklevel=4)
    data_skips = sorted(skip & {"sample-period", "rate-derivative", "signs"})
    if not (data_skips or notes):
        return run
    imp = dict(run.meta.get("import", {}))
    if data_skips:
        imp["skipped_checks"] = sorted({*imp.get("skipped_checks", []), *data_skips})
    if notes:
        imp["notes"] = notes
    return replace(run, meta={**run.meta, "import": imp})


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


def _unit_hint(name: str, key: str, value: float, declared: str | None) -> str:
    """'check the unit first (...); ' for a value of ``name`` outside the bound of ``key``."""
    unit = UNITS.get(key, "")
    if declared is not None and declared != unit:
        return (f"check the column's unit first (read as {declared}: is that its unit? "
                f"--units {name}=..., units={{{name!r}: ...}}); ")
    if key == "v" and value < PLAUSIBLE["v"][0]:
        return ("check the column's sign first (logged backwards? --flip v, flip=['v']) and "
                "its unit; ")
    factors: dict[float, list[str]] = {}
    for u, f in CONVERSIONS.get(unit, {}).items():
        if u != unit:
            factors.setdefault(f, []).append(u)
    others = [names[0] for names in factors.values()]  # one spelling per factor
    if not others:
        return "check the column's unit and sign first; "
    option = (f"give --units {name}={others[0]}, units={{{name!r}: {others[0]!r}}}"
              if name == key else f"convert it to {unit}")
    return f"check the column's unit first (in {' or '.join(others)}? {option}); "


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
    skip: Iterable[str] = (),
    units: Mapping[str, str] | None = None,
) -> Run:
    """Refuse a run whose numbers are not physical: the one check every loader runs.

    Checks, in this order:

    1. every measured (and noise-free) signal with a bound in
       ``sim.conventions.PLAUSIBLE`` lies inside it (or inside the bound of the name
       ``bounds_as`` maps it to), unless the range check of its unit
       (:data:`BOUND_CHECKS`: ``angle-bounds``, ``rate-bounds``, ``speed-bounds``,
       ``torque-bounds``, ``force-bounds``) is in ``skip``; the message suggests the unit
       (or, for a negative speed, the sign) first, then corruption, then the skip;
    2. none of :data:`CONSTANT_CHECKED` is constant over the run (an all-zero or dead
       channel);
    3. ``meta["speed"]``, if present, is a number in ``sim.conventions.NOMINAL_SPEED``
       (0 < speed <= 30 m/s; with ``speed-bounds`` skipped only > 0), and the mean of the
       run's own ``v`` over its settled rows
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
    skip : iterable of str, optional
        Range checks not to run (names of :data:`BOUND_CHECKS`; other names are ignored:
        they belong to other checks).  The caller records the skip (the importers in
        ``meta["import"]["skipped_checks"]``).
    units : mapping of str to str, optional
        The unit each signal was declared in before conversion to SI (the importers'
        ``units``), so that a message does not suggest the unit the user already gave.

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
    units = dict(units or {})
    skipped = _check_skip(skip)
    stop = run_stop(run)
    failed = stop is not None and not stop.get("physical", True)
    groups = [("", run.signals)] + ([("truth/", run.truth)] if run.truth is not None else [])
    if failed:  # flagged non-physical by its own stop record: see the docstring
        groups = []
    for prefix, sig in groups:
        for name, arr in sig.items():
            key = bounds_as.get(name, name)
            check = bound_check(key)
            if check is None or check in skipped:
                continue
            lo, hi = PLAUSIBLE[key]
            bad = (arr < lo) | (arr > hi)
            if bad.any():
                i = int(np.argmax(bad))
                col = prefix + name if prefix else columns.get(name, name)
                label = f"{col!r}" if col == prefix + name else f"{col!r} ({name})"
                unit = UNITS.get(key, "")
                hint = _unit_hint(name, key, float(arr[i]), units.get(name))
                raise ValueError(
                    f"{source}: {_where(i, rows)}, column {label}: value {arr[i]:.6g} {unit}"
                    f"{_at(i, run.t)} is outside the physical range {lo:g}..{hi:g} {unit} of {key} "
                    f"(sim.conventions.PLAUSIBLE; {_count(bad)}); {hint}otherwise the data is "
                    f"corrupt: fix or cut these rows (or, for a log of your own you know "
                    f"holds such values, --skip-check {check}; skip=[{check!r}] in Python)"
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
        if "speed-bounds" in skipped:
            hi = math.inf
        if (
            not isinstance(speed, (int, float))
            or isinstance(speed, bool)
            or not (np.isfinite(speed) and lo < speed <= hi)
        ):
            fast = (isinstance(speed, (int, float)) and not isinstance(speed, bool)
                    and np.isfinite(speed) and speed > hi)  # fmt: skip
            hint = (f"check its unit first (in km/h? give --speed {speed:g}km/h, speed="
                    f"{speed:g} / 3.6), otherwise fix the run's metadata (or, for a run you "
                    "know is that fast, --skip-check speed-bounds, skip=['speed-bounds'])"
                    if fast else "fix the run's metadata")  # fmt: skip
            raise ValueError(
                f"{source}: nominal speed meta['speed'] = {speed!r} is not a speed in "
                f"({lo:g}, {hi:g}] m/s (sim.conventions.NOMINAL_SPEED); {hint}"
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
