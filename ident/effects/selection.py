"""Effect selection: residual -> named physical effect -> augmented model.

Workflow (identification.md section 5, approaches A/B/E):

1. **Residuals.**  Output residuals of the experiment model (:mod:`ident.effects.experiment_model`)
   on free-decay windows (roll rate, steer angle), and equation-error residuals of the
   roll and steer rows in Moore & Hubbard's form ``M q'' + v C1 q' + (g K0 + v^2 K2) q
   = [0, T]`` (accelerations from zero-phase-filtered central differences).
   Diagnostics: whiteness (fraction of autocorrelations outside the 99 % band,
   lags 1..25), cross-correlation with the steer command, Welch spectra.
2. **Ranking.**  Additive candidates are ranked by the orthogonal error-reduction ratio
   (ERR, forward orthogonal least squares) on the steer- and roll-row equation errors.
   Every candidate (additive or structural: delay, lag, ...) is then fitted by
   output error on the decays; the structural ones by a scan of their parameter
   followed by a local refinement.  Candidates are ordered by the fraction of the
   output-error cost they remove.  With a nominal uncertainty the nominal's offsets are
   calibrated within their box before any effect and refitted with every candidate (held
   at the pre-effect calibration they would already carry part of the missing effect).
3. **Acceptance** (:class:`bikeid.ident.effects.acceptance.AcceptanceRule`).  An effect is
   accepted only if its t = |value - absent| / std (standard errors clustered by window,
   :func:`bikeid.ident.effects.fit.effect_std`) is significant against Student's t with
   G - 1 degrees of freedom at the level alpha / m (Bonferroni over the m candidate tests
   of all rounds: family-wise error rate alpha) *and* it lowers the error on held-out
   windows (every other window is held out while selecting); among those, a round takes the
   smallest product of held-out cost ratio and held-out weave-error ratio, or, among the
   passing candidates the paired held-out test cannot tell from that one, the one of least
   held-out cost (:func:`first_name`).  Accepted effects
   are refitted jointly on all fit windows, and those no longer significant there are
   pruned.  Each accepted effect's p-value is reported; with the nominal calibrated on its
   box's edge, the tests are marked as conditional on that edge.
4. **"unexplained".**  With the rule ``instruments`` (opt-in) the verdict is ``unexplained``
   when the final model's cost exceeds ``INSTRUMENT_MAX`` times the floor of the instruments
   (:func:`bikeid.ident.effects.instrument_floor.instrument_floor`: coloured sensor noise,
   quantization, drift and speed wander measured on the logs); with no effect accepted
   and no structure left, nothing is said.  The default rule ``floor``: the
   measurement-noise floor of each window is estimated from
   second differences (sigma^2 = mean((y[k+1] - 2 y[k] + y[k-1])^2) / 6).  If the
   accepted effects remove less than the rule's threshold (``EXPLAINED_MIN`` = 90 %; 85 %
   with the nominal calibrated) of the nominal cost
   above that floor, the verdict is ``unexplained`` (listed first), with the
   accepted effects reported as partial; if they remove less than ``EXPLAINED_TO_NAME``
   (50 %), no library member explains the residual well: they are its nearest members,
   reported in the evidence (``nearest``) and not named, and the verdict is
   ``unexplained`` alone.
5. **Options and evidence.**  The rule's ``min_heldout_gain`` and ``min_improved`` (share of
   held-out decays improved) make acceptance stricter; ``unexplained_rule`` decides ``unexplained``
   from the second-difference floor (default), a coloured-noise floor, or the final
   residual's own noise floor.  :attr:`Identification.evidence` records, per accepted effect
   and for ``unexplained``, the numbers behind the verdict (:func:`evidence_lines` prints
   them); their rates on the blind trials are in docs/measured.md "Blind trials".
6. **The nominal plant, chosen after selection** (:func:`choose_plant`).  ``measured fit
   --plant auto`` runs the selection with the linear and with the nonlinear plant on the same
   decays and compares the two final models by their per-decay out-of-fold costs (each
   effect set refitted on the other half of the decays: the penalty for the number of
   effects), a sign-flip paired test (stratified by file) at the rule's ``alpha``.  A
   separated pair gives the better plant; alike fits give the nonlinear plant (the default)
   when the two selections agree up to their ambiguity sets
   (:func:`compare_plant_selections`) and :data:`PLANT_UNCERTAIN` when they do not.  The
   nominal costs before any effect (:func:`compare_nominal_plants`) are reported but no
   longer choose: an effect in the data shifts them (linear truths with a command gain gave
   nominal cost ratios nonlinear / linear of 0.49-1.03 on the closure benchmark: the wrong
   plant looked as good or better before any effect).

The pieces live in their own modules: the library and its fit settings in
:mod:`bikeid.ident.effects.library` (effect facts: :mod:`bikeid.sim.effect_registry`), the
output-error fits in :mod:`bikeid.ident.effects.fit`, the weave eigenvalue in
:mod:`bikeid.ident.effects.weave`, the equation-error ranking and the before/after evaluation in
:mod:`bikeid.ident.effects.diagnostics`.  This module holds the greedy selection
:func:`select_effects` and its stability check :func:`selection_frequencies`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from bikeid.dataset.windows import Window
from bikeid.ident.effects.acceptance import (
    EXPLAINED_MIN,
    EXPLAINED_MIN_CALIBRATED,
    EXPLAINED_TO_NAME,
    LINEAR_PLANT_MARGIN,
    RESIDUAL_MAX,
    WEAVE_EPS,
    AcceptanceRule,
    paired_p_value,
    t_p_value,
)
from bikeid.ident.effects.diagnostics import err_ranking
from bikeid.ident.effects.experiment_model import ExperimentModel, window_errors
from bikeid.ident.effects.fit import (
    EffectEstimate,
    FitResult,
    corrected,
    fit_effects,
    joint_fit,
    noise_floor,
    output_residuals,
    residual_noise_floor,
)
from bikeid.ident.effects.instrument_floor import instrument_floor
from bikeid.ident.effects.library import LIBRARY, Candidate
from bikeid.ident.effects.nominal_uncertainty import Calibration, NominalUncertainty
from bikeid.ident.effects.weave import WeaveTerm, decay_eigenvalue, weave_error, weave_targets
from bikeid.sim.blas import single_threaded_blas

__all__ = [
    "AcceptanceRule",
    "EXPLAINED_MIN",
    "EXPLAINED_MIN_CALIBRATED",
    "LINEAR_PLANT_MARGIN",
    "RESIDUAL_MAX",
    "choose_nominal_plant",
    "compare_nominal_plants",
    "compare_plant_selections",
    "choose_plant",
    "out_of_fold_costs",
    "plant_verdict",
    "PLANT_UNCERTAIN",
    "evidence_lines",
    "first_name",
    "WEAVE_EPS",
    "Identification",
    "select_effects",
    "selection_frequencies",
]

#: The verdict of a fit whose nominal plant is uncertain: the final models of the selections
#: with the two plants fit the decays alike (:func:`choose_plant`'s paired test of their
#: out-of-fold costs does not separate them) and the selections disagree beyond their
#: ambiguity sets (:func:`compare_plant_selections`), so the named effects would depend on a
#: plant the data cannot choose: the plant mismatch, not effects of the bicycle.
PLANT_UNCERTAIN = "nominal plant uncertain"


def _t_value(name: str, value: float, sd: float, cal: Calibration | None) -> float:
    """t of an effect: its distance from absent, or for a parameter correction along a
    calibrated direction its reach beyond the uncertainty band, over its standard error."""
    excess = cal.excess(name, value) if cal is not None else None
    d = abs(value - LIBRARY[name].absent) if excess is None else excess
    return d / sd if sd > 0 else (np.inf if d > 0 else 0.0)


def _scan_start(model, windows, cand: Candidate, base: list[str], start: dict) -> float:
    best, arg = np.inf, cand.grid[0]
    for g in cand.grid:
        m = model.with_effects(**start, **{cand.name: g})
        r = output_residuals(m, windows)
        if r @ r < best:
            best, arg = float(r @ r), g
    return arg


@dataclass
class Identification:
    """Outcome of :func:`select_effects`.

    Attributes
    ----------
    model : ExperimentModel
        The final model with the accepted effects.
    effects : list of EffectEstimate
        Accepted effects after the joint fit and pruning, by contribution.
    ranking : list of EffectEstimate
        The first round's candidates, by the fraction of the cost they remove.
    verdict : list of str
        Accepted effect names, ``"unexplained"`` first when they remove less than
        :data:`EXPLAINED_MIN` of the nominal cost above the noise floor.
    cost_nominal : float
        Output-error cost of the nominal model on all windows (dimensionless, a sum of
        NRMSE^2); with ``nominal_uncertainty``, of the nominal calibrated within it.
    cost_final : float
        Same cost of the final model.
    cost_floor : float
        Expected cost of a perfect model (:func:`bikeid.ident.effects.fit.noise_floor`).
    explained : float
        Fraction of ``cost_nominal - cost_floor`` removed by the final model.
    eq_ranking : list of dict
        Equation-error (ERR) ranking of the additive candidates
        (:func:`bikeid.ident.effects.diagnostics.err_ranking`).
    rounds : list of dict
        Forward-selection log, one entry per round.
    weave_weight : float
        Weight of the weave-eigenvalue term in the fits (0: decay signals only).
    evidence : dict
        Why each name of the verdict is there: ``effects`` maps each accepted effect to
        the round it was accepted in, its fit gain, held-out cost ratio and held-out gain
        (1 - ratio), the held-out windows it improved, its held-out weave error before and
        after, and its t after the joint fit (for a parameter correction along a calibrated
        direction, t beyond the band), its degrees of freedom and p-values (``p_value``,
        ``p_adjusted``; ``conditional_on``: calibration offsets held on the box's edge), and
        ``alike``: the other candidates of its round significant at ``alpha`` alone (whether
        or not they passed the round's corrected test and held-out checks:
        ``passed_round``) whose held-out decay costs a paired t test (Student t, n - 1
        degrees of freedom over the n held-out decays) cannot tell from its own at ``alpha``
        (their held-out cost ratio, fit gain, t, p-values and value: the evidence for each);
        ``test``: the level, correction and number of tests; ``nominal_calibration`` (with
        ``nominal_uncertainty``) the offsets of the fit half and of the final fit, which
        sit on the band's edge, the held-out cost before and after the calibration and the
        cost of the stated and the calibrated nominal; ``unexplained`` holds the final cost,
        the noise
        floors (second differences, coloured, from the final residual), the explained
        fractions, the rule and its threshold, and the verdict it gave.
    windows : list of Window
        The decays with the final fit's defect correction (nonlinear plant).
    calibration : Calibration or None
        The nominal's offsets within its uncertainty at the final fit (None when the stated
        bicycle was taken as exact).
    """

    model: ExperimentModel
    effects: list[EffectEstimate]
    ranking: list[EffectEstimate]
    verdict: list[str]
    cost_nominal: float
    cost_final: float
    cost_floor: float
    explained: float
    eq_ranking: list[dict] = field(default_factory=list)
    rounds: list[dict] = field(default_factory=list)  # forward-selection log, per round
    weave_weight: float = 0.0  # weight of the weave-eigenvalue term in the fits
    evidence: dict = field(default_factory=dict)  # why each name is in the verdict
    windows: list[Window] = field(default_factory=list)  # with the final defect correction
    calibration: Calibration | None = None  # the nominal's offsets of the final fit

    @property
    def ambiguity(self) -> dict[str, list[str]]:
        """Each accepted effect's ambiguity set: itself and the candidates its held-out decays
        cannot tell it from (``evidence["effects"][name]["alike"]``), in order of held-out
        cost ratio; an effect told apart from every other has a set of one."""
        out = {}
        for e in self.effects:
            alike = self.evidence.get("effects", {}).get(e.name, {}).get("alike", [])
            out[e.name] = [e.name] + [a["name"] for a in
                                      sorted(alike, key=lambda a: a["heldout_cost_ratio"])]
        return out

    def as_dict(self) -> dict:
        """The identification's JSON record (``identification`` of a model file).

        Returns
        -------
        dict
            ``selection_rounds``, ``verdict``, ``effects``, ``ranking``,
            ``equation_error_ranking``, ``cost_nominal``, ``cost_final``,
            ``cost_noise_floor``, ``explained_fraction``, ``weave_weight``, ``evidence``,
            ``ambiguity`` (:attr:`ambiguity`).
        """
        return {
            "selection_rounds": self.rounds,
            "verdict": self.verdict,
            "effects": [e.as_dict() for e in self.effects],
            "ranking": [e.as_dict() for e in self.ranking],
            "equation_error_ranking": self.eq_ranking,
            "cost_nominal": self.cost_nominal,
            "cost_final": self.cost_final,
            "cost_noise_floor": self.cost_floor,
            "explained_fraction": self.explained,
            "weave_weight": self.weave_weight,
            "evidence": self.evidence,
            "ambiguity": self.ambiguity,
        }


def _merge(fit_w: list[Window], val_w: list[Window]) -> list[Window]:
    """The windows in their original order from the fit (even) and held-out (odd) halves."""
    out: list[Window] = [None] * (len(fit_w) + len(val_w))  # type: ignore[list-item]
    out[0::2], out[1::2] = fit_w, val_w
    return out


@dataclass
class _Search:
    """The state of one forward selection: the halves of the windows (values, each replaced
    when its defect correction is taken at another model), the current model and
    calibration, the held-out costs, the weave terms and the log.  Each step of
    :func:`select_effects` is a method."""

    model: ExperimentModel
    names: list[str]
    rule: AcceptanceRule
    nonlinear: bool
    fit_w: list[Window]
    val_w: list[Window]
    tests: int  # candidate tests of all rounds: the Bonferroni family
    cur: ExperimentModel = None  # type: ignore[assignment]
    cal: Calibration | None = None
    wv_fit: WeaveTerm | None = None
    wv_all: WeaveTerm | None = None
    lam_val: list = field(default_factory=list)
    accepted: list[str] = field(default_factory=list)
    ranking: list[EffectEstimate] = field(default_factory=list)
    rounds: list[dict] = field(default_factory=list)
    ev_effects: dict[str, dict] = field(default_factory=dict)
    ev_nominal: dict | None = None
    cur_val: float = 0.0
    cur_wv: float = 0.0
    cur_val_w: np.ndarray = None  # type: ignore[assignment]
    # this round's candidates significant at alpha alone that did not pass (name, fit, fit
    # gain, estimate, held-out costs per window or None): candidates for the ambiguity sets
    rivals: list[tuple] = field(default_factory=list)

    @property
    def windows(self) -> list[Window]:
        return _merge(self.fit_w, self.val_w)

    def correct_all(self, m: ExperimentModel) -> None:
        """Both halves with the defect correction at ``m``."""
        ws = corrected(self.windows, m, self.nonlinear)
        self.fit_w, self.val_w = ws[0::2], ws[1::2]

    def estimate(self, n: str, res: FitResult, gain: float) -> EffectEstimate:
        """Candidate ``n``'s estimate in ``res``: t, its p-value on ``res.dof``."""
        v, sd = res.values[n], res.std[n]
        t = _t_value(n, v, sd, res.calibration or self.cal)  # the offsets fitted with it
        return EffectEstimate(n, v, sd, LIBRARY[n].unit, t, gain, p_value=t_p_value(t, res.dof),
                              dof=res.dof)  # fmt: skip

    def calibrate_nominal(self, uncertainty: NominalUncertainty) -> None:
        """The nominal within its uncertainty, fitted on the fit half (no effect yet)."""
        cal0 = Calibration(uncertainty, self.model.p)
        c = joint_fit(self.model, self.fit_w, [], None, self.nonlinear, self.wv_fit, cal0)
        self.cur, self.cal, self.fit_w = c.model, c.calibration, c.windows
        held = []
        for m in (self.model, self.cur):  # held-out cost of the stated and calibrated nominal
            self.val_w = corrected(self.val_w, m, self.nonlinear)
            held.append(fit_effects(m, self.val_w, []).cost)
        self.ev_nominal = {"fit_half": self.cal.as_dict(), "heldout_cost_stated": held[0],
                           "heldout_cost_calibrated": held[1],
                           "heldout_gain": 1 - held[1] / max(held[0], 1e-300)}  # fmt: skip
        self.fit_w = corrected(self.fit_w, self.cur, self.nonlinear)  # held-out: already at cur
        if self.wv_fit:
            self.wv_fit = self.wv_fit.at(self.cur, self.fit_w)

    def heldout_state(self) -> None:
        """The held-out cost (total and per window) and weave error of the current model."""
        sims = self.cur.simulate(self.val_w)
        self.cur_val_w = np.sum(window_errors(self.val_w, sims) ** 2, axis=1)
        self.cur_val = float(np.sum(self.cur_val_w))
        self.cur_wv = weave_error(self.val_w, sims, self.lam_val)

    def fit_candidates(self, base_cost: float, progress, counter: list[int], _round: int):
        """Every remaining candidate fitted on the fit half with the accepted ones:
        (gain, name, fit, estimate), by gain."""
        trials = []
        for n in self.names:
            if n in self.accepted:
                continue
            if progress:
                progress(counter[0], counter[1], f"round {_round + 1}: {n}")
                counter[0] += 1
            cand = LIBRARY[n]
            start = {}
            if cand.kind == "structural":
                start[n] = _scan_start(self.cur, self.fit_w, cand, self.accepted, {})
            # with a calibration, its offsets are refitted with every candidate: calibrated
            # before any effect, they absorb what they can of a missing effect (an input
            # delay pushed the inertias to the box's edges), and a candidate fitted at those
            # frozen offsets competes against that bent nominal (a lag then beat the delay)
            res = fit_effects(self.cur, self.fit_w, self.accepted + [n], start, self.wv_fit,
                              self.cal)  # fmt: skip
            gain = (base_cost - res.cost) / max(base_cost, 1e-300)
            trials.append((gain, n, res, self.estimate(n, res, gain)))
        trials.sort(key=lambda z: -z[0])
        return trials

    def rerank_leaders(self, trials: list, base_cost: float) -> list:
        """Nonlinear plant: the three leaders refitted with the correction taken at each."""
        top = []
        for _gain, n, res, _est in trials[:3]:
            self.correct_all(res.model)
            wv_n = self.wv_fit.at(res.model, self.fit_w) if self.wv_fit else None
            res = fit_effects(self.cur, self.fit_w, self.accepted + [n], res.values, wv_n,
                              res.calibration)  # fmt: skip
            gain = (base_cost - res.cost) / max(base_cost, 1e-300)
            top.append((gain, n, res, self.estimate(n, res, gain)))
        return sorted(top, key=lambda z: -z[0]) + trials[3:]

    def heldout_checks(self, trials: list) -> tuple[list, list[dict]]:
        """The candidates that pass the significance test, the fit gain and the held-out
        checks, with their selection score; and the round's log rows."""
        rule, level = self.rule, self.rule.level(self.tests)
        passing, log = [], []
        self.rivals = []
        for gain, n, res, est in trials:
            row = {"name": n, "value": est.value, "t": est.t, "dof": est.dof,
                   "p_value": est.p_value, "fit_gain": gain}  # fmt: skip
            log.append(row)
            if gain < rule.min_gain or not est.p_value <= rule.alpha:
                continue
            if not est.p_value <= level:
                self.rivals.append((n, res, gain, est, None))
                continue
            self.val_w = corrected(self.val_w, res.model, self.nonlinear)  # held-out only
            sims = res.model.simulate(self.val_w)
            val_wn = np.sum(window_errors(self.val_w, sims) ** 2, axis=1)
            val = float(np.sum(val_wn))
            row["heldout_cost_ratio"] = val / self.cur_val
            row["heldout_improved"] = int(np.sum(val_wn < self.cur_val_w))
            if val >= self.cur_val * (1 - rule.heldout_gain):
                self.rivals.append((n, res, gain, est, val_wn))
                continue
            if row["heldout_improved"] < rule.min_improved * len(self.val_w) - 1e-9:
                self.rivals.append((n, res, gain, est, val_wn))
                continue
            wv = weave_error(self.val_w, sims, self.lam_val)
            score = val / self.cur_val * (wv + WEAVE_EPS) / (self.cur_wv + WEAVE_EPS)
            row.update(heldout_weave_error=wv, heldout_weave_before=self.cur_wv, score=score)
            passing.append((score, n, res, val, wv, val_wn, gain, est))
        return passing, log

    def accept(self, passing: list, _round: int) -> None:
        """Take the passing candidate of least score, or the one of least held-out cost among
        those the paired test cannot tell from it (:func:`first_name`); with a calibration,
        refit the offsets with it."""
        _score, n, res, val, wv, val_wn, gain, est = first_name(passing, self.rule.alpha)
        # Alike: a candidate significant at alpha alone (passing this round's corrected test
        # or not, its held-out checks or not) whose held-out decays the paired test cannot
        # tell from the chosen one's.  Counting only the candidates that passed the corrected
        # test hid an input delay behind the actuator lag that fits it to 1-7 % (seeds 1, 5, 6
        # of the closure's linear-truth delay logs).
        others = [(m, val_m, wn_m, gain_m, est_m, True)
                  for _s, m, _r, val_m, _wv, wn_m, gain_m, est_m in passing if m != n]
        for m, r_m, gain_m, est_m, wn_m in self.rivals:
            if wn_m is None:  # not simulated yet on the held-out decays
                vw = corrected(self.val_w, r_m.model, self.nonlinear)
                wn_m = np.sum(window_errors(vw, r_m.model.simulate(vw)) ** 2, axis=1)
            others.append((m, float(np.sum(wn_m)), wn_m, gain_m, est_m, False))
        alike = []
        for m, val_m, wn_m, gain_m, est_m, passed in others:
            p = paired_p_value(wn_m - val_wn)
            if p > self.rule.alpha:
                alike.append({"name": m, "heldout_cost_ratio": val_m / self.cur_val,
                              "fit_gain": gain_m, "t_round": est_m.t,
                              "p_value_round": est_m.p_value, "paired_p_value": p,
                              "value": est_m.value, "passed_round": passed})  # fmt: skip
        self.ev_effects[n] = {
            "round": _round + 1, "fit_gain": gain, "heldout_cost_ratio": val / self.cur_val,
            "heldout_gain": 1 - val / self.cur_val,
            "heldout_windows_improved": int(np.sum(val_wn < self.cur_val_w)),
            "heldout_windows": len(self.val_w), "heldout_weave_error_before": self.cur_wv,
            "heldout_weave_error_after": wv, "t_round": est.t, "dof_round": est.dof,
            "p_value_round": est.p_value, "alike": alike,
        }  # fmt: skip
        self.cur_val, self.cur_wv, self.cur_val_w = val, wv, val_wn
        self.accepted.append(n)
        self.cur = res.model
        if self.cal is not None:  # the offsets move with the accepted effects
            res = fit_effects(self.cur, self.fit_w, self.accepted, res.values, self.wv_fit,
                              self.cal)  # fmt: skip
            self.cur, self.cal = res.model, res.calibration
            self.val_w = corrected(self.val_w, self.cur, self.nonlinear)
            self.heldout_state()

    def run_round(self, _round: int, progress, counter: list[int]) -> bool:
        """One round of forward selection; True when an effect was accepted."""
        base_cost = fit_effects(self.cur, self.fit_w, [], weave=self.wv_fit).cost
        trials = self.fit_candidates(base_cost, progress, counter, _round)
        if self.nonlinear:  # re-rank the leaders with the correction taken at each of them
            trials = self.rerank_leaders(trials, base_cost)
        if _round == 0:
            self.ranking = [z[3] for z in trials]
        passing, log = self.heldout_checks(trials)
        if passing:
            self.accept(passing, _round)
        self.rounds.append({"accepted": self.accepted[-1] if passing else None,
                            "candidates": log})  # fmt: skip
        self.correct_all(self.cur)
        if passing and self.wv_fit:  # the estimator offsets follow the current model
            self.wv_fit = self.wv_fit.at(self.cur, self.fit_w)
        return bool(passing)

    def joint_fit_and_prune(self) -> tuple[FitResult, list[Window]]:
        """The accepted effects refitted jointly on all windows, then pruned backwards of
        any whose joint-fit p-value is above the test's level."""
        windows = self.windows
        if self.wv_all:
            self.wv_all = self.wv_all.at(self.cur, windows)
        accepted = self.accepted
        final = joint_fit(self.model, windows, accepted, {n: self.cur.e(n) for n in accepted},
                          self.nonlinear, self.wv_all, self.cal)  # fmt: skip
        windows = final.windows
        level = self.rule.level(self.tests)

        def pval(n):
            v, sd, cal = final.values[n], final.std[n], final.calibration
            return t_p_value(_t_value(n, v, sd, cal), final.dof)

        while accepted and max(pval(n) for n in accepted) > level:  # backward pruning
            accepted.remove(max(accepted, key=pval))
            final = fit_effects(self.model, windows, accepted, final.values, self.wv_all,
                                final.calibration)  # fmt: skip
            windows = corrected(windows, final.model, self.nonlinear)
        return final, windows

    def conditional_on(self, cal: Calibration | None) -> list[str]:
        """The calibrated offsets held on their box's edge (the tests are conditional on)."""
        return list(cal.as_dict()["at_edge"]) if cal is not None else []


