"""The measured-data closure: fit the Whipple model to free decays, trace the residual to an
effect the model lacks, add it, and report the error before and after.

Front door:

- :func:`select_effects`: greedy forward selection of effects from the library, with
  significance and out-of-sample checks, ending in a named set or ``unexplained``.
- :class:`AcceptanceRule`: when an effect is accepted (significance level and its
  multiple-comparison correction, fit and held-out gains, the ``unexplained`` rule, the
  stated bicycle's uncertainty), one value with its defaults stated once.
- :func:`fit_model`: the whole pipeline on decay windows (nominal calibration, selection,
  joint fit), returning a :class:`FittedModel`-like record that saves to JSON.
- :func:`evaluate`: before/after errors of a model on held-out decays.
- :func:`decays_from_logs`: the free-decay windows of anyone's logs (the one loader,
  :func:`bikeid.dataset.logs.load_runs`, with every check) and their nominal experiment.
- :func:`discover`: the terms of the roll and steer equations the decays support, from a
  dictionary generated from the effect laws' language (:mod:`.discovery`).
- :class:`ExperimentModel`: the plant of the experiment (linear or nonlinear Whipple
  bicycle, its controller or the replayed torque, effects of
  :mod:`bikeid.sim.effect_registry`).

Modules: :mod:`.log_decays`, :mod:`.experiment_model`, :mod:`.library` (the candidate
effects and their fit
settings), :mod:`.acceptance` (the acceptance rule and its test), :mod:`.fit` (fitting
effect values, standard errors), :mod:`.nominal_uncertainty`
(the stated bicycle's uncertainty and its calibration), :mod:`.selection`,
:mod:`.diagnostics` (equation error, residual spectra, push asymmetry, ``evaluate``),
:mod:`.weave` (the measured weave eigenvalue of decays), :mod:`.kstep` (the k-step
prediction error of logs without the controller law, ``kstep_error``),
:mod:`.instrument_floor` (the cost the instruments alone leave), :mod:`.synthetic_decays` (decays of
a known model, for tests), :mod:`.before_after` (a before/after error ratio with its interval,
paired test and verdict) and :mod:`.pipeline` (fit, save, load, evaluate).
"""

from bikeid.ident.effects.acceptance import AcceptanceRule
from bikeid.ident.effects.diagnostics import evaluate
from bikeid.ident.effects.discovery import discover
from bikeid.ident.effects.experiment_model import ExperimentModel
from bikeid.ident.effects.log_decays import ControlLaw, decays_from_logs
from bikeid.ident.effects.pipeline import fit_model
from bikeid.ident.effects.selection import select_effects

__all__ = [
    "AcceptanceRule",
    "ControlLaw",
    "ExperimentModel",
    "decays_from_logs",
    "discover",
    "evaluate",
    "fit_model",
    "select_effects",
]
