"""Tables of samples as every reader hands them to :meth:`bikeid.dataset.run.Run.from_table`.

A reader (CSV and HDF5 in :mod:`bikeid.dataset.importers`, a data frame or numpy arrays in
:class:`~bikeid.dataset.run.Run`'s constructors) reads the user's columns into a
:class:`Table` and checks the mapping arguments with :func:`check_request`; the run is then
built and its data checked by one implementation, :meth:`~bikeid.dataset.run.Run.from_table`.
This module holds what those readers share and imports no reader, so that
:mod:`~bikeid.dataset.run` (the constructors) and :mod:`~bikeid.dataset.importers` (the file
readers) both import it and not each other.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from bikeid.sim.conventions import UNITS

from .units import unit_factor

__all__ = [
    "EXTRA_SIGNALS",
    "JITTER",
    "REQUIRED",
    "SIGNAL_UNITS",
    "SPEED_RANGE",
    "TIME",
    "ArrayTable",
    "Table",
    "check_missing",
    "check_request",
    "first_line",
    "frame_column",
    "relative_path",
]

#: Signals every run holds.
REQUIRED = ("phi", "delta", "phidot", "deltadot", "v", "T_delta")

#: Default relative tolerance on sampling jitter (of the median sample period).
JITTER = 0.01
#: Default largest allowed speed range (max - min) relative to the mean speed.
SPEED_RANGE = 0.10

#: Key under which the time column's unit is given in ``units``.
TIME = "t"

#: Signals a log may carry beyond :data:`~bikeid.sim.conventions.UNITS`, with their SI unit:
#: ``dither``, the measured external steer-torque excitation (part of T_delta), becomes
#: :attr:`bikeid.dataset.run.Run.dither` (the closed-loop-safe reference of frequency-response
#: estimates, ``bikeid validate``).
EXTRA_SIGNALS = {"dither": "N m"}
#: SI unit of every signal a reader maps.
SIGNAL_UNITS = {**UNITS, **EXTRA_SIGNALS}


class Table:
    """Columns read from one source, with how to name a row of it in a message.

    Parameters
    ----------
    label : str
        What messages call the source ("data.csv", "log.h5", "data frame"); starts every
        message.
    data : dict of str to (N,) ndarray
        The user's column name -> float samples (only the columns used).
    row : callable
        ``row(i)`` -> the phrase naming sample ``i`` ("row 7", "index 5").
    fmt : str
        Format recorded in the provenance ("csv", "hdf5", "dataframe").
    path : Path or None
        The file read, or None for data in memory.
    digest : str
        SHA-256 of the file's bytes (or of the used columns' float64 bytes).
    first : int, optional
        Leading data rows skipped before the first sample (the time base's offset when the
        log has no time column).
    """

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
        self.label = label
        self.data = data
        self.row = row
        self.fmt = fmt
        self.path = path
        self.digest = digest
        self.first = first


class ArrayTable:
    """Arrays by name as a table (``.columns`` and ``[name]``), for a data-frame reader.

    Parameters
    ----------
    arrays : mapping of str to array_like
        Column name -> samples.
    """

    def __init__(self, arrays: Mapping[str, Any]) -> None:
        self._arrays = dict(arrays)
        self.columns = list(self._arrays)

    def __getitem__(self, name: str) -> Any:
        """The column ``name`` (a KeyError when there is none)."""
        return self._arrays[name]


def relative_path(path: Path) -> str:
    """A path relative to the working directory (provenance never holds a machine's
    absolute path).

    Parameters
    ----------
    path : Path
        The file.

    Returns
    -------
    str
        The relative POSIX path; the file name alone when there is none (another drive).
    """
    try:
        return Path(os.path.relpath(path.resolve())).as_posix()
    except ValueError:  # another drive (Windows)
        return path.name


def first_line(exc: BaseException) -> str:
    """The first line of an exception's message (its type when it has none), for a message.

    Parameters
    ----------
    exc : BaseException
        The exception.

    Returns
    -------
    str
        One line.
    """
    text = str(exc).strip("'\" ")
    return text.splitlines()[0] if text else type(exc).__name__


def check_missing(label: str, wanted: Iterable[str], have: list[str], kind: str) -> None:
    """Refuse a table without some wanted columns, listing what it has.

    Parameters
    ----------
    label : str
        The source, for the message.
    wanted : iterable of str
        Names needed.
    have : list of str
        Names the source has.
    kind : str
        "column" or "dataset", for the message.

    Raises
    ------
    ValueError
        ``<label>: missing columns [...]; the file has [...]``.
    """
    absent = [c for c in dict.fromkeys(wanted) if c not in have]
    if absent:
        raise ValueError(f"{label}: missing {kind}s {absent}; the file has {have}")


def _unit_of(signal: str) -> str:
    return "s" if signal == TIME else SIGNAL_UNITS[signal]


def check_request(
    columns: Mapping[str, str],
    units: Mapping[str, str] | None,
    time: str | None,
    speed: float | None,
    dt: float | None,
    flip: Iterable[str],
    what: str,
) -> tuple[dict[str, str], dict[str, str], set[str]]:
    """Validate a reader's mapping arguments (independent of the data).

    Parameters
    ----------
    columns : mapping of str to str
        bikeid signal name -> the user's column name.
    units : mapping of str to str or None
        bikeid signal name (or ``"t"``) -> the user's unit
        (:data:`bikeid.dataset.units.CONVERSIONS`, matched as
        :func:`bikeid.dataset.units.resolve_unit`: ``"KM/H"`` is km/h).
    time : str or None
        The time column (None: none, then ``dt`` is needed).
    speed : float or None
        Constant nominal speed [m/s] instead of a speed column.
    dt : float or None
        Expected sample period [s].
    flip : iterable of str
        Signals with the opposite sign.
    what : str
        What the mapping is called in messages ("columns", "datasets").

    Returns
    -------
    columns : dict of str to str
        The mapping.
    units : dict of str to str
        The units in the table's spelling.
    flip : set of str
        The flipped signals.

    Raises
    ------
    ValueError
        Naming the bad argument and what is allowed.
    """
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
        units[k] = unit_factor(u, _unit_of(k), repr(k))[0]
    flip = {flip} if isinstance(flip, str) else set(flip)
    bad = sorted(k for k in flip if k not in columns)
    if bad:
        raise ValueError(f"flip names signals {bad} that are not in {what} ({list(columns)})")
    return columns, units, flip


def frame_column(label: str, df: Any, col: str) -> np.ndarray:
    """One column of a table in memory as floats, each cell checked.

    Parameters
    ----------
    label : str
        The table, for messages.
    df : object
        Anything with ``df[col]`` returning a 1-D array-like (a pandas DataFrame).
    col : str
        The column.

    Returns
    -------
    (N,) ndarray
        The column as float64.

    Raises
    ------
    ValueError
        If the column cannot be read, is not 1-D, or a cell is not a number (rows numbered
        with the header as row 1).
    """
    try:
        raw = df[col]
    except Exception as exc:  # noqa: BLE001 - any table type; report, never a traceback
        raise ValueError(f"{label}: column {col!r} cannot be read ({first_line(exc)})") from None
    values = getattr(raw, "to_numpy", None)
    try:
        src = values() if callable(values) else raw
        obj = np.asarray(src)
        if obj.dtype.kind not in "fiu":  # mixed cells: look at each as the user wrote it
            obj = np.asarray(src, dtype=object)
    except Exception as exc:  # noqa: BLE001
        raise ValueError(
            f"{label}: column {col!r} is not array-like ({first_line(exc)})"
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