def first_name(passing: list, alpha: float) -> tuple:
    """The candidate a round names first: the best fitting of those the data cannot separate.

    The round's score (held-out cost ratio times held-out weave-error ratio) picks a leader;
    among the passing candidates whose held-out decay costs the paired test
    (:func:`bikeid.ident.effects.acceptance.paired_p_value`) cannot tell from the leader's at
    ``alpha``, the one of least held-out cost is named first (a lag was named before a delay
    that fitted the held-out half better, 0.024 against 0.026, paired p = 0.16).

    Parameters
    ----------
    passing : list of tuple
        (score, name, fit, held-out cost, weave error, held-out cost per decay, fit gain,
        estimate) of each candidate that passed the round's checks.
    alpha : float
        Level of the paired test.

    Returns
    -------
    tuple
        The entry of ``passing`` named first.
    """
    lead = min(passing, key=lambda z: z[0])
    alike = [z for z in passing
             if z is lead or paired_p_value(np.asarray(z[5]) - lead[5]) > alpha]  # fmt: skip
    return min(alike, key=lambda z: (z[3], z is not lead))


def _unexplained(rule: AcceptanceRule, cost0: float, cost_sig: float, floor: float,
                 windows: list[Window], r_sig: np.ndarray, model: ExperimentModel
                 ) -> dict:  # fmt: skip
    """The ``unexplained`` test of the final model (module docstring, step 4)."""
    explained = (cost0 - cost_sig) / max(cost0 - floor, 1e-12 * cost0)
    floor_c = noise_floor(windows, "coloured")
    explained_c = (cost0 - cost_sig) / max(cost0 - floor_c, 1e-12 * cost0)
    floor_r = residual_noise_floor(r_sig, [w.n for w in windows for _ in range(2)])
    left_r = cost_sig / max(floor_r, 1e-300)
    thr = rule.threshold
    inst = instrument_floor(model, windows)
    left_i = cost_sig / max(inst["floor"], 1e-300)
    if rule.unexplained_rule == "instruments":
        structured = left_i > thr
    elif rule.unexplained_rule == "residual":
        structured = left_r > thr
    else:
        structured = (explained if rule.unexplained_rule == "floor" else explained_c) < thr
    return {
        "rule": rule.unexplained_rule, "threshold": thr, "structured": bool(structured),
        "cost_nominal": cost0, "cost_final": cost_sig,
        "floor_second_difference": floor, "floor_coloured": floor_c,
        "floor_residual": floor_r, "explained": float(explained),
        "explained_coloured": float(explained_c), "final_over_residual_floor": left_r,
        "floor_instruments": inst, "final_over_instrument_floor": float(left_i),
    }  # fmt: skip


