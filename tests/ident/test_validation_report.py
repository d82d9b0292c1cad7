"""ident.validation_report and ``bikeid validate``: every verdict checked both ways on a linear
plant with a known model (dataset.linear_loop: exact ZOH simulation of the benchmark bicycle
under the default PID), every number against an independent value."""

import dataclasses
import json

import numpy as np
import pytest

from bikeid.dataset.linear_loop import simulate
from bikeid.ident.canonical import theta_from_matrices
from bikeid.ident.pem import CanonicalModel
from bikeid.ident.validate import independence_test, portmanteau
from bikeid.ident.validation_report import frequency_response_estimate, validate_model
from bikeid.sim.linear import canonical_matrices, state_space
from bikeid.sim.parameters import benchmark

P = benchmark()


def _canonical(v: float, dt: float, outputs=("phi", "delta"), rel: float = 0.0) -> CanonicalModel:
    """The true (or, at another speed, a wrong) canonical model with K = 0 (output error)
    and independent parameter errors of ``rel`` times each parameter (standard deviation)."""
    n = len(outputs)
    theta = theta_from_matrices(canonical_matrices(P), v)
    return CanonicalModel(theta=theta, covariance=np.diag((rel * theta) ** 2),
                          K=np.zeros((4, n)), dt=dt, speed=v, noise_covariance=np.eye(n),
                          outputs=outputs)  # fmt: skip


def test_bode_band_holds_the_estimate_of_the_true_model_not_of_a_wrong_one(noisy_run):
    """Both ways: the true model with 20 % parameter standard errors has a band (median
    half-width ~4 dB) wider than the estimate's own scatter (median relative error 0.2-0.24,
    ~2 dB), so nearly every point lies inside (measured 62 of 66; required >= 85 %); the
    4 m/s model with 1 % errors misses them all (measured 0 of 66; required <= 5 %).  The
    half-widths are 1.959964 standard errors of ident.uncertainty.bode_bands."""
    from bikeid.ident.uncertainty import bode_bands

    true = _canonical(5.0, noisy_run.dt, rel=0.2)
    rep = validate_model(true, noisy_run)
    band = rep.band_summary()
    assert band["fraction"] >= 0.85 and "linear plant only" in band["calibration"]
    e = rep.frequency_responses[0]
    ref = bode_bands(true, 2 * np.pi * e.f)[list(true.outputs).index(e.output)]
    np.testing.assert_allclose(e.band_db, 1.959964 * ref.std_magnitude_db, rtol=1e-6)
    wrong = validate_model(_canonical(4.0, noisy_run.dt, rel=0.01), noisy_run).band_summary()
    assert wrong["fraction"] <= 0.05
    # widened by the estimate's own 95 % error: the exact model (zero band) is consistent
    # at every point (measured 66 of 66; Bendat & Piersol's error counts non-overlapping
    # segments, so it is conservative), the 4 m/s model at fewer (measured 57 of 66)
    exact = validate_model(_canonical(5.0, noisy_run.dt), noisy_run).band_summary()
    assert exact["n_inside"] == 0 and exact["fraction_consistent"] >= 0.95
    assert wrong["fraction_consistent"] <= 0.9
    # the criterion itself: a point 0.5 half-width off in dB and phase is inside, 1.5 is not
    for k, expect in ((0.5, True), (1.5, False)):
        H = e.model * 10 ** (k * e.band_db / 20) * np.exp(1j * np.radians(k * e.band_deg))
        moved = dataclasses.replace(e, H=H)
        assert np.all(moved.in_band[e.valid] == expect)
    assert (
        validate_model(state_space(P, 5.0, inputs=("T_delta",)), noisy_run).band_summary() is None
    )


@pytest.fixture(scope="module")
def noisy_run():
    """60 s at 5 m/s, 2 N m white dither, white sensor noise 1e-3 rad / 1e-2 rad/s."""
    return simulate(P, 5.0, duration=60, seed=3, dither=2.0, angle_noise=1e-3, rate_noise=1e-2)


