"""Runs on disk: HDF5 files (one group per run) and CSV export of one run.

HDF5 layout (format ``bikeid-runs``, version 1)::

    /                       attrs: format="bikeid-runs", format_version=1, bikeid_version,
                                   extra JSON attributes given by the writer (``attrs``)
    /runs/<name>/           attrs: meta (JSON text of Run.meta), meta_crc32, n (samples)
        t                   time [s]                          attrs: units
        signals/<signal>    measured signals                  attrs: units
        truth/<signal>      noise-free signals (simulated)    attrs: units
        dither, reference   optional                          attrs: units

Every dataset is float64, chunked as one chunk with the Fletcher-32 checksum filter, and
the file uses the HDF5 1.10+ format whose object headers carry checksums; the metadata JSON
(a variable-length string, kept in the unchecksummed global heap) carries its own CRC-32.
So flipped bytes in data or metadata are detected on reading.  Runs keep their insertion order.

Writes are atomic (:func:`dataset.files.atomic_path`, re-exported here): a temporary file
in the target folder is written, flushed and fsynced, then renamed over the target with
:func:`os.replace` (and the folder fsynced); an interrupted write leaves the old file
untouched, and a symlink or device at the target is refused.  The reader validates
everything (format and version, required datasets, equal lengths, finite values,
checksums, metadata JSON) and raises a :class:`ValueError` naming the file, the run
group and the problem.  Every run read is then checked by
:func:`dataset.run.check_plausible` (physical bounds of ``sim.conventions.PLAUSIBLE``, no
constant state or steer-torque channel, nominal speed in range and equal to the mean of the
run's own ``v``), so a run edited to a speed of 100 m/s, or an all-zero run, is refused with
the run, column and row named.
"""

from __future__ import annotations

import errno
import json
import os
import uuid
import zlib
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bikeid.sim.conventions import INPUTS, MEASURED, UNITS
from bikeid.sim.errors import InputError, memory_limit

from .files import (
    atomic_path,
    check_free_space,
    check_h5_dataset,
    check_input_file,
    storage_error,
)
from .importers import JITTER
from .run import REQUIRED, Run, check_plausible

__all__ = [
    "FORMAT",
    "FORMAT_VERSION",
    "atomic_path",
    "check_h5_dataset",
    "copy_runs",
    "export_csv",
    "file_attrs",
    "list_runs",
    "read_run",
    "read_runs",
    "write_runs",
]

FORMAT = "bikeid-runs"
FORMAT_VERSION = 1
#: Largest relative deviation of a time step from the run's median step (the importers'
#: :data:`~bikeid.dataset.importers.JITTER`): a larger one is a gap (or a jump) in the time base.
TIME_JITTER = JITTER
#: Bytes of HDF5 metadata per run on top of its data (groups, attributes, chunk indexes), for
#: the free-space estimate of a write (a run with 27 datasets takes about 40 KiB).
RUN_OVERHEAD = 64 * 1024


def package_version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("bikeid")
    except PackageNotFoundError:  # running from a source tree
        return "unknown"


def _units(name: str) -> str:
    return UNITS.get(name, "")


def _h5():
    import h5py

    return h5py


def _new_file(path: Path | str, attrs: Mapping[str, Any] | None, **driver: Any):
    h5py = _h5()
    f = h5py.File(path, "w", libver=("v110", "latest"), track_order=True, **driver)
    f.attrs["format"] = FORMAT
    f.attrs["format_version"] = FORMAT_VERSION
    f.attrs["bikeid_version"] = package_version()
    for key, value in (attrs or {}).items():
        if key in ("format", "format_version", "bikeid_version"):
            raise ValueError(f"file attribute {key!r} is reserved")
        f.attrs[key] = json.dumps(value)
    f.create_group("runs", track_order=True)
    return f


def _check_name(name: str) -> str:
    if not isinstance(name, str) or not name or "/" in name or name in (".", ".."):
        raise ValueError(f"run name {name!r} is not valid: use a non-empty name without '/'")
    return name


def _put(group, name: str, data: np.ndarray, units: str) -> None:
    data = np.ascontiguousarray(data, dtype=np.float64)
    ds = group.create_dataset(
        name, data=data, chunks=(max(1, data.size),), fletcher32=True, track_times=False
    )
    ds.attrs["units"] = units