@single_threaded_blas
def select_effects(
    model: ExperimentModel,
    windows: list[Window],
    candidates: list[str] | None = None,
    max_effects: int = 3,
    nonlinear: bool = False,
    weave_weight: float | str = "auto",
    progress: Callable[[int, int, str], None] | None = None,
    rule: AcceptanceRule | None = None,
) -> Identification:
    """Greedy forward selection of library effects by output error (module docstring).

    The steps, each a method of the search state: the nominal calibrated within its
    uncertainty (with ``rule.nominal_uncertainty``), then per round every candidate fitted on
    the fit half, the leaders re-ranked (nonlinear plant), the significance test and the
    held-out checks, the acceptance of the least score; then the joint fit on all windows with
    backward pruning, the ``unexplained`` test and the evidence.

    Significance (:mod:`bikeid.ident.effects.acceptance`): an effect's t (window-clustered
    standard error) is referred to Student's t with the fit's degrees of freedom (G - 1 for
    G clusters), and its p-value must be at most ``rule.alpha / m`` (Bonferroni over the m
    candidate tests of all ``max_effects`` rounds) in its round and again after the joint fit
    (else it is pruned).  The p-values are reported in the evidence.

    ``weave_weight``: every fit also matches the measured weave eigenvalue of each speed
    with >= 3 decays (:class:`WeaveTerm`, targets from the windows being fitted, offsets
    for the estimator bias re-taken at the current model with the defect correction).
    "auto" (default) weighs it so that, at the nominal model, it carries as much cost as
    the decay signals (w^2 chi2_weave = output-error cost); 0 fits the decay signals only.

    ``nonlinear``: the model is the nonlinear plant through the per-window defect
    correction (:func:`bikeid.ident.effects.experiment_model.with_nonlinear_correction`),
    taken again at the current model after each accepted effect, at each of the three
    leading candidates of a round before they are re-ranked (first-order corrections favoured
    a fractional input delay over a true actuator lag), and twice in the final joint fit.
    The windows given are values and are not changed; the returned identification's
    ``windows`` carry the correction of the final fit.  After the joint fit, effects whose
    p-value is above the level are dropped (backward pruning) and the rest are listed by
    their contribution (increase of the cost when the effect alone is set back to absent).

    Parameters
    ----------
    model : ExperimentModel
        The nominal model.
    windows : list of Window
        The decays (at least 2; every other one is held out while selecting).
    candidates : list of str, optional
        Library names to try (default: all of :data:`bikeid.ident.effects.library.LIBRARY`).
    max_effects : int, optional
        At most this many rounds.
    nonlinear : bool, optional
        Nonlinear plant by defect correction.
    weave_weight : float or "auto", optional
        Weight of the weave term (see above).
    progress : callable, optional
        ``progress(done, total, label)`` before each candidate fit; ``total`` counts the
        candidate fits of ``max_effects`` full rounds (an early stop jumps to the end).
    rule : AcceptanceRule, optional
        When an effect is accepted and when the verdict is ``unexplained``
        (:class:`bikeid.ident.effects.acceptance.AcceptanceRule`: the significance level
        and correction, the fit and held-out gains, the share of held-out decays improved,
        the ``unexplained`` rule and threshold, the nominal uncertainty).  Default:
        :meth:`AcceptanceRule.exact` (the default rule with the stated bicycle taken as
        exact); ``bikeid measured fit`` passes :class:`AcceptanceRule` built from its
        options (by default with the nominal uncertainty).

    Returns
    -------
    Identification
        The final model, accepted effects with values [registry units], standard errors,
        t and p-values, the first round's ranking, the verdict, costs (dimensionless), the
        round log and the final windows.

    Raises
    ------
    ValueError
        If a candidate is not in the library, fewer than 2 windows are given or
        ``weave_weight`` is negative or not finite.
    """
    rule = AcceptanceRule.exact() if rule is None else rule
    names = list(candidates or LIBRARY)
    bad = [n for n in names if n not in LIBRARY]
    if bad:
        raise ValueError(f"unknown candidate effects {bad}; the library has {sorted(LIBRARY)}")
    if len(windows) < 2:
        raise ValueError("identification needs at least 2 windows (one is held out)")
    windows = corrected(windows, model, nonlinear)
    cost0 = cost_stated = fit_effects(model, windows, []).cost  # decay signals ("explained")
    floor = noise_floor(windows)
    lam_all = [decay_eigenvalue(w) for w in windows]  # measured weave of each decay
    unit = WeaveTerm(1.0, weave_targets(windows, lam_all))
    if weave_weight == "auto":
        unit = unit.at(model, windows) if unit.targets else unit
        chi0 = float(np.sum(unit.residuals(model) ** 2)) if unit.targets else 0.0
        weave_weight = math.sqrt(cost0 / chi0) if chi0 > 0 else 0.0  # no weave data: off
    weave_weight = float(weave_weight)
    if not (weave_weight >= 0 and math.isfinite(weave_weight)):
        raise ValueError(f"weave_weight must be 'auto' or a finite number >= 0, got {weave_weight}")
    tests = sum(max(len(names) - r, 0) for r in range(max_effects))
    st = _Search(model, names, rule, nonlinear, windows[0::2], windows[1::2], tests, cur=model,
                 lam_val=lam_all[1::2])  # fmt: skip
    if weave_weight > 0:
        st.wv_fit = WeaveTerm(weave_weight, weave_targets(st.fit_w, lam_all[0::2])).at(
            model, st.fit_w
        )
        st.wv_all = replace(unit, weight=weave_weight)  # offsets taken at the final model
    if rule.nominal_uncertainty is not None:  # the nominal within its uncertainty, fit half
        st.calibrate_nominal(rule.nominal_uncertainty)
        cost0 = fit_effects(st.cur, st.windows, []).cost
    st.heldout_state()
    st.cur_val = fit_effects(st.cur, st.val_w, []).cost  # the same sum, as it was computed
    counter = [0, tests]
    for _round in range(max_effects):
        if not st.run_round(_round, progress, counter):
            break
    if progress:
        progress(tests, tests, "joint fit")
    final, windows = st.joint_fit_and_prune()
    accepted = st.accepted
    contrib = {}  # increase of the fitted cost (signals + weave term) without the effect
    for n in accepted:
        without = final.model.with_effects(**{n: LIBRARY[n].absent})
        contrib[n] = fit_effects(without, windows, [], weave=st.wv_all).cost - final.cost
    accepted.sort(key=lambda n: -contrib[n])
    r_sig = output_residuals(final.model, windows)
    cost_sig = float(r_sig @ r_sig)  # decay signals only, as cost0 and the floor
    unexpl = _unexplained(rule, cost0, cost_sig, floor, windows, r_sig, final.model)
    edge = st.conditional_on(final.calibration)
    effects = []
    for n in accepted:
        v, sd = final.values[n], final.std[n]
        t = _t_value(n, v, sd, final.calibration)
        effects.append(EffectEstimate(n, v, sd, LIBRARY[n].unit, t, unexpl["explained"],
                                      accepted=True, p_value=t_p_value(t, final.dof),
                                      dof=final.dof))  # fmt: skip
    for e in effects:
        st.ev_effects[e.name].update(
            t_joint=e.t, dof_joint=e.dof, p_value=e.p_value,
            p_adjusted=rule.adjusted(e.p_value, tests), conditional_on=edge,
            value=float(e.value),
        )  # fmt: skip
    structured = unexpl.pop("structured")
    nearest = {}
    if structured and effects and unexpl["explained"] < EXPLAINED_TO_NAME:
        nearest = {e.name: st.ev_effects[e.name] for e in effects}  # not named
        st.accepted, effects = [], []
        final, windows = st.joint_fit_and_prune()  # the model without them
    verdict = [e.name for e in effects]
    if structured or (not effects and rule.unexplained_rule != "instruments"):
        verdict = ["unexplained"] + verdict  # (instruments: nothing left, nothing said)
    unexpl["unexplained"] = bool(verdict) and verdict[0] == "unexplained"
    unexpl["explained_to_name"] = EXPLAINED_TO_NAME
    evidence = {
        "effects": {e.name: st.ev_effects[e.name] for e in effects},
        "nearest": nearest,
        "unexplained": unexpl,
        "min_heldout_gain": rule.heldout_gain,
        "min_improved": rule.min_improved,
        "test": {"alpha": rule.alpha, "correction": rule.correction, "tests": tests,
                 "level": rule.level(tests), "reference": "Student t, G - 1 degrees of "
                 "freedom for G window clusters (weave term one more)",
                 "conditional_on_edge_offsets": edge},  # fmt: skip
        "rule": rule.as_dict(),
    }
    if final.calibration is not None:
        evidence["nominal_calibration"] = {
            **st.ev_nominal, **final.calibration.as_dict(), "cost_stated": cost_stated,
            "cost_calibrated": cost0,
        }  # fmt: skip
    return Identification(
        model=final.model, effects=effects, ranking=st.ranking, verdict=verdict,
        cost_nominal=cost0, cost_final=cost_sig, cost_floor=floor,
        explained=unexpl["explained"], eq_ranking=err_ranking(model, windows), rounds=st.rounds,
        weave_weight=weave_weight, evidence=evidence, windows=windows,
        calibration=final.calibration,
    )  # fmt: skip