def test_true_model_on_noise_free_data_fits_100_percent():
    """Noise-free run, true model sampled exactly (ZOH on both sides), x0 estimated: the fit
    is 100 % to rounding (1e-7 %, the 1e-9 of test_validate's compare check in percent), for
    simulation and the 10-step prediction alike."""
    r = simulate(P, 5.0, duration=20, seed=1, dither=1.0)
    rep = validate_model(state_space(P, 5.0, inputs=("T_delta",)), r)
    for o in ("phi", "delta", "phidot", "deltadot"):
        assert rep.fit[o] == pytest.approx(100.0, abs=1e-7)
        assert rep.fit_k_step[o] == pytest.approx(100.0, abs=1e-7)
    assert rep.to_json()["fit"]["phi"] == pytest.approx(100.0, abs=1e-7)


def test_fit_of_a_gain_error_matches_the_analytic_nrmse():
    """From rest (x0 = 0, ic="zero") a model whose B is scaled by c simulates exactly c y
    (linearity), so its fit is 100 (1 - |c - 1| ||y|| / ||y - mean y||).  Tolerance 1e-8 %:
    the only difference is the rounding of the ZOH of c B against c times that of B."""
    r = simulate(P, 5.0, duration=20, seed=2, dither=1.0, x0=[0, 0, 0, 0])
    import control

    sys = state_space(P, 5.0, inputs=("T_delta",))
    c = 1.1
    scaled = control.ss(sys.A, c * sys.B, sys.C, sys.D, inputs=sys.input_labels,
                         outputs=sys.output_labels)  # fmt: skip
    rep = validate_model(scaled, r, ic="zero")
    for o in rep.outputs:
        y = r[o]
        expected = 100 * (1 - abs(c - 1) * np.linalg.norm(y) / np.linalg.norm(y - y.mean()))
        assert rep.fit[o] == pytest.approx(expected, abs=1e-8)
        assert 0 < expected < 95  # a real loss, not a rounding effect


def test_portmanteau_and_independence_tests_are_calibrated():
    """Under the null hypothesis the chi-squared tests reject at their level (1 %): 200 white
    residual series against a strongly coloured input (AR(1), a = 0.9) are rejected
    2 +- 2 times (binomial(200, 0.01): 99.9 % quantile 7, the bound used).  The naive statistic
    N sum r^2 ignores the input's colour and rejects far more often, the reason for R_u.
    A residual that is the input two samples late is rejected by both tests (p < 1e-10).
    The naive count must exceed 14, which a calibrated 1 % test reaches with probability
    below 1e-8 (binomial(200, 0.01))."""
    rng = np.random.default_rng(0)
    from scipy.signal import lfilter

    n, M, rejected, naive = 2000, 25, 0, 0
    from bikeid.ident.validate import cross_correlation

    for _ in range(200):
        u = lfilter([1.0], [1.0, -0.9], rng.normal(size=n))
        e = rng.normal(size=n)
        c = cross_correlation(e, u, M)
        rejected += not c["test"]["passed"]
        naive += n * np.sum(c["ccf"][M + 1 :] ** 2) > 44.31  # chi2(25) 99 % quantile
    assert rejected <= 7
    assert naive > 14
    u = rng.normal(size=n)
    e = np.roll(u, 2) + 0.5 * rng.normal(size=n)
    c = cross_correlation(e, u, M)
    assert c["test"]["p_value"] < 1e-10
    assert independence_test(c["ccf"][M + 1 :], np.r_[1.0, np.zeros(M - 1)], n)["passed"] is False
    ar = lfilter([1.0], [1.0, -0.3], rng.normal(size=n))
    r1 = np.array([np.dot(ar[k:], ar[: n - k]) for k in range(1, M + 1)]) / np.dot(ar, ar)
    assert portmanteau(r1, n)["p_value"] < 1e-10


def _with_gain(m: CanonicalModel, k: float) -> CanonicalModel:
    """The model with a small innovation gain K = k (all entries): a noise model, so the
    structure check tests whiteness, changing the one-step prediction by O(k)."""
    return dataclasses.replace(m, K=np.full_like(m.K, k))


