"""The one loader of logs and run files: import options as a value, every check applied.

``bikeid identify``, ``validate`` and ``measured`` parse their data options into a
:class:`LogOptions` and call :func:`load_runs`; the Python API, the benchmarks and the
tutorials call the same function, so the Python path checks what the command line checks:

1. read (bikeid run files, the steer-by-wire logs, or a user's CSV/HDF5 logs through
   :mod:`bikeid.dataset.importers` with the options' columns, units, time, speed and flips;
   the physical range checks of the import);
2. cut to ``start``..``stop``;
3. the sample period (:mod:`bikeid.dataset.plausibility`: a time unit mistake would make
   nonsense of what follows);
4. split logs whose speed varies into constant-speed stretches (``speed_tolerance``,
   ``min_stretch``, ``min_speed``); a stretch whose speed trend exceeds the tolerance is
   dropped with a note;
5. each rate against the derivative of its angle (units and single flipped signals);
6. with a nominal ``bicycle``: the relative signs of roll, steer and torque against its
   equations of motion (:mod:`bikeid.dataset.signs`: a mirrored roll axis);
7. the signal used as the steer-torque input (``input``).

Each check is skipped by name (``skip``), never silently: the ``note`` callback receives a
note for each skip and for each step that changed the data.  Informativity (excitation) is
checked by the fitters (:mod:`bikeid.ident.informativity`).
"""

from __future__ import annotations

import dataclasses
import math
import sys
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bikeid.sim.errors import InputError

from .plausibility import CHECKS, bounds_notes, check_runs
from .run import BOUND_CHECKS, SPEED_RANGE, Run, split_by_speed

__all__ = [
    "FORMATS",
    "IMPORT_FORMATS",
    "TABLE_SUFFIXES",
    "LogOptions",
    "applied_skips",
    "data_files",
    "import_check_notes",
    "load_runs",
    "print_note",
    "pool_runs",
    "pool_speeds",
    "with_input",
]

#: Data formats the loader reads, and what each is.
FORMATS = {
    "bikeid": "files written by bikeid (sweep, store)",
    "csv": "your own logs, read with --columns (dataset.importers)",
    "hdf5": "your own logs, read with --columns (dataset.importers)",
    "sbw": "TU Delft steer-by-wire logs (files or folders; the settled part of each, v = "
    "treadmill speed, dataset.sbw_logs)",
}
#: A user's own logs: their range checks may be skipped; bikeid run files and the
#: steer-by-wire logs are always range-checked.
IMPORT_FORMATS = ("csv", "hdf5")
#: File name endings read as CSV text when columns are given (a ``.csv`` is never HDF5).
TABLE_SUFFIXES = (".csv", ".txt", ".csv.gz", ".txt.gz")
Note = Callable[[str], None]


def print_note(msg: str) -> None:
    """The default ``note``: ``note: MSG`` on stderr.

    Parameters
    ----------
    msg : str
        The note.

    Returns
    -------
    None
    """
    print(f"note: {msg}", file=sys.stderr, flush=True)


def _names(value: Any) -> tuple[str, ...]:
    if value is None:
        return ()
    if isinstance(value, str):
        value = value.split(",")
    return tuple(dict.fromkeys(str(v).strip() for v in value if str(v).strip()))


