"""Resumable, deterministic, parallel sweeps of closed-loop runs over speeds and seeds.

A sweep is one controller run at every (speed, seed) of a grid.  Guarantees:

- **Deterministic.**  Run (speed, seed) draws all its randomness (dither, sensor noise)
  from ``numpy.random.SeedSequence([seed, round(speed * 1e6), crc32(controller)])``,
  never from worker order, so the stored data are bit-identical whatever ``workers``
  or Dask cluster computed them (the file is consolidated in grid order).
- **Resumable.**  Every finished run is written atomically as its own file
  ``FILE.h5.parts/<run>.h5`` (HDF5, see :mod:`dataset.store`); when all are done they
  are copied into ``FILE.h5`` by one atomic replace, and the part files of this sweep and
  its lock are deleted (the folder too if nothing else is left in it: files a sweep did
  not write are never touched).
  Killed at any moment (even SIGKILL) and started again with the same arguments, a sweep
  reuses every valid part and every run already in ``FILE.h5`` and computes only the
  missing ones; ``FILE.h5`` is at all times either absent, the previous complete file,
  or the new complete file.  Runs already in ``FILE.h5`` that the new grid does not
  list are kept.  A lock file (``flock``) refuses a second sweep on the same output; it is
  removed when the sweep ends or is refused.
- **Honest.**  A run that ended early keeps its stop (``meta["stop"]``, see
  :mod:`dataset.closed_loop`); the report counts falls and numerical failures apart.
- **Parallel.**  Through :mod:`bikeid.experiments.parallel`: ``workers`` local processes,
  or a Dask cluster (``dask="local"`` starts a ``LocalCluster`` of ``workers`` processes;
  otherwise a scheduler address).  Results travel back to this process, which alone
  writes files, so Dask workers need no shared file system.
"""

from __future__ import annotations

import contextlib
import fcntl
import math
import os
import sys
import time
import zlib
from collections.abc import Callable, Iterator, Sequence
from dataclasses import asdict, dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from bikeid.controllers.excitation import ChirpReference, UniformDither, ZeroReference
from bikeid.controllers.registry import STUDY_CONTROLLERS, canonical_name, make
from bikeid.dataset.closed_loop import simulate_run
from bikeid.dataset.run import Run, run_stop
from bikeid.dataset.sensors import Sensors
from bikeid.dataset.store import copy_runs, file_attrs, list_runs, read_run, read_runs, write_runs
from bikeid.experiments.parallel import check_workers, imap
from bikeid.sim.parameters import by_name

__all__ = [
    "CONTROLLERS",
    "stabilization_counts",
    "stabilization_markdown",
    "stabilization_table",
    "SweepReport",
    "SweepSpec",
    "Task",
    "run_seed",
    "run_sweep",
    "simulate_task",
]

#: Controllers a sweep runs, by the names stored in its files (``controllers.registry``).
CONTROLLERS = STUDY_CONTROLLERS
REFERENCES = ("chirp", "zero")
SENSORS = ("default", "ideal")


@dataclass(frozen=True)
class Task:
    """One run of a sweep: its group name, speed [m/s] and user seed.

    Attributes
    ----------
    name : str
        Run (HDF5 group) name, ``<controller>_v<speed, 3 decimals>_s<seed>``.
    speed : float
        Forward speed [m/s].
    seed : int
        User seed (non-negative); the run's random streams come from :func:`run_seed`.
    """

    name: str
    speed: float
    seed: int


#: Identification excitation by speed band (``vmax`` [m/s], roll chirp amplitude [deg],
#: dither hold [s]), used when a sweep leaves ``chirp_amplitude``/``dither_hold`` at None.
#: Small chirps and a slow dither at low speed, where a 3 deg roll chirp drives the steer
#: angle to ~0.5 rad, far outside the linearization; larger chirps at high speed.  Chosen
#: from amplitude/hold scans on the PID loop (docs/accuracy.md); ``bikeid accuracy`` uses it.
EXCITATION_BANDS: tuple[tuple[float, float, float], ...] = (
    (3.0, 0.5, 0.05),
    (6.0, 1.5, 0.02),
    (math.inf, 3.0, 0.02),
)


def excitation_for(speed: float) -> tuple[float, float]:
    """(chirp amplitude [rad], dither hold [s]) of :data:`EXCITATION_BANDS` at ``speed``."""
    vmax, deg, hold = next(b for b in EXCITATION_BANDS if speed < b[0])
    return math.radians(deg), hold


