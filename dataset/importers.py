"""A user's own bicycle logs become a :class:`~bikeid.dataset.run.Run`: CSV, HDF5, data frames.

The readers share one validation step, :meth:`bikeid.dataset.run.Run.from_table`:

- :func:`from_csv`: a text table with one header line (lines before it that start with
  ``#`` are comments, e.g. the metadata line of :func:`bikeid.dataset.store.export_csv`);
- :func:`from_hdf5`: any HDF5 file, one 1-D dataset per signal at paths the user names;
- the data object's constructors are classmethods of :class:`~bikeid.dataset.run.Run`:
  ``Run.from_dataframe`` (any object with ``.columns`` and ``obj[name]`` returning an
  array-like: a :class:`pandas.DataFrame`, ...; pandas is not needed), ``Run.from_arrays``
  (numpy arrays by your own names, as MATLAB's ``iddata``) and ``Run.from_timeresponse``
  (python-control's ``TimeResponseData``; the reverse is ``Run.to_timeresponse``).  This
  module names them :data:`from_dataframe`, :data:`from_arrays` and
  :data:`from_timeresponse` too (the same functions).

``columns`` (``datasets`` for HDF5) maps bikeid signal names
(:data:`~bikeid.sim.conventions.UNITS`: ``phi``, ``delta``, ``phidot``, ``deltadot``, ``v``,
``T_delta``, ``psi``, ..., and ``dither``, a measured external steer-torque excitation kept
as ``Run.dither``) to the user's column names; the time column is ``time``.  ``units``
converts from the user's units to bikeid's SI units (:data:`CONVERSIONS`, the table of
:mod:`bikeid.dataset.units`): angles ``"deg"``/``"rad"``, rates ``"deg/s"``/``"rad/s"``,
speed ``"m/s"``/``"km/h"``/``"kph"``/``"mph"``, torque ``"N m"``/``"N cm"``, time
``"s"``/``"ms"``; case-insensitive where that cannot change the meaning (``"KM/H"``;
``"Ms"``, a megasecond, is refused).  Signs: bikeid uses Meijaard et al. (2007) signs, roll,
steer, yaw and steer torque positive to the right (x forward, y right, z down); list in
``flip`` the signals whose log uses the opposite sign.  Speed is a mapped column, or the
constant nominal ``speed`` [m/s] when the log has none.

The data are refused with a one-line :class:`ValueError` naming the file, the column and
the row (CSV: the 1-based line number, which is the row a spreadsheet shows, counting the
comment and header lines; data frames: header = row 1; HDF5: 0-based index) when a signal
or column is missing (the message lists what exists), a column name is duplicated, a cell
is not a number, a value is NaN or infinite, time does not strictly increase, the sampling
is irregular (a spacing differs from the median by more than ``jitter`` = 1 % of it; the
worst row is named), the given ``dt`` differs from the file's by more than ``jitter``, a
signal is constant, the speed varies by more than ``speed_range`` = 10 % of its mean (a
constant-speed linear model does not fit: split the log), a value lies outside its
physical range (:func:`bikeid.dataset.run.check_plausible`; each range check has a name,
``angle-bounds``, ``rate-bounds``, ``speed-bounds``, ``torque-bounds``, ``force-bounds``,
which ``skip`` turns off for a log you know is odd, recorded in the provenance), or the file
is empty or unreadable.  Nothing else escapes from a malformed file: only :class:`ValueError` and
:class:`OSError` with a message.

A log without a time column (one row per sample period, ``time=None`` with ``dt``), with
leading rows logged before recording began (``skip_leading``), extra columns kept as logged
(``extra``) or a speed that ramps (``speed_range=None``) is read by the same path: the TU Delft
steer-by-wire logs are (:func:`bikeid.dataset.sbw_logs.load_log` is a mapping onto
:func:`from_csv`).  A ``.gz`` CSV is decompressed.

The run's ``meta`` gets ``source = "imported"``, ``speed`` (mean of v) [m/s] and
``import``: the file name, its path relative to the working directory, SHA-256 of its
bytes, format, the column mapping, the time column, the unit conversions (user unit, SI
unit, factor), the flipped signals and the skipped checks.
"""

from __future__ import annotations

import csv
import hashlib
import io
import os
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from bikeid.sim.conventions import UNITS

from .files import check_h5_dataset, read_bounded, sha256_file
from .run import Run
from .tabular import (
    EXTRA_SIGNALS,
    JITTER,
    SIGNAL_UNITS,
    SPEED_RANGE,
    TIME,
    Table,
    check_missing,
    check_request,
    first_line,
)
from .units import CONVERSIONS