@dataclass(frozen=True)
class LogOptions:
    """How to read logs: format, columns, units, signs, window, speed split, checks.

    Attributes
    ----------
    format : str
        One of :data:`FORMATS` (default ``"bikeid"``; a ``.csv``/``.txt`` file given with
        ``columns`` is read as CSV whatever the format says).
    columns : mapping of str to str or None
        csv/hdf5: bikeid signal name -> your column (CSV header) or HDF5 dataset path.
    units : mapping of str to str or None
        csv/hdf5: units of non-SI columns (``{"phi": "deg", "v": "km/h", "t": "ms"}``).
    time : str
        csv/hdf5: the time column (default ``"t"``).
    speed : float or None
        csv/hdf5: constant speed [m/s] when the log has no speed column.
    flip : tuple of str
        csv/hdf5: bikeid names of signals logged with the opposite sign (bikeid: roll and
        steer positive to the right, Meijaard 2007).
    skip : tuple of str
        Checks not to run (:data:`bikeid.dataset.plausibility.CHECKS`), each noted.
    no_checks : bool
        Every check skipped (a note says which still run on bikeid/steer-by-wire files).
    start, stop : float or None
        Keep samples at ``start <= t < stop`` [s, the run's own time base].
    speed_tolerance : float
        Speed range of a constant-speed stretch when a log's speed varies [m/s] (default
        0.25); also the pooling tolerance of :func:`pool_runs`.
    min_stretch : float or None
        Shortest constant-speed stretch kept [s] (default 10); None: no splitting.
    min_speed : float
        Stretches slower than this are dropped [m/s] (default 0.5).
    input : str
        The logged steer torque used as T_delta (default ``"T_delta"``).
    bicycle : str, path or BicycleParameters or None
        The nominal bicycle; when given, the relative signs of roll, steer and torque are
        checked against its equations of motion (:mod:`bikeid.dataset.signs`).
    truth : bool
        bikeid run files: also read the simulated runs' noise-free signals (``Run.truth``;
        default); False leaves them out (``validate`` does: it never reads them, and they
        are over half of a sweep's memory).
    """

    format: str = "bikeid"
    columns: Mapping[str, str] | None = None
    units: Mapping[str, str] | None = None
    time: str = "t"
    speed: float | None = None
    flip: tuple[str, ...] = ()
    skip: tuple[str, ...] = ()
    no_checks: bool = False
    start: float | None = None
    stop: float | None = None
    speed_tolerance: float = 0.25
    min_stretch: float | None = 10.0
    min_speed: float = 0.5
    input: str = "T_delta"
    bicycle: Any = field(default=None, compare=False)
    truth: bool = True

    def __post_init__(self) -> None:
        if self.format not in FORMATS:
            raise InputError(f"format {self.format!r}: choose from {', '.join(FORMATS)}")
        for name in ("columns", "units"):
            value = getattr(self, name)
            if value is not None:
                object.__setattr__(self, name, dict(value))
        object.__setattr__(self, "flip", _names(self.flip))
        skip = _names(self.skip)
        bad = [s for s in skip if s not in CHECKS]
        if bad:
            raise InputError(f"skip {','.join(bad)}: unknown check; choose from "
                             f"{', '.join(CHECKS)}")  # fmt: skip
        object.__setattr__(self, "skip", tuple(CHECKS) if self.no_checks else skip)
        for name in ("start", "stop", "speed", "speed_tolerance", "min_stretch", "min_speed"):
            value = getattr(self, name)
            if value is not None and not (isinstance(value, (int, float))
                                          and math.isfinite(value)):  # fmt: skip
                raise InputError(f"{name}={value!r}: give a finite number")
        if self.start is not None and self.stop is not None and not self.start < self.stop:
            raise InputError(f"--start {self.start:g} s is not before --stop {self.stop:g} s; "
                             "swap them")  # fmt: skip
        if self.speed_tolerance < 0 or self.min_speed < 0 or (
                self.min_stretch is not None and self.min_stretch < 0):  # fmt: skip
            raise InputError("speed_tolerance, min_stretch and min_speed must be >= 0")

    def replace(self, **changes: Any) -> LogOptions:
        """A copy with ``changes`` (the options are a value; nothing is changed in place).

        Parameters
        ----------
        **changes
            Attributes and their new values (checked as at construction).

        Returns
        -------
        LogOptions
        """
        return dataclasses.replace(self, **changes)

    def settings(self) -> dict[str, Any]:
        """The options as saved with a model (JSON-serializable; the bicycle is saved by the
        model's own record, not here).

        Returns
        -------
        dict
            ``format``, ``input``; for csv/hdf5 ``columns``, ``units``, ``time``, ``speed``,
            ``flip``; ``start``, ``stop``, ``speed_tolerance``, ``min_stretch``,
            ``min_speed`` and ``skipped_checks`` (:func:`applied_skips`).
        """
        s: dict[str, Any] = {"format": self.format, "input": self.input}
        if self.format in IMPORT_FORMATS:
            s.update(columns=self.columns, units=self.units, time=self.time, speed=self.speed,
                     flip=list(self.flip))  # fmt: skip
        s.update(start=self.start, stop=self.stop, speed_tolerance=self.speed_tolerance,
                 min_stretch=self.min_stretch, min_speed=self.min_speed,
                 skipped_checks=applied_skips(self))  # fmt: skip
        return s