def _write_run(runs_group, name: str, run: Run) -> None:
    if not isinstance(run, Run):
        raise ValueError(f"run {name!r} is a {type(run).__name__}, not a dataset.Run")
    g = runs_group.create_group(_check_name(name), track_order=True)
    text = json.dumps(run.meta)
    g.attrs["meta"] = text
    # Variable-length strings live in the global heap, which HDF5 does not checksum.
    g.attrs["meta_crc32"] = np.uint32(zlib.crc32(text.encode()))
    g.attrs["n"] = run.n
    _put(g, "t", run.t, "s")
    sig = g.create_group("signals", track_order=True)
    for key, arr in run.signals.items():
        _put(sig, _check_name(key), arr, _units(key))
    if run.truth is not None:
        tr = g.create_group("truth", track_order=True)
        for key, arr in run.truth.items():
            _put(tr, _check_name(key), arr, _units(key))
    if run.dither is not None:
        _put(g, "dither", run.dither, "N m")
    if run.reference is not None:
        _put(g, "reference", run.reference, "rad")


def _names_for(runs: Sequence[Run], names: Sequence[str] | None) -> list[str]:
    if names is None:
        names = [f"run_{i:04d}" for i in range(len(runs))]
    names = [_check_name(n) for n in names]
    if len(names) != len(runs):
        raise ValueError(f"got {len(runs)} runs but {len(names)} names")
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ValueError(f"duplicate run names {dup}")
    return names


def write_runs(
    path: str | Path,
    runs: Iterable[Run],
    names: Sequence[str] | None = None,
    attrs: Mapping[str, Any] | None = None,
) -> Path:
    """Write ``runs`` to a new HDF5 file at ``path`` atomically (replacing any old file).

    ``names`` are the group names (default ``run_0000``, ``run_0001``, ...); ``attrs`` are
    extra JSON-serializable file attributes (e.g. the sweep settings).

    Parameters
    ----------
    path : str or pathlib.Path
        Target file; any old file there is replaced only once the new one is complete
        (:func:`atomic_path`; a symlink or device at the target is refused).
    runs : iterable of Run
        The runs to store (time [s], signals in the SI units of
        :data:`sim.conventions.UNITS`, recorded as each dataset's ``units`` attribute).
    names : sequence of str, optional
        One group name per run, unique, non-empty, without ``/``.
    attrs : mapping of str to object, optional
        Extra file attributes, each stored as JSON text; ``format``, ``format_version``
        and ``bikeid_version`` are reserved.

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    ValueError
        If an entry of ``runs`` is not a :class:`Run`, a name is invalid or duplicated,
        the numbers of runs and names differ, an attribute name is reserved, or ``path``
        is not a regular file (a symlink or device; :func:`atomic_path`).
    """
    runs = list(runs)
    names = _names_for(runs, names)
    path = Path(path)
    need = sum(_run_bytes(r) for r in runs if isinstance(r, Run))
    check_free_space(path, need)  # HDF5 cannot always fail cleanly on a full disk: not there
    with (
        atomic_path(path) as tmp,
        _h5_write_errors(path, need),
        _h5_target(tmp, attrs, need) as f,
    ):
        for name, run in zip(names, runs, strict=True):
            _write_run(f["runs"], name, run)
    return path


class _h5_target:
    """A new bikeid run file for ``tmp``, built in memory (HDF5's core driver) when it is at
    most a quarter of the memory limit and then written with Python's own ``write``: a full
    disk is then an :class:`OSError` Python sees, never an error inside the HDF5 library
    (which can leave the interpreter in a bad state).  Larger files are written by HDF5
    directly, after the free-space check."""

    def __init__(self, tmp: Path, attrs: Mapping[str, Any] | None, need: float) -> None:
        self.tmp, self.attrs = tmp, attrs
        self.in_memory = need <= memory_limit() / 4

    def __enter__(self):
        if self.in_memory:
            self.f = _new_file(f"bikeid-{uuid.uuid4().hex}.h5", self.attrs, driver="core",
                               backing_store=False)  # fmt: skip
        else:
            self.f = _new_file(self.tmp, self.attrs)
        return self.f

    def __exit__(self, kind, exc, tb) -> bool:
        if exc is not None or not self.in_memory:
            self.f.close()
            return False
        self.f.flush()
        image = self.f.id.get_file_image()
        self.f.close()
        try:
            with open(self.tmp, "wb") as fh:  # a full disk: an OSError Python sees
                fh.write(image)
        except OSError:
            os.truncate(self.tmp, 0)  # free the space now: the message then states it right
            raise
        return False


