"""Measured-data loader, experiment model and CLI on the TU Delft steer-by-wire logs."""

from __future__ import annotations

import gzip
import os
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from bikeid.dataset.decays import read_segments
from bikeid.dataset.download import fetch
from bikeid.dataset.sbw_logs import despike, load_log, treadmill_speed
from bikeid.ident.effects.experiment_model import ExperimentModel

DATA = os.environ.get("BIKEID_DATA", str(Path(__file__).resolve().parents[4] / "shared" / "data"))
HAVE = (Path(DATA) / "tudelft-sbw" / "eigen").is_dir()
needs_data = pytest.mark.skipif(not HAVE, reason=f"measured data not found at {DATA} (BIKEID_DATA)")
HEADER = ("sil_command,speed,lean_angle,lean_rate,hand_angle,fork_angle,fork_rate,lean_torque,"
          "hand_torque,x_acceleration,y_acceleration,command_fork,command_hand")  # fmt: skip


def _write(path: Path, rows: list[str], header: str = HEADER) -> Path:
    with gzip.open(path, "wt") as fh:
        fh.write(header + "\n" + "\n".join(rows) + "\n")
    return path


def test_loader_cuts_empty_sil_rows_and_time_base(tmp_path):
    """Leading empty sil_command rows are dropped; t = row index * 0.01 s (README)."""
    # the states and the command vary (a constant channel is refused, test_plausibility.py)
    rows = [",4.1,0,0,0,0,0,0,0,0,0,0,0"] * 3 + [
        f"0.1,4.1,{0.01 * i},{0.02 * i},0,{0.03 * i},{0.01 * i},0,0,0,0,{0.1 * i},0"
        for i in range(20)
    ]
    run = load_log(_write(tmp_path / "x.log.gz", rows))
    assert run.n == 20 and run.meta["first_index"] == 3
    assert run.t[0] == pytest.approx(0.03) and run.dt == pytest.approx(0.01)
    # calibration sensor = 1.066 treadmill - 0.128 (README): 4.1 -> (4.1 + 0.128)/1.066
    assert run.meta["speed"] == pytest.approx((4.1 + 0.128) / 1.066, abs=1e-12)


@pytest.mark.parametrize(
    "content, match",
    [("a,b\n1,2\n", "missing columns"), (HEADER + "\n" + "x,1,1,1,1,1,1,1,1,1,1,1,1\n" * 12,
                                          "non-numeric")],
)  # fmt: skip
def test_loader_rejects_malformed(tmp_path, content, match):
    p = tmp_path / "bad.log.gz"
    with gzip.open(p, "wt") as fh:
        fh.write(content)
    with pytest.raises(ValueError, match=match):
        load_log(p)


def test_loader_rejects_truncated_gzip(tmp_path):
    good = _write(tmp_path / "g.log.gz", ["0,1,0,0,0,0,0,0,0,0,0,0,0"] * 2000)
    cut = tmp_path / "cut.log.gz"
    cut.write_bytes(good.read_bytes()[:-30])
    with pytest.raises(ValueError, match="truncated"):
        load_log(cut)


def test_despike_removes_isolated_spike_only():
    """A single 3 rad/s jump in a 1 Hz sine is found and replaced by the interpolation
    of its neighbours (error < 1e-3, the sine's change over one sample is 6e-3)."""
    t = np.arange(500) * 0.01
    x = np.sin(2 * np.pi * t)
    y = x.copy()
    y[200] += 3.0
    out, n = despike(y, 0.5)
    assert n == 1 and abs(out[200] - x[200]) < 1e-3


def test_fetch_with_local_opener_records_checksums(tmp_path):
    """fetch writes gzip files atomically and refuses a changed upstream file."""
    payload = {"https://x/a.log": b"h\n1\n"}
    files = {"eigen/a.log.gz": "a.log"}
    sums = fetch(tmp_path, opener=lambda u: payload[u], url_pattern="https://x/{path}", files=files)
    assert gzip.decompress((tmp_path / "tudelft-sbw/eigen/a.log.gz").read_bytes()) == b"h\n1\n"
    import hashlib

    assert sums["eigen/a.log.gz"] == hashlib.sha256(b"h\n1\n").hexdigest()
    payload["https://x/a.log"] = b"changed"
    with pytest.raises(ValueError, match="checksum mismatch"):
        fetch(tmp_path, opener=lambda u: payload[u], url_pattern="https://x/{path}", files=files)


