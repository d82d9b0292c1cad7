"""Stage 4, identification: Moore & Hubbard direct least squares, Chen & Dao canonical PEM,
validation, and the effect-library analysis of measured data.

The papers' estimators (on any :class:`~bikeid.dataset.run.Run`):

- :mod:`~bikeid.ident.signals`: mean removal, zero-phase Butterworth, differentiation, and
  the sampling contract every estimator checks (``check_sampling``).
- :mod:`~bikeid.ident.direct`: Moore & Hubbard's direct method, ``identify`` (least
  squares / IV on the rows of M q'' + v C1 q' + (g K0 + v^2 K2) q = T + H F), ``vaf_moore``,
  ``vaf_variance``.
- :mod:`~bikeid.ident.tailored_iv`: instrumental variables built from a fitted controller.
- :mod:`~bikeid.ident.canonical`: Chen & Dao's canonical form and its speed
  parameterization.
- :mod:`~bikeid.ident.subspace`: PBSID (closed-loop safe) and PO-MOESP (open loop) start
  values.
- :mod:`~bikeid.ident.pem`: ``fit`` (one speed) and ``fit_speed_model``
  (speed-parameterized); models give ``control.StateSpace`` in bikeid's state order.
- :mod:`~bikeid.ident.methods`: the identification methods as one table (``METHODS``: name
  -> fit function, settings with named defaults, model classes, model-file kinds).
- :mod:`~bikeid.ident.linear_model`: the one base of every linear model class
  (``state_space(speed, dt)`` with named states, inputs and outputs in bikeid's order,
  ``eigenvalues(speed)`` in one order with mode names, and over speed
  ``eigenvalues_vs_speed``, ``critical_speeds``).
- :mod:`~bikeid.ident.predictor`: the innovations predictor, Levenberg-Marquardt minimizer
  and sandwich covariance shared by ``pem`` and ``greybox``.
- :mod:`~bikeid.ident.innovation_gain`: the innovation gain as the Kalman gain of fitted
  noise covariances (a one-step predictor stable by construction; ``pem.fit``'s default).
- :mod:`~bikeid.ident.greybox`: grey-box PEM of entries of M, C1, K0, K2 (any free set, one
  fit over all speeds), with standard errors and the conditioning of the free set.
- :mod:`~bikeid.ident.validate`: ``compare`` (simulation and k-step prediction),
  ``resid`` (whiteness, input cross-correlation), ``goodness_of_fit``, poles, zeros.
- :mod:`~bikeid.ident.validation_report`: ``validate_model`` (fits, residual tests and a
  nonparametric frequency response against a model, ``bikeid validate``) and
  ``validate_decays`` (the same on measured decays, ``bikeid measured evaluate``).
- :mod:`~bikeid.ident.model_file`: ``save_model`` / ``load_model``, the one JSON file
  format of every identified model (parameters bit for bit, covariance, provenance).
- :mod:`~bikeid.ident.uncertainty`: profile and delta-method intervals on eigenvalues, v_w,
  v_c, Bode.
- :mod:`~bikeid.ident.trust`: what the interval functions refuse by default (boundary fit,
  rejected structure, output error of an unstable plant, roll amplitude), each by keyword.
- :mod:`~bikeid.ident.structure`: ``check_structure``, whether the data reject the model
  structure the intervals assume (residual tests valid in closed loop), run before
  ``bikeid identify`` prints intervals.
- :mod:`~bikeid.ident.informativity`: whether data can determine a model (the steer
  torque's feedback share and the order of excitation of the rest); ``check`` refuses.

The measured-data analysis, :mod:`bikeid.ident.effects` (one subpackage with a small front
door: the experiment model, the effect library, the fit, the nominal calibration, the
selection and the before/after evaluation).
"""

from bikeid.ident.direct import DirectResult, identify, vaf_moore, vaf_variance
from bikeid.ident.model_file import load_model, read_model_file, save_model
from bikeid.ident.pem import CanonicalModel, SpeedCanonicalModel, fit, fit_speed_model

__all__ = [
    "CanonicalModel",
    "DirectResult",
    "SpeedCanonicalModel",
    "fit",
    "fit_speed_model",
    "identify",
    "load_model",
    "read_model_file",
    "save_model",
    "vaf_moore",
    "vaf_variance",
]