def import_check_notes(skip: Iterable[str], fmt: str, no_checks: bool = False) -> list[str]:
    """The notes of the import's skipped range checks, or a refusal where they cannot be skipped.

    Parameters
    ----------
    skip : iterable of str
        The checks turned off (:data:`bikeid.dataset.plausibility.CHECKS` names).
    fmt : str
        The data format (:data:`FORMATS`).
    no_checks : bool, optional
        Every check was turned off (then a format without skippable range checks gets a
        note saying so instead of a refusal).

    Returns
    -------
    list of str
        One note per skipped range check; for bikeid or steer-by-wire files with
        ``no_checks``, one note that their range checks still run.

    Raises
    ------
    bikeid.sim.errors.InputError
        A range check named for a format whose files are always checked.
    """
    bounds = [s for s in skip if s in BOUND_CHECKS]
    if fmt in IMPORT_FORMATS or not bounds:
        return bounds_notes(bounds)
    if not no_checks:
        raise InputError(
            f"--skip-check {','.join(bounds)} applies to --format csv or hdf5 (your own logs); "
            f"--format {fmt} files are always range-checked: drop it"
        )
    return [f"the range checks ({', '.join(bounds)}) still run on --format {fmt} files "
            "(written by bikeid or the steer-by-wire logger)"]  # fmt: skip


def applied_skips(options: LogOptions) -> list[str]:
    """The skipped checks that were in fact skipped (the model file's record).

    Parameters
    ----------
    options : LogOptions
        The options.

    Returns
    -------
    list of str
        ``options.skip`` without the range checks where they still run (bikeid and
        steer-by-wire files).
    """
    return [c for c in options.skip
            if options.format in IMPORT_FORMATS or c not in BOUND_CHECKS]  # fmt: skip


def _is_table(path: Path) -> bool:
    name = path.name.lower()
    return any(name.endswith(s) for s in TABLE_SUFFIXES)


def resolve_format(files: Sequence[Any], options: LogOptions) -> LogOptions:
    """The options with the format the files need: CSV text given as another format.

    A ``.csv``/``.txt`` file is never a bikeid run file, an HDF5 log or a steer-by-wire
    log folder: with ``columns`` it is read as CSV; without, the refusal names CSV and the
    columns option (instead of "not a readable HDF5 file").
    """
    tables = [Path(f) for f in files if _is_table(Path(f))]
    if not tables or options.format == "csv":
        return options
    if options.format == "sbw" and all(Path(f).name.lower().endswith((".log", ".log.gz"))
                                       for f in files):  # fmt: skip
        return options
    if options.columns:
        return options.replace(format="csv")
    raise InputError(
        f"{tables[0]} is CSV text, not a --format {options.format} file: read it with "
        "--format csv --columns NAME=COL,... mapping phi, delta, phidot, deltadot, T_delta "
        "(and v, or give --speed) to its header"
    )


def data_files(files: Sequence[Any], options: LogOptions) -> list[Path]:
    """The files the runs are read from (steer-by-wire folders expanded): the provenance.

    Parameters
    ----------
    files : sequence of path
        The files or (steer-by-wire) folders given.
    options : LogOptions
        Their format.

    Returns
    -------
    list of Path
        One entry per file read.
    """
    out = []
    for f in map(Path, files):
        if f.is_dir() and options.format == "sbw":
            from .sbw_logs import find_logs

            logs = find_logs(f)
            if not logs:
                raise InputError(f"{f} holds no steer-by-wire logs (*.log, *.log.gz)")
            out += logs
        else:
            out.append(f)
    return out


