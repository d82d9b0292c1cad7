"""What every interval function checks before it gives intervals (the Python API's defaults).

``bikeid identify`` withholds intervals where they are known not to hold; the interval
functions of :mod:`ident.uncertainty` refuse the same by default, each refusal opted out of
by name (a keyword):

- ``refuse_boundary``: a fit with a free innovation gain (``pem.fit(noise_model="gain")``)
  that ended on its one-step predictor's stability boundary (:func:`check_predictor_interior`);
- ``refuse_structure``: a model whose attached structure check
  (:func:`bikeid.ident.structure.check_structure`, attached by ``pem.fit`` and
  ``pem.fit_speed_model`` as ``model.structure``) rejects it at the speed asked for (any
  speed, for a model over speed);
- ``refuse_amplitude``: a fit to runs of a nonlinear plant (measured, or simulated by the
  Whipple model) whose RMS roll angle exceeds :data:`AMPLITUDE_LIMIT_DEG`: the estimate is
  then the best linear model *at that amplitude*, biased from the upright linearization by
  more than the residual tests can see;
- ``refuse_output_error``: an output-error fit (``noise_model="none"``) of an open-loop
  unstable plant, the identified one or the nominal one (the fit's start): output error
  then simulates an unstable plant, which a stable fit cannot follow
  (``model.unstable_plant`` names why).

A model without an attached structure check gets its intervals with a note
(:data:`NO_STRUCTURE_NOTE`).  A refusal raises :class:`WithheldIntervals`, whose
``reason`` and ``remedy`` callers print; every remedy is measured: following it gives
intervals that cover at their stated rate (docs/uncertainty.md, "A predictor stable by
construction", ``benchmarks/bench_predictor.py``).  A refusal with no measured remedy gives
none.
"""

from __future__ import annotations

import numpy as np

from bikeid.ident.predictor import discretize, output_matrix
from bikeid.sim.errors import UntrustworthyResult

__all__ = [
    "AMPLITUDE_LIMIT_DEG",
    "NO_STRUCTURE_NOTE",
    "PREDICTOR_BOUNDARY_TOL",
    "CLI_REMEDIES",
    "REMEDY_KALMAN",
    "WithheldIntervals",
    "check_predictor_interior",
    "check_trust",
    "predictor_radius",
]

#: A fixed-speed PEM fit whose one-step predictor Ad - K C has spectral radius above
#: 1 - PREDICTOR_BOUNDARY_TOL ended on the stability boundary the fit keeps its predictor
#: inside (:func:`predictor_radius`).  Measured on the default path (benchmark, nonlinear
#: plant, roll PID, 5 m/s, 1 N m dither, 20 seeds each of 30, 60, 90, 120 and 300 s, and
#: the output-error and 3 N m variants): the 73 fits stopped there have 1 - radius of at
#: most 8.3e-7, the 107 others 6.6e-4 or more (the slowest plant pole, exp(-0.32 dt) at
#: K = 0, is 1 - 3.2e-3); 1e-4 lies between the two groups (docs/uncertainty.md).
PREDICTOR_BOUNDARY_TOL = 1e-4

#: The remedy of a boundary fit and of an output-error fit of an unstable plant: the Kalman
#: gain, whose predictor is stable by construction.  Measured on the README example
#: (benchmarks/bench_predictor.py, docs/uncertainty.md).
REMEDY_KALMAN = (
    "refit with pem.fit(runs, noise_model='kalman'), the default (a predictor stable by "
    "construction)"
)
#: The same remedies as the command line states them (``bikeid identify``).
CLI_REMEDIES = {
    REMEDY_KALMAN: "refit with --noise-model kalman, the default (a predictor stable by "
                   "construction)",
}  # fmt: skip
#: The note beside intervals of a model that carries no structure check.
NO_STRUCTURE_NOTE = (
    "no structure check is attached to this model, so nothing says the data do not reject "
    "its structure (ident.structure.check_structure; pem.fit attaches one)"
)


