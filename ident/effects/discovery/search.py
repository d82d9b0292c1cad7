"""The discovery search: which terms of the dictionary the decays support, with coefficients.

:func:`discover` is a forward selection over the dictionary
(:func:`bikeid.ident.effects.discovery.dictionary.dictionary`, 43 terms the closure can fit)
on the closure error, the one function given as ``error`` (default :func:`window_error`,
the window output error of the effect fits):

1. The decays are split as the effect selection splits them: every even decay fits, every
   odd one is held out.
2. Each round fits every remaining term with the terms kept so far, by least squares of the
   error on the fitting half.  A term's coefficient has a standard error clustered by decay
   (:func:`bikeid.ident.effects.fit.effect_std`; each decay lies within one log, so the
   clusters are decays within logs), t = |coefficient| / standard error, and a two-sided
   p-value against Student's t with G - 1 degrees of freedom for G decays.
3. A term passes when its p-value is at most ``alpha / m``, m the tests of all rounds
   (Bonferroni over every test the search can make: K + (K - 1) + ... for K terms and
   ``max_terms`` rounds, as :class:`~bikeid.ident.effects.acceptance.AcceptanceRule`
   counts them), when it lowers the fitting half's cost by the rule's ``min_gain`` and the
   held-out half's by its held-out gain.  Of the passing terms (one parameter more each) the
   one of least cost over all decays (fitting half at its fit, held-out half at the same
   coefficients) is kept.  On decays with no missing term, the probability that any term
   is kept (the familywise error rate) is then at most ``alpha`` under the test's
   assumptions (the model right, the decays independent), whatever the dependence between
   the tests.  With the stated bicycle's uncertainty (the rule's ``nominal_uncertainty``,
   as ``measured fit`` takes it; by default) the model is right only up to that
   uncertainty: the nominal's offsets (each body's inertia scale, the trail) are
   calibrated within their box on the fitting half first, the terms are screened with the
   offsets held there, and a passing term is kept only if its p-value stays at most
   ``alpha / m`` with the offsets refitted jointly with it, as the final joint fit's are (a
   term that only does what an inertia or trail within its uncertainty would do is then not
   significant).
4. A term the decays cannot tell from the kept one joins its ``indistinguishable`` set:
   among the terms significant at ``alpha`` alone in that round that remove at least half
   as much of the cost, those which, fitted jointly with the kept term on all decays, leave
   the kept term not significant at ``alpha`` (they can stand in for it).  Under the logs'
   controller a term can be a combination of others (in free decays the steer torque is
   K (V - v) phidot, a combination of phidot and v*phidot), and few decays at few speeds
   cannot separate a damping from the same damping growing with v.
5. The kept terms are refitted jointly on all decays (coefficients, standard errors and 95 %
   intervals, t quantile on the clusters' degrees of freedom) and pruned backwards of any
   whose p-value is above ``alpha / m``.
6. Before/after: the nominal (calibrated, with an uncertainty) against the kept terms
   fitted on the fitting half, on the
   held-out half (:func:`bikeid.ident.effects.diagnostics.evaluate`, the ``measured
   evaluate`` figures with the ratio's interval).  Those decays were not used for the
   coefficients of that model but were used to choose the terms: the figure is not out of
   sample.

No regression on differentiated signals enters: the coefficients and their intervals are
those of the closure error.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from scipy import stats
from scipy.optimize import least_squares

from bikeid.dataset.windows import Window
from bikeid.ident.effects.acceptance import AcceptanceRule, t_p_value
from bikeid.ident.effects.discovery.dictionary import Term, declarations, dictionary, registered
from bikeid.ident.effects.experiment_model import ExperimentModel
from bikeid.ident.effects.fit import (
    bounded_std,
    corrected,
    output_residuals,
    trial_residuals,
)
from bikeid.ident.effects.nominal_uncertainty import Calibration
from bikeid.sim.blas import single_threaded_blas

__all__ = ["Discovery", "ErrorFunction", "INTERVAL_LEVEL", "discover", "window_error"]

#: The closure error: per decay, the residual array a model leaves on it (dimensionless).
ErrorFunction = Callable[[ExperimentModel, list[Window]], list[np.ndarray]]
#: Confidence level of the coefficients' intervals (each term on its own).
INTERVAL_LEVEL = 0.95
#: Torque [N m] of one fit step of a term at its typical (rms) size in the decays.
_STEP_TORQUE = 0.1


def window_error(model: ExperimentModel, windows: list[Window]) -> list[np.ndarray]:
    """The closure error of the effect fits, per decay.

    It is the error ``measured fit`` uses: each decay through
    :meth:`ExperimentModel.simulate`, which replays a decay with a controller law in a loop
    and predicts a decay of logs without a law k samples ahead through the nominal's Kalman
    filter (``drive == "kstep"``, :mod:`bikeid.ident.effects.kstep`).

    Parameters
    ----------
    model : ExperimentModel
        The model simulated on each decay (:meth:`ExperimentModel.simulate`).
    windows : list of Window
        The decays.

    Returns
    -------
    list of ndarray
        Per decay, the simulated minus measured roll rate and steer angle, each divided by
        its ||y - mean y|| (:func:`bikeid.ident.effects.fit.output_residuals`;
        dimensionless: a decay's sum of squares is its NRMSE^2 summed over the channels).
    """
    r = output_residuals(model, windows)
    cuts = np.cumsum([2 * w.n for w in windows])[:-1]
    return np.split(r, cuts)


def _signal(t: Term, w: Window, dt: float) -> np.ndarray:
    """The term's signal on a decay (its measured samples; 1 for a constant or a sign)."""
    s = t.law.signal
    if s in ("1", "sign(phidot)", "sign(deltadot)"):
        x = np.ones(w.n)
    elif s == "phiddot":
        x = np.gradient(w.phidot, dt)
    elif s == "deltaddot":
        x = np.gradient(w.deltadot, dt)
    elif s == "T":
        x = w.T_logged if w.T_logged is not None else np.ones(w.n)
    else:
        x = getattr(w, s)
    return x * max(w.speed, 0.1) ** t.law.speed_power


def _steps(terms: list[Term], windows: list[Window], dt: float) -> dict[str, float]:
    """Each term's fit step [its unit]: :data:`_STEP_TORQUE` over the term's rms in the decays."""
    out = {}
    for t in terms:
        rms = math.sqrt(np.mean(np.concatenate([_signal(t, w, dt) ** 2 for w in windows])))
        out[t.label] = _STEP_TORQUE / rms if rms > 0 and math.isfinite(rms) else 1.0
    return out


@dataclass
class _Fit:
    model: ExperimentModel
    coef: dict[str, float]
    std: dict[str, float]
    cost: float
    dof: float
    calibration: Calibration | None = None

    def p_value(self, label: str) -> float:
        sd = self.std[label]
        t = abs(self.coef[label]) / sd if sd > 0 else (math.inf if self.coef[label] else 0.0)
        return t_p_value(t, self.dof)


def _with(model: ExperimentModel, terms: list[Term], coefs) -> ExperimentModel:
    return model.with_effects(**{t.entry: t.value(c) for t, c in zip(terms, coefs, strict=True)})


def _fit(model: ExperimentModel, windows: list[Window], terms: list[Term], steps: dict,
         error: ErrorFunction, start: dict | None = None,
         calibration: Calibration | None = None) -> _Fit:  # fmt: skip
    """Least squares of ``error`` over the terms' coefficients, standard errors clustered by
    decay; with ``calibration``, the nominal's offsets fitted too within their box, as the
    effect fits do (:func:`bikeid.ident.effects.fit.fit_effects`: an offset on the box's
    edge is held there, one inside stays in the covariance with the box as prior
    information, so a term's standard error counts what the offsets can mimic)."""
    start = start or {}
    k = len(terms)
    sc = np.array([steps[t.label] for t in terms])
    x0 = np.array([start.get(t.label, 0.0) for t in terms]) / sc
    lo, hi = np.full(k, -np.inf), np.full(k, np.inf)
    ncal = 0 if calibration is None else len(calibration.offsets)
    if ncal:
        x0 = np.concatenate([x0, np.clip(calibration.offsets, -1 + 1e-9, 1 - 1e-9)])
        lo, hi = np.concatenate([lo, -np.ones(ncal)]), np.concatenate([hi, np.ones(ncal)])

    def mk(x):
        m = _with(model, terms, x[:k] * sc)
        return replace(m, p=calibration.params(x[k:])) if ncal else m

    sizes: list[int] = []  # each decay's residual length (fixed: read at the first call)

    def per_decay(x):
        per = error(mk(x), windows)
        sizes[:] = [len(e) for e in per]
        return np.concatenate(per)

    fun = trial_residuals(per_decay)
    if x0.size == 0:  # nothing to fit: the model's cost
        r = fun(x0)
        return _Fit(model, {}, {}, float(r @ r), float("inf"))
    sol = least_squares(fun, x0, bounds=(lo, hi), x_scale=1.0, diff_step=1e-3, max_nfev=60)
    r = sol.fun
    std, dof = bounded_std(sol, lo, hi, k, sizes)  # an offset on the box's edge is held
    coef = sol.x[:k] * sc
    labels = [t.label for t in terms]
    cal = replace(calibration, offsets=sol.x[k:].copy(), std=std[k:]) if ncal else None
    return _Fit(mk(sol.x), dict(zip(labels, map(float, coef), strict=True)),
                dict(zip(labels, map(float, std[:k] * sc), strict=True)), float(r @ r),
                dof, cal)  # fmt: skip


def _costs(error: ErrorFunction, model: ExperimentModel, windows: list[Window]) -> np.ndarray:
    """Each decay's cost (sum of squared errors)."""
    return np.array([float(e @ e) for e in error(model, windows)])


@dataclass
class Discovery:
    """Outcome of :func:`discover`.

    Attributes
    ----------
    terms : list of dict
        The kept terms (module docstring), each with ``equation``, ``term``, ``coefficient``
        [``unit``: generalized torque per unit of the term; positive adds torque],
        ``interval`` (:data:`INTERVAL_LEVEL`), ``unit``, ``std``, ``dof``, ``p_value`` and
        ``p_adjusted`` (Bonferroni), ``reading``, ``entry`` (the registry name) and
        ``indistinguishable`` (terms the decays cannot tell from it, :func:`_alike`:
        ``equation``, ``term``, ``coefficient`` kept instead and its ``interval`` (the
        round's fit on the fitting half), ``unit``, ``reading``,
        ``fit_gain``, ``joint_p_value`` of the kept term and ``joint_p_value_rival``).
    model : ExperimentModel
        The nominal with the kept terms (joint fit on all decays).  A kept term without a
        registered entry of its own is declared only during the search: to simulate this
        model, load :meth:`effects_file`'s file first (else that term is not simulated, and
        a copy of the model with other effects is refused).
    kept : list of Term
        The kept terms' dictionary entries, in the order of :attr:`terms`.
    rounds : list of dict
        Per round, every term tried: coefficient, p-value, fit gain (and held-out cost
        ratio where checked), and the term kept.
    test : dict
        ``alpha``, ``correction``, ``tests`` (the Bonferroni family), ``level``,
        ``dictionary`` (terms tried), ``not_fitted`` (terms the closure cannot carry, with
        the reason).
    before_after : dict or None
        The held-out half's before/after summary (module docstring, step 6; None with no
        kept term).
    """

    terms: list[dict]
    model: ExperimentModel
    kept: list[Term]
    rounds: list[dict] = field(default_factory=list)
    test: dict = field(default_factory=dict)
    before_after: dict | None = None

    def as_dict(self) -> dict:
        """The discovery, JSON-ready.

        Returns
        -------
        dict
            ``terms``, ``before_after``, ``test``, ``rounds``.
        """
        return {"terms": self.terms, "before_after": self.before_after, "test": self.test,
                "rounds": self.rounds}  # fmt: skip

    def effects_file(self, path: str | Path) -> Path:
        """Write the kept terms as an effects file (``measured fit|evaluate
        --effects-file``): each a library candidate with its coefficient as ``value``.

        Terms in the steer torque (the command gain, a built-in library effect no file
        declares) are left out.

        Parameters
        ----------
        path : str or Path
            ``.yaml`` / ``.yml`` or ``.json``.

        Returns
        -------
        Path
            The file written.
        """
        import json

        import yaml

        from bikeid.dataset.files import atomic_write_text

        terms = [t for t in self.kept if t.law.kind != "torque"]
        vals = {d["equation"] + ": " + d["term"]: d["coefficient"] for d in self.terms}
        decl = declarations(terms, {t.label: vals[t.label] for t in terms}, in_library=True)
        p = Path(path)
        text = (json.dumps({"effects": decl}, indent=1) if p.suffix.lower() == ".json"
                else yaml.safe_dump({"effects": decl}, sort_keys=False))  # fmt: skip
        atomic_write_text(p, text)
        return p


def _confirmed(stated, windows, kept, passing, steps, error, cal, level, log) -> bool:
    """Whether a passing term stays significant at ``level`` with the nominal's offsets
    fitted jointly with it (and the kept terms) on the fitting half; its row of ``log``
    records that p-value (``p_value_calibrated``)."""
    _c, t, f, _gain = passing
    g = _fit(stated, windows, kept + [t], steps, error, f.coef, cal)
    p = g.p_value(t.label)
    for row in log:
        if row["equation"] == t.equation and row["term"] == t.term:
            row["p_value_calibrated"] = p
    return p <= level


def _alike(model, windows, kept, best, coef, rivals, gain, steps, error, alpha) -> list[dict]:
    """The rivals the decays cannot tell from ``best``: fitted jointly with it (and the kept
    terms) on all decays, ``best`` is no longer significant at ``alpha`` (the rival can
    stand in for it).  Only rivals removing at least half of ``best``'s fit gain are tried (a
    term that explains less cannot stand in for it).  Each with its coefficient when kept
    instead of ``best`` (its own fit of the round), its fit gain, and the p-values of
    ``best`` and of the rival in the joint fit."""
    out = []
    for t, g, c, ci in rivals:
        if t is best or g < 0.5 * gain:
            continue
        f = _fit(model, windows, kept + [best, t], steps, error, coef)
        p = f.p_value(best.label)
        if p > alpha:
            out.append({"equation": t.equation, "term": t.term, "coefficient": c,
                        "interval": ci, "unit": t.unit, "reading": t.reading, "fit_gain": g,
                        "joint_p_value": p, "joint_p_value_rival": f.p_value(t.label)})  # fmt: skip
    return sorted(out, key=lambda a: -a["fit_gain"])


def _interval(f: _Fit, label: str) -> list[float]:
    """The coefficient's :data:`INTERVAL_LEVEL` interval (Student t on the fit's dof)."""
    q = float(stats.t.ppf(0.5 + INTERVAL_LEVEL / 2, f.dof))
    c, sd = f.coef[label], f.std[label]
    return [c - q * sd, c + q * sd]


def _row(t: Term, f: _Fit) -> dict:
    return {"equation": t.equation, "term": t.term, "coefficient": f.coef[t.label],
            "std": f.std[t.label], "p_value": f.p_value(t.label)}  # fmt: skip


@single_threaded_blas
def discover(
    model: ExperimentModel,
    windows: list[Window],
    *,
    nonlinear: bool = False,
    error: ErrorFunction = window_error,
    max_terms: int = 3,
    rule: AcceptanceRule | None = None,
    terms: list[Term] | None = None,
    family: int | None = None,
    progress: Callable[[int, int, str], None] | None = None,
) -> Discovery:
    """Terms of the equations of motion the decays support (module docstring).

    Parameters
    ----------
    model : ExperimentModel
        The nominal (or a fitted model: its effects are kept, and the terms it already
        carries are not tried).
    windows : list of Window
        The decays (at least 4: half fit, half held out), e.g. those of
        :func:`bikeid.ident.effects.decays_from_logs` (the loader of ``measured fit``), with
        the nominal experiment it returns as ``model``.
    nonlinear : bool, optional
        Nonlinear plant by the defect correction, taken at the nominal and again at each
        kept term (default False: the linear experiment model).
    error : callable, optional
        The closure error ``error(model, windows) -> list of per-decay residual arrays``
        (default :func:`window_error`); coefficients, standard errors, the held-out checks
        and the joint fits of the indistinguishable sets all come from it.
    max_terms : int, optional
        At most this many rounds (default 3).
    rule : AcceptanceRule, optional
        ``alpha``, ``correction``, ``min_gain``, the held-out gain and the stated
        bicycle's ``nominal_uncertainty`` (default :class:`AcceptanceRule` with its
        defaults, as ``measured fit``: the default uncertainty; its ``unexplained``
        settings are not used).  With an uncertainty (None: the bicycle taken as exact) its
        offsets are calibrated on the fitting half before any term; the terms are screened
        with them held there, and a term is kept only if it stays significant with the
        offsets fitted jointly with it (module docstring, step 3), as are the final joint
        fit's p-values and intervals: a nominal off by no more than its uncertainty is not
        a term.
    terms : list of Term, optional
        The dictionary (default :func:`dictionary`).
    family : int, optional
        The Bonferroni family: the number of tests the search is charged with (default
        the tests it makes, K + (K - 1) + ... over ``max_terms`` rounds for the K terms
        tried).  When ``terms`` were screened from a larger dictionary on the same decays,
        give that dictionary's count: the screen chose them by the same data.
    progress : callable, optional
        ``progress(done, total, label)`` before each term's fit.

    Returns
    -------
    Discovery

    Raises
    ------
    ValueError
        With fewer than 4 decays or ``max_terms`` < 1.
    """
    from bikeid.ident.effects.diagnostics import evaluate

    rule = rule or AcceptanceRule()
    if len(windows) < 4:
        raise ValueError(f"discovery needs at least 4 decays (half are held out), got "
                         f"{len(windows)}")  # fmt: skip
    if max_terms < 1:
        raise ValueError(f"max_terms must be >= 1, got {max_terms}")
    d = dictionary() if terms is None else list(terms)
    with registered(d) as fit_able:
        cands = [t for t in fit_able if model.e(t.entry) == t.absent]
        k = len(cands)
        tests = sum(max(k - r, 0) for r in range(max_terms))
        done, total = 0, tests
        if family is not None:
            if family < tests:
                raise ValueError(f"family {family} is smaller than the {tests} tests the "
                                 "search makes; give at least that many")  # fmt: skip
            tests = int(family)
        level = rule.level(tests)
        raw = list(windows)
        stated = model
        ws = corrected(raw, model, nonlinear)
        steps = _steps(cands, ws, model.dt)
        cal, calibration = None, None
        uncertainty = rule.nominal_uncertainty
        if uncertainty is not None and uncertainty.names:
            cal = _fit(model, ws[0::2], [], steps, error,
                       calibration=Calibration(uncertainty, model.p)).calibration  # fmt: skip
            model = replace(model, p=cal.params())  # the nominal within its uncertainty
            calibration = {"fit_half": cal.as_dict()}
            if nonlinear:
                ws = corrected(raw, model, True)
        kept: list[Term] = []
        coef: dict[str, float] = {}
        sets: dict[str, list[dict]] = {}
        rounds: list[dict] = []
        cur = model
        cur_val = _costs(error, cur, ws[1::2])
        for _round in range(max_terms):
            fit_w, val_w = ws[0::2], ws[1::2]
            base = float(np.sum(_costs(error, cur, fit_w)))
            trials = []
            for t in cands:
                if t in kept:
                    continue
                if progress:
                    progress(done, total, f"round {_round + 1}: {t.label}")
                done += 1
                f = _fit(model, fit_w, kept + [t], steps, error, coef)
                trials.append((t, f, (base - f.cost) / max(base, 1e-300)))
            log, passing, rivals = [], [], []
            for t, f, gain in trials:
                row = {**_row(t, f), "fit_gain": gain}
                log.append(row)
                if gain < rule.min_gain or not row["p_value"] <= rule.alpha:
                    continue
                val_wn = _costs(error, f.model, val_w)
                row["heldout_cost_ratio"] = float(np.sum(val_wn) / np.sum(cur_val))
                rivals.append((t, gain, f.coef[t.label], _interval(f, t.label)))
                if row["p_value"] <= level and row["heldout_cost_ratio"] < 1 - rule.heldout_gain:
                    passing.append((f.cost + float(np.sum(val_wn)), t, f, gain))
            passing.sort(key=lambda z: z[0])
            if cal is not None:  # the best one significant with the offsets fitted with it
                first = next((z for z in passing if _confirmed(stated, fit_w, kept, z, steps,
                                                               error, cal, level, log)), None)
                passing = [] if first is None else [first]
            if not passing:
                rounds.append({"kept": None, "terms": log})
                break
            _c, best, f, gain = passing[0]
            sets[best.label] = _alike(model, ws, kept, best, f.coef, rivals, gain, steps, error,
                                      rule.alpha)  # fmt: skip
            kept.append(best)
            coef = dict(f.coef)
            cur = f.model
            rounds.append({"kept": best.label, "terms": log})
            if nonlinear:
                ws = corrected(raw, cur, True)
            cur_val = _costs(error, cur, ws[1::2])
        final = None
        while kept:  # joint fit on all decays (with the offsets), pruned backwards
            if nonlinear:
                ws = corrected(raw, _with(model, kept, [coef[t.label] for t in kept]), True)
            final = (_fit(model, ws, kept, steps, error, coef) if cal is None
                     else _fit(stated, ws, kept, steps, error, coef, cal))  # fmt: skip
            worst = max(kept, key=lambda t: final.p_value(t.label))
            if final.p_value(worst.label) <= level:
                break
            kept.remove(worst)
            final = None
        out = []
        for t in kept:
            c, sd, p = final.coef[t.label], final.std[t.label], final.p_value(t.label)
            out.append({"equation": t.equation, "term": t.term, "coefficient": c,
                        "interval": _interval(final, t.label), "unit": t.unit, "std": sd,
                        "dof": final.dof, "p_value": p, "p_adjusted": rule.adjusted(p, tests),
                        "reading": t.reading, "entry": t.entry,
                        "indistinguishable": sets.get(t.label, [])})  # fmt: skip
        ba = None
        if kept:
            held_model = _fit(model, corrected(raw, final.model, nonlinear)[0::2], kept, steps,
                              error, coef).model  # fmt: skip
            ba = evaluate(model, held_model, raw[1::2], nonlinear)["summary"]
            ba["note"] = ("held-out half of the decays: not used for these coefficients, but "
                          "used to choose the terms (not out of sample)")  # fmt: skip
        test = {
            "alpha": rule.alpha,
            "correction": rule.correction,
            "tests": tests,
            "level": level,
            "dictionary": [t.equation + ": " + t.term for t in cands],
            "not_fitted": {t.label: t.no_closure for t in d if t.no_closure},
            "interval_level": INTERVAL_LEVEL,
            "reference": "Student t, G - 1 degrees of freedom for G decay clusters",
        }
        if calibration is not None:
            if final is not None and final.calibration is not None:
                calibration["final"] = final.calibration.as_dict()
            test["nominal_calibration"] = calibration
        return Discovery(out, final.model if final else model, kept, rounds, test, ba)
