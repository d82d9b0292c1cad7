"""Free-decay windows of anyone's logs, with the experiment they were measured in.

:func:`decays_from_logs` is what ``bikeid measured fit|evaluate`` read: a user's logs through
the one loader (:func:`bikeid.dataset.logs.load_runs`, every import check and, with the
nominal bicycle, the sign check), or the steer-by-wire logs with their listed or detected
decays; the windows are checked against the bicycle's toppling rate
(:func:`check_decay_rates`), and the nominal :class:`ExperimentModel` (bicycle, sample
period, speed calibration, controller law) comes with them.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from bikeid.dataset.logs import LogOptions, import_check_notes, load_runs
from bikeid.dataset.signs import nominal_bicycle
from bikeid.sim.errors import InputError

__all__ = ["ControlLaw", "check_decay_rates", "decays_from_logs", "toppling_rate"]


@dataclass(frozen=True)
class ControlLaw:
    """The logs' controller law, closed around the model over each window.

    Attributes
    ----------
    name : str
        ``"steer-into-lean"``: ``T_delta = K (V - v) phidot``.
    K : float
        Gain [N s^2/rad] (default 2, the steer-by-wire logs').
    V : float
        Speed above which the law stops steering [m/s] (default 6.5).
    """

    name: str = "steer-into-lean"
    K: float = 2.0
    V: float = 6.5

    def __post_init__(self) -> None:
        if self.name != "steer-into-lean":
            raise InputError(f"controller law {self.name!r}: bikeid knows steer-into-lean")
        if not (math.isfinite(self.K) and math.isfinite(self.V)):
            raise InputError(f"law gains K={self.K}, V={self.V}: give finite numbers")


def toppling_rate(p: Any) -> float:
    """The roll rate [rad/s] at which bicycle ``p``, rigid with the steer locked, reaches the
    ground falling from upright: m g h = I w^2 / 2, I = sum(I_xx + m z^2) about the contact
    line (the derivation of ``sim.conventions.PLAUSIBLE["phidot"]``): 4.43 rad/s for the
    benchmark, 5.24 rad/s for the steer-by-wire bicycle (below the point-mass bound
    sqrt(2 g / h) the conventions quote, 4.8 and 5.9 rad/s).

    Parameters
    ----------
    p : bikeid.sim.parameters.BicycleParameters
        The bicycle (benchmark axes, z down; SI units).

    Returns
    -------
    float
        The toppling rate [rad/s], > 0.
    """
    d = p.as_dict()
    parts = [(d["mR"], -d["rR"], d["IRxx"]), (d["mF"], -d["rF"], d["IFxx"]),
             (d["mB"], d["zB"], d["IBxx"]), (d["mH"], d["zH"], d["IHxx"])]  # fmt: skip
    m = sum(q[0] for q in parts)
    h = -sum(q[0] * q[1] for q in parts) / m
    inertia = sum(q[2] + q[0] * q[1] ** 2 for q in parts)
    return math.sqrt(2 * m * d["g"] * h / inertia)


def check_decay_rates(windows: list, p: Any, skip: Sequence[str] = ()) -> None:
    """Refuse a decay window whose roll rate exceeds bicycle ``p``'s toppling rate.

    A free decay after a push of a few degrees never approaches the rate of a fall from
    upright to the ground (the steer-by-wire logs stay below 1.5 rad/s, under a third of its
    5.24 rad/s), so a larger value is a glitch even inside the generic 20 rad/s bound.

    Parameters
    ----------
    windows : list of bikeid.dataset.windows.Window
        The decays (``phidot`` [rad/s], ``start`` the first row in the log).
    p : bikeid.sim.parameters.BicycleParameters
        The bicycle the logs are of.
    skip : sequence of str, optional
        Checks skipped on request: with ``rate-bounds`` nothing is checked (the reader
        prints the note).

    Raises
    ------
    bikeid.sim.errors.InputError
        Naming the log, the row, the value and the bound, and the fix.
    """
    if "rate-bounds" in skip:
        return
    bound = toppling_rate(p)
    for w in windows:
        x = np.abs(np.asarray(w.phidot, float))
        i = int(np.argmax(x)) if x.size else 0
        if x.size and x[i] > bound:
            raise InputError(
                f"{w.file}: row {w.start + i} of a decay window: roll rate {float(x[i]):.3g} "
                f"rad/s, beyond {bound:.3g} rad/s, the rate at which {p.name} hits the ground "
                "falling from upright: check the right --bicycle / --units first, otherwise "
                "a glitch in the log: cut it out (or --skip-check rate-bounds for a log you "
                "know holds such rates)"
            )


def _sbw_runs(files: Sequence[Any], o: LogOptions, decays: str, data: Any, note
              ) -> tuple[list, dict, list[str]]:  # fmt: skip
    from bikeid.dataset.decays import steer_by_wire_logs
    from bikeid.dataset.files import check_distinct_inputs
    from bikeid.dataset.sbw_logs import data_dir, find_logs

    for msg in import_check_notes(o.skip, "sbw", o.no_checks):
        note(msg)  # range checks of the logs cannot be skipped: refused by name, or noted
    for opt in ("columns", "units", "speed"):
        if getattr(o, opt) is not None:
            raise InputError(f"--{opt} applies to --format csv or hdf5 (your own logs)")
    if o.flip:
        raise InputError("--flip applies to --format csv or hdf5 (sbw logs: bikeid signs)")
    if files and data:
        raise InputError("give either --data FOLDER or log files, not both")
    paths = []
    for f in map(Path, files) if files else [data_dir(data)]:
        found = find_logs(f, "eigen") if f.is_dir() else [f]
        if f.is_dir() and not found:
            raise InputError(f"{f} holds no steer-by-wire eigen logs (eigen*.log[.gz])")
        paths += found
    check_distinct_inputs(paths)  # a log given twice would count its decays twice
    runs, listed = steer_by_wire_logs(paths, decays)
    read = [str(p) for p in paths] + sorted(
        {str(p.parent / "segments.csv") for p in paths
         if decays == "listed" and (p.parent / "segments.csv").is_file()})  # fmt: skip
    return runs, listed, read


def decays_from_logs(
    files: Sequence[Any],
    options: LogOptions,
    law: ControlLaw | None = None,
    *,
    decays: str = "listed",
    data: Any = None,
    drive: str | None = None,
    speeds: list[float] | None = None,
    exclude: list[float] | None = None,
    min_decays: int = 1,
    purpose: str = "the fit",
    experiment: dict | None = None,
    note: Callable[[str], None] | None = None,
) -> tuple[list, Any, ControlLaw | None, dict]:
    """The decay windows of logs and their nominal experiment.

    Parameters
    ----------
    files : sequence of path
        A user's logs (``options.format`` csv/hdf5, read by
        :func:`bikeid.dataset.logs.load_runs`), or steer-by-wire logs or folders
        (``format="sbw"``; none: the folder ``data`` or ``$BIKEID_DATA``).
    options : LogOptions
        How to read them; ``options.bicycle`` is the nominal bicycle (required for a user's
        logs; default the steer-by-wire bicycle for its logs and for ``experiment``).
    law : ControlLaw, optional
        The logs' controller law (default: the steer-by-wire logs' steer-into-lean law for
        ``format="sbw"``; none for a user's logs, which are then scored by the k-step error).
    decays : str, optional
        steer-by-wire logs: ``"listed"`` (the transcribed windows) or ``"detected"``; a user's
        logs are always detected from the roll rate.
    data : path, optional
        steer-by-wire: the data folder when no files are given.
    drive : str, optional
        ``"loop"`` (the law closed around the model), ``"kstep"`` (the k-step prediction
        error through the model's Kalman filter on the logged torque,
        :mod:`bikeid.ident.effects.kstep`) or ``"logged"`` (the logged torque replayed open
        loop); default loop with a law, else kstep.
    speeds, exclude : list of float, optional
        Keep only / drop windows near these speeds [m/s].
    min_decays : int, optional
        Fewest usable decays (fewer: a refusal counting them and the rejections).
    purpose : str, optional
        What the decays are for (in the refusal).
    experiment : dict, optional
        A model file's ``experiment`` (evaluate): its sample period must match the logs', and
        its law is used when none is given.
    note : callable, optional
        Receives the loader's notes (default: printed on stderr).

    Returns
    -------
    windows : list of Window
        The decays, each with its ``drive`` and its log's instrument nuisances measured on
        the log's quietest stretch (``meta["instrument_noise"]``,
        :func:`bikeid.ident.effects.instrument_floor.with_noise`).
    model : ExperimentModel
        The nominal experiment: bicycle, sample period [s], speed calibration, law gains.
    law : ControlLaw or None
        The logs' law (given, the steer-by-wire logs', or the model file's), None when
        none is known (the k-step error on the logged torque, or its replay).
    report : dict
        :func:`bikeid.dataset.decays.decays_from_runs`'s report, plus ``read`` (files read).
    """
    from bikeid.dataset.decays import decays_from_runs
    from bikeid.dataset.files import check_distinct_inputs
    from bikeid.dataset.logs import print_note
    from bikeid.dataset.sbw_logs import DT, SPEED_CALIBRATION
    from bikeid.ident.effects.experiment_model import ExperimentModel
    from bikeid.sim.parameters import steer_by_wire

    note = note or print_note
    files = list(files or [])
    sbw = options.format == "sbw"
    if sbw:
        runs, listed, read = _sbw_runs(files, options, decays, data, note)
        dt, cal = DT, SPEED_CALIBRATION
    else:
        if data:
            raise InputError(f"--data is the steer-by-wire folder; with --format "
                             f"{options.format} give your log files as FILE...")  # fmt: skip
        if not files:
            raise InputError(f"--format {options.format} needs log files: FILE... with "
                             "--columns")  # fmt: skip
        check_distinct_inputs(files)  # a log given twice would count its decays twice
        opts = options  # evaluate without --bicycle: the model file's bicycle (steer-by-wire)
        if options.bicycle is None and experiment is not None:
            opts = options.replace(bicycle=steer_by_wire())
        runs, listed, read = load_runs(files, opts, note), {}, [str(f) for f in files]
        if opts.bicycle is None:  # after the import's own checks, which need no bicycle
            raise InputError("your own logs need --bicycle NAME|FILE: the nominal parameters "
                             "of the bicycle (a name of bikeid eig -h, or a .yaml/.json)")
        dts = [r.dt for r in runs]
        dt = sorted(dts)[len(dts) // 2]
        if max(abs(d / dt - 1) for d in dts) > 0.01:
            raise InputError(f"the logs' sample periods differ ({min(dts):g}-{max(dts):g} s); "
                             "fit logs of one sample period together")  # fmt: skip
        cal = (1.0, 0.0)  # the logged speed is the bicycle's speed
    if experiment and experiment.get("dt") and abs(experiment["dt"] / dt - 1) > 0.01:
        raise InputError(f"the model was fitted at a sample period of {experiment['dt']:g} s, "
                         f"the logs have {dt:g} s; evaluate on logs like the fit's")  # fmt: skip
    p = nominal_bicycle(options.bicycle) or steer_by_wire()
    given = law is not None
    if law is None and sbw:
        law = ControlLaw()
    if experiment and not given and experiment.get("law"):  # the model's own law
        law = ControlLaw(experiment["law"], float(experiment["K"]), float(experiment["V"]))
    drive = drive or ("loop" if law else "kstep")
    if drive == "loop" and law is None:
        raise InputError("--drive loop needs the controller law: give --controller "
                         "steer-into-lean --gains K=..,V=.. or use --drive kstep")  # fmt: skip
    gains = law or ControlLaw()
    model = ExperimentModel(p=p, K=gains.K, V=gains.V, dt=dt, speed_calibration=tuple(cal))
    windows, report = decays_from_runs(runs, "listed" if sbw else "detected", listed, speeds,
                                       exclude, min_decays, purpose)  # fmt: skip
    check_decay_rates(windows, p, () if sbw else options.skip)  # a glitch inside the
    # generic bound, beyond this bicycle's
    from bikeid.ident.effects.instrument_floor import with_noise

    windows = with_noise(windows, runs)  # each log's quiet-stretch nuisances
    if drive == "logged":
        windows = [replace(w, drive="logged") for w in windows]
    elif drive == "kstep":  # the k-step error, its horizon fixed at the stated bicycle
        from bikeid.ident.effects.kstep import with_horizon

        windows = with_horizon(windows, model)
    report["read"] = read
    return windows, model, law, report