def test_fetch_all_speeds_adds_the_campaign_runs(tmp_path, monkeypatch, capsys):
    """`bikeid data fetch --all-speeds` asks for the 20 pinned files plus the campaign's
    four other eigen runs (2, 3, 4, 5 m/s: 7.2, 10.8, 14.4, 18 km/h, the names the
    transcribed segments.csv lists) at the pinned commit."""
    import bikeid.dataset.download as dm
    from bikeid.experiments.cli import main

    asked = []
    monkeypatch.setattr(dm, "_urlopen", lambda url: asked.append(url) or b"h\n1\n")
    assert main(["data", "fetch", "--dest", str(tmp_path), "--all-speeds"]) == 0
    assert len(asked) == 24 and all(dm.UPSTREAM_COMMIT in u for u in asked)
    kph = sorted(float(u.split("_")[-1][:-7]) for u in asked if "eigen_normal" in u)
    assert kph == [5.4, 7.2, 9.0, 10.8, 12.6, 14.4, 16.2, 18.0]
    assert (tmp_path / "tudelft-sbw/eigen/eigen_normal_sil6.5n2_18kph.log.gz").is_file()


def test_closed_loop_sign_stabilizes():
    """Steer-into-lean +K (V - v) phidot keeps the Whipple model of this bicycle stable at
    the measured speeds; the opposite sign does not (physics check of the log signs)."""
    m = ExperimentModel()
    for v in (1.5, 2.5, 3.5, 4.5):
        vs = 1.066 * v - 0.128
        assert np.all(m.eigenvalues(vs).real < 0)
        assert np.any(ExperimentModel(K=-2.0).eigenvalues(vs).real > 0)


def test_simulation_matches_closed_loop_matrix():
    """Second method: the vectorized simulation equals powers of the augmented loop
    matrix (delay, lag, gain, biases) to round-off (1e-10)."""
    from bikeid.ident.effects.synthetic_decays import synthetic_windows

    m = ExperimentModel(effects={"input_delay": 0.023, "actuator_lag": 0.02, "command_gain": 0.9,
                                 "roll_rate_bias": 0.01, "steer_torque_bias": 0.05})  # fmt: skip
    w = replace(synthetic_windows(ExperimentModel(), [3.0], 1, noise=0.0)[0], hist=np.zeros(20))
    s = m.simulate([w])[0]
    Phi, G, c, npl = m.closed_loop(float(np.mean(w.v_sensor)))
    x0 = w.state0()
    z = np.zeros(Phi.shape[0])
    z[:4] = [x0[0], x0[1], (x0[2] - 0.01), x0[3]]
    for k in range(w.n):
        assert abs(z[1] - s["delta"][k]) < 1e-10
        z = Phi @ z + c
    # frequency response: DC gain of T_ext -> delta equals the steady state of the loop
    H0 = m.frequency_response(3.0 * 1.066 - 0.128, [0.0])[0, 1]
    Phi2, G2, _, _ = m.closed_loop(3.0 * 1.066 - 0.128)
    dc = np.linalg.solve(np.eye(Phi2.shape[0]) - Phi2, G2)[1]
    assert abs(H0 - dc) < 1e-12