__all__ = [
    "CONVERSIONS",
    "EXTRA_SIGNALS",
    "JITTER",
    "SIGNAL_UNITS",
    "SPEED_RANGE",
    "TIME",
    "from_arrays",
    "from_csv",
    "from_dataframe",
    "from_hdf5",
    "from_timeresponse",
]

#: Bytes of memory parsing takes per byte of CSV text (the text, the parsed rows and a
#: Python float per used cell: a 404 MB log peaked at 4.4 GB), for the estimate made from
#: the file's size before it is read (:func:`bikeid.dataset.files.read_bounded`).
CSV_MEMORY_FACTOR = 12

#: :meth:`Run.from_arrays <bikeid.dataset.run.Run.from_arrays>` under its former name (the
#: data object's constructors are classmethods of :class:`~bikeid.dataset.run.Run`).
from_arrays = Run.from_arrays
#: :meth:`Run.from_dataframe <bikeid.dataset.run.Run.from_dataframe>` under its former name.
from_dataframe = Run.from_dataframe
#: :meth:`Run.from_timeresponse <bikeid.dataset.run.Run.from_timeresponse>` under its former
#: name.
from_timeresponse = Run.from_timeresponse


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
        check_missing(label, wanted, header, "column")
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
    skip: Iterable[str] = (),
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
    skip : iterable of str, optional
        Range checks not to run, for a log you know holds values beyond the physical
        ranges (names of :data:`bikeid.dataset.run.BOUND_CHECKS`: ``angle-bounds``,
        ``rate-bounds``, ``speed-bounds``, ``torque-bounds``, ``force-bounds``); recorded in
        ``meta["import"]["skipped_checks"]``.

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
    columns, units, flipped = check_request(columns, units, time, speed, dt, flip, "columns")
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
    table = Table(label, data, lambda i: f"row {rows[i]}", "csv", path, digest, first)
    return Run.from_table(
        table, columns, units, flipped, time=time, speed=speed, dt=dt, meta=meta,
        jitter=jitter, speed_range=speed_range, extra=extra, bounds_as=bounds_as, skip=skip,
    )  # fmt: skip


# -- HDF5 -------------------------------------------------------------------------------
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
        raise ValueError(f"{where} cannot be opened ({first_line(exc)}); corrupt file") from None
    if kind not in "fiub":
        raise ValueError(f"{where} has dtype {dtype}, not numbers")
    if len(shape) != 1 and not (len(shape) == 2 and 1 in shape):
        raise ValueError(f"{where} has shape {shape}, expected 1-D (one value per sample)")
    try:
        return np.asarray(ds[()], dtype=float).reshape(-1)
    except _H5_DAMAGE as exc:
        raise ValueError(f"{where} cannot be read ({first_line(exc)}); corrupt file") from None


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
    skip: Iterable[str] = (),
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
    skip : iterable of str, optional
        Range checks not to run, for a log you know holds values beyond the physical
        ranges (names of :data:`bikeid.dataset.run.BOUND_CHECKS`: ``angle-bounds``,
        ``rate-bounds``, ``speed-bounds``, ``torque-bounds``, ``force-bounds``); recorded in
        ``meta["import"]["skipped_checks"]``.

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
    columns, units, flipped = check_request(
        columns=datasets, units=units, time=time, speed=speed, dt=dt, flip=flip, what="datasets"
    )
    if not path.exists():
        raise FileNotFoundError(f"{label}: no such file")
    if path.is_dir():
        raise ValueError(f"{label}: is a folder, not an HDF5 file")
    try:
        f = h5py.File(path, "r")
    except _H5_DAMAGE as exc:
        raise ValueError(f"{label}: not a readable HDF5 file ({first_line(exc)})") from None
    wanted = list(dict.fromkeys([time] + list(columns.values())))
    with f:
        try:
            have = _h5_datasets(f)
        except _H5_DAMAGE as exc:
            raise ValueError(
                f"{label}: cannot list its datasets ({first_line(exc)}); corrupt file"
            ) from None
        check_missing(label, [w.strip("/") for w in wanted], have, "dataset")
        data = {w: _h5_read(label, f, w) for w in wanted}
    sizes = {c: a.size for c, a in data.items()}
    if len(set(sizes.values())) > 1:
        raise ValueError(f"{label}: datasets have different lengths {sizes}")
    table = Table(label, data, lambda i: f"index {i}", "hdf5", path, sha256_file(path))
    return Run.from_table(
        table, columns, units, flipped, time=time, speed=speed, dt=dt, meta=meta,
        jitter=jitter, speed_range=speed_range, skip=skip,
    )  # fmt: skip