@dataclass(frozen=True)
class SweepSpec:
    """Everything that defines a sweep's runs (all JSON-serializable).

    controller: ``fuzzy``, ``pid`` or ``pole`` (``controllers.registry`` defaults);
    speeds [m/s]; seeds (non-negative integers); duration [s]; bicycle: a name for
    ``sim.parameters.by_name``; reference: ``chirp`` (roll chirp of ``chirp_amplitude``
    [rad], 0.05 -> 0.5 Hz over the run) or ``zero``; dither: uniform dither amplitude
    [N m] held ``dither_hold`` [s] (0 = none); ``chirp_amplitude`` or ``dither_hold`` None
    (the default) means "by speed band" (:data:`EXCITATION_BANDS`, the identification
    design); sensors: ``default`` or ``ideal`` at
    ``sensor_rate`` [Hz]; sample_time: controller period [s] (at most the sensor period);
    extra: keywords for :func:`dataset.closed_loop.simulate_run` (e.g. ``mode``).
    Controllers are ``controllers.registry`` defaults; pole placement is designed at the
    run's speed (``design_speed``), PID and fuzzy schedule on the measured speed.

    Parameters
    ----------
    controller : {"fuzzy", "pid", "pole"}
        Controller name (:data:`CONTROLLERS`).
    speeds : tuple of float
        Forward speeds [m/s], positive, at least 1 mm/s apart.
    seeds : tuple of int, optional
        Non-negative user seeds.
    duration : float, optional
        Length of each run [s].
    bicycle : str, optional
        Bicycle parameter set, a name for ``sim.parameters.by_name``.
    reference : {"chirp", "zero"}, optional
        Roll reference.
    chirp_amplitude : float or None, optional
        Roll chirp amplitude [rad]; None: by speed band.
    dither : float, optional
        Uniform steer-torque dither amplitude [N m] (0 = none).
    dither_hold : float or None, optional
        Dither hold [s]; None: by speed band.
    sensors : {"default", "ideal"}, optional
        Sensor model.
    sensor_rate : float, optional
        Sensor sample rate [Hz].
    sample_time : float, optional
        Controller period [s].
    extra : dict, optional
        Further keywords for :func:`dataset.closed_loop.simulate_run`.

    Raises
    ------
    ValueError
        If the controller, reference or sensors is unknown, a speed is not positive and
        finite, a seed is not a non-negative integer, the duration is not positive, the
        dither amplitude is negative, or two speeds give the same run name.
    """

    controller: str
    speeds: tuple[float, ...]
    seeds: tuple[int, ...] = (0,)
    duration: float = 50.0
    bicycle: str = "benchmark"
    reference: str = "chirp"
    chirp_amplitude: float | None = None
    dither: float = 1.0
    dither_hold: float | None = None
    sensors: str = "default"
    sensor_rate: float = 100.0
    sample_time: float = 0.01
    extra: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.controller not in CONTROLLERS:
            raise ValueError(
                f"unknown controller {self.controller!r}; choose one of {', '.join(CONTROLLERS)}"
            )
        if self.reference not in REFERENCES:
            raise ValueError(f"unknown reference {self.reference!r}; choose {REFERENCES}")
        if self.sensors not in SENSORS:
            raise ValueError(f"unknown sensors {self.sensors!r}; choose {SENSORS}")
        speeds = tuple(float(v) for v in np.atleast_1d(self.speeds))
        if not speeds or not all(math.isfinite(v) and v > 0 for v in speeds):
            raise ValueError(f"sweep speeds must be positive and finite, got {speeds}")
        raw = list(np.atleast_1d(self.seeds))
        seeds = tuple(int(s) for s in raw)
        if not seeds or any(s < 0 or s != f for s, f in zip(seeds, raw, strict=True)):
            raise ValueError(f"sweep seeds must be non-negative integers, got {self.seeds}")
        if not (math.isfinite(self.duration) and self.duration > 0):
            raise ValueError(f"sweep duration must be > 0 s, got {self.duration}")
        if not (math.isfinite(self.dither) and self.dither >= 0):
            raise ValueError(f"dither amplitude must be >= 0 N m, got {self.dither}")
        object.__setattr__(self, "speeds", speeds)
        object.__setattr__(self, "seeds", seeds)
        names = [t.name for t in self.tasks()]
        if len(set(names)) != len(names):
            raise ValueError("sweep speeds must differ by at least 1 mm/s (run names collide)")

    def tasks(self) -> list[Task]:
        """The grid, speed-major then seed, in file order.

        Returns
        -------
        list of Task
            One task per (speed, seed).
        """
        return [
            Task(f"{self.controller}_v{v:07.3f}_s{s}", v, s)
            for v in self.speeds
            for s in self.seeds
        ]

    def settings(self) -> dict[str, Any]:
        """What must match for runs to be reused (everything but the grid).

        Returns
        -------
        dict
            The fields of the spec without ``speeds`` and ``seeds`` (JSON-able).
        """
        d = asdict(self)
        del d["speeds"], d["seeds"]
        return d