def _read(files: Sequence[Any], o: LogOptions) -> tuple[list[Run], list[str]]:
    """The runs of every file and what each came from."""
    if o.format in ("bikeid", "sbw"):
        for opt in ("columns", "units", "speed"):
            if getattr(o, opt) is not None:
                raise InputError(f"--{opt} applies to --format csv or hdf5 (your own logs)")
    if o.format == "bikeid":
        from .store import list_runs, read_runs

        runs, sources = [], []
        for f in files:
            got = read_runs(f, truth=o.truth)
            runs += got
            names = list_runs(f) if len(got) > 1 else [None]
            sources += [f"{f}: run {n!r}" if n else str(f) for n in names]
        return runs, sources
    if o.format == "sbw":
        from .sbw_logs import load_log, settled

        if o.flip:
            raise InputError("--flip applies to --format csv or hdf5 (sbw logs: bikeid signs)")
        paths = data_files(files, o)
        return [settled(load_log(p)) for p in paths], [str(p) for p in paths]
    from . import importers

    if not o.columns:
        raise InputError(
            f"--format {o.format} needs --columns NAME=COL,... mapping phi, delta, phidot, "
            "deltadot, T_delta (and v, or give --speed) to your columns"
        )
    read = importers.from_csv if o.format == "csv" else importers.from_hdf5
    runs = [read(f, o.columns, o.units, time=o.time, speed=o.speed, flip=list(o.flip),
                 speed_range=None, skip=list(o.skip)) for f in files]  # fmt: skip
    return runs, [str(f) for f in files]


def _window(runs: list[Run], sources: list[str], o: LogOptions) -> list[Run]:
    """``start``/``stop``: each run cut to the time window."""
    if o.start is None and o.stop is None:
        return runs
    out = []
    for r, src in zip(runs, sources, strict=True):
        t0 = r.t[0] if o.start is None else o.start
        t1 = r.t[-1] + r.dt if o.stop is None else o.stop
        if ((r.t >= t0) & (r.t < t1)).sum() < 3:
            raise InputError(
                f"{src}: --start/--stop keep fewer than 3 samples of its {r.t[0]:.6g}.."
                f"{r.t[-1]:.6g} s; give a window inside the run"
            )
        w = r.window(t0, t1)
        w.meta["window"] = [float(t0), float(t1)]
        if w.meta.get("source") == "imported" and w.meta.get("import", {}).get(
            "speed_source"
        ) == "column":
            w.meta["speed"] = float(w.signals["v"].mean())
        out.append(w)
    return out


def _trend(run: Run) -> float:
    """Speed change along a run from a fitted linear trend [m/s]."""
    v = np.asarray(run.signals["v"], float)
    if v.size < 3:
        return 0.0
    t = run.t - run.t[0]
    slope = np.polyfit(t, v, 1)[0]
    return float(abs(slope) * (t[-1] - t[0]))


