"""Windows are values: a fit never changes the windows it is given, so fitting twice on the
same windows gives the same result; and the acceptance rule is one checked value."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from bikeid.ident.effects.acceptance import AcceptanceRule, t_p_value
from bikeid.ident.effects.experiment_model import ExperimentModel, with_nonlinear_correction
from bikeid.ident.effects.fit import joint_fit
from bikeid.ident.effects.selection import select_effects
from bikeid.ident.effects.synthetic_decays import synthetic_windows

TRUTH = ExperimentModel(effects={"steer_viscous_damping": 0.4})


def test_window_is_frozen_and_correction_is_returned():
    """Assigning a field is refused; the defect correction comes back on new windows and the
    inputs keep none (known both ways: the returned windows carry one per channel)."""
    ws = synthetic_windows(TRUTH, [1.5], 2, seed=1)
    with pytest.raises(dataclasses.FrozenInstanceError):
        ws[0].correction = {}
    out = with_nonlinear_correction(ws)
    assert all(w.correction is None for w in ws)
    assert all(set(w.correction) == {"phi", "delta", "phidot", "deltadot"} for w in out)
    # at 1.5 m/s the nonlinear plant differs from the linear one (docs: NRMSE 0.1-0.45)
    assert max(np.abs(w.correction["delta"]).max() for w in out) > 1e-4


def test_fitting_twice_on_the_same_windows_gives_the_same_result():
    """The nonlinear joint fit and the whole selection, run twice on the same windows, give
    bit-identical values.  When the correction was attached in place, the second joint fit
    started from the first one's correction instead of the nominal's (the fault of a
    correction attached twice), so this equality is what the value semantics buy."""
    ws = synthetic_windows(TRUTH, [1.5, 3.5], 2, seed=1)
    a = joint_fit(ExperimentModel(), ws, ["steer_viscous_damping"], None, nonlinear=True)
    b = joint_fit(ExperimentModel(), ws, ["steer_viscous_damping"], None, nonlinear=True)
    assert a.values == b.values and a.cost == b.cost
    assert all(w.correction is None for w in ws)
    kw = {"candidates": ["steer_viscous_damping", "command_gain"], "max_effects": 1,
          "nonlinear": True}  # fmt: skip
    r1 = select_effects(ExperimentModel(), ws, **kw)
    r2 = select_effects(ExperimentModel(), ws, **kw)
    assert r1.verdict == r2.verdict
    assert [e.value for e in r1.effects] == [e.value for e in r2.effects]
    assert r1.cost_final == r2.cost_final
    assert all(w.correction is None for w in ws)
    assert all(w.correction is not None for w in r1.windows)


def test_acceptance_rule_defaults_and_refusals():
    """Defaults stated once (the held-out gain follows the fit gain; the unexplained
    threshold follows the nominal uncertainty; the ``instruments`` rule's is 1.3 times the
    instruments' floor), Bonferroni level alpha / m, and every field outside its range
    refused by name."""
    r = AcceptanceRule()
    assert r.heldout_gain == r.min_gain == 0.02
    assert r.threshold == 0.85 and AcceptanceRule.exact().threshold == 0.9
    assert AcceptanceRule(unexplained_rule="instruments").threshold == 1.3
    assert AcceptanceRule(unexplained_rule="residual").threshold == 2.0
    assert r.level(54) == pytest.approx(0.05 / 54)
    assert AcceptanceRule(correction="none").level(54) == 0.05
    assert r.adjusted(0.01, 54) == 0.54 and r.adjusted(0.1, 54) == 1.0
    for bad, field in (({"alpha": 0.0}, "alpha"), ({"correction": "holm"}, "correction"),
                       ({"min_heldout_gain": 1.0}, "min_heldout_gain"),
                       ({"min_improved": 1.5}, "min_improved"),
                       ({"unexplained_rule": "x"}, "unexplained_rule"),
                       ({"unexplained_threshold": -1.0}, "unexplained_threshold")):  # fmt: skip
        with pytest.raises(ValueError, match=field):
            AcceptanceRule(**bad)


def test_t_p_value_against_tables():
    """Student t two-sided p-values against printed tables: t = 2.571 at 5 degrees of freedom
    is the 5 % point, 2.447 at 6 (Student t table, 3 decimals: tolerance 1e-3), and the
    normal limit 1.960 at infinite degrees of freedom."""
    assert t_p_value(2.571, 5) == pytest.approx(0.05, abs=1e-3)
    assert t_p_value(-2.447, 6) == pytest.approx(0.05, abs=1e-3)
    assert t_p_value(1.960, float("inf")) == pytest.approx(0.05, abs=1e-3)
    assert t_p_value(float("inf"), 3) == 0.0 and t_p_value(float("nan"), 3) == 1.0


def test_paired_p_value_closed_form():
    """The paired t test of the ambiguity sets against the closed form of Student t with 2
    degrees of freedom, two-sided p = 1 - t / sqrt(t^2 + 2) (exact; tolerance 1e-12):
    d = [1, 2, 3] gives t = 2 sqrt(3); differences that cancel give p = 1, equal non-zero
    ones p = 0."""
    from bikeid.ident.effects.acceptance import paired_p_value

    t = 2 * np.sqrt(3.0)
    assert paired_p_value([1.0, 2.0, 3.0]) == pytest.approx(1 - t / np.sqrt(t * t + 2), abs=1e-12)
    assert paired_p_value([1.0, -1.0, 1.0, -1.0]) == pytest.approx(1.0)
    assert paired_p_value([0.5, 0.5, 0.5]) == 0.0 and paired_p_value([0.0, 0.0]) == 1.0


def test_evidence_lines_print_p_values_and_the_ambiguity_set():
    """An accepted effect's line carries its degrees of freedom, p-value, adjusted p-value
    and the edge offsets it is conditional on; a candidate the held-out decays cannot tell
    from it gets its own line with its numbers."""
    from bikeid.ident.effects.selection import evidence_lines

    ev = {"min_heldout_gain": 0.02,
          "test": {"alpha": 0.05, "correction": "bonferroni", "tests": 54, "level": 0.05 / 54},
          "effects": {"input_delay": {
              "round": 1, "fit_gain": 0.6, "heldout_cost_ratio": 0.4, "heldout_gain": 0.6,
              "heldout_windows_improved": 6, "heldout_windows": 6, "t_joint": 9.0,
              "dof_joint": 12.0, "p_value": 1.1e-6, "p_adjusted": 5.9e-5,
              "conditional_on": ["trail"],
              "alike": [{"name": "actuator_lag", "heldout_cost_ratio": 0.41, "fit_gain": 0.59,
                         "t_round": 8.0, "p_value_round": 1e-4, "paired_p_value": 0.62,
                         "value": 0.03}]}}}  # fmt: skip
    lines = evidence_lines(ev)
    assert "(12 degrees of freedom), p = 1.1e-06, bonferroni-adjusted 5.9e-05 over 54" in lines[0]
    assert "conditional on the calibration's edge offsets trail" in lines[0]
    assert "input_delay cannot be told apart" in lines[1] and "actuator_lag" in lines[1]
    assert "paired p = 0.62" in lines[1]


def test_trial_residuals_step_back_from_points_the_model_cannot_take():
    """A least-squares search whose residual raises beyond x = 2.5 (as the k-step error's
    Kalman filter does for a trial model too unstable to have one) steps back and finds the
    root of exp(x) - e^2 at x = 2 (analytic; tolerance: least_squares' default xtol 1e-8),
    where the unguarded search stops at the error (both ways).  At the start point the
    error is the caller's and is raised; residuals are clipped to +-TRIAL_FAILURE and
    non-finite ones set to it."""
    from scipy.optimize import least_squares

    from bikeid.ident.effects.fit import TRIAL_FAILURE, trial_residuals

    tried = []

    def fun(x):
        tried.append(float(x[0]))
        if x[0] > 2.5:
            raise ValueError("no model here")
        return np.array([np.exp(x[0]) - np.exp(2.0)])

    sol = least_squares(trial_residuals(fun), [0.0])
    assert max(tried) > 2.5  # the search did try a point the model cannot take
    assert sol.x[0] == pytest.approx(2.0, abs=1e-7)
    with pytest.raises(ValueError, match="no model here"):
        least_squares(fun, [0.0])
    with pytest.raises(ValueError, match="no model here"):
        trial_residuals(fun)(np.array([3.0]))  # the start: raised
    g = trial_residuals(lambda x: np.array([x[0], np.inf, -np.nan, -5e3]))
    np.testing.assert_array_equal(g(np.array([1.0])), [1.0, TRIAL_FAILURE, TRIAL_FAILURE,
                                                       -TRIAL_FAILURE])  # fmt: skip
