"""A user's own bicycle logs become a :class:`~bikeid.dataset.run.Run`: CSV, HDF5, data frames.

The readers share one validation step:

- :func:`from_csv`: a text table with one header line (lines before it that start with
  ``#`` are comments, e.g. the metadata line of :func:`bikeid.dataset.store.export_csv`);
- :func:`from_hdf5`: any HDF5 file, one 1-D dataset per signal at paths the user names;
- :func:`from_dataframe`: any object with ``.columns`` and ``obj[name]`` returning an
  array-like (a :class:`pandas.DataFrame`, a dict-like table, ...; pandas is not needed);
- :func:`from_arrays`: numpy arrays by your own names (the data object built in memory, as
  MATLAB's ``iddata``), and :func:`from_timeresponse`: python-control's
  ``TimeResponseData`` (the reverse is :meth:`bikeid.dataset.run.Run.to_timeresponse`).

``columns`` (``datasets`` for HDF5) maps bikeid signal names (:data:`~bikeid.sim.conventions.UNITS`:
``phi``, ``delta``, ``phidot``, ``deltadot``, ``v``, ``T_delta``, ``psi``, ..., and
``dither``, a measured external steer-torque excitation kept as ``Run.dither``) to the
user's column names; the time column is ``time``.  ``units`` converts from the user's units
to bikeid's SI units (:data:`CONVERSIONS`): angles ``"deg"``/``"rad"``, rates
``"deg/s"``/``"rad/s"``, speed ``"m/s"``/``"km/h"``, torque ``"N m"``/``"N cm"``, time
``"s"``/``"ms"``.  Signs: bikeid uses Meijaard et al. (2007) signs, roll, steer, yaw and steer
torque positive to the right (x forward, y right, z down); list in ``flip`` the signals whose
log uses the opposite sign.  Speed is a mapped column, or the constant nominal ``speed``
[m/s] when the log has none.

The data are refused with a one-line :class:`ValueError` naming the file, the column and
the row (CSV: the 1-based line number, which is the row a spreadsheet shows, counting the
comment and header lines; data frames: header = row 1; HDF5: 0-based index) when a signal
or column is missing (the message lists what exists), a column name is duplicated, a cell
is not a number, a value is NaN or infinite, time does not strictly increase, the sampling
is irregular (a spacing differs from the median by more than ``jitter`` = 1 % of it; the
worst row is named), the given ``dt`` differs from the file's by more than ``jitter``, a
signal is constant, the speed varies by more than ``speed_range`` = 10 % of its mean (a
constant-speed linear model does not fit: split the log), or the file is empty or
unreadable.  Nothing else escapes from a malformed file: only :class:`ValueError` and
:class:`OSError` with a message.

A log without a time column (one row per sample period, ``time=None`` with ``dt``), with
leading rows logged before recording began (``skip_leading``), extra columns kept as logged
(``extra``) or a speed that ramps (``speed_range=None``) is read by the same path: the TU Delft
steer-by-wire logs are (:func:`bikeid.dataset.sbw_logs.load_log` is a mapping onto
:func:`from_csv`).  A ``.gz`` CSV is decompressed.

The run's ``meta`` gets ``source = "imported"``, ``speed`` (mean of v) [m/s] and
``import``: the file name, its path relative to the working directory, SHA-256 of its
bytes, format, the column mapping, the time column, the unit conversions (user unit, SI
unit, factor) and the flipped signals.
"""

from __future__ import annotations

import csv
import hashlib
import io
import math
import os
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from bikeid.sim.conventions import UNITS

from .files import check_h5_dataset, read_bounded, sha256_file
from .run import CONSTANT_CHECKED, REQUIRED, Run, check_finite, check_plausible

__all__ = [
    "CONVERSIONS",
    "from_arrays",
    "from_csv",
    "from_dataframe",
    "from_hdf5",
    "from_timeresponse",
]

_DEG = math.pi / 180.0