def _run_bytes(run: Run) -> int:
    """Estimated bytes of one run in a file: its arrays plus :data:`RUN_OVERHEAD`."""
    arrays = [run.t, *run.signals.values(), *(run.truth or {}).values()]
    arrays += [a for a in (run.dither, run.reference) if a is not None]
    return sum(int(np.asarray(a).size) * 8 for a in arrays) + RUN_OVERHEAD


class _h5_write_errors:
    """Turn h5py's storage errors while writing ``path`` (RuntimeError or OSError, often
    without an errno: recognized by the errno or HDF5's "write failed") into one line naming
    the file and the space; other errors pass unchanged.  The temporary file is removed by
    :func:`atomic_path`."""

    def __init__(self, path: Path, need: float) -> None:
        self.path, self.need = path, need

    def __enter__(self) -> None:
        return None

    def __exit__(self, kind, exc, tb) -> bool:
        if exc is None or isinstance(exc, (ValueError, KeyboardInterrupt, SystemExit)):
            return False
        if isinstance(exc, (OSError, RuntimeError)):
            text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            code = getattr(exc, "errno", None)
            if code is None and ("errno = 28" in text or "No space left" in text):
                code = errno.ENOSPC
            if code is not None:
                err = storage_error(OSError(code, os.strerror(code)), self.path, self.need)
                if isinstance(err, InputError):
                    raise err from None
            if "write failed" in text or "Can't write" in text or "unable to write" in text:
                raise InputError(
                    f"cannot write {self.path} ({text}); check the disk and rerun"
                ) from None
        return False


def copy_runs(
    path: str | Path,
    sources: Sequence[tuple[str | Path, str]],
    attrs: Mapping[str, Any] | None = None,
) -> Path:
    """Atomically write ``path`` holding groups copied from other run files.

    ``sources`` is a list of (file, run name); each source group is validated (read as a
    :class:`Run`) before it is copied byte for byte with HDF5's object copy.

    Parameters
    ----------
    path : str or pathlib.Path
        Target file, written atomically (:func:`atomic_path`).
    sources : sequence of (str or pathlib.Path, str)
        (source run file, run name) pairs; the run keeps its name, so names must be
        unique.
    attrs : mapping of str to object, optional
        Extra file attributes stored as JSON text (as in :func:`write_runs`).

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    FileNotFoundError
        If a source file does not exist.
    KeyError
        If a source file has no run of that name.
    ValueError
        If a name repeats, an attribute name is reserved, a source run fails
        validation (:func:`read_run`), or ``path`` is not a regular file; the target is
        then left as it was.
    """
    h5py = _h5()
    path = Path(path)
    seen: set[str] = set()
    need = sum(Path(src).stat().st_size for src in dict.fromkeys(s for s, _ in sources))
    check_free_space(path, need)  # HDF5 cannot always fail cleanly on a full disk: not there
    with (
        atomic_path(path) as tmp,
        _h5_write_errors(path, need),
        _h5_target(tmp, attrs, need) as f,
    ):
        for src, name in sources:
            if name in seen:
                raise ValueError(f"duplicate run name {name!r} while copying")
            seen.add(name)
            read_run(src, name)  # validates
            with h5py.File(src, "r") as s:
                s.copy(s["runs"][name], f["runs"], name=name)
    return path


# -- reading --------------------------------------------------------------------------
def _open(path: str | Path):
    h5py = _h5()
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such run file")
    check_input_file(path, "run file")  # a device or FIFO could block or never end
    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise ValueError(
            f"{path}: not a readable HDF5 file, probably truncated or corrupt "
            f"({str(exc).splitlines()[0]}); if it is a sweep's output, delete or rename it "
            "and rerun the sweep (a sweep never overwrites a file it cannot read)"
        ) from None
    try:
        fmt = f.attrs.get("format")
        fmt = fmt.decode() if isinstance(fmt, bytes) else fmt
        if fmt != FORMAT:
            raise ValueError(
                f"{path}: not a bikeid run file (format attribute {fmt!r}, expected {FORMAT!r})"
            )
        version = f.attrs.get("format_version")
        try:
            version = int(version)
        except (TypeError, ValueError):
            version = None
        if version is None or version > FORMAT_VERSION or version < 1:
            raise ValueError(
                f"{path}: run file format version {version} is not supported "
                f"(this bikeid reads versions 1..{FORMAT_VERSION}); upgrade bikeid"
            )
        if "runs" not in f:
            raise ValueError(f"{path}: the group /runs is missing; the file is malformed")
        if not isinstance(f["runs"], h5py.Group):
            raise ValueError(
                f"{path}: /runs is a {type(f['runs']).__name__.lower()}, not a group of runs; "
                "the file is malformed: write it again with bikeid"
            )
    except ValueError:
        f.close()
        raise
    except (OSError, RuntimeError, KeyError, TypeError) as exc:  # damaged header objects
        f.close()
        raise ValueError(f"{path}: damaged file header ({exc}); the file is corrupt") from None
    return f