def _p_text(e: dict, test: dict | None) -> str:
    """The p-value part of an effect's evidence line (empty for records without one)."""
    if not test or "p_value" not in e:
        return ""
    out = (f" ({e['dof_joint']:g} degrees of freedom), p = {e['p_value']:.2g}, "
           f"{test['correction']}-adjusted {e['p_adjusted']:.2g} over {test['tests']} tests "
           f"(level {test['alpha']:g})")  # fmt: skip
    if e.get("conditional_on"):
        out += f"; conditional on the calibration's edge offsets {', '.join(e['conditional_on'])}"
    return out


def evidence_lines(evidence: dict) -> list[str]:
    """The evidence of :attr:`Identification.evidence` as printable lines, one per name.

    Parameters
    ----------
    evidence : dict
        :attr:`Identification.evidence` (or the ``evidence`` of its JSON record).

    Returns
    -------
    list of str
        With a nominal calibration, first a line with its offsets, which sit on the band's
        edge, and its cost and held-out gain; one line per accepted effect (held-out cost
        ratio and gain, held-out windows improved, fit gain, t after the joint fit, its
        degrees of freedom, p-value, adjusted p-value and any edge offsets it is conditional
        on), then
        one for ``unexplained`` (the final
        cost against the noise floors, the rule, its threshold and its answer), and one for
        the nearest members not named, if any.
    """
    out = []
    cal = evidence.get("nominal_calibration")
    if cal:
        offs = ", ".join(f"{k} {100 * v:+.1f} %" if k.startswith("inertia") else
                         f"{k} {1000 * v:+.2f} mm" for k, v in cal["offsets"].items())  # fmt: skip
        edge = ", ".join(cal["at_edge"]) or "none"
        out.append(
            f"nominal within its uncertainty (inertia +-{100 * cal['uncertainty']['inertia']:g} "
            f"%, trail +-{1000 * cal['uncertainty']['trail']:g} mm), final offsets {offs} "
            f"(on the band's edge: {edge}); before any effect the calibration took the cost "
            f"{cal['cost_stated']:.4g} -> {cal['cost_calibrated']:.4g} with held-out gain "
            f"{100 * cal['heldout_gain']:.1f} % (a correction, not an effect)"
        )
    for name, e in evidence.get("effects", {}).items():
        out.append(
            f"evidence for {name}: held-out cost ratio {e['heldout_cost_ratio']:.3f} (gain "
            f"{100 * e['heldout_gain']:.1f} %, needed {100 * evidence['min_heldout_gain']:.1f} "
            f"%), {e['heldout_windows_improved']}/{e['heldout_windows']} held-out decays "
            f"improved, fit gain {100 * e['fit_gain']:.1f} % (round {e['round']}), t "
            f"{e.get('t_joint', float('nan')):.1f} after the joint fit"
            + _p_text(e, evidence.get("test"))
        )
        if e.get("alike"):
            out.append(f"  {name} cannot be told apart (paired held-out test) from: " + "; ".join(
                f"{a['name']} (held-out cost ratio {a['heldout_cost_ratio']:.3f}, fit gain "
                f"{100 * a['fit_gain']:.1f} %, paired p = {a['paired_p_value']:.2g}"
                + ("" if a.get("passed_round", True) else ", not significant after the "
                   "correction") + ")"
                for a in e["alike"]))  # fmt: skip
    u = evidence.get("unexplained")
    if u:
        if u["rule"] == "residual":
            test = (f"final cost / residual floor {u['final_over_residual_floor']:.2f} "
                    f"(unexplained above {u['threshold']:.2f})")  # fmt: skip
        else:
            key = "explained" if u["rule"] == "floor" else "explained_coloured"
            floor = "second-difference" if u["rule"] == "floor" else "coloured"
            test = (f"explained fraction ({floor} floor) {u[key]:.2f} (unexplained below "
                    f"{u['threshold']:.2f})")  # fmt: skip
        out.append(
            f"evidence for unexplained: cost nominal {u['cost_nominal']:.4g} -> final "
            f"{u['cost_final']:.4g}; noise floors: second differences "
            f"{u['floor_second_difference']:.4g}, coloured {u['floor_coloured']:.4g}, final "
            f"residual {u['floor_residual']:.4g}; {test} -> "
            + ("unexplained" if u["unexplained"] else "explained")
        )
    near = evidence.get("nearest") or {}
    if near:
        out.append(
            "nearest library members, not named (accepted by the tests, yet with them "
            f"{u['explained']:.2f} of the nominal's excess over the floor is explained, below "
            f"{u.get('explained_to_name', EXPLAINED_TO_NAME):.2f}: no member explains the "
            "residual well): " + "; ".join(
                f"{n} {e['value']:.4g} (held-out gain {100 * e['heldout_gain']:.1f} %, "
                f"{e['heldout_windows_improved']}/{e['heldout_windows']} held-out decays "
                "improved)" for n, e in near.items()))  # fmt: skip
    return out