def test_parameter_corrections_match_meijaard_mass_matrix():
    """Parameter corrections against Meijaard 2007 appendix A written out by hand:
    M_phiphi = T_xx = I_Rxx + I_Bxx + I_Hxx + I_Fxx + m_R r_R^2 + m_B z_B^2 + m_H z_H^2
    + m_F r_F^2, and M_deltadelta = I_Alamlam + 2 mu I_Alamz + mu^2 T_zz (mu = c cos lam / w)
    with the front frame's inertia in I_Alamlam (I_Hxx sin^2 lam + 2 I_Hxz sin lam cos lam +
    I_Hzz cos^2 lam), I_Alamz (I_Hxz sin lam + I_Hzz cos lam) and T_zz (I_Hzz).  So scaling IH
    by s adds (s - 1) times those inertia terms to M_dd, scaling IB adds
    (s - 1) I_Bxx to M_phiphi and (s - 1) mu^2 I_Bzz to M_dd, and a mass shift dm (total
    mass and B+H mass centre kept) changes M_phiphi by the point-mass terms m z^2 only.
    Tolerance 1e-12: round-off."""
    from bikeid.sim.linear import canonical_matrices

    m0 = ExperimentModel()
    p = m0.p
    M0 = canonical_matrices(p).M
    sl, cl = np.sin(p.lam), np.cos(p.lam)
    M = ExperimentModel(effects={"front_inertia_scale": 3.0}).canonical().M
    mu = p.c * cl / p.w
    ih = p.IHxx * sl**2 + 2 * p.IHxz * sl * cl + p.IHzz * cl**2
    ih += 2 * mu * (p.IHxz * sl + p.IHzz * cl) + mu**2 * p.IHzz
    assert abs(M[1, 1] - M0[1, 1] - 2.0 * ih) < 1e-12
    assert abs(M[0, 0] - M0[0, 0] - 2.0 * p.IHxx) < 1e-12
    M = ExperimentModel(effects={"rear_inertia_scale": 1.5}).canonical().M
    assert abs(M[0, 0] - M0[0, 0] - 0.5 * p.IBxx) < 1e-12
    assert abs(M[1, 1] - M0[1, 1] - 0.5 * mu**2 * p.IBzz) < 1e-12  # I_Bzz in T_zz
    dm = 2.0
    q = ExperimentModel(effects={"front_mass_shift": dm}).plant_params()
    assert abs(q.mB + q.mH - p.mB - p.mH) < 1e-12
    for a in ("x", "z"):
        before = p.mB * getattr(p, a + "B") + p.mH * getattr(p, a + "H")
        assert abs(q.mB * getattr(q, a + "B") + q.mH * getattr(q, a + "H") - before) < 1e-12
    M = ExperimentModel(effects={"front_mass_shift": dm}).canonical().M
    point = q.mB * q.zB**2 + q.mH * q.zH**2 - p.mB * p.zB**2 - p.mH * p.zH**2
    assert abs(M[0, 0] - M0[0, 0] - point) < 1e-12
    with pytest.raises(ValueError, match="front_mass_shift"):
        ExperimentModel(effects={"front_mass_shift": -1.0}).plant_params()


def test_small_expm_matches_scipy():
    """The experiment model's ZOH exponential (``sim.sampling.expm_small``: scaling and
    squaring of a Taylor series) equals scipy.linalg.expm (Pade) on the loop matrices at
    1-6 m/s with an actuator lag (second method).

    Tolerance: both are accurate to rounding in the scaled exponential, and each of the s
    squarings (scaling to norm 0.5) can double the relative error (Higham 2005, sec. 2), so
    they agree to c n eps max|exp(hA)| 2^s with n the matrix size; c = 8 (observed: below
    0.07 in those units, at s = 1 and s = 5)."""
    from scipy.linalg import expm

    from bikeid.sim.sampling import expm_small

    m = ExperimentModel(effects={"actuator_lag": 0.02, "steer_viscous_damping": 0.5})
    for v in (1.0, 3.0, 6.0):
        A, B = m.continuous(v)
        big = np.zeros((A.shape[0] + 3, A.shape[0] + 3))
        big[: A.shape[0], : A.shape[0]] = A
        big[: A.shape[0], A.shape[0] :] = B
        for h in (0.01, 0.1):
            ref = expm(big * h)
            norm = float(np.max(np.sum(np.abs(big * h), axis=1)))
            squarings = max(0, int(np.ceil(np.log2(norm / 0.5)))) if norm > 0.5 else 0
            eps, n = np.finfo(float).eps, big.shape[0]
            tol = 8 * n * eps * np.max(np.abs(ref)) * 2.0**squarings
            assert np.max(np.abs(expm_small(big * h) - ref)) < tol