def _read_array(path, gname: str, ds, n: int | None) -> np.ndarray:
    name = getattr(ds, "name", None) or "?"
    where = f"{path}: run {gname!r}: dataset {name.split('/', 3)[-1]!r}"
    check_h5_dataset(ds, where)
    if ds.dtype.kind != "f":
        raise ValueError(f"{where} has dtype {ds.dtype}, expected float64")
    try:
        arr = ds[()]
    except (OSError, RuntimeError) as exc:
        raise ValueError(
            f"{where} cannot be read ({str(exc).splitlines()[0]}): the file is corrupt; rewrite it"
        ) from None
    arr = np.asarray(arr, dtype=np.float64)
    if arr.ndim != 1:
        raise ValueError(f"{where} has shape {arr.shape}, expected 1-D")
    if n is not None and arr.size != n:
        raise ValueError(f"{where} has {arr.size} samples but t has {n}; the file is malformed")
    bad = ~np.isfinite(arr)
    if bad.any():
        i = int(np.argmax(bad))
        raise ValueError(
            f"{where} holds non-finite values (first {float(arr[i])!r} at row {i}, "
            f"{int(bad.sum())} in all); the file is corrupt"
        )
    return arr


def _read_group(path, g, gname: str, truth: bool = True) -> Run:
    where = f"{path}: run {gname!r}"
    try:
        meta_text = g.attrs["meta"]
    except (KeyError, OSError):
        raise ValueError(f"{where} has no 'meta' attribute; the file is malformed") from None
    raw = (
        meta_text if isinstance(meta_text, bytes) else meta_text.encode("utf-8", "surrogateescape")
    )
    crc = g.attrs.get("meta_crc32")
    if crc is None or int(crc) != zlib.crc32(raw):
        raise ValueError(f"{where}: metadata checksum mismatch; the file is corrupt")
    meta_text = raw.decode()
    try:
        meta = json.loads(meta_text)
    except (TypeError, ValueError):
        raise ValueError(f"{where}: metadata is not valid JSON; the file is corrupt") from None
    if not isinstance(meta, dict):
        raise ValueError(f"{where}: metadata is not a JSON object")
    h5py = _h5()
    for key in ("signals", "truth"):
        if key in g and not isinstance(g[key], h5py.Group):
            raise ValueError(f"{where}: {key!r} is not a group; the file is malformed: write "
                             "it again with bikeid")  # fmt: skip
    if "t" not in g:
        raise ValueError(f"{where} has no dataset 't'; the file is malformed")
    t = _read_array(path, gname, g["t"], None)
    n = t.size
    _check_time_base(where, t)
    if "n" in g.attrs and int(g.attrs["n"]) != n:
        raise ValueError(
            f"{where}: 't' has {n} samples but the run was written with {int(g.attrs['n'])}; "
            "the file is truncated or corrupt"
        )
    if "signals" not in g:
        raise ValueError(f"{where} has no 'signals' group; the file is malformed")
    missing = [k for k in REQUIRED if k not in g["signals"]]
    if missing:
        raise ValueError(
            f"{where} is missing required signal datasets {missing} (required: {list(REQUIRED)})"
        )
    signals = {k: _read_array(path, gname, ds, n) for k, ds in g["signals"].items()}
    noise_free = None
    if truth and "truth" in g:
        noise_free = {k: _read_array(path, gname, ds, n) for k, ds in g["truth"].items()}
    extra = {}
    for k in ("dither", "reference"):
        extra[k] = _read_array(path, gname, g[k], n) if k in g else None
    try:
        run = Run(t=t, signals=signals, truth=noise_free, meta=meta, **extra)
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None
    columns = {k: f"signals/{k}" for k in signals}
    return check_plausible(run, where, columns=columns)