def compare_nominal_plants(model: ExperimentModel, windows: list[Window]) -> dict:
    """How the nominal model fits the windows as a linear and as a nonlinear plant.

    A structural mismatch of the nominal plant (a linear truth fitted by the nonlinear plant,
    or the reverse) is otherwise read as an effect; comparing both before selecting lets
    the fit start from the plant that the data prefer and say so.

    Parameters
    ----------
    model : ExperimentModel
        The nominal model (no effects fitted).
    windows : list of Window
        The decays; left unchanged (copies carry the nonlinear correction).

    Returns
    -------
    dict
        ``linear`` and ``nonlinear``: summed squared NRMSE of roll rate and steer angle
        (:func:`bikeid.ident.effects.experiment_model.window_errors`, dimensionless);
        ``preferred``: the plant with the lower cost; ``ratio``: nonlinear / linear cost.
    """
    out: dict = {}
    for name, nonlinear in (("linear", False), ("nonlinear", True)):
        ws = corrected([replace(w, correction=None) for w in windows], model, nonlinear)
        out[name] = float(np.sum(window_errors(ws, model.simulate(ws)) ** 2))
    out["preferred"] = "nonlinear" if out["nonlinear"] <= out["linear"] else "linear"
    out["ratio"] = out["nonlinear"] / max(out["linear"], 1e-300)
    return out


