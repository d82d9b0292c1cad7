"""Injected-effect checks with the *linear* experiment model as the simulator (10 substeps,
noise + encoder quantization): the pipeline, not told, names the effect.  The randomized
trials on the nonlinear plant are in tests/experiments/measured/test_effect_trials.py."""

from __future__ import annotations

from dataclasses import replace

import pytest

from bikeid.ident.effects.diagnostics import evaluate
from bikeid.ident.effects.experiment_model import ExperimentModel
from bikeid.ident.effects.fit import fit_effects
from bikeid.ident.effects.selection import select_effects, selection_frequencies
from bikeid.ident.effects.synthetic_decays import synthetic_windows
from bikeid.ident.effects.weave import weave_error
from bikeid.ident.validate import whiteness


def test_whiteness_band():
    """White noise: about 1 % of r(1..25) outside the 99 % band (identification.md T10)."""
    import numpy as np

    e = np.random.default_rng(0).normal(size=20000)
    assert whiteness(e)["fraction_outside"] <= 0.12


@pytest.mark.parametrize(
    "effect, value",
    [
        ("steer_viscous_damping", 0.4),
        ("command_gain", 0.8),
        ("input_delay", 0.03),
        ("steer_stiffness", 1.5),
    ],  # fmt: skip
)
def test_injected_library_effect_is_named(effect, value):
    """Right effect ranked first, magnitude within 20 % (brief), held-out error halves."""
    truth = ExperimentModel(effects={effect: value})
    fit = synthetic_windows(truth, [1.5, 3.5], 4, seed=1)
    held = synthetic_windows(truth, [2.5, 4.5], 4, seed=2)
    res = select_effects(ExperimentModel(), fit, max_effects=2)
    assert res.verdict[0] == effect
    assert res.effects[0].value == pytest.approx(value, rel=0.2)
    ev = evaluate(ExperimentModel(), res.model, held)
    assert ev["summary"]["error_after"] <= 0.5 * ev["summary"]["error_before"]


def test_effect_outside_library_is_unexplained():
    """Roll viscous damping is not in the library: the verdict must start 'unexplained'."""
    truth = ExperimentModel(effects={"roll_viscous_damping": 1.5})
    res = select_effects(ExperimentModel(), synthetic_windows(truth, [1.5, 3.5], 4, seed=3),
                   max_effects=2)  # fmt: skip
    assert res.verdict[0] == "unexplained"


def test_weave_error_same_estimator_cancels_fit_bias():
    """evaluate() compares the damped-oscillation fit of the data with the same fit of the
    model's decays: a model that *is* the truth (noise-free) scores ~0 (bound 1e-3, fit
    round-off) although the fit's bias against the loop's root (a second, independent
    number) is larger."""
    truth = ExperimentModel(effects={"steer_viscous_damping": 0.3})
    ws = synthetic_windows(truth, [2.5], 3, noise=0.0, seed=4)
    # synthetic_windows quantizes the steer angle; undo for a clean check
    ws = [replace(w, delta=truth.simulate([w], nsub=10)[0]["delta"]) for w in ws]
    ev = evaluate(truth, truth, ws)["summary"]
    assert ev["weave_error_before"] < 1e-3 and ev["weave_error_after"] < 1e-3
    assert ev["weave_root_error_before"] > ev["weave_error_before"]


def test_effect_std_matches_monte_carlo_scatter():
    """The clustered (by window) standard error of an output-error estimate agrees with the
    scatter of the estimate over 30 independent noise draws (a second, empirical number).
    Noise 0.05 rad/s (5x the default) so the scatter is not round-off.  Tolerance: the
    sample std of 30 draws is uncertain by ~13 % (1/sqrt(2 (n-1))) and a clustered
    standard error over 8 windows by ~25 %; the ratio must lie in [0.6, 1.6]."""
    import numpy as np

    truth = ExperimentModel(effects={"steer_viscous_damping": 0.4})
    est, std = [], []
    for seed in range(30):
        ws = synthetic_windows(truth, [2.5, 4.5], 4, noise=0.05, seed=100 + seed)
        r = fit_effects(ExperimentModel(), ws, ["steer_viscous_damping"])
        est.append(r.values["steer_viscous_damping"])
        std.append(r.std["steer_viscous_damping"])
    ratio = np.median(std) / np.std(est, ddof=1)
    assert 0.6 <= ratio <= 1.6, (ratio, np.mean(est))
    assert abs(np.mean(est) - 0.4) < 3 * np.std(est, ddof=1) / np.sqrt(30) + 1e-3