@needs_data
def test_real_logs_sign_and_controller():
    """sil_command = +2 (6.5 - speed) lean_rate in the logs (README), to 1e-4 N m."""
    root = Path(DATA) / "tudelft-sbw"
    run = load_log(next((root / "eigen").glob("*.log.gz")))
    pred = 2.0 * (6.5 - run["v"]) * run["phidot"]
    assert np.max(np.abs(pred - run.signals["sil_command"])) < 1e-4
    segs = read_segments(root / "eigen" / "segments.csv", {run.meta["file"]})
    assert segs and abs(treadmill_speed(run.meta["speed_sensor"]) - segs[0].speed) < 0.1


@pytest.fixture(scope="module")
def fit_2545(tmp_path_factory) -> Path:
    """``bikeid measured fit --data DATA --speeds 2.5,4.5``: the default path's model file
    (one fit shared by the evaluate and report tests below)."""
    if not DATA:
        pytest.skip("needs the measured data ($BIKEID_DATA)")
    from bikeid.experiments.cli import main

    model = tmp_path_factory.mktemp("fit_2545") / "m.json"
    args = ["measured", "fit", "--data", DATA, "--speeds", "2.5,4.5", "--out", str(model)]
    assert main(args) == 0
    return model


@needs_data
@pytest.mark.slow
def test_cli_fit_evaluate_states_the_goal(fit_2545, capsys):
    """The goal (held-out decay error halved) on the 2.5 + 4.5 m/s -> 1.5 + 3.5 m/s split, by
    the default path (``measured fit`` with ``--plant auto``, the default acceptance rule and
    nominal uncertainty; ``measured evaluate --json``).  The verdict is computed here from the
    interval (``halved`` only when its upper end is below 0.5, ``reduced`` when below 1), and
    must be what evaluate prints: ``reduced``, the goal is **not shown** (measured 0.43, 95 %
    interval 0.35-0.58; docs/measured.md).  The interval's ends are checked to 0.02, the
    bootstrap's resampling scatter at 2000 resamples (fixed seed: the ends are reproduced
    exactly; the band only allows the printed rounding).  The weave ratio has no interval (one
    median per file), so only its direction is asserted.  The other five splits (1.5 + 3.5 ->
    2.5 + 4.5: 0.61, 0.55-0.67, the same verdict) are ``benchmarks/measured_speed_splits.py``'s
    (none halved by its interval)."""
    import json

    from bikeid.experiments.cli import main

    capsys.readouterr()
    assert main(["measured", "evaluate", "--model", str(fit_2545), "--data", DATA, "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["plant"] == "nonlinear"
    assert all({"name", "value", "std", "unit"} <= set(e) for e in out["effects"])
    assert all({"file", "speed", "error_before", "error_after", "weave_error_before",
                "weave_error_after"} <= set(f) for f in out["files"])  # fmt: skip
    assert {round(f["speed"], 1) for f in out["files"]} == {1.5, 3.5}
    s = out["summary"]
    lo, hi = s["ratio_ci"]
    assert lo <= s["ratio"] <= hi
    expected = "halved" if hi < 0.5 else "reduced" if hi < 1 and s["p_value"] < 0.05 else None
    assert s["verdict"] == expected == "reduced"
    assert s["ratio"] == pytest.approx(0.43, abs=0.01)
    assert lo == pytest.approx(0.35, abs=0.02) and hi == pytest.approx(0.58, abs=0.02)
    assert s["weave_error_after"] < s["weave_error_before"]


@needs_data
@pytest.mark.slow
def test_report_bode_runs_are_an_independent_check(fit_2545, tmp_path):
    """``bikeid measured report``: a model fitted on the 2.5 + 4.5 m/s free decays predicts the
    4 m/s Bode runs (handlebar torque sweeps, never used in the fit: independent data) better
    than the nominal model: median relative complex error of T_ext -> (roll rate, steer)
    measured 0.61 -> 0.45, better in 13 of 14 files.  Asserted: the median drops and more than
    half of the files improve (a model that only fitted the decays' quirks would not)."""
    import json

    from bikeid.experiments.cli import main

    out = tmp_path / "report"
    rep_args = ["measured", "report", "--model", str(fit_2545), "--data", DATA, "--out", str(out)]
    assert main(rep_args) == 0
    rep = json.loads((out / "report.json").read_text())
    rows = rep["bode"]
    assert len(rows) >= 10
    nom = np.median([r["nominal"] for r in rows])
    aug = np.median([r["augmented"] for r in rows])
    assert aug < nom
    assert sum(r["augmented"] < r["nominal"] for r in rows) > len(rows) / 2
    assert {"decays.png", "eigenvalues.png", "bode.png", "report.md"} <= {
        p.name for p in out.iterdir()
    }


def test_cli_fit_refuses_negative_stability(tmp_path, capsys):
    """``--stability`` is a count of subsamples: a negative one is refused by name before any
    data is read (no model file is written)."""
    from bikeid.experiments.cli import main

    out = tmp_path / "m.json"
    rc = main(["measured", "fit", "--data", str(tmp_path), "--out", str(out), "--stability", "-1"])
    assert rc != 0 and "--stability" in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.parametrize("value", ["abc", float("nan"), None])
def test_model_effect_values_must_be_numbers(value):
    """A model JSON with a non-numeric or NaN effect value is refused naming the effect and
    its unit (not a bare float() error)."""
    with pytest.raises(ValueError, match=r"'steer_stiffness' must be a finite number \[N m/rad\]"):
        ExperimentModel(effects={"steer_stiffness": value})


# -- free-decay detection (logs without segments.csv rows) -----------------------------------
def _push_log(tmp_path: Path, name: str, pushes: dict[int, float], n: int = 3000) -> Path:
    """A synthetic eigen log at 3 m/s sensor speed: roll-rate noise (0.01 rad/s) plus, at
    each push index k, a push lobe rising over 0.1 s to amplitude a, then the free decay
    a e^{-3 t} cos(8 t) (a weave-like root, docs/measured.md)."""
    rng = np.random.default_rng(0)
    pr = 0.01 * rng.standard_normal(n)
    for k, a in pushes.items():
        tt = np.arange(10) * 0.01
        pr[k - 10 : k] += a * np.sin(0.5 * np.pi * tt / 0.1)  # rising lobe, extreme at k
        t = np.arange(n - k) * 0.01
        pr[k:] += a * np.exp(-3.0 * t) * np.cos(8.0 * t)
    phi = np.cumsum(pr) * 0.01  # roll angle and a steer following it: not constant channels
    rows = [
        f"{2 * (6.5 - 3.0) * r:.6f},3.0,{a:.6f},{r:.6f},0,{0.5 * a:.6f},{0.5 * r:.6f},0,0,0,0,"
        f"{2 * (6.5 - 3.0) * r:.6f},0"
        for a, r in zip(phi, pr, strict=True)
    ]
    return _write(tmp_path / name, rows)


def test_detect_decays_finds_clean_pushes_only(tmp_path, monkeypatch):
    """Pushes at known rows: the windows start at each push's roll-rate extreme (the lobe's
    maximum is at k by construction) plus the settling delay, DECAY_SETTLE x the lobe's
    10-sample rise (its onset is the lobe's first sample, the only one below DECAY_ONSET x
    the peak: sin(pi / 20) = 0.156), to 1 sample, and last 1 s.  Rejected by the
    rules of ``detect_decays``: a decay spoilt by a second push 0.5 s in (its peak is
    exceeded within the window; 1000 by 1050, 2000 by 2060; the search resumes after
    the spoilt window).  The quiet-before rule matters: switched off, a third window
    (the tail of the 2060 push) is accepted.
    """
    import bikeid.dataset.decays as dm
    from bikeid.dataset.decays import detect_decays

    pushes = {500: 0.8, 1000: -0.6, 1050: 0.9, 2000: 0.7, 2060: -0.7, 2600: 0.5}
    run = load_log(_push_log(tmp_path, "eigen_x.log.gz", pushes))
    starts = [s.start for s in detect_decays(run)]
    assert len(starts) == 2
    late = dm.DECAY_SETTLE * 10
    assert abs(starts[0] - 500 - late) <= 1 and abs(starts[1] - 2600 - late) <= 1
    assert all(s.end - s.start == 100 for s in detect_decays(run))
    monkeypatch.setattr(dm, "DECAY_QUIET", 10.0)
    assert len(detect_decays(run)) == 3


def test_iter_decays_rejects_unknown_source(tmp_path):
    from bikeid.dataset.decays import iter_decays

    with pytest.raises(ValueError, match="unknown decay source"):
        list(iter_decays(tmp_path, "guessed"))


@needs_data
def test_detected_decays_match_transcribed_segments():
    """The detector against an independent source, the windows the source's analysis
    script picked by hand (eigen/segments.csv, starting at the roll-rate extreme): on the
    four logs 26 of the 28 listed windows are found, each starting its settling delay after
    the listed start (6-10 samples measured; tests/dataset/test_decays.py names the two
    missed).  Asserted: >= 90 % found within 0 to DECAY_MAX_SETTLE + 3 samples."""
    from bikeid.dataset.decays import DECAY_MAX_SETTLE, iter_decays

    root = Path(DATA) / "tudelft-sbw"
    listed = read_segments(root / "eigen" / "segments.csv", {p.name for p in root.rglob("*.gz")})
    found = {r.meta["file"]: [s.start for s in sg] for r, sg in iter_decays(root, "detected")}
    late = round(DECAY_MAX_SETTLE / 0.01) + 3
    hits = [any(0 <= d - s.start <= late for d in found.get(s.file, [])) for s in listed]
    assert len(listed) >= 20 and np.mean(hits) >= 0.9, (sum(hits), len(listed))


@needs_data
def test_unlisted_log_is_evaluated_from_detected_decays(tmp_path, capsys):
    """A log the segments file does not list (here a copy of the 3.5 m/s log under a new
    name, in a folder without segments.csv) is evaluated from detected windows.  Check
    against the listed windows of the original: on the detected windows that coincide
    with listed ones (9 of 9, each starting its settling delay, 6-10 samples, after the
    listed start at the extreme), the nominal error is the same to 10 % (measured 0.419
    listed vs 0.398 detected, 5 %: the later start drops the largest part of the first
    swing; 10 % leaves room for the 0.2 s longest delay), and `measured evaluate` runs on
    the folder."""
    import json
    import shutil

    from bikeid.dataset.decays import load_decays
    from bikeid.experiments.cli import main

    src = Path(DATA) / "tudelft-sbw" / "eigen" / "eigen_normal_sil6.5n2_12.6kph.log.gz"
    (tmp_path / "tudelft-sbw" / "eigen").mkdir(parents=True)
    shutil.copy(src, tmp_path / "tudelft-sbw" / "eigen" / "eigen_new_run_3.5mps.log.gz")
    new = load_decays(str(tmp_path))
    old = [w for w in load_decays(DATA) if w.file == src.name]
    assert len(new) >= len(old) - 1
    pairs = [(o, n) for o in old for n in new if 0 <= n.start - o.start <= 23]
    assert len(pairs) == len(old)
    from bikeid.ident.effects.experiment_model import window_errors, with_nonlinear_correction

    m = ExperimentModel()
    eo, en = (with_nonlinear_correction([p[i] for p in pairs], m) for i in (0, 1))
    e_old = window_errors(eo, m.simulate(eo)).mean()
    e_new = window_errors(en, m.simulate(en)).mean()
    assert e_new == pytest.approx(e_old, rel=0.1)
    model = tmp_path / "m.json"
    model.write_text(json.dumps({"effects": {"steer_viscous_damping": 0.44}, "plant": "nonlinear"}))
    assert main(["measured", "evaluate", "--model", str(model), "--data", str(tmp_path),
                 "--speeds", "3.5", "--json"]) == 0  # fmt: skip
    out = json.loads(capsys.readouterr().out)
    assert [f["file"] for f in out["files"]] == ["eigen_new_run_3.5mps.log.gz"]
    assert out["files"][0]["windows"] == len(new)


def test_fit_model_plant_uncertain_names_no_effect(monkeypatch):
    """The pipeline's wiring of the plant rule, both ways on the same decays (synthetic, from
    the linear nominal model itself; no selection round, so each plant's final model is its
    nominal): with the plant test's answer replaced by a hand-built disagreeing one
    (alike fits, the linear selection naming a steer damping, the nonlinear a tyre scrub
    torque), ``fit_model`` names no effect, its verdict is ``nominal plant uncertain``, both
    selections and the test are in ``plant_check`` and a note names the difference; with the
    real rule the two nominals are compared and the linear plant, the data's, is chosen
    after selection (separated: at 1.5 m/s the decays reach steer angles where the
    nonlinear plant departs from the linear truth), with a sentence saying so; the stability
    subsamples run with the chosen plant."""
    from bikeid.ident.effects import pipeline
    from bikeid.ident.effects.acceptance import AcceptanceRule
    from bikeid.ident.effects.selection import PLANT_UNCERTAIN
    from bikeid.ident.effects.synthetic_decays import synthetic_windows

    ws = synthetic_windows(ExperimentModel(), (1.5, 2.5), per_speed=4, noise=0.01, seed=4)
    rule = AcceptanceRule.exact()
    real = pipeline.fit_model(ws, max_effects=0, rule=rule, stability=2)
    assert real["plant"] == "linear" and not real["plant_choice"]["uncertain"]
    assert real["stability"]["plant"] == "linear"  # the subsamples run the chosen plant
    assert real["selection_frequency"] == {"unexplained": 1.0}  # nothing else to select
    assert real["plant_check"]["test"]["separated"] and "linear plant fits better" in \
        real["plant_choice"]["reason"]  # fmt: skip
    side = {"verdict": ["steer_viscous_damping"], "effects": {"steer_viscous_damping": 0.5},
            "ambiguity": {"steer_viscous_damping": ["steer_viscous_damping"]}}
    other = {"verdict": ["tire_scrub_torque"], "effects": {"tire_scrub_torque": 0.4},
             "ambiguity": {"tire_scrub_torque": ["tire_scrub_torque"]}}
    diff = ["steer_viscous_damping (named with the linear plant; ...)",
            "tire_scrub_torque (named with the nonlinear plant; ...)"]

    def hand_built(model, linear, nonlinear, alpha=0.05):
        return {"plant": "linear", "uncertain": True, "reason": "hand-built: alike, disagree",
                "test": {"linear_cost": 1.0, "nonlinear_cost": 1.01, "p_value": 0.6,
                         "alpha": alpha, "separated": False},
                "check": {"agree": False, "linear": side, "nonlinear": other,
                          "differences": diff}}  # fmt: skip

    monkeypatch.setattr(pipeline, "choose_plant", hand_built)
    out = pipeline.fit_model(ws, max_effects=0, rule=rule)
    assert out["effects"] == {} and out["identification"]["verdict"] == [PLANT_UNCERTAIN]
    assert out["identification"]["effects"] == [] and out["plant_choice"]["uncertain"]
    assert out["plant_check"]["linear"] == side and out["plant_check"]["nonlinear"] == other
    assert out["plant_check"]["test"]["p_value"] == 0.6
    note = next(n for n in out["notes"] if n.startswith(PLANT_UNCERTAIN))
    assert all(d in note for d in diff) and "p = 0.6 > 0.05" in note