def choose_nominal_plant(comparison: dict, margin: float = LINEAR_PLANT_MARGIN) -> dict:
    """The nominal plant chosen before any effect, given :func:`compare_nominal_plants`.

    Used by the blind trials' ``nonlinear="auto"``
    (:func:`bikeid.experiments.measured.blind_trials.run_blind_trial`, the calibration of
    :data:`LINEAR_PLANT_MARGIN`); ``bikeid measured fit`` chooses after selection instead
    (:func:`choose_plant`), because an effect in the data shifts these costs.
    The nonlinear plant is the default (the real bicycle is nonlinear); the linear plant is
    taken only when its nominal cost is lower by more than the factor ``margin``, so that a
    plant mismatch larger than the fit scatter is not read as an effect, while decays that
    barely prefer the linear plant (the real ones: 1.4 % at 2.5+4.5 m/s) keep the nonlinear.

    Parameters
    ----------
    comparison : dict
        :func:`compare_nominal_plants`'s result (``linear``, ``nonlinear``: summed squared
        NRMSE, dimensionless).
    margin : float, optional
        Least ratio nonlinear / linear cost for the linear plant (>= 1; default
        :data:`LINEAR_PLANT_MARGIN`).

    Returns
    -------
    dict
        ``plant`` (``"linear"`` or ``"nonlinear"``), ``ratio`` (nonlinear / linear cost),
        ``margin``, ``reason`` (one sentence: the costs and the rule) and ``inconclusive``
        (True when the ratio lies within [1 / margin, margin]: neither plant fits better by
        the margin, so the nominal costs alone do not settle the plant; the blind trials'
        nonlinear truths reach 1.14 and linear truths lie within 5 % of 1, both inside).

    Raises
    ------
    ValueError
        If ``margin`` is below 1 or not finite.
    """
    if not (math.isfinite(margin) and margin >= 1.0):
        raise ValueError(f"margin must be a finite number >= 1, got {margin!r}")
    lin, nl = float(comparison["linear"]), float(comparison["nonlinear"])
    ratio = nl / max(lin, 1e-300)
    linear = ratio > margin
    how = "more" if linear else "not more"
    reason = (f"nominal cost linear {lin:.4g}, nonlinear {nl:.4g} (ratio {ratio:.3g}): the "
              f"linear plant fits {how} than {margin:g} times better, so the "
              f"{'linear' if linear else 'nonlinear'} plant")  # fmt: skip
    return {"plant": "linear" if linear else "nonlinear", "ratio": ratio, "margin": margin,
            "reason": reason, "inconclusive": bool(1.0 / margin <= ratio <= margin)}  # fmt: skip