def _split(runs: list[Run], sources: list[str], o: LogOptions, note: Note
           ) -> tuple[list[Run], list[str]]:  # fmt: skip
    """Logs whose speed varies split into constant-speed stretches; trending stretches dropped."""
    tol = o.speed_tolerance
    out, out_src = [], []
    for r, src in zip(runs, sources, strict=True):
        if r.meta.get("source") != "imported":
            out.append(r)
            out_src.append(src)
            continue
        v = r.signals["v"]
        mean = float(np.mean(v))
        if np.ptp(v) <= SPEED_RANGE * mean:
            parts, split = [r], False
        else:
            parts = split_by_speed(r, tolerance=max(tol, 1e-9), min_duration=o.min_stretch,
                                   min_speed=o.min_speed)  # fmt: skip
            split = True
            if not parts:
                raise InputError(
                    f"{src}: speed varies {v.min():.3g}..{v.max():.3g} m/s and no stretch of "
                    f"{o.min_stretch:g} s stays within --speed-tolerance {tol:g} m/s above "
                    f"--min-speed {o.min_speed:g} m/s; raise --speed-tolerance, lower "
                    "--min-stretch, or cut the log with --start/--stop"
                )
        kept = []
        for p in parts:
            change, limit = _trend(p), min(tol, SPEED_RANGE * p.speed)
            if tol > 0 and change > limit:
                note(f"{src} [{p.t[0]:.1f}..{p.t[-1]:.1f} s]: dropped: its speed changes "
                     f"{change:.3g} m/s along it (a linear trend), more than {limit:.3g} m/s "
                     f"(--speed-tolerance {tol:g} m/s or {100 * SPEED_RANGE:g} % of its "
                     f"{p.speed:.3g} m/s): the bicycle was changing speed, and a model at one "
                     "speed would not describe it")  # fmt: skip
                continue
            kept.append(p)
        if not kept:
            raise InputError(
                f"{src}: every stretch changes speed along it by more than --speed-tolerance "
                f"{tol:g} m/s or {100 * SPEED_RANGE:g} % of its speed (the treadmill or rider "
                "was changing speed); cut a part at steady speed with --start/--stop"
            )
        if split:
            spans = ", ".join(f"{p.t[0]:.1f}..{p.t[-1]:.1f} s at {p.speed:.3g} m/s"
                              for p in kept)  # fmt: skip
            note(f"{src}: speed varies {v.min():.3g}..{v.max():.3g} m/s: split into "
                 f"{len(kept)} constant-speed stretch{'es' if len(kept) > 1 else ''} ({spans})")
        out += kept
        out_src += [f"{src} [{p.t[0]:.1f}..{p.t[-1]:.1f} s]" if split else src for p in kept]
    return out, out_src


def with_input(runs: Sequence[Run], name: str) -> list[Run]:
    """The runs with the logged signal ``name`` as the steer-torque input T_delta.

    Parameters
    ----------
    runs : sequence of Run
        The runs.
    name : str
        A logged torque signal [N m] (``"T_delta"``: the runs unchanged).

    Returns
    -------
    list of Run
        New runs (``meta["input"]`` records the choice).
    """
    from bikeid.sim.conventions import UNITS

    if name == "T_delta":
        return list(runs)
    if UNITS.get(name, "N m") != "N m":
        raise InputError(
            f"--input {name}: that signal is in {UNITS[name]}, not a torque; give a steer "
            "torque [N m] such as T_delta"
        )
    for i, r in enumerate(runs):
        if name not in r.signals:
            raise InputError(
                f"--input {name}: run {i + 1} has no signal {name!r}; its signals are "
                f"{', '.join(sorted(r.signals))}"
            )
        if not r.signals[name].any():
            raise InputError(f"--input {name}: the signal is zero in run {i + 1}; nothing to fit")
    return [
        dataclasses.replace(r, signals={**r.signals, "T_delta": r.signals[name]},
                            meta={**r.meta, "input": name})
        for r in runs
    ]  # fmt: skip