def run_seed(seed: int, speed: float, controller: str) -> int:
    """The 32-bit seed of run (seed, speed, controller), independent of worker order.

    Parameters
    ----------
    seed : int
        User seed, non-negative.
    speed : float
        Forward speed [m/s] (enters rounded to 1e-6 m/s).
    controller : str
        Controller name (enters by its CRC-32).

    Returns
    -------
    int
        First word of ``numpy.random.SeedSequence([seed, round(speed * 1e6),
        crc32(controller)])``, in [0, 2^32).
    """
    ss = np.random.SeedSequence([int(seed), round(speed * 1e6), zlib.crc32(controller.encode())])
    return int(ss.generate_state(1)[0])


def simulate_task(spec: SweepSpec, task: Task) -> Run:
    """Simulate one run of ``spec`` (runs in a worker process).

    Parameters
    ----------
    spec : SweepSpec
        The sweep.
    task : Task
        The run's speed and seed.

    Returns
    -------
    Run
        The closed-loop run on the nonlinear plant; ``meta["sweep"]`` records the
        settings, the user seed and the derived run seed; ``meta["fell_at"]`` [s] or None.

    Raises
    ------
    ValueError
        If the controller cannot be designed at this speed or the simulation refuses its
        options.
    """

    seed = run_seed(task.seed, task.speed, spec.controller)
    child = np.random.SeedSequence(seed).spawn(2)
    band_amplitude, band_hold = excitation_for(task.speed)
    amplitude = band_amplitude if spec.chirp_amplitude is None else spec.chirp_amplitude
    hold = band_hold if spec.dither_hold is None else spec.dither_hold
    if spec.reference == "chirp":
        reference = ChirpReference(amplitude=amplitude, f0=0.05, f1=0.5, duration=spec.duration)
    else:
        reference = ZeroReference()
    dither = None
    if spec.dither > 0:
        dither = UniformDither(spec.dither, hold, int(child[0].generate_state(1)[0]))
    if spec.sensors == "default":
        sensors = Sensors.default(rate=spec.sensor_rate)
    else:
        sensors = Sensors.ideal(rate=spec.sensor_rate)
    bicycle = by_name(spec.bicycle)
    options: dict[str, Any] = {"sample_time": spec.sample_time}
    if canonical_name(spec.controller) == "pole-placement":  # placed at the run's speed
        options["design_speed"] = task.speed
    controller = make(spec.controller, bicycle, **options)
    run = simulate_run(
        bicycle,
        controller,
        task.speed,
        duration=spec.duration,
        reference=reference,
        dither=dither,
        sensors=sensors,
        seed=int(child[1].generate_state(1)[0]),
        **spec.extra,
    )
    run.meta["sweep"] = {"settings": spec.settings(), "seed": task.seed, "run_seed": seed}
    return run