def _check_time_base(where: str, t: np.ndarray) -> None:
    """Refuse a time base that does not increase or has a gap (as the importers do)."""
    if t.size < 2:
        return
    step = np.diff(t)
    if np.any(step <= 0):
        i = int(np.argmax(step <= 0)) + 1
        raise ValueError(f"{where}: time does not increase at row {i} (t = {float(t[i])!r} s "
                         f"after {float(t[i - 1])!r} s); the run is damaged")  # fmt: skip
    h = float(np.median(step))
    dev = np.abs(step - h) / h
    worst = int(np.argmax(dev))
    if dev[worst] > TIME_JITTER:
        raise ValueError(
            f"{where}: a gap in time at row {worst + 1}: the step {float(step[worst]):.6g} s "
            f"differs from the median {h:.6g} s by {100 * float(dev[worst]):.3g} % (tolerance "
            f"{100 * TIME_JITTER:g} %); split the run at the gap (bikeid identify reads runs "
            "sampled uniformly)"
        )


def _read_damaged(path, f, name: str, truth: bool = True) -> Run:
    """:func:`_read_group` of run ``name``, with h5py's errors on damaged objects (KeyError,
    RuntimeError, OSError, TypeError, UnicodeDecodeError) turned into a ValueError naming the
    file and the run."""
    g = _group(path, f, name)
    if not isinstance(g, _h5().Group):
        raise ValueError(f"{path}: run {name!r} is a dataset, not a group; the file is "
                         "malformed: write it again with bikeid")  # fmt: skip
    try:
        return _read_group(path, g, name, truth)
    except ValueError:
        raise
    except (OSError, RuntimeError, KeyError, TypeError, UnicodeDecodeError,
            AttributeError) as exc:  # fmt: skip
        raise ValueError(
            f"{path}: run {name!r} cannot be read ({type(exc).__name__}: "
            f"{str(exc).splitlines()[0] if str(exc) else ''}); the file is corrupt"
        ) from None


def _group(path, f, name: str):
    try:
        present = name in f["runs"]
    except (OSError, RuntimeError, KeyError, TypeError, ValueError) as exc:
        raise ValueError(
            f"{path}: the run index cannot be read ({str(exc).splitlines()[0]}); the file is "
            "corrupt"
        ) from None
    if not present:
        raise KeyError(f"{path}: no run named {name!r}")
    try:
        return f["runs"][name]
    except (OSError, RuntimeError, KeyError, TypeError, ValueError) as exc:  # damaged header
        raise ValueError(
            f"{path}: run {name!r} cannot be opened ({str(exc).splitlines()[0]}); the file is "
            "corrupt"
        ) from None


def list_runs(path: str | Path) -> list[str]:
    """Names of the runs in ``path``, in the order they were written.

    Parameters
    ----------
    path : str or pathlib.Path
        A run file written by :func:`write_runs` or :func:`copy_runs`.

    Returns
    -------
    list of str
        Run group names in insertion order.

    Raises
    ------
    FileNotFoundError
        If ``path`` does not exist.
    ValueError
        If the file is not a readable ``bikeid-runs`` file of a supported version, or is
        corrupt or malformed (the message names the file, the run group and the problem).
    """
    with _open(path) as f:
        try:
            return list(f["runs"].keys())
        except (OSError, RuntimeError, KeyError, TypeError, UnicodeDecodeError) as exc:
            raise ValueError(f"{path}: run index cannot be read ({exc}); corrupt file") from None


def file_attrs(path: str | Path) -> dict[str, Any]:
    """The extra (JSON) file attributes given to :func:`write_runs`.

    Parameters
    ----------
    path : str or pathlib.Path
        A run file written by :func:`write_runs` or :func:`copy_runs`.

    Returns
    -------
    dict of str to object
        Attribute name -> decoded JSON value (``format``, ``format_version`` and
        ``bikeid_version`` excluded).

    Raises
    ------
    FileNotFoundError
        If ``path`` does not exist.
    ValueError
        If the file is not a readable ``bikeid-runs`` file of a supported version, or is
        corrupt or malformed (the message names the file, the run group and the problem).
    """
    with _open(path) as f:
        out = {}
        for key, value in f.attrs.items():
            if key in ("format", "format_version", "bikeid_version"):
                continue
            try:
                out[key] = json.loads(value)
            except (TypeError, ValueError):
                raise ValueError(f"{path}: file attribute {key!r} is not valid JSON") from None
        return out