#: For each SI unit of :data:`~bikeid.sim.conventions.UNITS` (and time, "s"), the units a
#: log may be in and the factor that converts a value in that unit to the SI unit.
CONVERSIONS: dict[str, dict[str, float]] = {
    "rad": {"rad": 1.0, "deg": _DEG},
    "rad/s": {"rad/s": 1.0, "deg/s": _DEG},
    "m/s": {"m/s": 1.0, "km/h": 1.0 / 3.6},
    "N m": {"N m": 1.0, "N cm": 0.01},
    "N": {"N": 1.0},
    "m": {"m": 1.0},
    "s": {"s": 1.0, "ms": 1e-3},
}

#: Bytes of memory parsing takes per byte of CSV text (the text, the parsed rows and a
#: Python float per used cell: a 404 MB log peaked at 4.4 GB), for the estimate made from
#: the file's size before it is read (:func:`bikeid.dataset.files.read_bounded`).
CSV_MEMORY_FACTOR = 12

#: Default relative tolerance on sampling jitter (of the median sample period).
JITTER = 0.01
#: Default largest allowed speed range (max - min) relative to the mean speed.
SPEED_RANGE = 0.10

#: Key under which the time column's unit is given in ``units``.
TIME = "t"


# -- the table read from a source ------------------------------------------------------
class _Table:
    """Columns read from one source, with how to name a row of it in a message."""

    def __init__(
        self,
        label: str,
        data: dict[str, np.ndarray],
        row: Callable[[int], str],
        fmt: str,
        path: Path | None,
        digest: str,
        first: int = 0,
    ) -> None:
        self.label = label  # "data.csv" / "log.h5" / "data frame", starts every message
        self.data = data  # user column name -> float array (only the columns used)
        self.row = row  # sample index -> "row 7" / "index 5"
        self.fmt = fmt
        self.path = path
        self.digest = digest
        self.first = first  # leading data rows skipped (skip_leading): the time base's offset


def _relative(path: Path) -> str:
    """The path relative to the working directory (provenance never holds a machine's
    absolute path); the file name alone when there is none."""
    try:
        return Path(os.path.relpath(path.resolve())).as_posix()
    except ValueError:  # another drive (Windows)
        return path.name


#: Signals a log may carry beyond :data:`~bikeid.sim.conventions.UNITS`, with their SI unit:
#: ``dither``, the measured external steer-torque excitation (part of T_delta), becomes
#: :attr:`bikeid.dataset.run.Run.dither` (the closed-loop-safe reference of frequency-response
#: estimates, ``bikeid validate``).
EXTRA_SIGNALS = {"dither": "N m"}
SIGNAL_UNITS = {**UNITS, **EXTRA_SIGNALS}


def _unit_of(signal: str) -> str:
    return "s" if signal == TIME else SIGNAL_UNITS[signal]


def _check_request(
    columns: Mapping[str, str],
    units: Mapping[str, str] | None,
    time: str,
    speed: float | None,
    dt: float | None,
    flip: Iterable[str],
    what: str,
) -> tuple[dict[str, str], dict[str, str], set[str]]:
    """Validate the mapping arguments (independent of the file)."""
    if not isinstance(columns, Mapping):
        raise ValueError(f"{what} must be a mapping of bikeid signal name -> your column name")
    columns = dict(columns)
    unknown = [k for k in columns if k not in SIGNAL_UNITS]
    if unknown:
        raise ValueError(
            f"{what} maps unknown bikeid signals {unknown}; known signals are "
            f"{list(SIGNAL_UNITS)} "
            "(the time column is given with time=...)"
        )
    for k, v in columns.items():
        if not isinstance(v, str) or not v:
            raise ValueError(f"{what}[{k!r}] must be a non-empty column name, got {v!r}")
    if time is None:
        if dt is None:
            raise ValueError(
                "a log without a time column (time=None) needs its sample period dt=<s>"
            )
    elif not isinstance(time, str) or not time:
        raise ValueError(f"time must be the name of your time column, got {time!r}")
    if speed is not None:
        if "v" in columns:
            raise ValueError(
                f"speed={speed!r} given but {what} also maps 'v' to {columns['v']!r}: give "
                "either a speed column or a constant nominal speed, not both"
            )
        if isinstance(speed, bool) or not isinstance(speed, (int, float)):
            raise ValueError(f"speed must be a number [m/s], got {speed!r}")
        if not (math.isfinite(speed) and speed > 0):
            raise ValueError(f"speed must be a positive finite number [m/s], got {speed!r}")
    missing = [k for k in REQUIRED if k not in columns and not (k == "v" and speed is not None)]
    if missing:
        raise ValueError(
            f"{what} does not map the required signals {missing}; a Run needs "
            f"{list(REQUIRED)} (for v: map a speed column or give speed=<m/s>)"
        )
    if dt is not None and (
        isinstance(dt, bool)
        or not isinstance(dt, (int, float))
        or not (math.isfinite(dt) and dt > 0)
    ):
        raise ValueError(f"dt must be a positive finite sample period [s], got {dt!r}")
    units = dict(units or {})
    for k, u in units.items():
        if k != TIME and k not in columns:
            raise ValueError(
                f"units given for {k!r}, which is not in {what} (mapped: {list(columns)}; "
                f"the time column's unit is units[{TIME!r}])"
            )
        allowed = CONVERSIONS[_unit_of(k)]
        if not isinstance(u, str) or u.strip() not in allowed:
            raise ValueError(f"unit {u!r} for {k!r} is not supported; allowed: {list(allowed)}")
        units[k] = u.strip()
    flip = {flip} if isinstance(flip, str) else set(flip)
    bad = sorted(k for k in flip if k not in columns)
    if bad:
        raise ValueError(f"flip names signals {bad} that are not in {what} ({list(columns)})")
    return columns, units, flip