@dataclass
class SweepReport:
    """What a sweep did: file, counts, fallen runs (name -> time [s]), wall time [s].

    Attributes
    ----------
    out : Path
        The HDF5 file written.
    total : int
        Runs of the grid.
    computed : int
        Runs simulated by this call.
    reused : int
        Runs taken from the file or its parts folder.
    fell : dict of str to float
        Runs in which the bicycle fell (a physical stop), name -> time of the fall [s].
    elapsed : float
        Wall time [s].
    failed : dict of str to dict
        Runs that ended early for a numerical reason (not a fall), name -> ``meta["stop"]``.
    causes : dict of str to str
        Stop cause of each fallen run (``sim.integrate.STOP_CAUSES``), by name.
    """

    out: Path
    total: int
    computed: int
    reused: int
    fell: dict[str, float]
    elapsed: float
    failed: dict[str, dict[str, Any]] = field(default_factory=dict)
    causes: dict[str, str] = field(default_factory=dict)

    def summary(self) -> str:
        """Human-readable summary of the sweep.

        Returns
        -------
        str
            A line with the file, counts and time, then the fallen runs (or "no run fell").
        """
        lines = [
            f"wrote {self.out}: {self.total} runs (computed {self.computed}, reused "
            f"{self.reused}) in {self.elapsed:.1f} s"
        ]
        if self.fell:
            lines.append(f"{len(self.fell)} run(s) fell (kept, flagged in meta['fell_at']):")
            lines += [
                f"  {name}: fell at {t:.2f} s ({self.causes.get(name, 'roll_limit')})"
                for name, t in self.fell.items()
            ]
        else:
            lines.append("no run fell")
        if self.failed:
            lines.append(
                f"{len(self.failed)} run(s) ended early for a numerical reason, not a fall "
                "(kept truncated, flagged in meta['stop']; estimators refuse them):"
            )
            lines += [
                f"  {name}: {st['cause']} at {st['time']:.2f} s: {st['message']}"
                for name, st in self.failed.items()
            ]
        return "\n".join(lines)


def parts_dir(out: Path) -> Path:
    return out.with_name(out.name + ".parts")


@contextlib.contextmanager
def _lock(parts: Path) -> Iterator[None]:
    """Hold ``parts/.lock`` for the sweep; on exit (done, refused or failed) delete the
    lock while still holding it, and the folder if it is then empty."""
    parts.mkdir(parents=True, exist_ok=True)
    lock = parts / ".lock"
    busy = ValueError(
        f"another sweep is writing {parts.name[: -len('.parts')]}; wait for it or use "
        "another --out"
    )
    fh = open(lock, "w")  # noqa: SIM115 - held for the whole sweep
    try:
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise busy from None
        try:
            # a sweep that just finished may have deleted the file we opened: then the
            # lock we hold is on an orphan and a third sweep could lock a new file
            if os.stat(lock).st_ino != os.fstat(fh.fileno()).st_ino:
                raise busy
        except FileNotFoundError:
            raise busy from None
        try:
            yield
        finally:
            lock.unlink(missing_ok=True)
            with contextlib.suppress(OSError):  # not empty: someone else's files
                parts.rmdir()
    finally:
        fh.close()


def _check_settings(where: Path, found: Any, spec: SweepSpec) -> None:
    if found != spec.settings():
        want = spec.settings()
        diff = sorted(
            k for k in set(want) | set(found or {}) if (found or {}).get(k) != want.get(k)
        )
        raise ValueError(
            f"{where} was made by a sweep with different settings ({', '.join(diff)}); use "
            "another --out or delete it"
        )


def _existing(out: Path, parts: Path, spec: SweepSpec, log: Callable[[str], None]):
    """Runs already done: name -> source file, after validation."""
    done: dict[str, Path] = {}
    for tmp in parts.glob(".*.h5.*.tmp"):  # left by a killed atomic write (we hold the lock)
        tmp.unlink(missing_ok=True)
    for tmp in out.parent.glob(f".{out.name}.*.tmp"):
        tmp.unlink(missing_ok=True)
    extra: list[str] = []
    wanted = {t.name for t in spec.tasks()}
    if out.exists():
        _check_settings(out, file_attrs(out).get("sweep"), spec)
        for name in list_runs(out):
            done[name] = out
            if name not in wanted:
                extra.append(name)
    for part in sorted(parts.glob("*.h5")):
        name = part.stem
        if name in done or name not in wanted:  # not a part of this grid: leave it alone
            continue
        try:
            run = read_run(part, name)
        except (ValueError, KeyError) as exc:
            log(f"discarding damaged part {part.name}: {str(exc).splitlines()[0]}")
            part.unlink()
            continue
        _check_settings(part, run.meta.get("sweep", {}).get("settings"), spec)
        done[name] = part
    return done, extra


def _execute(
    fn: Callable[[SweepSpec, Task], Any],
    spec: SweepSpec,
    todo: Sequence[Task],
    workers: int,
    dask: str | None,
) -> Iterator[tuple[Task, Any]]:
    """``fn(spec, task)`` for every task, in completion order (:func:`parallel.imap`)."""
    for i, result in imap(partial(fn, spec), todo, workers, dask):
        yield todo[i], result


