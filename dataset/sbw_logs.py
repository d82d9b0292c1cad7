"""Parser of the TU Delft steer-by-wire treadmill logs (``tudelft-sbw``): reading and despiking.

Format (see the data README): gzip CSV with a header, one row per 10 ms control loop,
no time column, so t = i * 0.01 s.  Units are SI (rad, rad/s, N m, m/s).

What the loader does, and why
------------------------------
- **One reader**: :func:`load_log` maps the log's columns onto bikeid signals and reads
  them with :func:`bikeid.dataset.importers.from_csv` (parsing, row-numbered errors,
  plausibility, provenance in ``meta["import"]``: path and SHA-256); what follows is
  specific to these logs.
- **Time base**: t = i * 0.01 s from the first row of the file (row indices of
  ``eigen/segments.csv`` refer to the same numbering).
- **Free-decay windows**: :mod:`bikeid.dataset.decays` (the listed rows of
  ``eigen/segments.csv`` or detected from the roll rate); download:
  :mod:`bikeid.dataset.download`.
- **Empty sil_command rows**: some logs open with rows whose ``sil_command`` field is
  empty (controller not running yet).  Those leading rows are cut; an empty field later
  in the file is a malformed file.
- **Plausibility** (:func:`bikeid.dataset.run.check_plausible`): a NaN/Inf field, or a
  raw value outside the physical bound of its signal (``sim.conventions.PLAUSIBLE``:
  e.g. |lean_rate| <= 20 rad/s, |fork_rate| <= 30 rad/s, speed -0.5..30 m/s, torques
  <= 200 N m), or a constant lean_angle, fork_angle, lean_rate, fork_rate or
  command_fork, makes the file refused with its row (line number, header = row 1) and
  column.  The bounds are checked *before* despiking: the despiker below is for the
  documented encoder quirk (spikes of a few rad/s, < 5.4 rad/s in every log), not for
  values no bicycle produces, which mean a corrupt file and must not be averaged in.
- **Spikes** in ``fork_rate``, ``x_acceleration`` and ``y_acceleration``: a sample is a
  spike when its distance from the 5-sample running median exceeds
  ``SPIKE_K`` = 8 times the robust scale (1.4826 * median absolute deviation of that
  distance over the whole file) *and* ``SPIKE_FLOOR`` (0.5 rad/s, 5 m/s^2).  Spikes
  are replaced by linear interpolation between good neighbours; the count goes to
  ``meta['spikes']``.  (fork_rate is the encoder difference, quantized at 0.077 rad/s;
  its spikes are isolated one-sample jumps the steer angle does not follow.)
- **Speed**: the ``speed`` column is the rear-wheel encoder (500-sample moving
  average), which per the source's calibration reads ``1.066 * treadmill - 0.128``.
  ``signals['v']`` is the logged sensor speed (what the controller used);
  ``meta['speed']`` is the treadmill speed from the calibration applied to the median of
  the settled part of the file; ``meta['speed_sensor']`` the settled sensor median.
  The plateau is the most populated 0.05 m/s bin of the speed histogram; samples more
  than 5 % off it belong to a ramp.  ``meta['ramp_end_index']`` is the first settled
  row, ``meta['settled_end_index']`` one past the last one (a run-down at the end);
  the Run keeps all rows so that segment indices stay valid.
- **Signals**: phi = lean_angle, phidot = lean_rate, delta = fork_angle,
  deltadot = fork_rate, v = speed, T_delta = command_fork (total steer-motor command,
  the plant input); extras ``sil_command``, ``hand_torque``, ``hand_angle``,
  ``command_hand``, ``x_acceleration``, ``y_acceleration`` and ``T_ext`` =
  command_fork - sil_command (the part of the steer torque that is not the balance
  controller: the relayed handlebar torque in the Bode runs, zero in the eigen runs).

Sign conventions (checked against the physics, see ``docs/measured.md``)
------------------------------------------------------------------------
``sil_command`` equals ``+2 (6.5 - speed) lean_rate`` to 1e-9 (correlation) in every
file.  With roll and steer positive to the right (Meijaard 2007) a steer torque *in
the direction of the roll rate* is the stabilizing steer-into-lean law: the Whipple
model of this bicycle closed with ``T = +K (V - v) phidot`` is stable at 1.5-4.5 m/s,
with ``-K`` it is unstable.  The bicycle stayed up in all runs, and the free decays
show steer and roll of the same sign (steer into the lean), as the model predicts.  So
roll, roll rate, steer and steer torque of the logs share the benchmark's signs.  A
mirror image (all four flipped together) leaves the dynamics unchanged, so physics
alone cannot fix the absolute direction; the relative signs are what the model needs.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from bikeid.dataset.run import Run, check_plausible

from .importers import from_csv

__all__ = [
    "COLUMNS",
    "DATASET",
    "DT",
    "SPEED_CALIBRATION",
    "data_dir",
    "despike",
    "find_logs",
    "load_log",
    "settled",
    "treadmill_speed",
]

DT = 0.01  # s, one control loop

COLUMNS = (
    "sil_command", "speed", "lean_angle", "lean_rate", "hand_angle", "fork_angle",
    "fork_rate", "lean_torque", "hand_torque", "x_acceleration", "y_acceleration",
    "command_fork", "command_hand",
)  # fmt: skip

#: sensor = a * treadmill + b (source calibration, data README)
SPEED_CALIBRATION = (1.066, -0.128)

SPIKE_K = 8.0

SPIKE_FLOOR = {"fork_rate": 0.5, "x_acceleration": 5.0, "y_acceleration": 5.0}

DATASET = "tudelft-sbw"

#: Resolution of the treadmill's speed setting [m/s] (:func:`settled`).
SETTING_STEP = 0.1


def treadmill_speed(sensor: np.ndarray | float) -> np.ndarray | float:
    """Treadmill speed [m/s] from the rear-wheel sensor speed (inverse calibration).

    Parameters
    ----------
    sensor : float or ndarray
        Rear-wheel sensor speed [m/s] (the logs' ``speed`` column).

    Returns
    -------
    float or ndarray
        Treadmill speed (sensor - b) / a [m/s] with (a, b) = :data:`SPEED_CALIBRATION`,
        same shape as ``sensor``.
    """
    a, b = SPEED_CALIBRATION
    return (np.asarray(sensor) - b) / a


def data_dir(path: str | os.PathLike | None = None) -> Path:
    """The ``tudelft-sbw`` folder: from ``path`` (``--data``), else ``$BIKEID_DATA``.

    Either may name the folder itself or its parent (CI: ``BIKEID_DATA=../shared/data``).

    Parameters
    ----------
    path : str or path-like, optional
        The ``tudelft-sbw`` folder or its parent; None (default) uses ``$BIKEID_DATA``.

    Returns
    -------
    pathlib.Path
        The folder holding the logs (``*/*.log*`` or ``*.log*``).

    Raises
    ------
    ValueError
        If neither ``path`` nor ``$BIKEID_DATA`` is given, or the folder holds no logs
        (the message says how to get them).
    """
    src = path if path is not None else os.environ.get("BIKEID_DATA")
    if not src:
        raise ValueError(
            "no data directory: pass --data DIR or set BIKEID_DATA to the folder that "
            f"contains {DATASET}/ (get the files with 'bikeid data fetch')"
        )
    root = Path(src).expanduser()
    for cand in (root / DATASET, root):
        if cand.is_dir() and (any(cand.glob("*/*.log*")) or any(cand.glob("*.log*"))):
            return cand
    raise ValueError(f"data directory {root} holds no {DATASET} logs (*.log or *.log.gz)")


def find_logs(root: str | os.PathLike, kind: str | None = None) -> list[Path]:
    """All ``*.log``/``*.log.gz`` files under ``root`` (optionally whose name starts with kind).

    Parameters
    ----------
    root : str or path-like
        Folder searched recursively.
    kind : str, optional
        File-name prefix (``"eigen"``, ``"bode"``).

    Returns
    -------
    list of pathlib.Path
        Sorted.
    """
    files = sorted(
        p for p in Path(root).rglob("*") if p.is_file() and p.name.endswith((".log", ".log.gz"))
    )
    if kind:
        files = [p for p in files if p.name.startswith(kind)]
    return files


def despike(x: np.ndarray, floor: float, k: float = SPIKE_K) -> tuple[np.ndarray, int]:
    """Replace isolated spikes by interpolation (detector: see module docstring).

    Parameters
    ----------
    x : (n,) ndarray
        Signal (any unit; n < 5 is returned unchanged).
    floor : float
        Least deviation counted as a spike [unit of x].
    k : float, optional
        Threshold in robust standard deviations.

    Returns
    -------
    ndarray
        Despiked copy.
    int
        Number of spikes replaced.
    """
    x = np.asarray(x, dtype=float)
    if x.size < 5:
        return x.copy(), 0
    pad = np.pad(x, 2, mode="edge")
    med = np.median(np.lib.stride_tricks.sliding_window_view(pad, 5), axis=1)
    dev = np.abs(x - med)
    scale = 1.4826 * np.median(dev)
    bad = dev > max(k * scale, floor)
    nbad = int(bad.sum())
    if nbad == 0 or nbad == x.size:
        return x.copy(), 0
    out = x.copy()
    idx = np.arange(x.size)
    out[bad] = np.interp(idx[bad], idx[~bad], x[~bad])
    return out, nbad


def load_log(path: str | os.PathLike) -> Run:
    """Read one steer-by-wire log into a :class:`dataset.run.Run` (see module docstring).

    A thin mapping onto :func:`bikeid.dataset.importers.from_csv` (the one reader of a
    user's logs: columns, units, signs, provenance, errors): :data:`MAPPING` and
    :data:`EXTRA` name the columns, the units are SI already and no sign is flipped; then
    the loader adds ``T_ext``, despikes and finds the settled treadmill speed.

    Parameters
    ----------
    path : str or path-like
        A ``*.log`` or ``*.log.gz`` file.

    Returns
    -------
    Run
        ``t`` = row index * 0.01 s [s] (leading rows with an empty ``sil_command`` cut);
        ``signals`` phi, delta [rad], phidot, deltadot [rad/s], v (sensor speed) [m/s],
        T_delta (``command_fork``) and T_ext [N m], plus the extras of the module
        docstring; ``meta`` with ``file``, ``speed`` (treadmill) and ``speed_sensor``
        [m/s], ``first_index``, ``ramp_end_index``, ``settled_end_index`` (file rows),
        ``spikes`` (count per despiked column), ``dt`` [s] and ``import`` (the file's path,
        SHA-256 and the column mapping, :mod:`bikeid.dataset.importers`).

    Raises
    ------
    ValueError
        If the file does not exist, is empty, corrupt or truncated, lacks a column of
        :data:`COLUMNS`, has fewer than 10 data rows, a row with the wrong number of
        fields or a non-numeric or non-finite value (the message names the file, and the
        row and column where there is one), ``sil_command`` is empty in every row, or the
        values are not physical (:func:`bikeid.dataset.run.check_plausible`: a value beyond
        ``sim.conventions.PLAUSIBLE`` or a constant state or command column, named by
        file row and column).
    """
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"log file {path} does not exist")
    run = from_csv(
        path, MAPPING, time=None, dt=DT, extra=EXTRA, skip_leading="sil_command",
        speed_range=None, bounds_as=BOUNDS_AS, label=path.name,
    )  # fmt: skip
    if run.n < 10:
        raise ValueError(f"{path.name}: only {run.n} data rows; need at least 10")
    raw = {c: run.signals[SIGNAL_OF.get(c, c)] for c in COLUMNS}
    # T_ext is derived (no column of its own): its bound is checked here, by sample
    signals = _signals(raw)
    check_plausible(Run(t=run.t, signals=signals), path.name, columns=SIGNAL_COLUMNS,
                    bounds_as={"T_ext": "T_delta"})  # fmt: skip
    first = int(run.meta["import"].get("leading_rows_skipped", 0))
    settled, ramp_end, run_end = _settled_speed(raw["speed"])
    meta = {
        "source": "measured",
        "dataset": DATASET,
        "file": path.name,
        "speed": float(treadmill_speed(settled)),
        "speed_sensor": settled,
        "first_index": first,
        "ramp_end_index": first + ramp_end,
        "settled_end_index": first + run_end,
        "spikes": {},
        "controller": {"law": "steer-into-lean", "T": "K (V - speed) phidot", "K": 2.0, "V": 6.5},
        "bicycle": "steer-by-wire",
        "dt": DT,
        "import": run.meta["import"],
    }
    for c, floor in SPIKE_FLOOR.items():
        raw[c], meta["spikes"][c] = despike(raw[c], floor)
    return Run(t=run.t, signals=_signals(raw), meta=meta)


def settled(run: Run) -> Run:
    """The settled part of a log's run, with ``v`` the treadmill speed: what an estimator fits.

    The start-up ramp and any run-down (``meta["ramp_end_index"]`` ..
    ``meta["settled_end_index"]``) are cut, and the sensor speed is replaced by the
    treadmill speed through :func:`treadmill_speed` (the speed the bicycle's dynamics see).
    ``meta["speed"]`` becomes the treadmill's setting: the settled calibrated speed rounded
    to :data:`SETTING_STEP` (the logs' names give 1.5, 2.5, 3.5, 4.5 and 4 m/s; the
    calibrated plateaus of the 20 logs lie within 0.05 m/s of them), so that the logs of
    one setting form one speed for the estimators; ``meta["speed_calibrated"]`` keeps the
    unrounded value.

    Parameters
    ----------
    run : Run
        A run of :func:`load_log`.

    Returns
    -------
    Run
        The settled rows (same time base [s]); ``v`` [m/s] the treadmill speed,
        ``v_sensor`` [m/s] the logged sensor speed; ``meta["v"]`` says so.

    Raises
    ------
    ValueError
        If the run has no settled-speed metadata (not read by :func:`load_log`) or fewer
        than 2 settled samples.
    """
    if "ramp_end_index" not in run.meta:
        raise ValueError("settled() needs a run read by sbw_logs.load_log")
    part = run.window(run.meta["ramp_end_index"] * DT, run.meta["settled_end_index"] * DT)
    signals = {**part.signals, "v": treadmill_speed(part["v"]), "v_sensor": part["v"]}
    meta = {**part.meta, "v": "treadmill speed from the sensor calibration (sbw_logs.settled)",
            "speed": round(run.meta["speed"] / SETTING_STEP) * SETTING_STEP,
            "speed_calibrated": run.meta["speed"]}  # fmt: skip
    return Run(t=part.t, signals=signals, meta=meta)


#: Signal of the Run behind each column of the log (the required bikeid signals).
MAPPING = {
    "phi": "lean_angle", "phidot": "lean_rate", "delta": "fork_angle",
    "deltadot": "fork_rate", "v": "speed", "T_delta": "command_fork",
}  # fmt: skip
#: Further columns read as signals of the same name (lean_torque is only checked).
EXTRA = {c: c for c in COLUMNS if c not in MAPPING.values()}
SIGNAL_OF = {c: s for s, c in MAPPING.items()}


#: Column of the log behind each signal of the Run (for error messages).
SIGNAL_COLUMNS = {**MAPPING, "T_ext": "command_fork - sil_command"}

#: Extra signals checked against the physical bound of a convention name
#: (``sim.conventions.PLAUSIBLE``): the torques against the steer torque, the handlebar
#: angle against the steer angle.  The IMU accelerations have no bound (noisy, spiky,
#: unused by the identification); they are only checked for finiteness.
BOUNDS_AS = {
    "T_ext": "T_delta", "sil_command": "T_delta", "hand_torque": "T_delta",
    "command_hand": "T_delta", "hand_angle": "delta",
}  # fmt: skip


def _signals(raw: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The Run's signals from the log's columns (module docstring)."""
    v = raw["speed"]
    return {
        "phi": raw["lean_angle"],
        "phidot": raw["lean_rate"],
        "delta": raw["fork_angle"],
        "deltadot": raw["fork_rate"],
        "v": v,
        "T_delta": raw["command_fork"],
        "T_ext": raw["command_fork"] - raw["sil_command"],
        **{
            c: raw[c]
            for c in (
                "sil_command",
                "hand_torque",
                "hand_angle",
                "command_hand",
                "x_acceleration",
                "y_acceleration",
            )  # fmt: skip
        },
    }


def _settled_speed(v: np.ndarray) -> tuple[float, int, int]:
    """Treadmill plateau of the sensor speed: (median, first index, end index).

    The plateau is the most populated 0.05 m/s bin of the speed histogram; samples
    within 5 % of it are settled.  Returns the median of the settled samples, the first
    settled index (the end of a start-up ramp) and one past the last settled index
    (a run-down at the end is cut there).
    """
    edges = np.arange(np.floor(v.min() / 0.05) * 0.05, v.max() + 0.1, 0.05)
    hist, edges = np.histogram(v, bins=edges)
    mode = 0.5 * (edges[np.argmax(hist)] + edges[np.argmax(hist) + 1])
    ok = np.abs(v - mode) <= 0.05 * max(abs(mode), 0.1)
    settled = float(np.median(v[ok]))
    idx = np.flatnonzero(ok)
    return settled, int(idx[0]), int(idx[-1] + 1)