def read_run(path: str | Path, name: str) -> Run:
    """The run called ``name`` in ``path``, validated.

    Parameters
    ----------
    path : str or pathlib.Path
        A run file written by :func:`write_runs` or :func:`copy_runs`.
    name : str
        Run group name (:func:`list_runs`).

    Returns
    -------
    Run
        Time [s], signals and truth in SI units, optional dither [N m] and reference
        [rad], and the metadata.

    Raises
    ------
    FileNotFoundError
        If ``path`` does not exist.
    ValueError
        If the file is not a readable ``bikeid-runs`` file of a supported version, or is
        corrupt or malformed (the message names the file, the run group and the problem).
    KeyError
        If the file has no run called ``name``.
    """
    with _open(path) as f:
        return _read_damaged(path, f, name)


def read_runs(
    path: str | Path, names: Sequence[str] | None = None, truth: bool = True
) -> list[Run]:
    """All runs in ``path`` (or those in ``names``), in file order, each validated.

    Parameters
    ----------
    path : str or pathlib.Path
        A run file written by :func:`write_runs` or :func:`copy_runs`.
    names : sequence of str, optional
        Runs to read, in this order; default all, in file order.
    truth : bool, optional
        Also read the noise-free signals of simulated runs (default); False leaves
        ``Run.truth`` None (validation never reads them: a sweep's run holds 14 of them
        beside 9 measured signals).

    Returns
    -------
    list of Run
        As :func:`read_run`, one per name.

    Raises
    ------
    FileNotFoundError
        If ``path`` does not exist.
    ValueError
        If the file is not a readable ``bikeid-runs`` file of a supported version, or is
        corrupt or malformed (the message names the file, the run group and the problem).
    KeyError
        If a name is not in the file.
    """
    with _open(path) as f:
        if names is None:
            names = list_runs(path)
        return [_read_damaged(path, f, n, truth) for n in names]


# -- CSV ------------------------------------------------------------------------------
def _columns(run: Run) -> list[tuple[str, np.ndarray, str]]:
    order = list(MEASURED) + list(INPUTS)
    keys = [k for k in order if k in run.signals] + sorted(k for k in run.signals if k not in order)
    cols = [("t", run.t, "s")] + [(k, run.signals[k], _units(k)) for k in keys]
    if run.truth is not None:
        tkeys = [k for k in order if k in run.truth]
        tkeys += sorted(k for k in run.truth if k not in order)
        cols += [(f"true_{k}", run.truth[k], _units(k)) for k in tkeys]
    if run.dither is not None:
        cols.append(("dither", run.dither, "N m"))
    if run.reference is not None:
        cols.append(("reference", run.reference, "rad"))
    return cols


def export_csv(run: Run, path: str | Path) -> Path:
    """Write one run as CSV, atomically.

    Line 1: ``# bikeid run: `` followed by the metadata as one-line JSON; line 2: column
    headers ``name [units]`` (t, measured signals in MEASURED/INPUTS order, ``true_*``
    columns, dither, reference); then one row per sample with 17 significant digits, which
    round-trips float64 exactly.  Read back with ``numpy.loadtxt(path, delimiter=",",
    skiprows=2)`` or ``pandas.read_csv(path, comment="#")``.

    Parameters
    ----------
    run : Run
        The run to export.
    path : str or pathlib.Path
        Target CSV file, written atomically (:func:`atomic_path`; an old file is replaced
        only once the new one is complete, a symlink or device is refused).

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    ValueError
        If ``path`` is not a regular file (a symlink or device; :func:`atomic_path`).
    """
    cols = _columns(run)
    header = ",".join(f"{name} [{units}]" if units else name for name, _, units in cols)
    data = np.column_stack([c for _, c, _ in cols])
    path = Path(path)
    with atomic_path(path) as tmp:
        with open(tmp, "w", newline="\n") as fh:
            fh.write("# bikeid run: " + json.dumps(run.meta, separators=(",", ":")) + "\n")
            fh.write(header + "\n")
            np.savetxt(fh, data, delimiter=",", fmt="%.17g")
    return path