def _build(
    table: _Table,
    columns: dict[str, str],
    units: dict[str, str],
    flip: set[str],
    *,
    time: str,
    speed: float | None,
    dt: float | None,
    meta: Mapping[str, Any] | None,
    jitter: float,
    speed_range: float | None,
    extra: Mapping[str, str] | None = None,
    bounds_as: Mapping[str, str] | None = None,
) -> Run:
    """Check the table's data and convert it into a Run."""
    label, data, row = table.label, table.data, table.row
    extra = dict(extra or {})
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
            f"{label}: column {time!r}, {row(i)}: time {data[time][i]!r} does not increase "
            f"(previous row: {data[time][i - 1]!r}); sort the log or split it there"
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
            "path": None if table.path is None else _relative(table.path),
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
    try:
        run = Run(t=t, signals=signals, meta=out_meta, dither=signals.pop("dither", None))
    except ValueError as exc:
        raise ValueError(f"{label}: {exc}") from None
    return check_plausible(run, label, rows=row, columns={**extra, **columns}, bounds_as=bounds_as)


def _missing(label: str, wanted: Iterable[str], have: list[str], kind: str) -> None:
    absent = [c for c in dict.fromkeys(wanted) if c not in have]
    if absent:
        raise ValueError(f"{label}: missing {kind}s {absent}; the file has {have}")


# -- CSV --------------------------------------------------------------------------------
def _clip(text: str, n: int = 40) -> str:
    """``repr(text)`` for a message, at most about ``n`` characters."""
    return repr(text) if len(text) <= n else f"{text[:n]!r}... ({len(text):,} characters)"