def test_weave_error_is_relative_root_shift():
    """weave_error of noise-free decays: ~0 against their own model (bound 1e-3, fit
    round-off), and for a model with more steer damping the relative shift of the fitted
    weave, which must match the relative shift of the loop's weave root (the independent
    eigenvalue computation): measured 0.126 against 0.129 (2.4 % apart); bound 10 %, since
    the decay fit is not the root (the other modes leak into a 1 s fit)."""
    import numpy as np

    truth = ExperimentModel(effects={"steer_viscous_damping": 0.3})
    other = truth.with_effects(steer_viscous_damping=0.6)
    ws = synthetic_windows(truth, [3.5], 3, noise=0.0, seed=5)
    # undo the encoder quantization for a clean check
    ws = [replace(w, delta=truth.simulate([w], nsub=10)[0]["delta"]) for w in ws]
    from bikeid.ident.effects.weave import decay_eigenvalue

    lam = [decay_eigenvalue(w) for w in ws]
    assert weave_error(ws, truth.simulate(ws, nsub=10), lam) < 1e-3
    got = weave_error(ws, other.simulate(ws, nsub=10), lam)
    vs = float(np.mean(ws[0].v_sensor))
    r0, r1 = truth.weave(vs), other.weave(vs)
    assert got == pytest.approx(abs(r1 - r0) / abs(r0), rel=0.1)


def test_tire_twist_stiffness_is_a_spring_falling_as_one_over_speed():
    """tire_twist_stiffness k_t (kept out of the library) is the steer spring k_t / v at the
    true speed v: the sampled loops' eigenvalues agree to round-off (1e-9) at 1.5 and 4.5 m/s,
    and the nonlinear counterpart is a SteerStiffness of k_t / v (analytic identity)."""
    import numpy as np

    from bikeid.dataset.sbw_logs import SPEED_CALIBRATION
    from bikeid.ident.effects.experiment_model import COULOMB_EPS, DT
    from bikeid.sim.effects import nonlinear_effects

    a, b = SPEED_CALIBRATION
    for v in (1.5, 4.5):
        twist = ExperimentModel(effects={"tire_twist_stiffness": 3.0})
        spring = ExperimentModel(effects={"steer_stiffness": 3.0 / v})
        vs = a * v + b
        np.testing.assert_allclose(
            np.sort_complex(twist.eigenvalues(vs)), np.sort_complex(spring.eigenvalues(vs)),
            atol=1e-9,
        )  # fmt: skip
        fx, eq = nonlinear_effects(twist.effects, v, DT, COULOMB_EPS)
        assert eq == {"steer_stiffness": pytest.approx(3.0 / v, rel=1e-12)}


def test_selection_frequencies_stable_for_a_clear_effect():
    """Stability selection: with a clear injected steer damping (0.4 N m s/rad, 5 decays per
    speed, linear simulator) every 75 % subsample names it (frequency 1, the single-shot test
    above names it too); for roll damping, outside the library, every subsample says
    "unexplained".  Bad arguments are refused by name."""
    truth = ExperimentModel(effects={"steer_viscous_damping": 0.4})
    ws = synthetic_windows(truth, [1.5, 3.5], 5, seed=1)
    freq = selection_frequencies(ExperimentModel(), ws, resamples=4, max_effects=2)
    assert freq["steer_viscous_damping"] == 1.0
    assert freq.get("unexplained", 0.0) == 0.0
    outside = ExperimentModel(effects={"roll_viscous_damping": 1.5})
    ws = synthetic_windows(outside, [1.5, 3.5], 5, seed=3)
    freq = selection_frequencies(ExperimentModel(), ws, resamples=4, max_effects=2)
    assert freq["unexplained"] == 1.0
    with pytest.raises(ValueError, match="fraction"):
        selection_frequencies(ExperimentModel(), ws, resamples=2, fraction=1.5)
    with pytest.raises(ValueError, match="resamples"):
        selection_frequencies(ExperimentModel(), ws, resamples=0)


def test_push_asymmetry_mirror_symmetry():
    """The plant and the steer-into-lean loop are mirror-symmetric (analytic property of the
    Whipple equations and of T = K (V - v) phidot): a decay and its mirror image (every
    signal negated) have the same error under any model without a symmetry-breaking term,
    so the right/left ratio is 1 (to round-off) and the test cannot reject.  Then the
    statistic on random pushes: a symmetric missing term (steer damping + stiffness) leaves
    the two directions alike, while the same damping plus an encoder zero offset of 0.02 rad
    (the size fitted to the real logs) separates them.  Seeds 0-2; the levels are the test's
    own (p > 0.05 symmetric, p < 0.01 broken; measured 0.37-0.76 and 1.7e-4-2.5e-4)."""
    from dataclasses import replace

    import numpy as np

    from bikeid.ident.effects.diagnostics import push_asymmetry
    from bikeid.ident.effects.experiment_model import window_errors

    nominal = ExperimentModel()
    ws = synthetic_windows(ExperimentModel(effects={"steer_viscous_damping": 0.4}), [2.5, 4.0],
                           per_speed=6, noise=0.0)  # fmt: skip
    mirror = [replace(w, phi=-w.phi, delta=-w.delta, phidot=-w.phidot, deltadot=-w.deltadot,
                      hist=-w.hist) for w in ws]  # fmt: skip
    both = ws + mirror
    a = push_asymmetry(both, window_errors(both, nominal.simulate(both)).mean(axis=1))
    assert (a["n_right"], a["n_left"]) == (len(ws), len(ws))
    assert a["ratio"] == pytest.approx(1.0, abs=1e-9)
    assert a["p_value"] == pytest.approx(1.0)

    sym = {"steer_viscous_damping": 0.4, "steer_stiffness": 1.0}
    broken = {"steer_viscous_damping": 0.4, "steer_angle_bias": 0.02}
    for seed in range(3):
        for truth, symmetric in ((sym, True), (broken, False)):
            w2 = synthetic_windows(ExperimentModel(effects=truth), [2.5, 4.0], per_speed=8,
                                   noise=0.01, seed=seed)  # fmt: skip
            e = window_errors(w2, nominal.simulate(w2)).mean(axis=1)
            p = push_asymmetry(w2, e)["p_value"]
            assert (p > 0.05) if symmetric else (p < 0.01), (truth, seed, p)
    with pytest.raises(ValueError, match="one error per window"):
        push_asymmetry(ws, np.ones(len(ws) + 1))