def test_whiteness_verdict_is_the_structure_checks_both_ways(noisy_run):
    """The one whiteness test (ident.structure.check_structure): with a noise model (a small
    innovation gain K = 1e-4, so whiteness is tested) the true model's one-step residual is
    the white sensor noise and passes; the 4 m/s model (a 20 % speed error) leaves the model
    error in the residual and fails on both outputs (p < 1e-10).  Each verdict and p-value
    is check_structure's own on the same run and model (exact equality: one mechanism), and
    without a noise model (K = 0) there is no whiteness verdict, as in identify."""
    from bikeid.ident.structure import check_structure

    good_m = _with_gain(_canonical(5.0, noisy_run.dt), 1e-4)
    bad_m = _with_gain(_canonical(4.0, noisy_run.dt), 1e-4)
    good, bad = validate_model(good_m, noisy_run), validate_model(bad_m, noisy_run)
    for rep, m in ((good, good_m), (bad, bad_m)):
        ref = check_structure([noisy_run], {5.0: m})
        p = {t["output"]: t["p_value"] for t in ref.tests[5.0] if t["kind"] == "whiteness"}
        assert {o: w["p_value"] for o, w in rep.per_speed[0].whiteness.items()} == p
        assert rep.to_json()["residual_tests"]["tests"] == ref.to_json()["tests"]
    for o in ("phi", "delta"):
        assert good.per_speed[0].whiteness[o]["white"] is True
        assert good.per_speed[0].independence[o]["independent"] is True
        assert bad.per_speed[0].whiteness[o]["white"] is False
        assert bad.per_speed[0].whiteness[o]["p_value"] < 1e-10
        assert bad.fit_k_step[o] < good.fit_k_step[o]
    assert not any("identified at" in n for n in good.notes)
    assert any("identified at 4 m/s" in n for n in bad.notes)  # 1 m/s > max(0.5, 15 % of 4)
    oe = validate_model(_canonical(5.0, noisy_run.dt), noisy_run)  # K = 0: output error
    assert oe.per_speed[0].whiteness is None and any("no whiteness verdict" in n for n in oe.notes)
    from bikeid.experiments.cli.validate import table

    assert "not tested (K = 0)" in table(oe, "m.json")
    row = next(ln for ln in table(bad, "m.json").splitlines() if ln.startswith("      5 "))
    assert row.split()[4:6] == ["NOT:", "phi,delta"]


def test_frequency_response_estimate_within_its_bound(noisy_run):
    """At the frequencies the coherence allows (>= 0.5), the closed-loop estimate S_dy / S_du
    meets the true model's *sampled* response within 4 times its coherence-based random error
    (Bendat & Piersol's first-order formula; were it exact, a 4-sigma miss would happen with
    probability exp(-8) = 3e-4 per frequency).  Both ways: the 4 m/s model misses by more at
    some frequency of phi and phidot, and so does the true model's continuous response for
    deltadot (the hold's half-sample delay near Nyquist), so the bound is not vacuous."""
    true = state_space(P, 5.0, inputs=("T_delta",))
    ests = frequency_response_estimate(noisy_run, true)
    assert {e.output for e in ests} == {"phi", "delta", "phidot", "deltadot"}
    for e in ests:
        assert e.reference == "dither" and e.valid.sum() >= 10, e.output
        ratio = np.abs(e.H - e.model)[e.valid] / (np.abs(e.model) * e.rel_error)[e.valid]
        assert ratio.max() < 4, e.output
    at4 = state_space(P, 4.0, inputs=("T_delta",))
    wrong = {e.output: e for e in frequency_response_estimate(noisy_run, at4)}
    for o in ("phi", "phidot"):
        e = wrong[o]
        ratio = np.abs(e.H - e.model)[e.valid] / (np.abs(e.model) * e.rel_error)[e.valid]
        assert ratio.max() > 4, o
    e = next(e for e in ests if e.output == "deltadot")
    j = list(true.output_labels).index("deltadot")
    Gc = np.array([np.asarray(true(2j * np.pi * f))[j, 0] for f in e.f[e.valid]])
    assert (np.abs(e.H[e.valid] - Gc) / (np.abs(Gc) * e.rel_error[e.valid])).max() > 4


def test_no_dither_reports_not_enough_excitation():
    """A closed-loop run without dither: T_delta is only feedback, so no estimate is made and
    the report says so (an H1 estimate there would be -1/controller, not the bicycle)."""
    r = simulate(P, 5.0, duration=20, seed=1, dither=0.0, angle_noise=1e-3)
    rep = validate_model(_canonical(5.0, r.dt), r)
    assert all(not e.excited for e in rep.frequency_responses)
    assert any("not enough excitation" in n for n in rep.notes)
    assert rep.to_json()["frequency_responses"][0]["f"] == []