def _read_csv(
    path: Path, wanted: list[str], delimiter: str, label: str, skip_leading: str | None = None
) -> tuple[dict, list[int], str, int]:
    """Parse the wanted columns (a ``.gz`` file is decompressed first).

    Returns the columns, the line of each data row, the SHA-256 of the file's bytes and the
    number of leading data rows dropped because their ``skip_leading`` cell is empty.
    """
    if path.is_dir():
        raise ValueError(f"{label}: is a folder, not a CSV file")
    # memory estimated from the size before reading (a .gz streamed, its expansion capped)
    raw = read_bounded(path, label, CSV_MEMORY_FACTOR)
    # of the file's bytes, as saved in meta["import"] (read again only for a .gz)
    gz = path.name.endswith(".gz")
    digest = sha256_file(path) if gz else hashlib.sha256(raw).hexdigest()
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ValueError(f"{label}: not UTF-8 text (byte {exc.start}); is it a CSV file?") from None
    reader = csv.reader(io.StringIO(text, newline=""), delimiter=delimiter)
    try:
        header = None
        for fields in reader:
            if not fields or fields[0].lstrip().startswith("#"):
                continue
            header = [f.strip() for f in fields]
            break
        if header is None:
            raise ValueError(f"{label}: the file is empty (no header line)")
        header_line = reader.line_num
        dup = sorted({c for c in header if header.count(c) > 1})
        if dup:
            raise ValueError(
                f"{label}: row {header_line}: duplicated column names {dup}; rename them "
                "so each column is unique"
            )
        if len(header) == 1 and any(d in header[0] for d in ";\t|" if d != delimiter):
            raise ValueError(
                f"{label}: row {header_line}: the header is one column {header[0]!r}; the "
                "file is not separated by "
                f"{delimiter!r}: pass delimiter=';' (or the separator it uses)"
            )
        _missing(label, wanted, header, "column")
        idx = {c: header.index(c) for c in wanted}
        cols: dict[str, list[float]] = {c: [] for c in wanted}
        rows: list[int] = []
        first = 0
        lead = None if skip_leading is None else header.index(skip_leading)
        for fields in reader:
            line = reader.line_num
            if not fields or all(not f.strip() for f in fields):
                continue  # blank line
            if lead is not None and not rows and (len(fields) <= lead or not fields[lead].strip()):
                first += 1  # a leading row without the skip_leading value (not yet logging)
                continue
            if len(fields) != len(header):
                raise ValueError(
                    f"{label}: row {line}: {len(fields)} fields but the header (row "
                    f"{header_line}) has {len(header)}; fix the row or the delimiter "
                    f"({delimiter!r})"
                )
            for c, j in idx.items():
                cell = fields[j].strip()
                try:
                    cols[c].append(float(cell))
                except ValueError:
                    raise ValueError(
                        f"{label}: row {line}, column {c!r}: non-numeric value {_clip(cell)}"
                    ) from None
            rows.append(line)
    except csv.Error as exc:  # e.g. a field over csv.field_size_limit() characters
        raise ValueError(
            f"{label}: line {reader.line_num} is not CSV a log can hold ({exc}); the file is "
            "corrupt or not a CSV log"
        ) from None
    if skip_leading is not None and first and not rows:
        raise ValueError(f"{label}: column {skip_leading!r} is empty in every row")
    return {c: np.asarray(v, dtype=float) for c, v in cols.items()}, rows, digest, first


