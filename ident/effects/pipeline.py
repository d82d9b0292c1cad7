"""The measured-data study as a library: fit an experiment model, read it back, evaluate it.

What ``bikeid measured fit|evaluate|report`` and the measured-data benchmarks compute; the
CLI modules (:mod:`bikeid.experiments.cli.measured`, :mod:`bikeid.experiments.measured.report`)
only parse arguments, call these and print.  A *model object* is the JSON-able dict written
by ``measured fit`` (effects by registry name, in the registry's units; the plant; the fit
speeds [m/s]; the identification's log).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np

from bikeid.dataset.sbw_logs import DT
from bikeid.dataset.windows import Window
from bikeid.ident.effects.acceptance import AcceptanceRule
from bikeid.ident.effects.diagnostics import evaluate_windows
from bikeid.ident.effects.experiment_model import ExperimentModel
from bikeid.ident.effects.fit import FitResult, joint_fit
from bikeid.ident.effects.library import LIBRARY
from bikeid.ident.effects.selection import (
    PLANT_UNCERTAIN,
    choose_plant,
    compare_nominal_plants,
    select_effects,
    selection_frequencies,
)
from bikeid.sim.conventions import MAX_SPEED
from bikeid.sim.effect_registry import check_values, effect
from bikeid.sim.errors import InputError
from bikeid.sim.parameters import from_mapping
from bikeid.sim.textformats import loads_json, to_jsonable

__all__ = [
    "evaluate_json",
    "evaluate_plant_model",
    "fit_effect_set",
    "fit_model",
    "model_from_json",
    "plant_model_file",
    "save_fit",
]


#: Plants a model file may name (``measured fit`` records the one it fitted with); a file
#: without ``plant`` gets :data:`DEFAULT_PLANT`, the plant ``measured fit`` used before it
#: recorded one).
PLANTS = ("nonlinear", "linear")
DEFAULT_PLANT = "nonlinear"
#: ``measured fit --plant`` choices; ``auto`` (default) selects with both plants and applies
#: :func:`bikeid.ident.effects.selection.choose_plant` to the two final models.
PLANT_CHOICES = ("auto", *PLANTS)
#: Largest model file read [bytes] (a fitted model is a few kB; a stability run ~100 kB).
MAX_MODEL_BYTES = 20_000_000


def _is_number(v: object) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _experiment_model(obj: dict, where: str = "model object") -> ExperimentModel:
    """The experiment model of a model object: its ``effects`` on its ``parameters`` (the
    bicycle the fit calibrated within its uncertainty) or, without them, the stated
    steer-by-wire bicycle.  A ValueError names ``where`` and the bad field."""
    params = obj.get("parameters")
    try:
        p = None if params is None else from_mapping(params, name="steer-by-wire (calibrated)")
    except (TypeError, ValueError) as exc:
        raise InputError(f"{where}: 'parameters': {exc}") from None
    kw = experiment_settings(obj.get("experiment"), where)
    return ExperimentModel(effects=dict(obj["effects"]), **kw, **({} if p is None else {"p": p}))


def experiment_settings(exp: dict | None, where: str = "model object") -> dict:
    """The :class:`ExperimentModel` keywords of a model object's ``experiment`` entry.

    Parameters
    ----------
    exp : dict or None
        ``{"dt": s, "speed_calibration": [a, b], "K": N s^2/rad, "V": m/s, ...}`` as
        :func:`fit_model` records it; None (files written before it was recorded): the
        steer-by-wire experiment's defaults.
    where : str, optional
        What error messages call the object.

    Returns
    -------
    dict
        ``dt`` [s], ``speed_calibration`` (a, b), ``K``, ``V`` where given.

    Raises
    ------
    bikeid.sim.errors.InputError
        If an entry is not a finite number (or a pair of them).
    """
    if exp is None:
        return {}
    if not isinstance(exp, dict):
        raise InputError(f"{where}: 'experiment' must be an object, got {type(exp).__name__}")
    kw: dict = {}
    for k in ("dt", "K", "V"):
        if exp.get(k) is not None:
            if not _is_number(exp[k]):
                raise InputError(f"{where}: experiment '{k}' must be a finite number")
            kw[k] = float(exp[k])
    cal = exp.get("speed_calibration")
    if cal is not None:
        if not (isinstance(cal, list) and len(cal) == 2 and all(map(_is_number, cal))):
            raise InputError(f"{where}: experiment 'speed_calibration' must be [a, b]")
        kw["speed_calibration"] = (float(cal[0]), float(cal[1]))
    return kw


def experiment_record(model: ExperimentModel, law: str | None, bicycle: str) -> dict:
    """What a model object records of the experiment its windows come from.

    Parameters
    ----------
    model : ExperimentModel
        The nominal experiment (sample period, speed calibration, loop gains).
    law : str or None
        The controller law's name (``"steer-into-lean"``) or None when it is unknown (the
        logged steer torque replayed).
    bicycle : str
        The nominal bicycle's name or file.

    Returns
    -------
    dict
        ``dt`` [s], ``speed_calibration`` [a, b] (sensor = a true + b), ``law``, ``K``
        [N s^2/rad] and ``V`` [m/s] (None without a law), ``bicycle`` and
        ``stated_parameters`` (the nominal bicycle before any calibration, SI).
    """
    return {"dt": model.dt, "speed_calibration": list(model.speed_calibration), "law": law,
            "K": model.K if law else None, "V": model.V if law else None,
            "bicycle": bicycle, "stated_parameters": model.p.as_dict()}  # fmt: skip


def _nominal(obj: dict, where: str = "model object") -> ExperimentModel:
    """The stated nominal of a model object (the 'before' of evaluate): its experiment's
    stated bicycle and settings, no effects; the steer-by-wire experiment by default."""
    exp = obj.get("experiment")
    kw = experiment_settings(exp, where)
    stated = exp.get("stated_parameters") if isinstance(exp, dict) else None
    if stated is not None:
        try:
            kw["p"] = from_mapping(stated, name=str(exp.get("bicycle") or "stated"))
        except (TypeError, ValueError) as exc:
            raise InputError(f"{where}: experiment 'stated_parameters': {exc}") from None
    return ExperimentModel(**kw)


def simulable_windows(
    model: ExperimentModel, windows: list[Window]
) -> tuple[list[Window], list[dict]]:
    """Split the windows into those the nominal nonlinear plant can simulate and the rest.

    A window whose nonlinear simulation at ``model`` stops early (a rear wheel lifts, the
    bicycle falls) cannot be scored by any candidate that starts from it, so it is dropped
    for all candidates alike and counted (never an abort of the whole fit).

    Parameters
    ----------
    model : ExperimentModel
        The nominal model.
    windows : list of Window
        The decays.

    Returns
    -------
    kept : list of Window
        The windows simulated to their end (unchanged).
    dropped : list of dict
        ``file``, ``start`` (row) and ``reason`` of each dropped window.
    """
    from bikeid.ident.effects.experiment_model import SimulationFailed, nonlinear_correction

    kept, dropped = [], []
    for w in windows:
        try:
            nonlinear_correction(w, model)
        except SimulationFailed as exc:
            dropped.append({"file": w.file, "start": int(w.start), "reason": exc.reason})
            continue
        kept.append(w)
    return kept, dropped


def save_fit(
    obj: dict,
    path: str | Path,
    settings: dict | None = None,
    provenance: list | None = None,
) -> Path:
    """Write the model object of :func:`fit_model` as a bikeid model file.

    The file has ``kind = "experiment-model"`` (:mod:`bikeid.ident.model_file`): the
    effects in the model section, ``plant`` (and ``decays`` when given) in the settings, the
    fit speeds as ``speeds``, and the rest of ``obj`` (bicycle, files, windows, the
    identification log, selection frequencies) in ``results``.

    Parameters
    ----------
    obj : dict
        A model object (:func:`fit_model`), optionally with ``decays``.
    path : str or Path
        The JSON file to write (atomically).
    settings : dict, optional
        Further options of the fit (e.g. ``max_effects``, ``weave_weight``).
    provenance : list, optional
        The data files (paths) or :func:`bikeid.ident.model_file.file_provenance` entries.

    Returns
    -------
    Path
        ``path``.
    """
    from bikeid.ident.model_file import save_model


    settings = {"command": "bikeid measured fit", "plant": obj["plant"], **(settings or {})}
    if "decays" in obj:
        settings["decays"] = obj["decays"]
    skip = {"effects", "plant", "fit_speeds", "decays", "parameters"}
    results = to_jsonable({k: v for k, v in obj.items() if k not in skip})
    model = _experiment_model(obj)
    return save_model(model, path, provenance=provenance, settings=settings, results=results,
                      speeds=obj["fit_speeds"])  # fmt: skip


def _from_model_file(text: str, where: str) -> dict:
    """The model object of a bikeid model file (``measured fit`` since format version 1)."""
    from bikeid.ident.model_file import model_from_text

    mf = model_from_text(text, where)
    if mf.kind != "experiment-model":
        raise InputError(
            f"{where} holds a {mf.kind} model (bikeid identify); the measured commands need "
            "the MODEL.json written by 'bikeid measured fit'"
        )
    obj = {**mf.results, "effects": dict(mf.model.effects), "fit_speeds": list(mf.speeds or []),
           "parameters": mf.model.p.as_dict()}  # fmt: skip
    if "plant" in mf.settings:
        obj["plant"] = mf.settings["plant"]
    if "decays" in mf.settings:
        obj["decays"] = mf.settings["decays"]
    return obj


def model_from_json(path: str | Path) -> tuple[ExperimentModel, dict]:
    """Read and validate a model file written by ``bikeid measured fit``.

    Two layouts are read: the bikeid model file (:mod:`bikeid.ident.model_file`, kind
    ``experiment-model``), which ``measured fit`` writes, and the plain object earlier
    versions wrote (``effects``, ``plant``, ``fit_speeds``, ``identification`` at the top).

    Parameters
    ----------
    path : str or Path
        The JSON file.

    Returns
    -------
    model : ExperimentModel
        The experiment with the file's effects, on the file's bicycle parameters (those the
        fit calibrated within their uncertainty; the stated steer-by-wire bicycle when the
        file has none).
    obj : dict
        The model object (the plain layout; for a model file its results with
        ``effects``, ``plant`` and ``fit_speeds``); ``plant`` is filled in with
        :data:`DEFAULT_PLANT` (and ``plant_defaulted`` set True) when the file has none.

    Raises
    ------
    bikeid.sim.errors.InputError
        A ValueError naming the file and the field: if the file cannot be read or is not
        strict JSON (:func:`bikeid.sim.textformats.loads_json`: duplicate keys, NaN and
        deep nesting are refused), is not an object, is a model file of another kind or
        fails its checks (:func:`bikeid.ident.model_file.read_model_file`), lacks
        ``effects`` or has an effect that is unknown or not a finite number, names a plant
        other than :data:`PLANTS`, or has ``fit_speeds`` that are not a list of speeds in
        (0, 100] m/s, or an ``identification`` that is not an object.
    """
    path = Path(path)
    where = f"model file {str(path)!r}"
    try:
        size = path.stat().st_size
        if size > MAX_MODEL_BYTES:
            raise InputError(
                f"{where} is {size:,} bytes, more than a model file's {MAX_MODEL_BYTES:,}; "
                "give the MODEL.json written by 'bikeid measured fit'"
            )
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(f"{where} does not exist; write one with 'bikeid measured fit'") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read {where}: {exc}") from None
    obj = loads_json(text, where)
    if not isinstance(obj, dict):
        raise InputError(f"{where} must hold a JSON object, got {type(obj).__name__}")
    if "format" in obj:
        obj = _from_model_file(text, where)
    effects = obj.get("effects")
    if not isinstance(effects, dict):
        raise InputError(
            f"{where}: 'effects' must be an object of effect name: value, got "
            f"{type(effects).__name__ if 'effects' in obj else 'nothing'}"
        )
    try:  # known names, numbers (not bools), finite and in the registry's plausible range
        check_values(effects, where)
    except ValueError as exc:
        raise InputError(str(exc)) from None
    plant = obj.get("plant")
    if plant is None and "plant" not in obj:
        obj["plant"], obj["plant_defaulted"] = DEFAULT_PLANT, True
    elif plant not in PLANTS:
        raise InputError(
            f"{where}: 'plant' is {plant!r}; use one of {', '.join(map(repr, PLANTS))}"
        )
    speeds = obj.get("fit_speeds")
    if "fit_speeds" in obj and not (
        isinstance(speeds, list) and all(_is_number(v) and 0 < v <= MAX_SPEED for v in speeds)
    ):
        raise InputError(
            f"{where}: 'fit_speeds' must be a list of treadmill speeds in (0, 100] m/s, got "
            f"{json.dumps(speeds)[:60]}"
        )
    ident = obj.get("identification")
    if ident is not None and not (
        isinstance(ident, dict)
        and isinstance(ident.get("effects", []), list)
        and all(isinstance(e, dict) and "name" in e for e in ident.get("effects", []))
    ):
        raise InputError(
            f"{where}: 'identification' must be the object 'measured fit' writes (its "
            "'effects' a list of objects with a 'name'); delete the key or refit"
        )
    try:
        return _experiment_model(obj, where), obj
    except ValueError as exc:
        raise InputError(f"{where}: {exc}") from None


def fit_model(
    windows: list[Window],
    max_effects: int = 3,
    plant: str = "auto",
    stability: int = 0,
    weave_weight: float | str = "auto",
    progress: Callable[[int, int, str], None] | None = None,
    rule: AcceptanceRule | None = None,
    model: ExperimentModel | None = None,
    law: str | None = "steer-into-lean",
) -> dict:
    """Select effects on ``windows`` and return the model object ``measured fit`` writes.

    Parameters
    ----------
    windows : list of Window
        The fit decays.
    max_effects : int, optional
        At most this many effects (:func:`bikeid.ident.effects.selection.select_effects`).
    plant : str, optional
        ``"auto"`` (default): the selection is run with both nominal plants (the linear
        Whipple model and the nonlinear one by defect correction) on the same decays, and the
        plant is chosen after it by the two final models' fits
        (:func:`bikeid.ident.effects.selection.choose_plant`: per-decay out-of-fold costs, a
        sign-flip paired test at the rule's ``alpha``; alike fits keep the nonlinear plant
        when the selections agree, take the smaller selection's plant when one only adds
        effects to the other's, and give
        :data:`bikeid.ident.effects.selection.PLANT_UNCERTAIN` when they disagree otherwise);
        ``"nonlinear"`` or ``"linear"`` force one (one selection, no comparison).  The
        nominal fits before any effect are reported in every case (``nominal_fit``), the
        plant used as ``plant`` and why as ``plant_choice``.
    stability : int, optional
        With N > 0, also the selection frequency of each name over N random 75 % subsamples
        (:func:`bikeid.ident.effects.selection.selection_frequencies`).
    weave_weight : float or "auto", optional
        Weight of the measured weave eigenvalues in every fit.
    progress : callable, optional
        ``progress(done, total, label)`` through the subsamples, then the candidate fits
        (:mod:`bikeid.experiments.progress`).
    rule : AcceptanceRule, optional
        The acceptance rule (:class:`bikeid.ident.effects.acceptance.AcceptanceRule`: the
        significance level, gains, ``unexplained`` rule and the stated bicycle's
        uncertainty), also used by the stability subsamples; default ``AcceptanceRule()``,
        as ``measured fit`` (the nominal calibrated within its default uncertainty).
    model : ExperimentModel, optional
        The nominal experiment: the stated bicycle, the logs' sample period ``dt`` and speed
        calibration, the loop gains (default: the steer-by-wire experiment).
    law : str or None, optional
        The controller law of the logs (default ``"steer-into-lean"``, the gains of
        ``model``); None when it is unknown and the windows replay the logged steer torque
        (``drive == "logged"``): the weave term, which needs the closed loop, is then off.

    Returns
    -------
    dict
        Effects (registry units), the bicycle parameters of the fitted model
        (``parameters``, SI: the stated ones moved within ``nominal_uncertainty``), fit
        speeds [m/s], files, windows, the identification (of the plant used), ``plant``:
        the nominal plant of the reported model (its effects, parameters and
        identification); ``plant_choice``: ``asked`` (auto, linear or nonlinear), ``plant``,
        ``auto`` (the plant auto chose; None when the plant was forced: auto was not run),
        ``uncertain`` (the verdict is :data:`bikeid.ident.effects.selection.PLANT_UNCERTAIN`),
        ``ratio`` (nominal cost nonlinear / linear before any effect, for reference: it no
        longer chooses) and ``reason`` (a sentence: the final models' out-of-fold costs, the
        paired test and the rule's branch, or "as asked"); ``plant_check`` (auto only, None
        when forced): :func:`bikeid.ident.effects.selection.compare_plant_selections` of the
        two selections (``agree``, each plant's verdict, effects and ambiguity sets,
        ``differences``) with the plant test's numbers under ``test``
        (:func:`bikeid.ident.effects.selection.choose_plant`); when the plant is uncertain no
        effect is named (``effects`` empty, the identification's verdict
        :data:`bikeid.ident.effects.selection.PLANT_UNCERTAIN`, both selections in
        ``plant_check``, a note); ``nominal_fit``: the nominal model's summed squared NRMSE
        of roll rate and steer angle as linear and as nonlinear plant before any effect
        (:func:`bikeid.ident.effects.selection.compare_nominal_plants`), reported, not used
        to choose; ``experiment`` (:func:`experiment_record`); ``dropped_windows``
        (file, start row, reason of each window no candidate could be scored on: the
        nominal nonlinear plant cannot simulate it, so it is dropped for all candidates
        alike, :func:`simulable_windows`; a window that fails at an accepted effect is
        dropped too and the selection rerun) and ``notes`` (sentences saying so).

    Raises
    ------
    ValueError
        If ``plant`` is not one of :data:`PLANT_CHOICES` or ``select_effects`` refuses an
        option.
    """
    if plant not in PLANT_CHOICES:
        raise ValueError(f"plant must be one of {', '.join(PLANT_CHOICES)}, got {plant!r}")
    select_kw = {"rule": AcceptanceRule() if rule is None else rule}
    base = ExperimentModel() if model is None else model
    notes = []
    if law is None and weave_weight != 0:
        weave_weight = 0.0
        notes.append("weave term off: no controller law given, so the model has no closed "
                     "loop whose weave eigenvalue could be compared")  # fmt: skip
    windows, dropped = simulable_windows(base, windows)
    if dropped:
        notes.append(f"{len(dropped)} window(s) dropped for all candidates alike: the nominal "
                     "nonlinear plant cannot simulate them (" + "; ".join(
                         f"{d['file']}@{d['start']}: {d['reason']}" for d in dropped) + ")")
    nominal_fit = compare_nominal_plants(base, windows)
    asked = plant
    ratio = nominal_fit["ratio"]
    sel: dict[str, object] = {}
    # the nonlinear plant first: a window it cannot simulate at an accepted effect is dropped
    # for both plants, so the two selections run on the same decays
    for name in [p for p in ("nonlinear", "linear") if asked in ("auto", p)]:
        prog = progress
        if progress and asked == "auto":
            prog = (lambda lab: lambda d, t, label: progress(d, t, f"{lab} plant, {label}"))(name)
        res, more = _select_dropping(base, windows, max_effects, name == "nonlinear",
                                     weave_weight, prog, select_kw)  # fmt: skip
        sel[name] = res
        if more:
            dropped += more
            notes.append(f"{len(more)} more window(s) dropped for all candidates alike and the "
                         "selection rerun: the nonlinear plant could not simulate them at an "
                         "accepted effect (" + "; ".join(
                             f"{d['file']}@{d['start']}: {d['reason']}" for d in more) + ")")
            windows = [w for w in windows
                       if not any(d["file"] == w.file and d["start"] == w.start for d in more)]
    check = None
    if asked == "auto":
        pick = choose_plant(base, sel["linear"], sel["nonlinear"], select_kw["rule"].alpha)
        plant = pick["plant"]
        check = {**pick["check"], "test": pick["test"]}
        choice = {"asked": asked, "plant": plant, "auto": plant, "uncertain": pick["uncertain"],
                  "ratio": ratio, "reason": pick["reason"]}  # fmt: skip
        if pick["uncertain"]:
            t = pick["test"]
            notes.append(f"{PLANT_UNCERTAIN}: the final models of the two plants fit the decays "
                         f"alike (out-of-fold cost linear {t['linear_cost']:.4g}, nonlinear "
                         f"{t['nonlinear_cost']:.4g}, paired p = {t['p_value']:.2g} > "
                         f"{t['alpha']:g}) and their selections disagree ("
                         + "; ".join(check["differences"]) + "), so no effect is named: the "
                         "difference would be the plant mismatch")  # fmt: skip
        elif pick["plant_dependent"]:
            notes.append("plant-dependent effects not named: " + "; ".join(check["differences"])
                         + f"; the {plant} plant's selection, which both plants support, is "
                         "the answer")  # fmt: skip
    else:
        choice = {"asked": asked, "plant": plant, "auto": None, "uncertain": False,
                  "ratio": ratio,
                  "reason": f"{plant} plant as asked (not compared with the other plant; before "
                  f"any effect the nominal cost ratio nonlinear / linear is {ratio:.3g})"}
    res = sel[plant]
    nl = plant == "nonlinear"
    extra = {}
    if stability:
        freq = selection_frequencies(
            base, windows, stability, max_effects=max_effects, nonlinear=nl,
            progress=progress, **select_kw,
        )  # fmt: skip
        extra = {"selection_frequency": freq,
                 "stability": {"resamples": stability, "fraction": 0.75, "seed": 0,
                               "plant": plant}}  # fmt: skip
    uncertain = choice["uncertain"]
    ident = res.as_dict()
    if uncertain:
        ident.update(verdict=[PLANT_UNCERTAIN], effects=[])
    return {
        "bicycle": base.p.name,
        "experiment": experiment_record(base, law, base.p.name),
        "dropped_windows": dropped,
        "notes": notes,
        "parameters": res.model.p.as_dict(),
        "plant": plant,
        "plant_choice": choice,
        "plant_check": check,
        "effects": {} if uncertain else {e.name: float(e.value) for e in res.effects},
        "fit_speeds": sorted({round(w.speed, 2) for w in windows}),
        "fit_files": sorted({w.file for w in windows}),
        "fit_windows": [{"file": w.file, "start": w.start, "end": w.start + w.n} for w in windows],
        "identification": ident,
        "nominal_fit": nominal_fit,
        **extra,
    }


def _select_dropping(base, windows, max_effects, nl, weave_weight, progress, select_kw):
    """:func:`select_effects`, rerun without a window the nonlinear plant cannot simulate at
    an accepted effect (at most 5 times); returns the result and the windows dropped."""
    from bikeid.ident.effects.experiment_model import SimulationFailed

    more: list[dict] = []
    for _ in range(6):
        try:
            res = select_effects(
                base, windows, max_effects=max_effects, nonlinear=nl,
                weave_weight=weave_weight, progress=progress, **select_kw,
            )  # fmt: skip
            return res, more
        except SimulationFailed as exc:
            if len(more) == 5:
                raise
            more.append({"file": exc.file, "start": int(exc.start), "reason": exc.reason})
            windows = [w for w in windows if not (w.file == exc.file and w.start == exc.start)]
    raise AssertionError("unreachable")


def evaluate_json(model_obj: dict, windows: list[Window]) -> dict:
    """Error before (nominal) and after (the model object's effects) on ``windows``.

    Parameters
    ----------
    model_obj : dict
        A model object (:func:`fit_model`, :func:`model_from_json`).
    windows : list of Window
        The decays to evaluate on (usually held-out speeds).

    Returns
    -------
    dict
        The metric's description, plant, verdict, effects with standard errors, fit speeds,
        :func:`bikeid.ident.effects.diagnostics.evaluate`'s ``files`` and ``summary``
        (NRMSE, dimensionless; weave eigenvalues [1/s]), ``input`` (``"loop"`` or
        ``"kstep"`` or ``"logged"``: what drove the model,
        :attr:`bikeid.dataset.windows.Window.drive`;
        a nonlinear-plant model is replayed with the linear plant, and ``note`` says so),
        ``dropped_windows`` (file, start, reason of each window the nonlinear plant of the
        nominal or of the model cannot simulate: left out of both, and ``note`` says so),
        and ``validation``: the model's fit
        [%] and residual tests per file (:func:`bikeid.ident.validation_report.validate_decays`).

    Raises
    ------
    bikeid.sim.errors.InputError
        If the nonlinear plant can simulate none of the windows.
    """
    from bikeid.ident.validation_report import validate_decays

    aug = _experiment_model(model_obj)
    plant = model_obj.get("plant", DEFAULT_PLANT)  # as model_from_json and measured fit
    replay = bool(windows) and all(w.drive == "logged" for w in windows)
    note = None
    if replay and plant == "nonlinear":
        # Open loop, the nonlinear plant leaves its domain inside some windows (measured: a
        # 3.5 m/s decay unloads a wheel after 0.92 s), so replay runs the linear plant.
        plant = "linear"
        note = ("replayed with the linear plant: open loop, the nonlinear plant falls inside "
                "some windows (the model's effects are kept)")  # fmt: skip
    nominal, dropped = _nominal(model_obj), []
    if plant == "nonlinear":  # a window either model's nonlinear plant cannot carry: dropped
        for m in (nominal, aug):
            windows, more = simulable_windows(m, windows)
            dropped += more
        if dropped:
            note = ((note + "; ") if note else "") + (
                f"{len(dropped)} window(s) dropped for both models: the nonlinear plant cannot "
                "simulate them (" + "; ".join(f"{d['file']}@{d['start']}: {d['reason']}"
                                               for d in dropped) + ")")  # fmt: skip
        if not windows:
            raise InputError("no window left to evaluate: the nonlinear plant cannot simulate "
                             "any of them (see the model's plant; try --drive logged)")  # fmt: skip
    ev, at_aug = evaluate_windows(nominal, aug, windows,
                                  nonlinear=plant == "nonlinear")  # fmt: skip
    # the validation of `bikeid validate` on the decays (corrected at `aug`)
    validation = validate_decays(aug, at_aug)
    ident = model_obj.get("identification", {})
    std = {e["name"]: e for e in ident.get("effects", [])}
    effects = [
        {
            "name": k,
            "value": v,
            "std": std.get(k, {}).get("std"),
            "unit": std.get(k, {}).get("unit"),
        }
        for k, v in model_obj["effects"].items()
    ]
    return {
        "metric": "mean over decay windows of NRMSE ||y_sim - y|| / ||y - mean y|| of roll "
        "rate and steer angle (simulation from the measured initial state); weave error "
        "|lambda_model - lambda_data| / |lambda_data|, both the median of damped-oscillation "
        "fits to the decays (measured; simulated from the same initial states); "
        "weave_root_error: lambda_model = nearest root of the sampled linear loop",
        "plant": plant,
        "input": windows[0].drive if windows else "loop",
        "note": note,
        "dropped_windows": dropped,
        "verdict": ident.get("verdict"),
        "effects": effects,
        "fit_speeds": model_obj.get("fit_speeds"),
        **ev,
        "validation": validation,
    }


def fit_effect_set(windows: list[Window], names: list[str], nonlinear: bool = True) -> FitResult:
    """Fit a fixed set of effects jointly on all ``windows`` (no selection).

    Parameters
    ----------
    windows : list of Window
        The decays (not changed; the fit starts from the nominal's defect correction).
    names : list of str
        Registry names; each starts one library scale from absent (1 from absent for an
        effect outside the library).
    nonlinear : bool, optional
        Nonlinear plant by defect correction (default) or the linear model.

    Returns
    -------
    FitResult
        :func:`bikeid.ident.effects.fit.joint_fit` from the nominal model.
    """
    start = {n: LIBRARY[n].absent + LIBRARY[n].scale if n in LIBRARY else effect(n).absent + 1.0
             for n in names}  # fmt: skip
    windows = [replace(w, correction=None) for w in windows]  # from the nominal's correction
    return joint_fit(ExperimentModel(), windows, names, start, nonlinear)


def plant_model_file(path: str | Path):
    """The identified plant model in ``path``, or None for a ``measured fit`` model file.

    Parameters
    ----------
    path : str or Path
        A JSON model file.

    Returns
    -------
    object or None
        The model of a bikeid model file of a kind other than ``experiment-model`` (a
        :class:`bikeid.ident.pem.CanonicalModel`, ``SpeedCanonicalModel`` or
        :class:`bikeid.ident.direct.DirectResult` from ``bikeid identify --out``); None when
        the file is a ``measured fit`` model (either layout) or cannot be read as JSON (the
        caller's reader then names the problem).
    """
    from bikeid.ident.model_file import FORMAT, load_model

    try:
        obj = loads_json(Path(path).read_text(encoding="utf-8"), str(path))
    except (OSError, UnicodeDecodeError, ValueError):
        return None
    if not (isinstance(obj, dict) and obj.get("format") == FORMAT):
        return None
    if obj.get("kind") == "experiment-model":
        return None
    return load_model(path)


def _plant_state_space(model, v: float) -> tuple[np.ndarray, np.ndarray]:
    """Continuous (A, b) of a plant model at ``v`` [m/s]: states [phi, delta, phidot,
    deltadot], the steer-torque input column."""
    from bikeid.ident.direct import DirectResult

    if isinstance(model, DirectResult):
        ss = model.state_space(v, inputs=("T_delta",))
    elif hasattr(model, "at"):  # speed-parameterized canonical model
        ss = model.state_space(v)
    else:  # fixed-speed canonical model (input T_delta only)
        ss = model.state_space()
    return np.asarray(ss.A, dtype=float), np.asarray(ss.B, dtype=float)[:, 0]


def evaluate_plant_model(model, windows: list[Window], speed_tolerance: float = 0.1) -> dict:
    """Error before (Whipple nominal) and after (an identified plant model) on ``windows``,
    each driven open loop by its logged steer command from its measured start state.

    The model needs no controller: each window is simulated x[k+1] = Ad x[k] + bd T[k]
    (exact zero-order hold of the model at the window's treadmill speed, T the logged
    ``command_fork``) from :meth:`bikeid.dataset.windows.Window.state0`; the nominal is the
    linear Whipple model of the steer-by-wire bicycle, simulated the same way.  The error is
    that of ``measured evaluate``
    (:func:`bikeid.ident.effects.experiment_model.window_errors`: NRMSE
    of roll rate and steer angle, mean over windows).

    Parameters
    ----------
    model : CanonicalModel, SpeedCanonicalModel or DirectResult
        An identified model (``bikeid identify --out``).  A fixed-speed model is evaluated
        only on windows within ``speed_tolerance`` of its speed.
    windows : list of Window
        Decays with ``T_logged``.
    speed_tolerance : float, optional
        [m/s].

    Returns
    -------
    dict
        ``input`` ("logged"), ``model_kind``, ``files`` (file, speed [m/s], windows,
        error_before, error_after: means over the file's windows) and ``summary``
        (error_before, error_after: means over files, as ``measured evaluate``; windows;
        the skipped windows).

    Raises
    ------
    bikeid.sim.errors.InputError
        If no window is at the model's speed or a window has no logged command.
    """
    from bikeid.ident.effects.experiment_model import window_errors
    from bikeid.ident.validate import simulation
    from bikeid.sim.linear import state_space
    from bikeid.sim.parameters import steer_by_wire
    from bikeid.sim.sampling import zoh

    p = steer_by_wire()
    fixed = getattr(model, "speed", None) if not hasattr(model, "at") else None
    use, skipped = [], []
    for w in windows:
        if w.T_logged is None:
            raise InputError(f"{w.file}@{w.start}: the window has no logged steer command")
        if fixed is not None and abs(w.speed - fixed) > speed_tolerance:
            skipped.append(f"{w.file}@{w.start} at {w.speed:.2f} m/s")
            continue
        use.append(w)
    if not use:
        raise InputError(f"no decay window at the model's speed {fixed} m/s (+-{speed_tolerance}); "
                         "give --speeds near it or a model defined over speed")  # fmt: skip
    sims = {"before": [], "after": []}
    for w in use:
        nom = state_space(p, w.speed, inputs=("T_delta",))
        for key, (A, b) in (("before", (np.asarray(nom.A), np.asarray(nom.B)[:, 0])),
                            ("after", _plant_state_space(model, w.speed))):  # fmt: skip
            Ad, Bd = zoh(A, b[:, None], DT)
            Y, _ = simulation(Ad, Bd, np.eye(4), w.T_logged, ic=w.state0())
            sims[key].append({"phi": Y[:, 0], "delta": Y[:, 1], "phidot": Y[:, 2],
                              "deltadot": Y[:, 3]})  # fmt: skip
    e0 = window_errors(use, sims["before"]).mean(axis=1)
    e1 = window_errors(use, sims["after"]).mean(axis=1)
    files = []
    for f in dict.fromkeys(w.file for w in use):
        idx = [i for i, w in enumerate(use) if w.file == f]
        files.append({"file": f, "speed": float(use[idx[0]].speed), "windows": len(idx),
                      "error_before": float(e0[idx].mean()),
                      "error_after": float(e1[idx].mean())})  # fmt: skip
    return {
        "input": "logged",
        "model_kind": type(model).__name__,
        "metric": "mean over decay windows of the mean NRMSE of roll rate and steer angle; "
        "open-loop replay of the logged steer command from the measured start state",
        "files": files,
        "summary": {
            "error_before": float(np.mean([f["error_before"] for f in files])),
            "error_after": float(np.mean([f["error_after"] for f in files])),
            "windows": len(use),
            "skipped": skipped,
        },
    }