def test_unstable_model_simulation_refused_prediction_kept():
    """At 2 m/s the weave is unstable: the 60 s simulation is refused with its reason (as
    compare).  With all four states measured and the deadbeat observer gain K = Ad C' (so
    Ad - K C = 0), the 5-step prediction of the true model on noise-free data fits 100 % (to
    1e-6 %: five steps from the measured state, rounding only).  Without a noise model
    (K = 0) the predictor diverges too, and the report refuses (UntrustworthyResult)."""
    from bikeid.sim.errors import UntrustworthyResult

    r = simulate(P, 2.0, duration=60, seed=1, dither=1.0)
    m = _canonical(2.0, r.dt, outputs=("phi", "phidot", "delta", "deltadot"))
    Ad, _, C, _ = m.predictor()
    deadbeat = CanonicalModel(theta=m.theta, covariance=m.covariance, K=Ad @ C.T, dt=m.dt,
                              speed=2.0, noise_covariance=m.noise_covariance,
                              outputs=m.outputs)  # fmt: skip
    rep = validate_model(deadbeat, r, k_step=5)
    assert rep.headline == "k_step" and "unstable" in rep.simulation_note
    assert rep.series[0].simulated is None and rep.per_speed[0].fit_simulation is None
    assert rep.fit["phi"] is None and rep.to_json()["fit"]["phi"] is None
    for o in m.outputs:
        assert rep.fit_k_step[o] == pytest.approx(100.0, abs=1e-6)
    with pytest.raises(UntrustworthyResult, match="neither simulation nor prediction"):
        validate_model(m, r)


def test_models_over_speed_are_taken_at_each_runs_speed():
    """A DirectResult and a SpeedCanonicalModel built from the true matrices, validated on
    noise-free runs at 4 and 6 m/s: each run is compared with the model at its own speed, so
    every fit is 100 % to rounding (1e-7 %, as the fixed-speed case), and the frequency
    responses come in one group per speed."""
    from bikeid.ident.canonical import speed_params_from_matrices
    from bikeid.ident.direct import DirectResult
    from bikeid.ident.pem import SpeedCanonicalModel

    runs = [simulate(P, v, duration=10, seed=1, dither=1.0) for v in (4.0, 6.0)]
    cm = canonical_matrices(P)
    direct = DirectResult(
        M=cm.M, C1=cm.C1, K0=cm.K0, K2=cm.K2, H=np.zeros(2), g=cm.g, free={}, stderr={},
        covariance={}, condition={}, vaf_moore={}, vaf_variance={}, n_samples=0, method="ls",
    )  # fmt: skip
    dt = runs[0].dt
    per = {v: _canonical(v, dt, outputs=("phi", "phidot", "delta", "deltadot")) for v in (4.0, 6.0)}
    speed = SpeedCanonicalModel(params=speed_params_from_matrices(cm), per_speed=per, dt=dt,
                                covariance=np.zeros((14, 14)), g=cm.g)  # fmt: skip
    for model in (direct, speed):
        rep = validate_model(model, runs)
        for o in rep.outputs:
            assert rep.fit[o] == pytest.approx(100.0, abs=1e-7), (type(model).__name__, o)
            for row in rep.fit_per_run:
                assert row["simulation"][o] == pytest.approx(100.0, abs=1e-7)
        assert sorted({e.speed for e in rep.frequency_responses}) == [4.0, 6.0]