def from_csv(
    path: str | os.PathLike,
    columns: Mapping[str, str],
    units: Mapping[str, str] | None = None,
    *,
    time: str = "t",
    speed: float | None = None,
    dt: float | None = None,
    meta: Mapping[str, Any] | None = None,
    flip: Iterable[str] = (),
    delimiter: str = ",",
    jitter: float = JITTER,
    speed_range: float | None = SPEED_RANGE,
    extra: Mapping[str, str] | None = None,
    skip_leading: str | None = None,
    bounds_as: Mapping[str, str] | None = None,
    label: str | None = None,
) -> Run:
    """Read a CSV log into a :class:`~bikeid.dataset.run.Run` (SI units, Meijaard signs).

    Lines before the header that start with ``#`` are skipped, as are blank lines; only
    the mapped columns are parsed (other columns may hold anything).  A file whose name
    ends in ``.gz`` is decompressed (gzip) first.

    Parameters
    ----------
    path : str or path-like
        The CSV file (UTF-8, one header line of column names).
    columns : mapping of str to str
        bikeid signal name -> the header of its column, e.g. ``{"phi": "roll_deg",
        "delta": "steer_deg", ...}``.  Must cover phi, delta, phidot, deltadot, T_delta
        and v (or give ``speed``); other names of ``sim.conventions.UNITS`` are optional.
    units : mapping of str to str, optional
        bikeid signal name (or ``"t"`` for the time column) -> the unit the log uses, one
        of :data:`CONVERSIONS` for that signal's SI unit (angles "deg"/"rad", rates
        "deg/s"/"rad/s", speed "m/s"/"km/h", torque "N m"/"N cm", time "s"/"ms").
        Signals not listed are taken to be in SI units already.
    time : str or None, default "t"
        Header of the time column; None for a log with one row per sample period and no
        time column (then ``dt`` is required and t = row index * dt, counted from the
        first data row, including rows dropped by ``skip_leading``).
    speed : float, optional
        Constant nominal speed [m/s] for a log without a speed column (then ``v`` is this
        constant).  Not allowed together with a mapped ``v``.
    dt : float, optional
        The sample period [s] you expect; refused if the file's median step differs by
        more than ``jitter`` (relative).
    meta : mapping, optional
        Extra JSON-serializable metadata (e.g. ``{"controller": ...}``); the keys
        ``source`` and ``import`` are reserved.
    flip : iterable of str, optional
        Signals whose log sign is opposite to bikeid's (positive to the left); they are
        negated.
    delimiter : str, default ","
        Field separator.
    jitter : float, default 0.01
        Largest allowed relative deviation of a time step from the median step [-].
    speed_range : float or None, default 0.10
        Largest allowed (max - min) of the speed relative to its mean [-]; None accepts
        any variation (a log with a start-up ramp the caller cuts itself).
    extra : mapping of str to str, optional
        Further signals to keep, name -> column, taken as logged (no unit conversion, no
        flip), e.g. a controller's own torque; checked for finiteness and, through
        ``bounds_as``, for plausibility.
    skip_leading : str, optional
        A column whose empty cells at the start of the file mark rows logged before the
        recording began: those rows are dropped (``meta["import"]["leading_rows_skipped"]``).
    bounds_as : mapping of str to str, optional
        Extra signals checked against the physical bound of a bikeid signal
        (:func:`bikeid.dataset.run.check_plausible`), e.g. ``{"hand_torque": "T_delta"}``.
    label : str, optional
        What messages call the file (default its path).

    Returns
    -------
    Run
        Time [s] and signals [SI] of every row, ``meta["source"] == "imported"``,
        ``meta["speed"]`` [m/s] and the provenance in ``meta["import"]`` (file name, path,
        SHA-256, mapping, unit conversions, flips).

    Raises
    ------
    ValueError
        On a bad mapping or unit (naming the allowed ones), an empty, non-text or
        malformed file, or bad data (module docstring); the message names the file, the
        column and the row (the 1-based line number, counting comment and header lines).
    OSError
        If the file cannot be opened.

    Examples
    --------
    >>> run = from_csv("ride.csv", {"phi": "roll", "delta": "steer", "phidot": "roll_rate",
    ...                "deltadot": "steer_rate", "T_delta": "torque"},
    ...                units={"phi": "deg", "delta": "deg", "phidot": "deg/s",
    ...                       "deltadot": "deg/s"}, time="time", speed=4.5,
    ...                flip={"T_delta"})  # doctest: +SKIP
    """
    path = Path(path)
    label = str(path) if label is None else label
    columns, units, flipped = _check_request(columns, units, time, speed, dt, flip, "columns")
    if not isinstance(delimiter, str) or len(delimiter) != 1:
        raise ValueError(f"delimiter must be one character, got {delimiter!r}")
    extra = dict(extra or {})
    clash = sorted(k for k in extra if k in columns or k in UNITS)
    if clash:
        raise ValueError(f"extra names {clash} are bikeid signals: map them in columns instead")
    wanted = ([] if time is None else [time]) + list(columns.values()) + list(extra.values())
    if skip_leading is not None:
        wanted.append(skip_leading)
    data, rows, digest, first = _read_csv(
        path, list(dict.fromkeys(wanted)), delimiter, label, skip_leading
    )
    table = _Table(label, data, lambda i: f"row {rows[i]}", "csv", path, digest, first)
    return _build(
        table, columns, units, flipped, time=time, speed=speed, dt=dt, meta=meta,
        jitter=jitter, speed_range=speed_range, extra=extra, bounds_as=bounds_as,
    )  # fmt: skip


