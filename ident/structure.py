"""Do the data reject the model structure?  The check that runs before intervals are printed.

A confidence interval from a prediction-error fit (:mod:`bikeid.ident.uncertainty`) describes
the estimate's scatter *if the model set contains the system*.  When it does not, the
estimate converges to the best model of the set, whose distance from the truth (a bias) does
not shrink with more data while the standard errors do: with many long runs a "95 %" interval
then excludes the truth by tens of standard errors.  :func:`check_structure` tests, per speed,
whether the data reject the structure the intervals assume, with the residual tests of
:mod:`bikeid.ident.validate` (Ljung, *System Identification*, 2nd ed., sec. 16.6):

- **Residual-input independence at lags 1..M** (:func:`~bikeid.ident.validate.independence_test`
  through :func:`~bikeid.ident.validate.resid`, input T_delta).  If the model set holds the
  system and its noise model, the one-step prediction errors are the innovations, which are
  independent of everything measured before them, in closed loop as well: the input at
  t - k (k >= 1) is made by the controller from outputs up to t - k.  So correlation of the
  residual with the input *leading* it is evidence against the structure (missing dynamics, a
  delay, a nonlinearity the linear model averages differently over the record, a noise model
  held fixed at another model's value).  Lags <= 0 are not tested: in closed loop the input
  at t and later is computed from the output at t, so it correlates with e(t) through the
  feedback whatever the model (lag 0 included: the controller samples y(t) and applies u(t)).
- **Whiteness of each residual at lags 1..M** (:func:`~bikeid.ident.validate.portmanteau`),
  only when the noise model is part of the structure (a fit with a non-zero innovation gain
  K).  An output-error fit (K = 0) leaves the disturbance's response in its residual, coloured
  by construction, so its whiteness says nothing about the fit; its independence test still
  applies (in closed loop a coloured disturbance that the fit ignores correlates with past
  inputs and biases the plant estimate: Forssell & Ljung 1999, the direct approach).
  Whiteness is *advisory*: it is reported, and named in the note, but does not withhold
  intervals.  It tests the noise model, whose error biases the plant estimate in closed loop
  only in proportion to the disturbance's share of the input (Forssell & Ljung 1999), and it
  rejects fits whose intervals are right: on the linear plant of the coverage study
  (``bikeid coverage`` settings: 5 m/s, 3 N m dither, 0.5 N m unlogged torque held like the
  dither, 50 s), seeds 0-59, whiteness of phi or delta rejects 5 fits at the per-test level
  and all 20 of their eigenvalue real-part intervals contain the truth; independence rejects
  none of the 60.
- **Speed-parameterized model against its per-speed fits** (with ``speed_model``): the model
  over speed is the per-speed canonical model restricted to theta(v) = S(v) p, so at each
  fitted speed the difference d = theta_v - S(v) p between the free fit and the restricted
  one is tested, W = d' P_v^-1 d against chi^2(10) (a Hausman test; P_v the free fit's
  covariance, larger than the covariance of d when the restricted fit is efficient, so W is
  conservative).  It catches a model over speed whose restriction the data reject even where
  its residuals look clean.  It is skipped at a speed whose free fit ended on its one-step
  predictor's stability boundary (:func:`~bikeid.ident.uncertainty.predictor_radius` above
  1 - :data:`~bikeid.ident.uncertainty.PREDICTOR_BOUNDARY_TOL`): that covariance describes no
  optimum, so it is no yardstick (on two 20 s linear-plant runs at 4 and 6 m/s, both such
  fits, it rejected the model over speed at p = 2.6e-5 while its v_w and v_c intervals
  covered the truth).

The withholding tests (independence, and the comparison over speed) at all speeds form one
family: each is run at ``level / (number of them)`` (Bonferroni), so on data the structure
fits the chance that any withholds intervals is at most ``level`` (default
:data:`STRUCTURE_LEVEL`, 1 %); the advisory whiteness tests are judged at the same per-test
level.

What the check does not catch (measured on the README tour's sweep, 29 speeds x 5 runs of
50 s, and the same sweep on the exact linear plant): the bias of a *fixed-speed* fit to the
nonlinear plant at its excitation amplitude.  There the estimate is the best linear
approximation of the plant at that amplitude, whose residual is uncorrelated with past
inputs: at 3-4 m/s (1.5 deg roll chirp) the weave real part is 21-33 standard errors off
while every independence test passes (p >= 0.14, per-test level 8.6e-5).  Only data at a
second amplitude reveal it (docs/uncertainty.md, "Bias against excitation amplitude"); the
printed note says so.

What it catches there: the speed-parameterized model of that sweep (v_c = 6.170 m/s, its
interval [6.169, 6.171] against the linearized 6.024) is rejected: independence alone at 28
of its 29 speeds (p below 6.9e-5), so v_w, v_c and every eigenvalue interval are withheld.
Its main cause then was not the nonlinearity: the same sweep on the exact linear plant gave
v_c = 6.063 m/s with eigenvalue errors up to 94 standard errors (rejected there too,
independence at 22 speeds), because the model over speed held each speed's innovation
gain K at its per-speed fit's value, 14 of which ended on the predictor's stability
boundary.  Since the joint fit takes each speed's K as the Kalman gain of the joint model
(:func:`bikeid.ident.pem.fit_speed_model`), the linear-plant sweep gives v_w 4.29262
(+1.4 SE), v_c 6.02405 (-0.4 SE) and passes this check with intervals that contain the
truth; the nonlinear sweep gives v_w 4.2832, v_c 6.0196 and is still rejected (at 12
speeds in 1-7 m/s), its intervals withheld.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.stats import chi2

from bikeid.dataset.run import Run
from bikeid.ident.canonical import speed_map
from bikeid.ident.uncertainty import PREDICTOR_BOUNDARY_TOL, predictor_radius
from bikeid.ident.validate import resid
from bikeid.sim.errors import InputError
from bikeid.sim.textformats import to_jsonable

__all__ = ["MAX_LAG", "STRUCTURE_LEVEL", "StructureCheck", "check_structure"]

#: Family-wise level of the structure check: on data the model structure fits, the chance
#: that any of its withholding tests (all speeds, outputs and kinds) rejects is at most this.
STRUCTURE_LEVEL = 0.01
#: Largest lag [samples] of the residual tests (MATLAB ``resid``'s default, 25).
MAX_LAG = 25

#: The one-line cause printed when the structure is rejected.  It names no fix: none of
#: the candidates (shorter or gentler records, a per-speed fit, longer records) has been
#: measured to give intervals that cover when followed, and a remedy is printed only when it
#: has (docs/uncertainty.md, "Remedies that are printed").
REJECTED_NOTE = (
    "the data reject the model structure (residual tests at family level {level:g}, "
    "ident.structure): {causes}; the estimates' bias can exceed their standard errors, so no "
    "95 % intervals are given for {where} (the estimates stand)"
)
#: The one fix printed for a rejected model over speed (``bikeid identify``): the per-speed
#: fits these data allow, whose intervals are then checked speed by speed (structure,
#: amplitude), so following it cannot print an unchecked interval.
FIX_PER_SPEED = ("fit each speed alone (per-speed PEM: bikeid identify without "
                 "--speed-parameterized), whose intervals are checked speed by speed")  # fmt: skip
#: The fix where a per-speed fit ended on its predictor's stability boundary (a free
#: innovation gain): the measured remedy of :data:`bikeid.ident.trust.REMEDY_KALMAN`.
FIX_LONGER = ("refit with --noise-model kalman, the default (bikeid identify; in Python "
              "pem.fit(runs, noise_model='kalman')): a Kalman gain, whose predictor is stable "
              "by construction")  # fmt: skip
#: What a passed check does not show, printed beside the intervals.
PASSED_NOTE = (
    "the residual tests do not reject the model structure (family level {level:g}); they "
    "cannot see the bias of a linear fit to a nonlinear plant at its excitation amplitude: "
    "identify again at half the amplitude to check it"
)


@dataclass(frozen=True)
class StructureCheck:
    """The verdict of :func:`check_structure`.

    Attributes
    ----------
    level : float
        Family-wise level of the check (e.g. 0.01).
    per_test_level : float
        Level of each test, ``level / n_tests`` (Bonferroni).
    n_tests : int
        Number of withholding tests (independence, speed model) in the family.
    tests : dict of float to list of dict
        Per speed [m/s] every test: ``kind`` (``"independence"``, ``"whiteness"``,
        ``"speed_model"``, or ``"predictor"``: the residuals could not be formed, e.g. an
        unstable one-step predictor, p = 0), ``output`` (or None), ``statistic``, ``dof``,
        ``p_value``,
        ``rejected`` (p below the per-test level) and ``advisory`` (True for whiteness:
        reported, never withholding).
    rejected_speeds : tuple of float
        Speeds [m/s] at which some withholding test rejects.
    speed_model_rejected : bool
        Whether a model over speed is rejected at any speed: one parameter vector describes
        every speed, so a rejection anywhere rejects it, with its v_w, v_c and its
        eigenvalues at every speed.
    withheld_speeds : tuple of float
        Speeds [m/s] whose eigenvalue intervals are not to be given: every tested speed for
        a rejected model over speed, else :attr:`rejected_speeds`.
    """

    level: float
    per_test_level: float
    n_tests: int
    tests: dict[float, list[dict[str, Any]]] = field(default_factory=dict)
    rejected_speeds: tuple[float, ...] = ()
    speed_model_rejected: bool = False
    withheld_speeds: tuple[float, ...] = ()

    @property
    def passed(self) -> bool:
        """True when no test rejects (the data do not reject the structure)."""
        return not self.rejected_speeds

    def causes(self, speed: float | None = None) -> str:
        """The rejected tests in words, e.g. ``residuals correlate with the past input``.

        Parameters
        ----------
        speed : float, optional
            One speed [m/s]; None: every rejected speed.

        Returns
        -------
        str
            The kinds of rejected tests, each with its smallest p-value and the outputs.
        """
        words = {
            "independence": "residuals correlate with the past input",
            "whiteness": "residuals are not white",
            "speed_model": "the model over speed differs from the per-speed fits",
            "predictor": "its one-step predictor is unstable on the runs",
        }
        speeds = tuple(self.tests) if speed is None else (round(float(speed), 6),)
        rows = [t for v in speeds for t in self.tests.get(v, []) if t["rejected"]]
        parts = []
        for kind, text in words.items():
            hit = [t for t in rows if t["kind"] == kind]
            if hit:
                outs = sorted({t["output"] for t in hit if t["output"]})
                p = min(t["p_value"] for t in hit)
                parts.append(f"{text}" + (f" ({', '.join(outs)})" if outs else "")
                             + f", p = {p:.2g}")  # fmt: skip
        return "; ".join(parts)

    def note(self) -> str:
        """The one-line note printed with the intervals (cause and fix, or what a pass means).

        Returns
        -------
        str
            :data:`REJECTED_NOTE` filled in, or :data:`PASSED_NOTE`.
        """
        if self.passed:
            advisory = self.causes()
            if not advisory:
                return PASSED_NOTE.format(level=self.level)
            at = [v for v, r in self.tests.items() if any(t["rejected"] for t in r)]
            return PASSED_NOTE.format(level=self.level) + (
                f" (advisory: {advisory} at {_speeds_text(at)}: the noise "
                "model misses something; in closed loop that biases the estimates in "
                "proportion to the disturbance's share of the input)"
            )
        where = _speeds_text(self.withheld_speeds)
        if self.speed_model_rejected:
            where = (f"the model over speed (rejected at {_speeds_text(self.rejected_speeds)}): "
                     "v_w, v_c and its eigenvalues at every speed")  # fmt: skip
        return REJECTED_NOTE.format(level=self.level, causes=self.causes(), where=where)

    def to_json(self) -> dict[str, Any]:
        """The verdict as plain JSON types.

        Returns
        -------
        dict
            ``passed``, ``level``, ``per_test_level``, ``n_tests``, ``rejected_speeds``
            [m/s], ``speed_model_rejected``, ``note`` and ``tests`` (keyed by speed as text).
        """
        return to_jsonable({
            "passed": self.passed, "level": self.level, "per_test_level": self.per_test_level,
            "n_tests": self.n_tests, "rejected_speeds": list(self.rejected_speeds),
            "speed_model_rejected": self.speed_model_rejected,
            "withheld_speeds": list(self.withheld_speeds), "note": self.note(),
            "tests": {f"{v:g}": rows for v, rows in self.tests.items()},
        })  # fmt: skip


def _speeds_text(speeds: Sequence[float]) -> str:
    """``5, 6 m/s``, or for more than four ``29 speeds in 1-15 m/s``."""
    if len(speeds) <= 4:
        return ", ".join(f"{v:g}" for v in speeds) + " m/s"
    return f"{len(speeds)} speeds in {min(speeds):g}-{max(speeds):g} m/s"


def _speed_model_test(speed_model, v: float) -> dict[str, Any] | None:
    """Hausman-type comparison of a per-speed fit with the model over speed at ``v``."""
    per = getattr(speed_model, "per_speed", {}).get(v)
    if per is None:
        return None
    rho = predictor_radius(per)
    if rho is not None and rho > 1.0 - PREDICTOR_BOUNDARY_TOL:  # its covariance is no yardstick
        return None
    d = np.asarray(per.theta, float) - speed_map(v) @ np.asarray(speed_model.params, float)
    cov = np.asarray(per.covariance, float)
    w, V = np.linalg.eigh(0.5 * (cov + cov.T))
    keep = w > 1e-12 * max(w.max(), 1e-300)
    z = V[:, keep].T @ d
    stat = float(np.sum(z**2 / w[keep]))
    dof = int(keep.sum())
    return {"kind": "speed_model", "output": None, "statistic": stat, "dof": dof,
            "p_value": float(chi2.sf(stat, dof))}  # fmt: skip


def check_structure(
    runs: Sequence[Run],
    models: Mapping[float, Any],
    *,
    speed_model=None,
    level: float = STRUCTURE_LEVEL,
    max_lag: int = MAX_LAG,
) -> StructureCheck:
    """Test whether the runs reject the structure of the models the intervals come from.

    Parameters
    ----------
    runs : sequence of Run
        The runs the models were fitted to (closed or open loop), grouped by ``run.speed``
        rounded to 1e-6 m/s.
    models : mapping of float to CanonicalModel
        Per speed [m/s] the model whose intervals would be printed (a fixed-speed fit, or a
        model over speed taken at that speed), with its innovation gain ``K`` (all zero for
        an output-error fit: no whiteness test then).
    speed_model : SpeedCanonicalModel, optional
        Given when ``models`` are one model over speed (speed-parameterized PEM, joint
        grey-box): a rejection at any speed then withholds every speed's intervals; with
        per-speed fits (``per_speed``) it adds their comparison at each speed (module
        docstring).
    level : float, optional
        Family-wise level, in (0, 1) (default :data:`STRUCTURE_LEVEL`).
    max_lag : int, optional
        Largest lag M of the residual tests [samples], >= 1.

    Returns
    -------
    StructureCheck
        Every test's statistic and p-value, the speeds at which the structure is rejected.

    Raises
    ------
    InputError
        If ``level`` or ``max_lag`` is out of range, or a speed has no runs.
    """
    if not (isinstance(level, (int, float)) and 0 < level < 1):
        raise InputError(f"level={level!r}: need a family-wise level strictly between 0 and 1")
    if int(max_lag) != max_lag or max_lag < 1:
        raise InputError(f"max_lag={max_lag!r}: need a whole number of samples >= 1")
    tests: dict[float, list[dict[str, Any]]] = {}
    for v, model in models.items():
        v = round(float(v), 6)
        at_v = [r for r in runs if round(r.speed, 6) == v]
        if not at_v:
            raise InputError(f"no runs at {v:g} m/s for its model; pass the fitted runs")
        try:
            with np.errstate(over="ignore"):  # a diverging predictor is reported, not warned
                rr = resid(at_v, model, max_lag=int(max_lag))
        except ValueError as exc:  # e.g. an unstable one-step predictor: nothing to test
            rows = [{"kind": "predictor", "output": None, "statistic": float("inf"),
                     "dof": 0, "p_value": 0.0, "message": str(exc).splitlines()[0]}]  # fmt: skip
        else:
            rows = [{"kind": "independence", "output": o, **rr.independence_test[o]}
                    for o in rr.independence_test]  # fmt: skip
            if np.any(np.asarray(getattr(model, "K", 0.0), float)):  # a noise model is fitted
                rows += [{"kind": "whiteness", "output": o, **rr.whiteness_test[o]}
                         for o in rr.whiteness_test]  # fmt: skip
        if speed_model is not None:
            row = _speed_model_test(speed_model, v)
            rows += [row] if row is not None else []
        tests[v] = [{k: x for k, x in r.items() if k != "passed"} for r in rows]
        for r in tests[v]:
            r["advisory"] = r["kind"] == "whiteness"
    n = sum(not r["advisory"] for rows in tests.values() for r in rows)
    each = level / max(n, 1)
    rejected = []
    for v, rows in tests.items():
        for r in rows:
            r["rejected"] = bool(r["p_value"] < each)
        if any(r["rejected"] and not r["advisory"] for r in rows):
            rejected.append(v)
    one_model = bool(speed_model is not None and rejected)
    return StructureCheck(
        level=float(level), per_test_level=float(each), n_tests=n, tests=tests,
        rejected_speeds=tuple(sorted(rejected)), speed_model_rejected=one_model,
        withheld_speeds=tuple(sorted(tests) if one_model else sorted(rejected)),
    )  # fmt: skip