def test_validate_decays_fit_is_the_evaluate_error():
    """validate_decays (measured evaluate's validation) and
    bikeid.ident.effects.experiment_model.window_errors
    share one NRMSE (ident.validate.goodness_of_fit): fit = 100 (1 - error) to 1e-9 %, per
    file; a simulation 1.1 times the measured roll rate has the analytic error
    0.1 ||y|| / ||y - mean y|| (rounding only: 1e-12 relative) and an exact one 0; the
    true model fits its own noisy decays better than a model with a spurious effect."""
    from bikeid.ident.effects.experiment_model import ExperimentModel, window_errors
    from bikeid.ident.effects.synthetic_decays import synthetic_windows
    from bikeid.ident.validation_report import validate_decays

    truth = ExperimentModel()
    ws = synthetic_windows(truth, [2.5, 4.5], per_speed=3, seed=1)
    out = validate_decays(truth, ws)
    err = window_errors(ws, truth.simulate(ws))
    for f in out["files"]:
        idx = [i for i, w in enumerate(ws) if w.file == f["file"]]
        for j, c in enumerate(("phidot", "delta")):
            assert f["fit"][c] == pytest.approx(100 * (1 - err[idx, j].mean()), abs=1e-9)
        assert set(f["residuals"]["phidot"]) >= {"white", "whiteness_p", "fraction_outside"}
    wrong = validate_decays(truth.with_effects(steer_viscous_damping=1.0), ws)
    assert wrong["fit"]["phidot"] < out["fit"]["phidot"]
    scaled = window_errors(ws, [{"phidot": 1.1 * w.phidot, "delta": w.delta} for w in ws])
    for i, w in enumerate(ws):
        y = w.phidot
        expect = 0.1 * np.linalg.norm(y) / np.linalg.norm(y - y.mean())
        assert scaled[i, 0] == pytest.approx(expect, rel=1e-12) and scaled[i, 1] == 0.0