# -- data frames ------------------------------------------------------------------------
def _frame_column(label: str, df: Any, col: str) -> np.ndarray:
    try:
        raw = df[col]
    except Exception as exc:  # noqa: BLE001 - any table type; report, never a traceback
        raise ValueError(f"{label}: column {col!r} cannot be read ({_first_line(exc)})") from None
    values = getattr(raw, "to_numpy", None)
    try:
        src = values() if callable(values) else raw
        obj = np.asarray(src)
        if obj.dtype.kind not in "fiu":  # mixed cells: look at each as the user wrote it
            obj = np.asarray(src, dtype=object)
    except Exception as exc:  # noqa: BLE001
        raise ValueError(
            f"{label}: column {col!r} is not array-like ({_first_line(exc)})"
        ) from None
    if obj.ndim != 1:
        raise ValueError(f"{label}: column {col!r} has shape {obj.shape}, expected 1-D")
    if obj.dtype.kind in "fiu":  # numbers already: no per-cell check needed
        return obj.astype(float)
    out = np.empty(obj.size)
    for i, cell in enumerate(obj):
        try:
            if isinstance(cell, (str, bytes)) or cell is None:
                raise TypeError
            out[i] = float(cell)
        except (TypeError, ValueError):
            raise ValueError(
                f"{label}: column {col!r}, row {i + 2} (position {i}; header = row 1): "
                f"{cell!r} is not a number"
            ) from None
    return out


def from_dataframe(
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
) -> Run:
    """Convert a table in memory (a pandas DataFrame or any look-alike) into a Run.

    Parameters
    ----------
    df : object
        Anything with ``.columns`` (iterable of column names) and ``df[name]`` returning
        a 1-D array-like of numbers; pandas itself is not imported.
    columns : mapping of str to str
        bikeid signal name -> column name (see :func:`from_csv`).
    units : mapping of str to str, optional
        Units of the user's columns (see :func:`from_csv`).
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

    Returns
    -------
    Run
        As :func:`from_csv`; ``meta["import"]["file"]`` is None and ``sha256`` is the
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
    >>> run = from_dataframe(df, {"phi": "roll", "delta": "steer", "phidot": "p",
    ...                      "deltadot": "d", "T_delta": "tq", "v": "speed"},
    ...                      units={"v": "km/h"}, time="time")  # doctest: +SKIP
    """
    label = str(name)
    columns, units, flipped = _check_request(columns, units, time, speed, dt, flip, "columns")
    try:
        have = [str(c) if not isinstance(c, str) else c for c in list(df.columns)]
    except Exception:  # noqa: BLE001
        raise ValueError(
            f"{label}: a {type(df).__name__} has no usable .columns; pass a table such as a "
            "pandas DataFrame"
        ) from None
    dup = sorted({c for c in have if have.count(c) > 1})
    if dup:
        raise ValueError(f"{label}: duplicated column names {dup}; rename them")
    wanted = list(dict.fromkeys([time] + list(columns.values())))
    _missing(label, wanted, have, "column")
    data = {c: _frame_column(label, df, c) for c in wanted}
    sizes = {c: a.size for c, a in data.items()}
    if len(set(sizes.values())) > 1:
        raise ValueError(f"{label}: columns have different lengths {sizes}")
    h = hashlib.sha256()
    for c in wanted:
        h.update(np.ascontiguousarray(data[c], dtype="<f8").tobytes())
    table = _Table(label, data, lambda i: f"row {i + 2}", "dataframe", None, h.hexdigest())
    return _build(
        table, columns, units, flipped, time=time, speed=speed, dt=dt, meta=meta,
        jitter=jitter, speed_range=speed_range,
    )  # fmt: skip


class _Columns:
    """Arrays by name as a table (``.columns`` and ``[name]``) for :func:`from_dataframe`."""

    def __init__(self, arrays: Mapping[str, Any]) -> None:
        self._arrays = dict(arrays)
        self.columns = list(self._arrays)

    def __getitem__(self, name: str) -> Any:
        return self._arrays[name]


