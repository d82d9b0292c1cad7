"""The measured-data study as a library: fit an experiment model, read it back, evaluate it.

What ``bikeid measured fit|evaluate|report`` and the measured-data benchmarks compute; the
CLI modules (:mod:`bikeid.experiments.cmd_measured`, :mod:`bikeid.experiments.measured_report`)
only parse arguments, call these and print.  A *model object* is the JSON-able dict written
by ``measured fit`` (effects by registry name, in the registry's units; the plant; the fit
speeds [m/s]; the identification's log).
"""

from __future__ import annotations

import json
from pathlib import Path

from bikeid.dataset.windows import Window
from bikeid.ident.discrepancy_diagnostics import evaluate
from bikeid.ident.effect_fit import FitResult, joint_fit
from bikeid.ident.effect_library import LIBRARY
from bikeid.ident.effect_selection import select_effects, selection_frequencies
from bikeid.ident.experiment_model import ExperimentModel
from bikeid.sim.effect_registry import effect

__all__ = ["evaluate_json", "fit_effect_set", "fit_model", "model_from_json"]


def model_from_json(path: str | Path) -> tuple[ExperimentModel, dict]:
    """Read a model file written by ``bikeid measured fit``.

    Parameters
    ----------
    path : str or Path
        The JSON file.

    Returns
    -------
    model : ExperimentModel
        The nominal experiment with the file's effects.
    obj : dict
        The whole file.  ValueError when it cannot be read or lacks ``effects``.
    """
    try:
        obj = json.loads(Path(path).read_text())
        return ExperimentModel(effects=dict(obj["effects"])), obj
    except (OSError, json.JSONDecodeError, KeyError, TypeError) as exc:
        raise ValueError(f"cannot read model {path}: {exc}") from None


def fit_model(
    windows: list[Window],
    max_effects: int = 3,
    plant: str = "nonlinear",
    stability: int = 0,
    weave_weight: float | str = "auto",
) -> dict:
    """Select effects on ``windows`` and return the model object ``measured fit`` writes.

    Parameters
    ----------
    windows : list of Window
        The fit decays.
    max_effects : int, optional
        At most this many effects (:func:`bikeid.ident.effect_selection.select_effects`).
    plant : str, optional
        ``"nonlinear"`` (defect-corrected nonlinear Whipple plant) or ``"linear"``.
    stability : int, optional
        With N > 0, also the selection frequency of each name over N random 75 % subsamples
        (:func:`bikeid.ident.effect_selection.selection_frequencies`).
    weave_weight : float or "auto", optional
        Weight of the measured weave eigenvalues in every fit.

    Returns
    -------
    dict
        Effects (registry units), fit speeds [m/s], files, windows and the identification.
    """
    nl = plant == "nonlinear"
    extra = {}
    if stability:
        freq = selection_frequencies(
            ExperimentModel(), windows, stability, max_effects=max_effects, nonlinear=nl
        )
        extra = {"selection_frequency": freq,
                 "stability": {"resamples": stability, "fraction": 0.75, "seed": 0}}  # fmt: skip
    res = select_effects(
        ExperimentModel(), windows, max_effects=max_effects, nonlinear=nl, weave_weight=weave_weight
    )
    return {
        "bicycle": "steer-by-wire",
        "plant": plant,
        "effects": {e.name: float(e.value) for e in res.effects},
        "fit_speeds": sorted({round(w.speed, 2) for w in windows}),
        "fit_files": sorted({w.file for w in windows}),
        "fit_windows": [{"file": w.file, "start": w.start, "end": w.start + w.n} for w in windows],
        "identification": res.as_dict(),
        **extra,
    }


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
        and :func:`bikeid.ident.discrepancy_diagnostics.evaluate`'s ``files`` and ``summary``
        (NRMSE, dimensionless; weave eigenvalues [1/s]).
    """
    aug = ExperimentModel(effects=dict(model_obj["effects"]))
    plant = model_obj.get("plant", "linear")
    ev = evaluate(ExperimentModel(), aug, windows, nonlinear=plant == "nonlinear")
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
        "verdict": ident.get("verdict"),
        "effects": effects,
        "fit_speeds": model_obj.get("fit_speeds"),
        **ev,
    }


def fit_effect_set(windows: list[Window], names: list[str], nonlinear: bool = True) -> FitResult:
    """Fit a fixed set of effects jointly on all ``windows`` (no selection).

    Parameters
    ----------
    windows : list of Window
        The decays; their defect correction is reset and re-attached (left at the fit).
    names : list of str
        Registry names; each starts one library scale from absent (1 from absent for an
        effect outside the library).
    nonlinear : bool, optional
        Nonlinear plant by defect correction (default) or the linear model.

    Returns
    -------
    FitResult
        :func:`bikeid.ident.effect_fit.joint_fit` from the nominal model.
    """
    start = {n: LIBRARY[n].absent + LIBRARY[n].scale if n in LIBRARY else effect(n).absent + 1.0
             for n in names}  # fmt: skip
    for w in windows:  # start from the nominal's defect correction
        w.correction = None
    return joint_fit(ExperimentModel(), windows, names, start, nonlinear)