def test_cli_validate_writes_report_and_refuses_foreign_folders(tmp_path, noisy_run, capsys):
    """bikeid validate on a saved model: the JSON fit equals the library's, the figures and
    validation.json are written; a folder holding other files is refused (exit 3) before any
    work, as is an experiment model (validated by 'measured evaluate')."""
    pytest.importorskip("bikeid.ident.model_file", reason="needs ident.model_file (load_model)")
    from bikeid.dataset.store import write_runs
    from bikeid.experiments.cli import main
    from bikeid.ident.effects.experiment_model import ExperimentModel
    from bikeid.ident.model_file import save_model

    data = tmp_path / "runs.h5"
    run = noisy_run.window(0, 20)
    write_runs(data, [run])
    model = tmp_path / "m.json"
    save_model(_canonical(5.0, run.dt, rel=0.2), model)
    out = tmp_path / "val"
    assert main(["validate", "--model", str(model), str(data), "--out", str(out), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    lib = validate_model(_canonical(5.0, run.dt, rel=0.2), run)
    assert doc["bode_band"] == lib.band_summary() and doc["bode_band"]["n_points"] > 0
    assert [f["band"]["n_inside"] for f in doc["frequency_responses"]] == [
        int(e.in_band.sum()) for e in lib.frequency_responses
    ]
    assert doc["command"] == "bikeid validate"
    assert doc["fit"]["phi"] == pytest.approx(lib.fit["phi"], rel=1e-12)
    assert json.loads((out / "validation.json").read_text())["fit_k_step"] == doc["fit_k_step"]
    for name in ("compare_1.png", "resid.png", "bode.png"):
        assert (out / name).stat().st_size > 1000
    # the PNG header's width (bytes 16-19): four output panels, under 2,000 px
    assert int.from_bytes((out / "bode.png").read_bytes()[16:20], "big") <= 2000
    # the same folder again is fine (written by bikeid validate); a foreign one is not
    assert main(["validate", "--model", str(model), str(data), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "fit %: the simulation's" in text and "inside the model's 95 % band" in text
    assert "calibrated on the linear plant only" in text
    row = next(ln for ln in text.splitlines() if ln.startswith("      5    1 "))
    band = lib.band_summary()
    assert row.endswith(f"{band['n_inside']}/{band['n_points']} ({band['n_consistent']} with "
                        "own error)")  # fmt: skip
    assert f"{lib.fit['phi']:.1f}" in row.split()
    foreign = tmp_path / "mine"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("keep")
    assert main(["validate", "--model", str(model), str(data), "--out", str(foreign)]) == 3
    assert "not written by bikeid validate" in capsys.readouterr().err
    assert (foreign / "notes.txt").read_text() == "keep" and len(list(foreign.iterdir())) == 1
    exp = tmp_path / "exp.json"
    save_model(ExperimentModel(), exp)
    assert main(["validate", "--model", str(exp), str(data)]) == 3
    assert "measured evaluate" in capsys.readouterr().err


@pytest.fixture(scope="module")
def identified(tmp_path_factory):
    """A closed-loop run of the linear plant under the roll PID at 5 m/s, 30 s, and the model
    bikeid identify saves (a per-speed PEM fit with its noise model)."""
    from bikeid.controllers import UniformDither, make
    from bikeid.dataset.closed_loop import simulate_run
    from bikeid.dataset.store import write_runs
    from bikeid.experiments.cli import main

    run = simulate_run(P, make("pid", P), speed=5.0, duration=30.0,
                       dither=UniformDither(1.0, seed=2), seed=2, plant="linear")  # fmt: skip
    root = tmp_path_factory.mktemp("identified")
    data, model = root / "run.h5", root / "m.json"
    write_runs(data, [run])
    assert main(["identify", str(data), "--out", str(model), "--quiet"]) == 0
    return data, model


def test_identify_and_validate_agree_on_the_same_data(identified, capsys):
    """On the data a model was identified from, validate's residual tests are identify's
    (the structure check saved in the model file: every test's statistic and p-value
    equal, the same Bonferroni level), so the two agree on every output's whiteness; the
    printed row's verdict is the JSON's."""
    from bikeid.experiments.cli import main

    data, model = map(str, identified)
    capsys.readouterr()
    assert main(["validate", data, "--model", model, "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    saved = json.loads(identified[1].read_text())["results"]["structure_check"]
    tests = doc["residual_tests"]
    assert tests["tests"] == saved["tests"] and tests["per_test_level"] == saved["per_test_level"]
    assert any(t["kind"] == "whiteness" for t in saved["tests"]["5"])  # a noise model: tested
    white = doc["per_speed"][0]["whiteness"]
    assert {o: w["p_value"] for o, w in white.items()} == {
        t["output"]: t["p_value"] for t in saved["tests"]["5"] if t["kind"] == "whiteness"
    }
    from bikeid.experiments.cli.validate import table
    from bikeid.ident.model_file import load_model

    assert main(["validate", data, "--model", model]) == 0
    text = capsys.readouterr().out
    row = next(ln for ln in text.splitlines() if ln.startswith("      5    1 ")).split()
    assert row[2:6] == [f"{doc['per_speed'][0]['fit_simulation'][o]:.1f}" for o in
                        doc["outputs"]]  # fmt: skip
    bad = [o for o, w in white.items() if not w["white"]]
    assert row[6:8] == ["NOT:", ",".join(bad)] if bad else row[6] == "white"
    assert load_model(model).outputs == tuple(doc["outputs"]) and callable(table)


def test_a_refused_simulation_is_said_once_and_the_k_step_fit_leads():
    """Two speeds (2.0 and 2.1 m/s, 20 s each) where the 2 m/s model is unstable: the
    simulation is refused at both, the summary says so once (not per row) and leads with
    the 5-step prediction's fit, which for the true model's deadbeat predictor
    (Ad - K C = 0) on noise-free data is 100 % to rounding (1e-6 %), and lower at 2.1 m/s
    (the model's speed 5 % off); one row per speed."""
    from bikeid.experiments.cli.validate import table

    runs = [simulate(P, v, duration=20, seed=1, dither=1.0) for v in (2.0, 2.1)]
    m = _canonical(2.0, runs[0].dt, outputs=("phi", "phidot", "delta", "deltadot"))
    Ad, _, C, _ = m.predictor()
    rep = validate_model(dataclasses.replace(m, K=Ad @ C.T), runs[:1] * 2 + runs[1:], k_step=5)
    assert rep.headline == "k_step" and rep.simulation_note.startswith(
        "simulation refused at every speed"
    )
    text = table(rep, "m.json")
    assert text.count("simulation refused") == 1 and "fit %: the 5-step prediction's" in text
    rows = [ln.split() for ln in text.splitlines() if ln.startswith(("      2 ", "    2.1 "))]
    assert [r[:2] for r in rows] == [["2", "2"], ["2.1", "1"]]
    assert rows[0][2] == "100.0" and rep.per_speed[0].fit_k_step["phi"] == pytest.approx(
        100.0, abs=1e-6
    )
    assert float(rows[1][2]) < 99.9