def from_arrays(
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
) -> Run:
    """A run from numpy arrays with your own signal names, units and signs.

    The arrays go through the checks of every import (:func:`from_dataframe`): uniform
    sampling (each step within 1 % of the median), ``dt`` if given, finite values, units
    converted to SI, ``flip`` signals negated, the plausibility bounds of
    :mod:`bikeid.sim.conventions`.

    Parameters
    ----------
    t : (N,) array_like
        Time, strictly increasing, uniformly sampled [s, or ``units["t"]``, e.g. "ms"].
    signals : mapping of str to (N,) array_like
        Your signals by your names.
    mapping : mapping of str to str, optional
        bikeid signal name -> your name (phi, delta, phidot, deltadot, T_delta and v, unless
        ``speed`` is given; see :data:`bikeid.sim.conventions.UNITS`); default: your names
        are bikeid's.
    units : mapping of str to str, optional
        bikeid signal name -> the unit of your array (:data:`CONVERSIONS`: "deg", "deg/s",
        "km/h", "N cm"; ``"t"`` for the time: "ms"); default SI.
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

    Returns
    -------
    Run
        In SI units and bikeid's signs; ``meta["import"]`` records the mapping, the unit
        conversions, the flips and the sample period.

    Raises
    ------
    ValueError
        Naming the signal and the fix: a missing or unknown signal, an unknown unit, arrays
        of different lengths, irregular sampling, a ``dt`` that disagrees, implausible values.
    """
    names = dict(signals)
    time = TIME if TIME not in names else "__time__"
    columns = dict(mapping) if mapping is not None else {k: k for k in names}
    return from_dataframe(_Columns({time: t, **names}), columns, units, time=time, speed=speed,
                          dt=dt, meta=meta, flip=flip, name=name)  # fmt: skip