def compare_plant_selections(linear: Identification, nonlinear: Identification) -> dict:
    """Do the selections with the linear and the nonlinear nominal plant agree?

    They agree when every effect one of them accepts is accepted by the other or is alike one
    of the other's accepted effects (either effect in the other's ambiguity set,
    :attr:`Identification.ambiguity`, the sets the pipeline reports: two alike effects are
    the same answer), and both or neither say ``unexplained``.  Otherwise the effects named
    depend on the nominal plant: a mismatch of the plant would be read as an effect.

    Parameters
    ----------
    linear, nonlinear : Identification
        :func:`select_effects` on the same windows with ``nonlinear=False`` and ``True``.

    Returns
    -------
    dict
        ``agree`` (bool); ``linear`` and ``nonlinear``: each plant's ``verdict``, ``effects``
        (name -> value, registry units) and ``ambiguity``; ``differences``: sentences naming
        each effect only one plant names (empty when they agree); ``only``: the names of
        those effects by plant; ``nested``: when they disagree only because one selection
        names effects beyond the other's (every effect of the other is it or alike it,
        ``unexplained`` said by both or neither), the plant
        of the smaller selection, else None.
    """
    def side(r: Identification) -> dict:
        return {"verdict": list(r.verdict), "effects": {e.name: float(e.value) for e in r.effects},
                "ambiguity": r.ambiguity}  # fmt: skip

    def alike(n: str, mine: dict, m: str, other: dict) -> bool:  # either set holds the other
        return n == m or n in other["ambiguity"].get(m, []) or m in mine["ambiguity"].get(n, [])

    a, b = side(linear), side(nonlinear)
    diff, only = [], {}
    for mine, other, who, whom in ((a, b, "linear", "nonlinear"), (b, a, "nonlinear", "linear")):
        only[who] = [n for n in mine["effects"]
                     if not any(alike(n, mine, m, other) for m in other["effects"])]  # fmt: skip
        diff += [f"{n} (named with the {who} plant; no effect of the {whom} plant's selection "
                 "is it or alike it)" for n in only[who]]  # fmt: skip
    same_flag = ("unexplained" in a["verdict"]) == ("unexplained" in b["verdict"])
    if not same_flag:
        who = "linear" if "unexplained" in a["verdict"] else "nonlinear"
        diff.append(f"unexplained (only with the {who} plant)")
    nested = None
    if diff and same_flag and not (only["linear"] and only["nonlinear"]):
        nested = "nonlinear" if only["linear"] else "linear"
    return {"agree": not diff, "linear": a, "nonlinear": b, "differences": diff,
            "only": only, "nested": nested}  # fmt: skip


def out_of_fold_costs(
    model: ExperimentModel, selection: Identification, nonlinear: bool
) -> np.ndarray:
    """Each decay's cost under a selection's final effect set refitted without that decay.

    Two-fold cross-fitting on the selection's own halves (even and odd windows): the final
    model's effects (and, with a nominal calibration, its offsets within the box) are
    refitted on one half (:func:`bikeid.ident.effects.fit.joint_fit`, decay signals only,
    from the final values; with the nonlinear plant from the final fit's defect correction,
    taken again twice at the half's own fit) and every decay of the other half is scored by
    that fit (the nonlinear plant's correction taken at it), then the halves swap.  A
    parameter that only fits the noise of one half raises the other half's cost, so the
    number of effects is paid for in the cost itself (cross-validation; Stone 1977 shows
    leave-one-out cross-validation asymptotically equivalent to AIC, two folds penalize
    more).

    Parameters
    ----------
    model : ExperimentModel
        The nominal model the selection started from (stated bicycle, no effects).
    selection : Identification
        :func:`select_effects`'s result (its ``windows``, ``effects``, ``model`` and
        ``calibration``).
    nonlinear : bool
        The plant the selection ran with (True: the nonlinear plant by defect correction).

    Returns
    -------
    (n,) ndarray
        Per window of ``selection.windows``, in order: the summed squared NRMSE of roll rate
        and steer angle (dimensionless) of the fit on the other half; nan where the
        nonlinear plant could not simulate the window (or the half it was fitted on) at
        that fit.
    """
    from bikeid.ident.effects.experiment_model import SimulationFailed

    # the fit half starts from the final fit's defect correction (a nearer linearization
    # point than the nominal's: half the CPU; joint_fit then takes it twice at the half's own
    # fit); each held-out decay is corrected afresh at the half's fit
    ws = list(selection.windows) if nonlinear else [replace(w, correction=None)
                                                    for w in selection.windows]  # fmt: skip
    names = [e.name for e in selection.effects]
    start = {n: selection.model.e(n) for n in names}
    out = np.full(len(ws), np.nan)
    idx = np.arange(len(ws))
    for fit_i, held_i in ((idx[0::2], idx[1::2]), (idx[1::2], idx[0::2])):
        if fit_i.size == 0:
            continue
        try:
            f = joint_fit(model, [ws[i] for i in fit_i], names, start, nonlinear, None,
                          selection.calibration)  # fmt: skip
        except SimulationFailed:  # the half cannot be fitted: its held-out decays unscored
            continue
        for i in held_i:
            try:
                w = corrected([replace(ws[i], correction=None)], f.model, nonlinear)
            except SimulationFailed:
                continue
            out[i] = float(np.sum(window_errors(w, f.model.simulate(w)) ** 2))
    return out


def plant_verdict(
    costs_linear: np.ndarray,
    costs_nonlinear: np.ndarray,
    check: dict,
    alpha: float = 0.05,
    effects: tuple[int, int] | None = None,
    groups: list[str] | None = None,
) -> dict:
    """The rule of :func:`choose_plant`, from the per-decay costs and the selections' comparison.

    Over the decays scored by both plants (finite in both arrays), the out-of-fold cost
    ratio nonlinear / linear and its paired test are those of every before/after figure of
    the pipeline (:func:`bikeid.ident.effects.before_after.before_after`, "before" the
    linear, "after" the nonlinear: the statistic is the mean over log files of each file's
    mean decay cost; the test a two-sided sign-flip randomization test of the per-decay
    differences, stratified by file, 4000 flips, seed 0; the interval a bootstrap over decays
    within files).  The rule:

    - p <= ``alpha`` (separated): the plant of the lower cost;
    - otherwise (the final models fit alike) and the selections agree (``check["agree"]``):
      the nonlinear plant, the default (the real bicycle is nonlinear; the linear plant is
      taken only when the data show it fits better), whose effects are the agreed ones up
      to the ambiguity sets;
    - otherwise, when one selection only adds effects to the other's (``check["nested"]``):
      the plant of the smaller selection, whose effects both plants support (an effect
      named with one nominal plant only could be that plant's mismatch read as an effect;
      it is reported in ``plant_check`` as plant-dependent, not named);
    - otherwise :data:`PLANT_UNCERTAIN` (the nonlinear plant's selection is kept, its effects
      not named).

    Parameters
    ----------
    costs_linear, costs_nonlinear : (n,) ndarray
        Per-decay out-of-fold costs (:func:`out_of_fold_costs`, dimensionless; nan: not
        scored), the same decays in the same order.
    check : dict
        :func:`compare_plant_selections` of the two selections (``agree``).
    alpha : float, optional
        Level of the paired test (default 0.05).
    effects : tuple of int, optional
        Number of effects of the linear and the nonlinear final model (for the sentence).
    groups : list of str, optional
        Each decay's log file (the strata; default: one stratum).

    Returns
    -------
    dict
        ``plant``, ``uncertain``, ``plant_dependent`` (the effects named with the other
        plant only when the nested branch chose, else empty), ``reason`` and ``test`` as
        :func:`choose_plant` describes.

    Raises
    ------
    ValueError
        If the cost arrays (or ``groups``) differ in length.
    """
    from bikeid.ident.effects.before_after import before_after

    lin, nl = np.asarray(costs_linear, float), np.asarray(costs_nonlinear, float)
    g = ["decays"] * lin.size if groups is None else list(groups)
    if not lin.shape == nl.shape == (len(g),):
        raise ValueError(f"the selections ran on different windows ({lin.size} linear, "
                         f"{nl.size} nonlinear, {len(g)} files); run both on the same "
                         "decays")  # fmt: skip
    ok = np.isfinite(lin) & np.isfinite(nl)
    test = {"decays": int(ok.sum()), "unscored": int((~ok).sum()), "alpha": alpha,
            "statistic": "out-of-fold cost ratio nonlinear / linear (mean over files of the "
            "file means); sign-flip paired test, stratified by file"}  # fmt: skip
    if ok.sum() >= 2 and np.sum(lin[ok]) > 0:
        ba = before_after(lin[ok], nl[ok], [x for x, k in zip(g, ok, strict=True) if k])
        test.update(linear_cost=ba["error_before"], nonlinear_cost=ba["error_after"],
                    ratio=ba["ratio"], ratio_ci=ba["ratio_ci"], p_value=ba["p_value"])
    else:  # nothing to compare: the costs cannot separate the plants
        test.update(linear_cost=float(np.mean(lin[ok])) if ok.any() else float("nan"),
                    nonlinear_cost=float(np.mean(nl[ok])) if ok.any() else float("nan"),
                    ratio=float("nan"), ratio_ci=[float("nan")] * 2, p_value=1.0)
    p = test["p_value"]
    separated = bool(p <= alpha)
    better = "linear" if separated and test["ratio"] > 1 else "nonlinear"
    nested = None if separated or check["agree"] else check.get("nested")
    dependent = []
    if nested:
        better = nested
        dependent = check["only"]["linear" if nested == "nonlinear" else "nonlinear"]
    test["separated"] = separated
    uncertain = not separated and not check["agree"] and not nested
    n_eff = ("", "") if effects is None else (f" ({effects[0]} effects)", f" ({effects[1]} "
                                               "effects)")  # fmt: skip
    if effects is not None:
        test["effects"] = {"linear": int(effects[0]), "nonlinear": int(effects[1])}
    lo, hi = test["ratio_ci"]
    head = (f"chosen after selection: the final models' out-of-fold decay cost linear "
            f"{test['linear_cost']:.4g}{n_eff[0]}, nonlinear {test['nonlinear_cost']:.4g}"
            f"{n_eff[1]} (ratio {test['ratio']:.3g}, 95 % interval {lo:.3g}-{hi:.3g}) over "
            f"{test['decays']} decays, paired p = {p:.2g} (level {alpha:g}): ")  # fmt: skip
    if separated:
        tail = f"the {better} plant fits better, so the {better} plant and its effects"
    elif check["agree"]:
        tail = ("they fit alike and their selections agree, so the nonlinear plant (the "
                "default unless the linear fits better) and the agreed effects")  # fmt: skip
    elif nested:
        tail = (f"they fit alike and the other plant's selection only adds "
                f"{', '.join(dependent)} (named with one nominal plant only: plant-dependent, "
                f"not named), so the {nested} plant and the effects both plants support")
    else:
        tail = f"they fit alike and their selections disagree: {PLANT_UNCERTAIN}"
    return {"plant": better, "uncertain": uncertain, "plant_dependent": dependent,
            "reason": head + tail, "test": test}  # fmt: skip