def run_sweep(
    spec: SweepSpec,
    out: str | Path,
    workers: int = 1,
    dask: str | None = None,
    progress: bool = True,
    log: Callable[[str], None] | None = None,
) -> SweepReport:
    """Run (or finish) the sweep ``spec`` into the HDF5 file ``out``; see the module doc.

    Parameters
    ----------
    spec : SweepSpec
        The sweep.
    out : str or Path
        Output file, ending in ``.h5`` or ``.hdf5``.
    workers : int, optional
        Local worker processes (or the size of a local Dask cluster).
    dask : str or None, optional
        ``"local"`` or a Dask scheduler address; None: local processes.
    progress : bool, optional
        Show a progress bar on stderr.
    log : callable, optional
        Receives messages (default: stderr).

    Returns
    -------
    SweepReport
        Counts, fallen runs and wall time.

    Raises
    ------
    ValueError
        If ``workers`` is not a positive integer, ``out`` has another suffix, another
        sweep holds the lock on ``out``, ``out`` or a part was made with different
        settings, Dask is missing or unreachable, or a run's simulation raises.
    """
    t0 = time.perf_counter()
    workers = check_workers(workers)
    out = Path(out)
    if out.suffix not in (".h5", ".hdf5"):
        raise ValueError(f"sweep output {out} must end in .h5 or .hdf5")
    log = log or (lambda msg: print(msg, file=sys.stderr))
    parts = parts_dir(out)
    tasks = spec.tasks()
    with _lock(parts):
        done, extra = _existing(out, parts, spec, log)
        todo = [t for t in tasks if t.name not in done]
        reused = len(tasks) - len(todo)
        if todo:
            bar = tqdm(
                total=len(todo),
                desc=f"sweep {spec.controller}",
                unit="run",
                file=sys.stderr,
                disable=not progress,
            )
            with bar:
                for task, run in _execute(simulate_task, spec, todo, workers, dask):
                    part = parts / f"{task.name}.h5"
                    write_runs(part, [run], names=[task.name])
                    done[task.name] = part
                    bar.update(1)
        names = [t.name for t in tasks] + extra
        if any(done[n] != out for n in names) or not out.exists():
            copy_runs(out, [(done[n], n) for n in names], attrs={"sweep": spec.settings()})
        for n in names:  # only this sweep's parts, now in ``out``; other files stay
            if done[n] != out:
                done[n].unlink(missing_ok=True)
    fell: dict[str, float] = {}
    causes: dict[str, str] = {}
    failed: dict[str, dict[str, Any]] = {}

    for name, run in zip(names, read_runs(out, names), strict=True):
        stop = run_stop(run)
        if stop is None:
            continue
        if stop["physical"]:
            fell[name] = float(stop["time"])
            causes[name] = stop["cause"]
        else:
            failed[name] = stop
    return SweepReport(
        out, len(tasks), len(todo), reused, fell, time.perf_counter() - t0, failed, causes
    )


def default_workers() -> int:
    return max(1, min(os.cpu_count() or 1, 8))


# -- stabilization table -------------------------------------------------------------------
def stabilization_task(spec: SweepSpec, task: Task) -> dict[str, Any]:
    """One cell of the stabilization table: upright?, RMS tracking error, peak torque."""
    row: dict[str, Any] = {"controller": spec.controller, "speed": task.speed}
    try:
        run = simulate_task(spec, task)
    except ValueError as exc:  # e.g. pole placement at an uncontrollable speed
        return {**row, "upright": False, "fell_at": None, "stop": None,
                "error": str(exc).splitlines()[0], "rms_error_deg": None,
                "peak_torque": None}  # fmt: skip
    stop = run_stop(run)
    if stop is not None and not stop["physical"]:  # numbers up to a blow-up mean nothing
        return {**row, "upright": False, "fell_at": None, "stop": stop, "error": None,
                "rms_error_deg": None, "peak_torque": None}  # fmt: skip
    err = run.reference - run.true("phi")
    return {
        **row,
        "upright": stop is None,
        "fell_at": None if stop is None else stop["time"],
        "stop": stop,
        "error": None,
        "rms_error_deg": math.degrees(float(np.sqrt(np.mean(err**2)))),
        "peak_torque": float(np.max(np.abs(run.true("T_delta")))),
    }