#: Largest RMS roll angle [deg] of nonlinear-plant runs whose intervals are given.  Evidence
#: (benchmarks/bench_bias_amplitude.py, docs/uncertainty.md "Bias against excitation
#: amplitude"): the weave real-part bias at 4.2 m/s grows as the square of the amplitude,
#: -0.057 1/s at 3.49 deg RMS (25 printed standard errors of a 50 s fit), -0.014 at 1.74 deg
#: (14), -0.002 to -0.003 at 0.87 deg (1.3-1.9), within one standard error at 0.44 deg.
#: Above 0.5 deg it can exceed a standard error, more so for longer or pooled records,
#: whose standard errors are smaller.
AMPLITUDE_LIMIT_DEG = 0.5


class WithheldIntervals(UntrustworthyResult):
    """Intervals refused by :func:`check_trust`.

    Attributes
    ----------
    reason : str
        Why, in one line.
    remedy : str
        What, followed, gives intervals that hold (measured), or "" when nothing measured
        does.
    check : str
        The keyword that opts out of this refusal (e.g. ``"refuse_boundary"``).
    """

    def __init__(self, reason: str, remedy: str, check: str):
        self.reason, self.remedy, self.check = reason, remedy, check
        fix = f"; {remedy}" if remedy else ""
        super().__init__(f"{reason}{fix} (to get the intervals anyway: {check}=False)")

    def cli_message(self) -> str:
        """The reason and the remedy as ``bikeid`` commands state them (no Python keyword).

        Returns
        -------
        str
            ``reason; remedy`` with the remedy of :data:`CLI_REMEDIES` where it has one.
        """
        remedy = CLI_REMEDIES.get(self.remedy, self.remedy)
        return f"{self.reason}; {remedy}" if remedy else self.reason


def predictor_radius(model) -> float | None:
    """Spectral radius of the one-step predictor Ad - K C of a fixed-speed PEM fit.

    A prediction-error fit keeps Ad - K C stable (radius < 1: a trial step beyond is
    rejected).  A fit that needs a radius at 1 to lower its cost further stops *on* that
    boundary: its estimate is not a stationary point of the cost, so the covariance from
    the cost's curvature, and every interval built on it, describes nothing.  This happens
    when the free innovation gain K tries to model noise the loop does not have (the
    default testbed loop has no process noise: its optimal K is 0) and the record is short.

    Parameters
    ----------
    model : ident.pem.CanonicalModel
        A fixed-speed fit with ``theta``, ``K`` (4 x L), ``dt`` [s] and ``outputs``.

    Returns
    -------
    float or None
        max |eig(Ad - K C)| (dimensionless, per sample); None for a model whose theta and
        K were not fitted together by a prediction-error fit (no innovation gain, or
        ``nfev`` 0: a speed-parameterized model, or one taken from it at a speed by
        ``SpeedCanonicalModel.at``, whose K belongs to another theta), and for a fit whose
        K is the Kalman gain of its noise covariances (``noise_model == "kalman"``: stable
        for every parameter value, so the fit has no boundary to stop on).
    """
    K, theta = getattr(model, "K", None), getattr(model, "theta", None)
    if K is None or theta is None or callable(theta) or not hasattr(model, "outputs"):
        return None
    if getattr(model, "noise_model", "gain") == "kalman":  # K follows theta: no boundary
        return None
    if not getattr(model, "nfev", 0) > 0:  # theta and K not fitted together
        return None
    C, _ = output_matrix(model.outputs)
    Ad, _ = discretize(np.asarray(theta, float), float(model.dt))
    return float(np.max(np.abs(np.linalg.eigvals(Ad - np.asarray(K, float) @ C))))