def from_timeresponse(
    response: Any,
    mapping: Mapping[str, str] | None = None,
    units: Mapping[str, str] | None = None,
    *,
    speed: float | None = None,
    flip: Iterable[str] = (),
    meta: Mapping[str, Any] | None = None,
) -> Run:
    """A run from python-control's ``TimeResponseData`` (one trace).

    Its input and output labels are the signal names; a response made by
    :meth:`bikeid.dataset.run.Run.to_timeresponse` carries bikeid's names, units, sample
    period and speed (``params``), which are used and checked.

    Parameters
    ----------
    response : control.TimeResponseData
        A single-trace response: ``time`` (N,), ``inputs`` and ``outputs`` (n, N) with their
        labels.
    mapping : mapping of str to str, optional
        bikeid signal name -> label (default: the labels are bikeid's names).
    units : mapping of str to str, optional
        Units of the signals by bikeid name; default ``response.params["units"]`` if present,
        else SI.
    speed : float, optional
        Constant nominal speed [m/s] when there is no speed signal (default
        ``response.params["speed"]``).
    flip : iterable of str, optional
        bikeid names of signals with the opposite sign.
    meta : mapping, optional
        Extra JSON-serializable metadata.

    Returns
    -------
    Run
        As :func:`from_arrays`.

    Raises
    ------
    ValueError
        If the response holds several traces, a label repeats, or as :func:`from_arrays`.
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
        units = {k: u for k, u in (params.get("units") or {}).items() if k in (mapping or signals)}
    return from_arrays(t, signals, mapping, units, speed=speed, dt=params.get("dt"), flip=flip,
                       meta=meta, name="time response")  # fmt: skip


# -- HDF5 -------------------------------------------------------------------------------
def _first_line(exc: BaseException) -> str:
    text = str(exc).strip("'\" ")
    return text.splitlines()[0] if text else type(exc).__name__


def _h5_datasets(f) -> list[str]:
    import h5py

    names: list[str] = []

    def visit(name, obj):
        if isinstance(obj, h5py.Dataset):
            names.append(name)

    f.visititems(visit)
    return names


#: What h5py raises on damaged objects (besides its own messages): caught and reported.
_H5_DAMAGE = (OSError, RuntimeError, KeyError, TypeError, ValueError)


def _h5_read(label: str, f, key: str) -> np.ndarray:
    where = f"{label}: dataset {key!r}"
    try:
        ds = f[key]
        check_h5_dataset(ds, where, "copy the data into a plain dataset")  # before reading
        kind, shape, dtype = ds.dtype.kind, ds.shape, ds.dtype
    except _H5_DAMAGE as exc:
        if type(exc) is ValueError and str(exc).startswith(where):  # check_h5_dataset's
            raise
        raise ValueError(f"{where} cannot be opened ({_first_line(exc)}); corrupt file") from None
    if kind not in "fiub":
        raise ValueError(f"{where} has dtype {dtype}, not numbers")
    if len(shape) != 1 and not (len(shape) == 2 and 1 in shape):
        raise ValueError(f"{where} has shape {shape}, expected 1-D (one value per sample)")
    try:
        return np.asarray(ds[()], dtype=float).reshape(-1)
    except _H5_DAMAGE as exc:
        raise ValueError(f"{where} cannot be read ({_first_line(exc)}); corrupt file") from None


def from_hdf5(
    path: str | os.PathLike,
    datasets: Mapping[str, str],
    units: Mapping[str, str] | None = None,
    *,
    time: str = "t",
    speed: float | None = None,
    dt: float | None = None,
    meta: Mapping[str, Any] | None = None,
    flip: Iterable[str] = (),
    jitter: float = JITTER,
    speed_range: float = SPEED_RANGE,
) -> Run:
    """Read signals from any HDF5 file (one 1-D dataset per signal) into a Run.

    Parameters
    ----------
    path : str or path-like
        The HDF5 file.
    datasets : mapping of str to str
        bikeid signal name -> dataset path inside the file, e.g. ``{"phi":
        "imu/roll", ...}`` (see :func:`from_csv` for the required signals).
    units : mapping of str to str, optional
        Units of the user's datasets (see :func:`from_csv`).
    time : str, default "t"
        Dataset path of the time samples [s, or ``units["t"]``].
    speed : float, optional
        Constant nominal speed [m/s] when there is no speed dataset.
    dt : float, optional
        Expected sample period [s], checked against the data.
    meta : mapping, optional
        Extra JSON-serializable metadata.
    flip : iterable of str, optional
        Signals whose sign is opposite to bikeid's (Meijaard: positive to the right).
    jitter : float, default 0.01
        Largest allowed relative deviation of a time step from the median step [-].
    speed_range : float, default 0.10
        Largest allowed speed range relative to the mean speed [-].

    Returns
    -------
    Run
        As :func:`from_csv`, with ``meta["import"]["format"] == "hdf5"``.

    Raises
    ------
    ValueError
        On a bad mapping or unit, a file that is not HDF5, a missing dataset (the message
        lists the file's datasets), a dataset that is not 1-D numbers, datasets of
        different lengths, or bad data; samples are named by 0-based index.
    OSError
        If the file does not exist.

    Examples
    --------
    >>> run = from_hdf5("ride.h5", {"phi": "imu/roll", "delta": "steer/angle",
    ...                 "phidot": "imu/roll_rate", "deltadot": "steer/rate",
    ...                 "T_delta": "steer/torque", "v": "wheel/speed"},
    ...                 units={"v": "km/h"}, time="imu/time")  # doctest: +SKIP
    """
    import h5py

    path = Path(path)
    label = str(path)
    columns, units, flipped = _check_request(
        columns=datasets, units=units, time=time, speed=speed, dt=dt, flip=flip, what="datasets"
    )
    if not path.exists():
        raise FileNotFoundError(f"{label}: no such file")
    if path.is_dir():
        raise ValueError(f"{label}: is a folder, not an HDF5 file")
    try:
        f = h5py.File(path, "r")
    except _H5_DAMAGE as exc:
        raise ValueError(f"{label}: not a readable HDF5 file ({_first_line(exc)})") from None
    wanted = list(dict.fromkeys([time] + list(columns.values())))
    with f:
        try:
            have = _h5_datasets(f)
        except _H5_DAMAGE as exc:
            raise ValueError(
                f"{label}: cannot list its datasets ({_first_line(exc)}); corrupt file"
            ) from None
        _missing(label, [w.strip("/") for w in wanted], have, "dataset")
        data = {w: _h5_read(label, f, w) for w in wanted}
    sizes = {c: a.size for c, a in data.items()}
    if len(set(sizes.values())) > 1:
        raise ValueError(f"{label}: datasets have different lengths {sizes}")
    table = _Table(label, data, lambda i: f"index {i}", "hdf5", path, sha256_file(path))
    return _build(
        table, columns, units, flipped, time=time, speed=speed, dt=dt, meta=meta,
        jitter=jitter, speed_range=speed_range,
    )  # fmt: skip