def stabilization_table(
    speeds: Sequence[float],
    duration: float = 50.0,
    controllers: Sequence[str] = CONTROLLERS,
    workers: int = 1,
    dask: str | None = None,
    progress: bool = True,
    **spec_options: Any,
) -> list[dict[str, Any]]:
    """Run every controller at every speed (chirp reference, dither, default sensors) on the
    nonlinear model; one row per (controller, speed), in that order.  A tracking test: the
    chirp is 3 deg and the dither hold 10 ms at every speed unless given.

    Parameters
    ----------
    speeds : sequence of float
        Forward speeds [m/s].
    duration : float, optional
        Length of each run [s].
    controllers : sequence of str, optional
        Controller names (:data:`CONTROLLERS`).
    workers : int, optional
        Local worker processes.
    dask : str or None, optional
        ``"local"`` or a Dask scheduler address.
    progress : bool, optional
        Show a progress bar on stderr.
    **spec_options
        Further :class:`SweepSpec` fields (``chirp_amplitude`` [rad] defaults to 3 deg,
        ``dither_hold`` [s] to 0.01).

    Returns
    -------
    list of dict
        Per (controller, speed): ``controller``, ``speed`` [m/s], ``upright``,
        ``fell_at`` [s] or None, ``error`` (a failed design's message) or None,
        ``rms_error_deg`` (RMS of reference - true roll [deg]) and ``peak_torque`` (peak
        |T_delta| [N m]), the last two None after a failed design.

    Raises
    ------
    ValueError
        If a :class:`SweepSpec` is invalid.
    """

    spec_options.setdefault("chirp_amplitude", math.radians(3.0))
    spec_options.setdefault("dither_hold", 0.01)

    jobs = [(SweepSpec(c, tuple(speeds), (0,), duration, **spec_options)) for c in controllers]
    todo = [(spec, task) for spec in jobs for task in spec.tasks()]
    rows: dict[tuple[str, str], dict[str, Any]] = {}
    with tqdm(total=len(todo), desc="stabilization", unit="run", file=sys.stderr,
              disable=not progress) as bar:  # fmt: skip
        for spec in jobs:
            for task, row in _execute(stabilization_task, spec, spec.tasks(), workers, dask):
                rows[(spec.controller, task.name)] = row
                bar.update(1)
    return [rows[(spec.controller, t.name)] for spec, t in todo]


def stabilization_counts(rows: Sequence[dict[str, Any]]) -> dict[str, int]:
    """How many rows stayed ``upright``, ``fell`` (physical stop), ``failed`` numerically
    (``meta["stop"]`` not physical: no verdict on the controller) or had a design ``error``.

    Parameters
    ----------
    rows : sequence of dict
        Rows of :func:`stabilization_table`.

    Returns
    -------
    dict of str to int
        Counts under ``upright``, ``fell``, ``failed`` and ``error``.
    """
    counts = {"upright": 0, "fell": 0, "failed": 0, "error": 0}
    for r in rows:
        stop = r.get("stop")
        if r["error"]:
            counts["error"] += 1
        elif r["upright"]:
            counts["upright"] += 1
        elif stop is not None and not stop["physical"]:
            counts["failed"] += 1
        else:
            counts["fell"] += 1
    return counts


def stabilization_markdown(rows: Sequence[dict[str, Any]]) -> str:
    """The table as markdown: one line per (controller, speed).

    Parameters
    ----------
    rows : sequence of dict
        Rows of :func:`stabilization_table`.

    Returns
    -------
    str
        A markdown table (controller, speed [m/s], upright, RMS roll tracking error
        [deg], peak steer torque [N m]).
    """
    lines = [
        "| controller | speed [m/s] | upright | RMS roll tracking error [deg] "
        "| peak steer torque [N m] |",
        "|---|---:|---|---:|---:|",
    ]
    for r in rows:
        stop = r.get("stop")
        if r["error"]:
            status = f"design failed: {r['error']}"
        elif r["upright"]:
            status = "yes"
        elif stop is not None and not stop["physical"]:
            status = f"numerical failure ({stop['cause']}) at {stop['time']:.2f} s"
        elif stop is not None and stop["cause"] != "roll_limit":
            status = f"fell ({stop['cause']}) at {r['fell_at']:.2f} s"
        else:
            status = f"fell at {r['fell_at']:.2f} s"
        rms = "" if r["rms_error_deg"] is None else f"{r['rms_error_deg']:.3f}"
        peak = "" if r["peak_torque"] is None else f"{r['peak_torque']:.2f}"
        lines.append(f"| {r['controller']} | {r['speed']:g} | {status} | {rms} | {peak} |")
    return "\n".join(lines) + "\n"