def check_predictor_interior(model) -> float | None:
    """Refuse intervals from a fit that ended on its predictor's stability boundary.

    Parameters
    ----------
    model : ident.pem.CanonicalModel
        A fixed-speed fit (a model without an innovation gain passes unchecked).

    Returns
    -------
    float or None
        The predictor's spectral radius (:func:`predictor_radius`).

    Raises
    ------
    WithheldIntervals
        If the radius exceeds 1 - :data:`PREDICTOR_BOUNDARY_TOL` (remedy
        :data:`REMEDY_KALMAN`).
    """
    rho = predictor_radius(model)
    if rho is not None and rho > 1.0 - PREDICTOR_BOUNDARY_TOL:
        raise WithheldIntervals(
            f"the fit ended on the stability boundary of its one-step predictor (spectral "
            f"radius of Ad - K C = 1 - {max(1.0 - rho, 0.0):.1e}, above 1 - "
            f"{PREDICTOR_BOUNDARY_TOL:g}): its covariance is not the curvature of an optimum "
            "and its intervals miss the truth",
            REMEDY_KALMAN,
            "refuse_boundary",
        )
    return rho


def _rejected(structure, speed: float | None) -> bool:
    """Whether an attached structure check rejects the model at ``speed`` (None: anywhere)."""
    if structure.speed_model_rejected:
        return True
    withheld = set(getattr(structure, "withheld_speeds", ()))
    return bool(withheld) if speed is None else round(float(speed), 6) in withheld


def check_trust(
    model,
    speed: float | None = None,
    *,
    refuse_boundary: bool = True,
    refuse_structure: bool = True,
    refuse_output_error: bool = True,
    refuse_amplitude: bool = True,
) -> tuple[float | None, tuple[str, ...]]:
    """Refuse intervals where ``bikeid identify`` withholds them; else the notes to give.

    Parameters
    ----------
    model : CanonicalModel or SpeedCanonicalModel
        The fitted model (its ``structure``, ``noise_model`` and ``unstable_plant`` are
        read when present).
    speed : float, optional
        The speed [m/s] the intervals are for (None: the model over all its speeds, e.g.
        its critical speeds).
    refuse_boundary, refuse_structure, refuse_output_error, refuse_amplitude : bool, optional
        Each refusal (module docstring); False gives the intervals with a note instead.

    Returns
    -------
    radius : float or None
        The one-step predictor's spectral radius (:func:`predictor_radius`).
    notes : tuple of str
        What the intervals come with (no structure check; a refusal opted out of).

    Raises
    ------
    WithheldIntervals
        On a refusal that is not opted out of.
    """
    notes = []
    why = getattr(model, "unstable_plant", "")
    if why:
        reason = (
            f"an output-error fit of an open-loop unstable plant ({why}): output error "
            "simulates the plant, and a stable fit of an unstable one is biased"
        )
        if refuse_output_error:
            raise WithheldIntervals(reason, REMEDY_KALMAN, "refuse_output_error")
        notes.append(reason)
    if refuse_boundary:
        rho = check_predictor_interior(model)
    else:
        rho = predictor_radius(model)
        if rho is not None and rho > 1.0 - PREDICTOR_BOUNDARY_TOL:
            notes.append("the fit ended on its one-step predictor's stability boundary")
    structure = getattr(model, "structure", None)
    if structure is None:
        notes.append(NO_STRUCTURE_NOTE)
    elif _rejected(structure, speed):
        reason = ("the data reject the model structure (ident.structure: "
                  f"{structure.causes() or 'the model over speed'}), so its bias can exceed "
                  "its standard errors")  # fmt: skip
        if refuse_structure:
            raise WithheldIntervals(reason, "", "refuse_structure")
        notes.append(reason)
    rms = float(getattr(model, "roll_rms_deg", float("nan")))
    if rms > AMPLITUDE_LIMIT_DEG:
        reason = (f"the runs' RMS roll angle, {rms:.2g} deg, exceeds {AMPLITUDE_LIMIT_DEG:g} "
                  "deg: on a nonlinear plant the estimate is the linear model at that "
                  "amplitude, biased from the upright linearization by more than the "
                  "intervals show")  # fmt: skip
        if refuse_amplitude:
            raise WithheldIntervals(reason, "", "refuse_amplitude")
        notes.append(reason)
    return rho, tuple(notes)