def choose_plant(
    model: ExperimentModel,
    linear: Identification,
    nonlinear: Identification,
    alpha: float = 0.05,
) -> dict:
    """The nominal plant chosen after selection, by the two final models' fits to the decays.

    Each plant's selection (:func:`select_effects` on the same windows) ends in a final model;
    both are scored on every decay by :func:`out_of_fold_costs` (refitted on the other half:
    the penalty for the number of effects), and the per-decay costs are compared by the
    pipeline's paired before/after machinery
    (:func:`bikeid.ident.effects.before_after.before_after`: the ratio nonlinear / linear of
    the mean over files of the file-mean costs, a sign-flip paired test stratified by file,
    two-sided at ``alpha``; the decays are independent pushes, the clusters of the
    selection's own tests); :func:`plant_verdict` applies the rule:

    - p <= ``alpha``: the plant with the lower out-of-fold cost, and its selection;
    - otherwise the final models fit alike; if the selections agree
      (:func:`compare_plant_selections`: every effect named by one is named by the other or
      in an ambiguity set with one of its effects, ``unexplained`` on both or neither), the
      nonlinear plant (the default: the linear is taken only when the data show it fits
      better) and its effects, which are the agreed ones up to those sets;
    - otherwise, if one selection only adds effects to the other's (``nested``), the plant of
      the smaller one: the effects both plants support are named, the additions (named with
      one nominal plant only) are reported as plant-dependent;
    - otherwise :data:`PLANT_UNCERTAIN`: which effects are named depends on a plant the data
      cannot choose, so none is.

    The sign-flip test's smallest p-value with n decays is 2 / 2^n, so with 5 decays or fewer
    it never separates the plants at 0.05: such fits name effects only where the two
    selections agree.

    Parameters
    ----------
    model : ExperimentModel
        The nominal model both selections started from.
    linear, nonlinear : Identification
        :func:`select_effects` on the same windows with ``nonlinear=False`` and ``True``.
    alpha : float, optional
        Level of the paired test (two-sided; default 0.05, the acceptance rule's).

    Returns
    -------
    dict
        ``plant`` (``"linear"`` or ``"nonlinear"``: the selection to report; with
        ``uncertain``, the nonlinear, whose effects are not named),
        ``uncertain`` (bool), ``plant_dependent`` (effects the other plant's selection adds,
        not named; nested branch only), ``reason`` (one sentence: the costs, the test and
        the rule's branch), ``test`` (``linear_cost`` and ``nonlinear_cost``: out-of-fold
        costs, mean over files of the file means, over the decays both scored; ``ratio`` nonlinear /
        linear and ``ratio_ci`` its 95 % bootstrap interval; ``p_value``; ``alpha``;
        ``decays``; ``unscored``: decays left out for both because one plant could not
        simulate them; ``separated``: p <= alpha; ``effects``: the
        number of effects of each final model; ``costs``: the per-decay costs of each plant,
        in the windows' order, nan where not scored) and ``check``
        (:func:`compare_plant_selections`).
    """
    lin = out_of_fold_costs(model, linear, False)
    nl = out_of_fold_costs(model, nonlinear, True)
    check = compare_plant_selections(linear, nonlinear)
    out = plant_verdict(lin, nl, check, alpha, (len(linear.effects), len(nonlinear.effects)),
                        [w.file for w in linear.windows])  # fmt: skip
    out["test"]["costs"] = {"linear": [float(x) for x in lin],
                            "nonlinear": [float(x) for x in nl]}  # fmt: skip
    return {**out, "check": check}


def selection_frequencies(
    model: ExperimentModel,
    windows: list[Window],
    resamples: int = 20,
    fraction: float = 0.75,
    seed: int = 0,
    progress: Callable[[int, int, str], None] | None = None,
    **select_kw,
) -> dict[str, float]:
    """How stable is the verdict?  Fraction of subsamples in which each name is selected.

    Stability selection (Meinshausen & Buehlmann 2010) over decays: each of ``resamples``
    runs of :func:`select_effects` sees a random ``fraction`` of the windows of every file (drawn
    without replacement, at least 2 per file, so every speed stays in), and each name of its
    verdict (``"unexplained"`` included) is counted.  A name near 1 is what the data say
    whichever decays are used; names well below 1 depend on which pushes were logged.
    ``select_kw`` go to :func:`select_effects` (e.g. ``nonlinear=True``, ``max_effects``).

    Parameters
    ----------
    model : ExperimentModel
        The nominal model.
    windows : list of Window
        The decays to subsample.
    resamples : int, optional
        Number of subsamples.
    fraction : float, optional
        Fraction of each file's windows in a subsample.
    seed : int, optional
        Generator seed.
    progress : callable, optional
        ``progress(done, resamples, label)`` before each subsample.

    Returns
    -------
    dict of str to float
        Selection frequency (0-1) of each name, highest first.
    """
    if int(resamples) != resamples or resamples < 1:
        raise ValueError(f"resamples must be a positive integer, got {resamples!r}")
    if not 0.0 < fraction <= 1.0:
        raise ValueError(f"fraction must be in (0, 1], got {fraction!r}")
    rng = np.random.default_rng(seed)
    groups: dict[str, list[int]] = {}
    for i, w in enumerate(windows):
        groups.setdefault(w.file, []).append(i)
    counts: dict[str, int] = {}
    for i_sub in range(int(resamples)):
        if progress:
            progress(i_sub, int(resamples), f"subsample {i_sub + 1}")
        pick = []
        for idx in groups.values():
            k = min(len(idx), max(2, round(fraction * len(idx))))
            pick.extend(sorted(rng.choice(idx, size=k, replace=False)))
        sub = [replace(windows[i], correction=None) for i in sorted(pick)]  # own copies
        for name in select_effects(model, sub, **select_kw).verdict:
            counts[name] = counts.get(name, 0) + 1
    return dict(sorted(((k, v / resamples) for k, v in counts.items()), key=lambda z: -z[1]))
