"""The structure check before intervals (ident.structure), tested both ways.

Independent sources: the linearized truth (``sim.linear``) for whether an interval covers;
known constructions for the verdict: runs of the exact linear plant (``plant="linear"``),
whose structure the canonical model contains (must pass), and the same runs with the logged
torque 3 samples (30 ms) ahead of the torque that acts, a delay the canonical model lacks
(must be rejected; a delay shows as residual-input correlation at positive lags, Ljung
sec. 16.6).  Numbers quoted in comments were measured with this code.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.stats import chi2

from bikeid.controllers import UniformDither, make
from bikeid.dataset.closed_loop import simulate_run
from bikeid.ident import pem
from bikeid.ident.structure import STRUCTURE_LEVEL, check_structure
from bikeid.ident.uncertainty import eigenvalue_intervals
from bikeid.sim import linear
from bikeid.sim.errors import InputError
from bikeid.sim.parameters import benchmark


def _run(seed: int, speed: float = 5.0, duration: float = 60.0):
    p = benchmark()
    return simulate_run(p, make("pid", p), speed=speed, duration=duration,
                        dither=UniformDither(1.0, seed=seed), seed=seed,
                        plant="linear")  # fmt: skip


def _delayed(run, k: int = 3):
    """The run with its logged T_delta k samples ahead of the torque that acted."""
    sig = {n: (x[k:] if n == "T_delta" else x[:-k]) for n, x in run.signals.items()}
    return dataclasses.replace(run, t=run.t[:-k], signals=sig, truth={}, dither=None,
                               reference=None)  # fmt: skip


def _z(model, speed: float = 5.0) -> np.ndarray:
    """(estimate - linearized truth) / standard error of each eigenvalue's real part (of a
    rejected model too: the refusal opted out of, to show what it withholds)."""
    ei = eigenvalue_intervals(model, refuse_structure=False)
    truth = linear.match_eigenvalues(linear.eigenvalues(benchmark(), speed), ei.values)
    return (ei.values.real - truth.real) / ei.std_real


@pytest.fixture(scope="module")
def linear_run():
    # seed 3: seed 0's caster interval is one of the ~5 % that miss (caster coverage 928 of
    # 1000 on this plant, docs/uncertainty.md); this test is about keeping intervals
    return _run(3)


@pytest.fixture(scope="module")
def linear_fit(linear_run):
    return pem.fit(linear_run)


def test_linear_plant_passes_and_its_intervals_cover(linear_run, linear_fit):
    check = check_structure([linear_run], {5.0: linear_fit})
    # 4 independence tests withhold (Bonferroni at 1 %); 4 whiteness tests (free noise
    # model) are advisory, judged at the same per-test level
    assert check.n_tests == 4 and len(check.tests[5.0]) == 8
    assert sum(t["advisory"] for t in check.tests[5.0]) == 4
    assert check.per_test_level == pytest.approx(STRUCTURE_LEVEL / 4, rel=1e-12)
    assert check.passed and not check.rejected_speeds
    # the per-test level is 2.5e-3; measured p-values 0.19-0.86 (smallest: delta)
    assert min(t["p_value"] for t in check.tests[5.0]) > 0.01
    # the structure is right, so the intervals stand and contain the truth
    ei = eigenvalue_intervals(linear_fit)
    truth = linear.match_eigenvalues(linear.eigenvalues(benchmark(), 5.0), ei.values)
    assert all(lo <= t <= hi for (lo, hi), t in zip(ei.real_bounds, truth.real, strict=True))
    assert "cannot see the bias" in check.note()


def test_missing_delay_is_rejected_and_its_intervals_would_miss(linear_run):
    run = _delayed(linear_run)
    model = pem.fit(run)
    check = check_structure([run], {5.0: model})
    assert not check.passed and check.rejected_speeds == (5.0,)
    rejected = {t["kind"] for t in check.tests[5.0] if t["rejected"]}
    assert "independence" in rejected  # measured p = 0 (underflow) on all four outputs
    assert "correlate with the past input" in check.causes()
    note = check.note()
    assert "no 95 % intervals are given for 5 m/s" in note
    assert "Fix:" not in note  # no remedy is printed that was not measured to cover
    # and rightly so: the intervals the check withholds exclude the truth (measured
    # z = -2.4, -7.8, -7.8, -10.7 for caster, weave pair, capsize)
    assert np.max(np.abs(_z(model))) > 5.0


def test_output_error_fit_is_not_judged_by_whiteness(linear_run):
    model = pem.fit(linear_run, noise_model="none")
    assert not np.any(model.K)
    check = check_structure([linear_run], {5.0: model})
    assert {t["kind"] for t in check.tests[5.0]} == {"independence"}
    assert check.n_tests == 4


def test_whiteness_alone_is_advisory():
    """Seed 41 of the coverage study's linear plant (``bikeid coverage`` settings, a held
    unlogged steer torque the 4-state noise model cannot whiten exactly): its residual in
    delta is not white (measured p = 8e-15) while independence passes, and its intervals
    contain the truth, so they are kept and the note names the noise model.  Measured on
    the free innovation gain (``noise_model="gain"``, the coverage study's estimator)."""
    from bikeid.experiments.testbed.coverage import DEFAULTS, _closed_loop_run

    run = _closed_loop_run(benchmark(), {**DEFAULTS, "controller": "pid"}, 5.0, 41)
    model = pem.fit(run, noise_model="gain")
    check = check_structure([run], {5.0: model})
    white = [t for t in check.tests[5.0] if t["kind"] == "whiteness"]
    assert any(t["rejected"] and t["p_value"] < 1e-9 for t in white)
    assert check.passed and check.withheld_speeds == ()
    assert "advisory: residuals are not white (delta)" in check.note()
    ei = eigenvalue_intervals(model)
    truth = linear.match_eigenvalues(linear.eigenvalues(benchmark(), 5.0), ei.values)
    assert all(lo <= t <= hi for (lo, hi), t in zip(ei.real_bounds, truth.real, strict=True))


def test_speed_model_against_its_per_speed_fits():
    """The coverage study's linear plant at 3 and 7 m/s (its unlogged torque keeps the
    per-speed fits inside their predictor's stability region, 1 - radius 0.02 and 0.05,
    where their covariance is a yardstick): the model over speed passes (measured p 0.71,
    0.69), and moved 20 standard errors it is rejected."""
    from bikeid.experiments.testbed.coverage import DEFAULTS, _closed_loop_run

    runs = [_closed_loop_run(benchmark(), {**DEFAULTS, "controller": "pid"}, v, s)
            for v, s in ((3.0, 1), (7.0, 2))]  # fmt: skip
    sm = pem.fit_speed_model(runs)
    models = {v: sm.at(v) for v in (3.0, 7.0)}
    check = check_structure(runs, models, speed_model=sm)
    assert check.passed and not check.speed_model_rejected
    kinds = [t["kind"] for t in check.tests[3.0]]
    assert kinds.count("speed_model") == 1
    hausman = next(t for t in check.tests[7.0] if t["kind"] == "speed_model")
    # the statistic is d' P^-1 d of the 10 canonical parameters: recompute it here
    per = sm.per_speed[7.0]
    d = per.theta - sm.theta(7.0)
    assert hausman["dof"] == 10
    assert hausman["statistic"] == pytest.approx(d @ np.linalg.solve(per.covariance, d),
                                                 rel=1e-6)  # fmt: skip
    assert hausman["p_value"] == pytest.approx(chi2.sf(hausman["statistic"], 10), rel=1e-9)
    # a model over speed moved 20 standard errors away from the data is rejected there
    se = np.sqrt(np.diag(sm.covariance))
    moved = dataclasses.replace(sm, params=sm.params + 20 * se * np.sign(sm.params))
    bad = check_structure(runs, {v: moved.at(v) for v in (3.0, 7.0)}, speed_model=moved)
    assert bad.speed_model_rejected and not bad.passed
    assert "v_w, v_c" in bad.note() and bad.withheld_speeds == (3.0, 7.0)
    # no fix in the note: none is measured to give covering intervals (docs/uncertainty.md);
    # identify names the per-speed fit itself (ident.structure.FIX_PER_SPEED)
    assert "Fix:" not in bad.note()


def test_unstable_predictor_is_a_rejection(linear_run, linear_fit):
    """A model whose one-step predictor diverges on the runs has no residuals to test: its
    intervals are withheld, not the command aborted (here K = -3 C': Ad - K C then has an
    eigenvalue outside the unit circle, checked below)."""
    from bikeid.ident.predictor import output_matrix

    C = output_matrix(linear_fit.outputs)[0]
    bad = dataclasses.replace(linear_fit, K=-3.0 * C.T)
    Ad, _, _, _ = bad.predictor()
    assert np.max(np.abs(np.linalg.eigvals(Ad - bad.K @ C))) > 1.0
    check = check_structure([linear_run], {5.0: bad})
    assert check.rejected_speeds == (5.0,)
    assert "predictor is unstable" in check.note()


def test_speed_model_comparison_skips_boundary_fits():
    """Two 20 s linear-plant runs at 4 and 6 m/s (no process noise): both per-speed fits end
    on their predictor's stability boundary (measured 1 - radius 7.6e-7, 2.3e-7, below
    PREDICTOR_BOUNDARY_TOL = 1e-4), so their covariances are no yardstick and the comparison
    over speed is not made (it gave p = 2.6e-5 while v_w, v_c covered the truth)."""
    from bikeid.dataset.linear_loop import simulate
    from bikeid.ident.uncertainty import PREDICTOR_BOUNDARY_TOL, predictor_radius

    runs = [simulate(benchmark(), v, duration=20, seed=1, rate_noise=1e-3, angle_noise=1e-4)
            for v in (4.0, 6.0)]  # fmt: skip
    sm = pem.fit_speed_model(runs)
    assert all(1 - predictor_radius(m) < PREDICTOR_BOUNDARY_TOL for m in sm.per_speed.values())
    check = check_structure(runs, {v: sm.at(v) for v in (4.0, 6.0)}, speed_model=sm)
    assert not any(t["kind"] == "speed_model" for rows in check.tests.values() for t in rows)


def test_bad_arguments_are_one_line_errors(linear_run, linear_fit):
    with pytest.raises(InputError, match="level"):
        check_structure([linear_run], {5.0: linear_fit}, level=1.5)
    with pytest.raises(InputError, match="max_lag"):
        check_structure([linear_run], {5.0: linear_fit}, max_lag=0)
    with pytest.raises(InputError, match="no runs at 4 m/s"):
        check_structure([linear_run], {4.0: linear_fit})


def test_json_records_every_test(linear_run, linear_fit):
    out = check_structure([linear_run], {5.0: linear_fit}).to_json()
    assert out["passed"] is True and out["rejected_speeds"] == []
    assert len(out["tests"]["5"]) == 8
    assert {"statistic", "dof", "p_value", "rejected"} <= set(out["tests"]["5"][0])