def load_runs(
    files: Sequence[Any] | str | Path,
    options: LogOptions | None = None,
    note: Note | None = None,
) -> list[Run]:
    """The runs of ``files``, read, windowed, split into constant-speed stretches and checked.

    Parameters
    ----------
    files : path or sequence of path
        Run files (bikeid HDF5), a user's logs (CSV/HDF5 with ``options.columns``) or
        steer-by-wire logs/folders.
    options : LogOptions, optional
        How to read them (default: bikeid run files, every check).
    note : callable, optional
        ``note(msg)`` receives what was done beyond reading (windowing, speed splits, dropped
        stretches, skipped checks, undecidable signs); default: printed on stderr.

    Returns
    -------
    list of Run
        One per run (or constant-speed stretch), checked.

    Raises
    ------
    bikeid.sim.errors.InputError
        A unit, sign or sampling mistake, or an option that does not apply, each naming the
        fix (exit 3 on the command line).

    Examples
    --------
    >>> from bikeid.dataset.logs import LogOptions, load_runs
    >>> opts = LogOptions(format="csv", columns={"phi": "roll", ...}, units={"t": "ms"},
    ...                   bicycle="benchmark")                       # doctest: +SKIP
    >>> runs = load_runs(["ride.csv"], opts)                          # doctest: +SKIP
    """
    files = [files] if isinstance(files, (str, Path)) else list(files)
    if not files:
        raise InputError("no files given: give run files or logs")
    o = resolve_format(files, options or LogOptions())
    note = note or print_note
    if o.format != (options or LogOptions()).format:
        note(f"{Path(files[0]).name}: read as CSV (--columns given; --format csv says so)")
    for msg in import_check_notes(o.skip, o.format, o.no_checks):
        note(msg)
    runs, sources = _read(files, o)
    runs = _window(runs, sources, o)
    data_skip = [s for s in o.skip if s in ("sample-period", "rate-derivative", "signs")]
    # the sample period first: a time unit mistake would make nonsense of the speed split
    for msg in check_runs(runs, sources, sorted({*data_skip, "rate-derivative", "signs"})):
        if "sample-period" in msg:
            note(msg)
    if o.min_stretch is not None:
        runs, sources = _split(runs, sources, o, note)
    for msg in check_runs(runs, sources, sorted({*data_skip, "sample-period"})):
        if "sample-period" not in msg:
            note(msg)
    from .signs import check_signs, nominal_bicycle

    p = nominal_bicycle(o.bicycle)
    if p is not None and "signs" not in o.skip:
        label = sources[0] if len(sources) == 1 else f"{len(sources)} runs"
        for msg in check_signs(runs, p, label):
            note(msg)
    return with_input(runs, o.input)


def pool_speeds(speeds: list[float], weights: list[float], tolerance: float) -> list[int]:
    """Group index of each speed: sorted speeds within ``tolerance`` of a group's lowest pool.

    Parameters
    ----------
    speeds : list of float
        Mean speed of each run [m/s].
    weights : list of float
        Weight of each run (its number of samples).
    tolerance : float
        Largest speed difference within a group [m/s]; 0 pools equal speeds (to 1e-6 m/s).

    Returns
    -------
    list of int
        For each run, the index of its group (groups numbered by increasing speed).
    """
    order = sorted(range(len(speeds)), key=lambda i: speeds[i])
    group, lowest, k = [0] * len(speeds), None, -1
    for i in order:
        if lowest is None or speeds[i] - lowest > max(tolerance, 1e-6):
            k, lowest = k + 1, speeds[i]
        group[i] = k
    return group


def pool_runs(runs: Sequence[Run], tolerance: float) -> list[Run]:
    """The runs with each pooled group's sample-weighted mean speed as their model speed.

    A run's ``meta["speed"]`` becomes its group's mean; the speed it was logged at (its
    speed sensor's mean over the run) is kept as ``meta["measured_speed"]``.

    Parameters
    ----------
    runs : sequence of Run
        The runs.
    tolerance : float
        Largest speed difference pooled [m/s] (:func:`pool_speeds`).

    Returns
    -------
    list of Run
        New runs, in the given order.
    """
    speeds = [r.speed for r in runs]
    group = pool_speeds(speeds, [r.n for r in runs], tolerance)
    out = []
    for g in sorted(set(group)):
        idx = [i for i in range(len(runs)) if group[i] == g]
        n = sum(runs[i].n for i in idx)
        mean = round(sum(speeds[i] * runs[i].n for i in idx) / n, 6)
        for i in idx:
            meta = {**runs[i].meta, "speed": mean}
            if len(idx) > 1 or abs(speeds[i] - mean) > 1e-9:
                meta["measured_speed"] = speeds[i]
            out.append((i, dataclasses.replace(runs[i], meta=meta)))
    return [r for _, r in sorted(out, key=lambda x: x[0])]