def test_weave_uncertainty_matches_monte_carlo_scatter():
    """The bootstrap standard error of the measured weave (median of 7 decay fits) against
    the independent Monte Carlo answer: the scatter of that median over 30 independent
    sets of decays (new initial states and noise each, 3.5 m/s, roll-rate noise 0.05 rad/s).
    Measured: bootstrap 0.0140 (mean over the sets), Monte Carlo 0.0112.  The bootstrap of a
    median from 7 values is known to run high (the resampled median takes only a few
    distinct values; Efron & Tibshirani 1993, sec. 7.3), so the bound is 0.7-1.6x."""
    import numpy as np

    from bikeid.ident.effects.weave import decay_eigenvalue, median_complex, weave_uncertainty

    truth = ExperimentModel(effects={"steer_viscous_damping": 0.3})
    meds, boot = [], []
    for seed in range(30):
        ws = synthetic_windows(truth, [3.5], per_speed=7, noise=0.05, seed=seed)
        lams = [decay_eigenvalue(w) for w in ws]
        meds.append(median_complex(lams))
        boot.append(weave_uncertainty(lams))
    meds = np.array(meds)
    mc = np.sqrt(np.mean(np.abs(meds - meds.mean()) ** 2)) / abs(meds.mean())
    assert 0.7 * mc < np.mean(boot) < 1.6 * mc
    assert np.isnan(weave_uncertainty(meds[:2]))


def test_weave_term_recovers_linear_effects():
    """The weave-eigenvalue term (``weave_weight``, on by default) on synthetic decays of a
    known truth (steer damping 0.4 + steer spring 1.5). Independent checks:

    (1) the fit with the term recovers both values within 20 % (the issue's magnitude bound;
        measured 0.408 and 1.54);
    (2) at the truth the weave residuals are the estimator's scatter only: chi2 of the
        4 residuals 1.8 (bound 5, about the 4 degrees of freedom plus margin), the nominal
        model's 4027 (bound 100);
    (3) the default weight is the documented one, sqrt(output-error cost / weave chi2) at
        the nominal, recomputed here from its parts; weight 0 switches the term off;
    (4) a negative weight is refused.
    """
    import math

    import numpy as np

    from bikeid.ident.effects.fit import output_residuals
    from bikeid.ident.effects.weave import WeaveTerm, weave_targets

    truth = ExperimentModel(effects={"steer_viscous_damping": 0.4, "steer_stiffness": 1.5})
    ws = synthetic_windows(truth, [2.5, 4.5], 6, seed=4)
    tg = weave_targets(ws)
    assert len(tg) == 2
    chi_truth = float(np.sum(WeaveTerm(1.0, tg).residuals(truth) ** 2))
    chi_nom = float(np.sum(WeaveTerm(1.0, tg).residuals(ExperimentModel()) ** 2))
    assert chi_truth < 5.0 < 100.0 < chi_nom
    names = ["steer_viscous_damping", "steer_stiffness"]
    res = fit_effects(ExperimentModel(), ws, names, weave=WeaveTerm(0.3, tg))
    assert res.values["steer_viscous_damping"] == pytest.approx(0.4, rel=0.2)
    assert res.values["steer_stiffness"] == pytest.approx(1.5, rel=0.2)
    nominal = ExperimentModel()
    r = output_residuals(nominal, ws)
    unit = WeaveTerm(1.0, tg).at(nominal, ws)
    expect = math.sqrt(float(r @ r) / float(np.sum(unit.residuals(nominal) ** 2)))
    b = select_effects(nominal, ws, max_effects=1)
    assert b.weave_weight == pytest.approx(expect, rel=1e-9)
    assert [e.name for e in b.effects] in ([names[0]], [names[1]])  # one of two allowed
    assert select_effects(nominal, ws, max_effects=1, weave_weight=0.0).weave_weight == 0.0
    with pytest.raises(ValueError, match="weave_weight"):
        select_effects(nominal, ws, max_effects=1, weave_weight=-1.0)
