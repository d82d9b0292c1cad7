"""``bikeid identify`` on sweep files, as a user runs it: identified vs true eigenvalues.

Truth: the linearization (Meijaard 2007 Appendix A, ``sim.linear``) of the bicycle stored in
the runs' metadata, recomputed here independently of the command.
"""

import contextlib
import csv
import gzip
import io
import json
import os
from pathlib import Path

import numpy as np
import pytest

from bikeid.experiments.cli import main
from bikeid.experiments.testbed.sweep import SweepSpec, run_sweep
from bikeid.sim.linear import critical_speeds, eigenvalues, match_eigenvalues
from bikeid.sim.parameters import benchmark

SPEEDS = (3.0, 4.5, 6.0, 8.0)


@pytest.fixture(scope="module")
def sweeps(tmp_path_factory):
    root = tmp_path_factory.mktemp("identify")
    noisy, ideal = root / "pid.h5", root / "pid_ideal.h5"
    run_sweep(SweepSpec("pid", SPEEDS, (0,), 30.0), noisy, workers=2, progress=False)
    run_sweep(SweepSpec("pid", SPEEDS, (0,), 30.0, sensors="ideal"), ideal, workers=2,
              progress=False)  # fmt: skip
    return noisy, ideal


def _identify(capsys, *args):
    assert main(["identify", *map(str, args), "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def _complex(rows):
    return np.array([complex(e["re"], e["im"]) for e in rows])


def test_pem_per_speed_and_speed_model_match_truth(sweeps, capsys, tmp_path):
    """PEM on 30 s of noisy closed-loop data per speed. Tolerances: the issue's accuracy goal
    (2 %, or 0.05 1/s where |lambda| < 2.5) met by ``bikeid accuracy`` from 50 s runs; here
    runs are 30 s (standard errors ~sqrt(50/30) = 1.3x larger), so 1.5x that goal. Critical
    speeds: the goal is 0.05 m/s from 29 speeds; from 4 speeds we allow 0.15 m/s."""
    from bikeid.ident.model_file import load_model
    from bikeid.ident.uncertainty import critical_speed_intervals

    noisy, _ = sweeps
    p = benchmark()
    target = tmp_path / "speed.json"
    out = _identify(capsys, "--method", "pem", noisy, "--speed-parameterized", "--out", target)
    assert out["speeds"] == list(SPEEDS)
    for row in out["per_speed"]:
        truth = np.sort_complex(eigenvalues(p, row["speed"]))
        np.testing.assert_allclose(_complex(row["true_eigenvalues"]), truth, atol=1e-12)
        ident = match_eigenvalues(_complex(row["eigenvalues"]), truth)
        tol = 1.5 * np.maximum(0.02 * np.abs(truth), np.where(np.abs(truth) < 2.5, 0.05, 0))
        assert np.all(np.abs(ident - truth) <= tol), (row["speed"], ident, truth)
    cs, true_cs = out["critical_speeds"], critical_speeds(p)
    assert abs(cs["v_w"] - true_cs["v_w"]) < 0.15
    assert abs(cs["v_c"] - true_cs["v_c"]) < 0.15
    # the 95 % intervals (of the saved model, ident.uncertainty) are profile intervals
    # around the printed values; where the standard error is a small fraction of the value
    # (under 1 % here) the speed is nearly linear in the parameters over the interval, so
    # each end is within 5 % of the first-order half-width 1.96 SE
    # (ident.uncertainty.z_value(0.95) = 1.959964)
    # (these runs roll 2.8 deg RMS, above the amplitude limit: the intervals are withheld by
    # default, ident.trust; asked for by name to show the bias the limit guards against)
    crit = critical_speed_intervals(load_model(target), refuse_amplitude=False).to_json()
    assert crit["method"] == "profile"
    for name in ("v_w", "v_c"):
        c = crit[name]
        assert c["value"] == pytest.approx(cs[name], rel=1e-12)
        assert c["std"] < 0.01 * c["value"]
        lo, hi = c["interval"]
        assert hi - c["value"] == pytest.approx(1.959964 * c["std"], rel=0.05)
        assert c["value"] - lo == pytest.approx(1.959964 * c["std"], rel=0.05)
    # on these 30 s runs of the nonlinear plant the weave speed's interval excludes the
    # linearized truth (measured v_w 4.2809 +- 0.0009 [4.279, 4.283] for 4.2924, 12 SE;
    # v_c 6.0188 +- 0.0026 [6.014, 6.024] for 6.0243, 2 SE): the bias of a linear fit at the
    # excitation amplitude, which the residual tests cannot see (ident.structure), so they
    # pass and the note says how to check it.  (With each speed's K held at its per-speed
    # fit's, the model over speed was biased on the linear plant too and rejected here.)
    lo, hi = crit["v_w"]["interval"]
    assert not lo <= true_cs["v_w"] <= hi
    iv = out["intervals"]
    assert "linear plant only" in iv["calibration"] and iv["level"] == 0.95
    # the amplitude guard (ident.trust, 0.5 deg RMS roll) withholds them by default, saying
    # so: the bias shown above is what it guards
    from bikeid.ident.trust import WithheldIntervals

    with pytest.raises(WithheldIntervals, match="RMS roll angle"):
        critical_speed_intervals(load_model(target))
    assert iv["critical_speeds"] is None
    # the Kalman-gain per-speed fits are all off the predictor's stability boundary, so each
    # is compared with the model over speed (a fit on the boundary has no usable covariance
    # and is skipped); at 3 m/s the comparison sees the same bias (measured p = 3e-4 with the
    # Kalman gain, 1.5e-3 with the free gain, whose fits at 4.5 and 8 m/s sat on the boundary)
    st = iv["structure"]
    hausman = {float(v): r for v, rows in st["tests"].items() for r in rows
               if r["kind"] == "speed_model"}  # fmt: skip
    assert sorted(hausman) == list(SPEEDS)
    assert hausman[3.0]["p_value"] < 0.01
    rejected = any(r["p_value"] < st["per_test_level"] for rows in st["tests"].values()
                   for r in rows if not r["advisory"])  # fmt: skip
    assert st["speed_model_rejected"] is rejected
    # the verdict is recorded in the model file beside the covariance it judges
    doc = json.loads(target.read_text())
    assert doc["results"]["structure_check"]["passed"] is (not rejected)


def test_greybox_intervals_match_monte_carlo(sweeps, capsys, tmp_path):
    """``identify --method greybox --out``: the JSON's eigenvalue and v_w intervals are those
    of ident.uncertainty on the saved model (GreyboxModel.at / speed_model), and that
    first-order propagation from the free entries agrees with Monte Carlo: 400 draws of the
    entries from N(estimate, covariance / 1e4) (small, where first order is exact), each
    turned into matrices, eigenvalues at 5 m/s and v_w.  Measured agreement 2-5 %; the
    tolerance 15 % is ~4 sampling standard errors of an sd from 400 draws (1/sqrt(798))."""
    import dataclasses

    from bikeid.ident import uncertainty
    from bikeid.ident.greybox import _matrices
    from bikeid.ident.model_file import load_model
    from bikeid.sim.linear import state_matrices

    noisy, _ = sweeps
    target = tmp_path / "grey.json"
    out = _identify(capsys, "--method", "greybox", noisy, "--out", target)
    g = load_model(target)
    cv = uncertainty.critical_speed_intervals(g.speed_model()).to_json()
    assert out["intervals"]["critical_speeds"] == cv
    row = out["per_speed"][1]
    assert row["eigenvalue_intervals"] == uncertainty.eigenvalue_intervals(g.at(4.5)).to_json()
    # the structure check keeps them: only the advisory whiteness test rejects (phi at
    # 4.5 m/s, measured p = 1.2e-19), and the note says so
    st = out["intervals"]["structure"]
    assert st["passed"] and "advisory: residuals are not white (phi)" in st["note"]
    small = dataclasses.replace(g, covariance=g.covariance * 1e-4)
    ei = uncertainty.eigenvalue_intervals(small.at(5.0))
    v_w = uncertainty.critical_speed_intervals(small.speed_model())
    rng = np.random.default_rng(0)
    names, L = list(g.free), np.linalg.cholesky(small.covariance)
    base = {**g.fixed, **g.free}
    draws_vw, draws_ev = [], []
    for _ in range(400):
        vals = {**base, **dict(zip(names, np.array(list(g.free.values())) +
                                   L @ rng.standard_normal(len(names)), strict=True))}  # fmt: skip
        if g.symmetric:
            vals["Mdp"], vals["K0dp"] = vals["Mpd"], vals["K0pd"]
        cm = _matrices(vals, g.g)
        draws_vw.append(critical_speeds(cm)["v_w"])
        draws_ev.append(match_eigenvalues(np.linalg.eigvals(state_matrices(cm, 5.0)[0]),
                                          ei.values))  # fmt: skip
    ev = np.array(draws_ev)
    assert np.std(draws_vw, ddof=1) == pytest.approx(v_w.std_v_w, rel=0.15)
    np.testing.assert_allclose(ev.real.std(0, ddof=1), ei.std_real, rtol=0.15)
    complex_pair = ei.std_imag > 0
    np.testing.assert_allclose(ev.imag.std(0, ddof=1)[complex_pair], ei.std_imag[complex_pair],
                               rtol=0.15)  # fmt: skip


def test_direct_on_noise_free_sweep_matches_truth(sweeps, capsys):
    """Moore & Hubbard LS (their free entries) on noise-free data with the default
    interval-averaged equation (3 Hz filter): no errors-in-variables bias and no
    derivative bias; docs/accuracy.md measures the remaining error (discretization and
    nonlinearity, entries within ~1.3 %) at well under the 2 % goal; 5 %, 0.1 1/s near zero."""
    _, ideal = sweeps
    p = benchmark()
    out = _identify(capsys, "--method", "direct", ideal)
    assert max(out["condition"].values()) < 1e6  # roll and steer rows
    for row in out["per_speed"]:
        truth = np.sort_complex(eigenvalues(p, row["speed"]))
        ident = match_eigenvalues(_complex(row["eigenvalues"]), truth)
        tol = np.maximum(0.05 * np.abs(truth), 0.1)
        assert np.all(np.abs(ident - truth) <= tol), (row["speed"], ident, truth)


def test_moore_hubbard_recipe_is_biased_by_held_torque(sweeps, capsys):
    """Reference T9: central differences of 15 Hz-filtered rates misread the torque steps of
    a 100 Hz zero-order hold; on the same noise-free data the caster root moves by more than
    10 %, which is why the interval-averaged equation is the default."""
    _, ideal = sweeps
    out = _identify(capsys, "--method", "direct", ideal, "--derivative", "central",
                    "--cutoff", "15")  # fmt: skip
    row = next(r for r in out["per_speed"] if r["speed"] == 3.0)
    truth = np.sort_complex(eigenvalues(benchmark(), 3.0))
    ident = match_eigenvalues(_complex(row["eigenvalues"]), truth)
    assert abs(ident[0] - truth[0]) > 0.10 * abs(truth[0])  # caster, -10.35 1/s


def test_direct_single_speed_with_speed_noise_is_refused(tmp_path, capsys):
    """Reference T3: at one nominal speed g q and v^2 q are collinear; speed-sensor noise
    (1e-2 m/s) makes the regression numerically finite but meaningless, so the command must
    refuse with the conditioning, not print K0dd and K2dd."""
    f = tmp_path / "one.h5"
    run_sweep(SweepSpec("pid", (5.0,), (0, 1), 10.0), f, workers=1, progress=False)
    assert main(["identify", "--method", "direct", str(f)]) == 4  # no trustworthy answer
    err = capsys.readouterr().err
    assert "K0dd and K2dd are both free" in err and "condition number" in err


def test_speed_model_needs_two_speeds(tmp_path, capsys):
    f = tmp_path / "one.h5"
    run_sweep(SweepSpec("pid", (5.0,), (0,), 5.0), f, workers=1, progress=False)
    assert main(["identify", "--method", "pem", str(f), "--speed-parameterized"]) == 3  # input
    assert "two or more speeds" in capsys.readouterr().err


def test_plot_and_out_must_be_different_files(tmp_path, capsys):
    """--plot naming --out's model file is refused before the fit (the figure would have
    replaced the model); different names write both."""
    f = tmp_path / "one.h5"
    run_sweep(SweepSpec("pid", (5.0,), (0,), 10.0), f, workers=1, progress=False)
    same = tmp_path / "m.png"
    assert main(["identify", str(f), "--out", str(same), "--plot", str(same), "--quiet"]) == 3
    assert "also the model file of --out" in capsys.readouterr().err
    assert not same.exists()
    model, fig = tmp_path / "m.json", tmp_path / "e.png"
    assert main(["identify", str(f), "--out", str(model), "--plot", str(fig), "--quiet"]) == 0
    assert model.read_text().lstrip().startswith("{") and fig.read_bytes()[:4] == b"\x89PNG"


# -- a user's own logs: units, signs, excitation, pooling (ident.informativity, -----------
# -- dataset.plausibility); files written at test time in two non-bikeid formats ---------
DATA = os.environ.get("BIKEID_DATA", str(Path(__file__).resolve().parents[4] / "shared" / "data"))
EIGEN = Path(DATA) / "tudelft-sbw" / "eigen" / "eigen_normal_sil6.5n2_5.4kph.log.gz"
COLS = ("phi=Roll_deg,phidot=RollRate_dps,delta=Steer_deg,deltadot=SteerRate_dps,"
        "v=Speed_kmh,T_delta=SteerTorque_Nm")  # fmt: skip
UNITS = "phi=deg,phidot=deg/s,delta=deg,deltadot=deg/s,v=km/h,t=ms"


def _cli(argv, cwd: Path) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.chdir(cwd), contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main(list(map(str, argv)))
    return rc, out.getvalue(), err.getvalue()


def _logger_csv(path: Path, t_ms, roll_deg, roll_rate_dps, steer_deg, steer_rate_dps, kmh, tq):
    """An ordinary logger's CSV: ms, degrees, km/h, roll (and its rate) positive left."""
    table = np.column_stack([t_ms, -np.asarray(roll_deg), -np.asarray(roll_rate_dps), steer_deg,
                             steer_rate_dps, kmh, tq])  # fmt: skip
    with path.open("w") as fh:
        fh.write("Time_ms,Roll_deg,RollRate_dps,Steer_deg,SteerRate_dps,Speed_kmh,SteerTorque_Nm\n")
        np.savetxt(fh, table, delimiter=",", fmt="%.12g")
    return path


def _from_run(path: Path, run, speed_noise: float = 0.0, seed: int = 0) -> Path:
    rng = np.random.default_rng(seed)
    kmh = 3.6 * (run["v"] + speed_noise * rng.standard_normal(run.n))
    return _logger_csv(path, 1000 * run.t, np.degrees(run["phi"]), np.degrees(run["phidot"]),
                       np.degrees(run["delta"]), np.degrees(run["deltadot"]), kmh,
                       run["T_delta"])  # fmt: skip


@pytest.fixture(scope="module")
def sbw_csv(tmp_path_factory) -> Path:
    """The 5.4 km/h push log of the steer-by-wire bicycle rewritten as a user's CSV: the
    whole log (its speed sensor starts high and settles: a speed that varies)."""
    if not EIGEN.exists():
        pytest.skip("steer-by-wire logs not found")
    with gzip.open(EIGEN, "rt") as fh:
        rows = list(csv.reader(fh))
    head = rows[0]
    a = np.array([r for r in rows[1:] if all(x.strip() for x in r)], float)

    def col(name):
        return a[:, head.index(name)]

    d = tmp_path_factory.mktemp("sbwcsv")
    _logger_csv(d / "ride.csv", 10.0 * np.arange(len(a)), np.degrees(col("lean_angle")),
                np.degrees(col("lean_rate")), np.degrees(col("fork_angle")),
                np.degrees(col("fork_rate")), 3.6 * col("speed"), col("command_fork"))  # fmt: skip
    # the same log with the roll angle left in radians (a user's "deg" is then wrong)
    raw = (d / "ride.csv").read_text().splitlines()
    out = [raw[0]]
    for line in raw[1:]:
        cells = line.split(",")
        cells[1] = repr(float(cells[1]) * np.pi / 180)
        out.append(",".join(cells))
    (d / "ride_rad.csv").write_text("\n".join(out) + "\n")
    return d


@pytest.mark.parametrize(
    "units, flip, extra, code, words",
    [
        # the case: --time Time_ms without t=ms makes a 138 s ride last 38 hours
        (UNITS.replace(",t=ms", ""), "phi,phidot", [], 3,
         ["sample period 10 s", "--units t=ms"]),
        # that check off: the next one names the same mistake from the rates
        (UNITS.replace(",t=ms", ""), "phi,phidot", ["--skip-check", "sample-period"], 3,
         ["x d(phi)/dt", "milliseconds but read as seconds"]),
        # roll flipped but not its rate: factor -1
        (UNITS, "phi", [], 3, ["phidot is -0.99", "opposite sign", "--flip"]),
        # the roll rate in deg/s declared as rad/s: outside the physical range, unit first
        (UNITS.replace("phidot=deg/s,", ""), "phi,phidot", [], 3,
         ["outside the physical range", "--units phidot=deg/s"]),
        # correct: the pushes under the bicycle's own balance law are feedback only
        (UNITS, "phi,phidot", [], 4,
         ["cannot determine the canonical PEM model", "feedback only", "dither"]),
    ],
)
def test_users_csv_of_a_push_log(sbw_csv, units, flip, extra, code, words):
    """Each mistake of a user importing the steer-by-wire push log (ms, degrees, km/h, roll
    positive left) is refused with its cause and the option that fixes it; mapped right,
    the log is refused because it cannot determine the model (its torque is the balance
    law K (V - v) phidot, R^2 > 0.99), never fitted into a confident wrong model."""
    argv = ["identify", "ride.csv", "--format", "csv", "--columns", COLS, "--units", units,
            "--time", "Time_ms", "--flip", flip, *extra]  # fmt: skip
    rc, out, err = _cli(argv, sbw_csv)
    assert rc == code, err
    last = err.strip().splitlines()[-1]
    assert last.startswith("bikeid identify: error: ") and "Traceback" not in err
    for w in words:
        assert w in last, (w, err)


def test_users_csv_in_radians_declared_degrees(sbw_csv):
    """The roll angle logged in radians but declared deg: the roll rate is 57.3 x its
    derivative (measured factor within 5 % of 180/pi: the log's gyro and angle filter agree
    to 1-4 %, tests/test_plausibility)."""
    argv = ["identify", "ride_rad.csv", "--format", "csv", "--columns", COLS, "--units", UNITS,
            "--time", "Time_ms", "--flip", "phi,phidot"]  # fmt: skip
    rc, _, err = _cli(argv, sbw_csv)
    assert rc == 3 and "phi in rad declared as deg" in err, err
    factor = float(err.split("phidot is ")[1].split(" x ")[0])
    assert abs(factor / (180 / np.pi) - 1) < 0.05, err


def test_users_csv_window_and_split_stretches(sbw_csv):
    """The speed of the whole log varies (sensor start-up, then the treadmill's 1.5 m/s):
    it is split into constant-speed stretches (a note says which), not refused; --start/
    --stop keep a window; checks turned off are named on stderr."""
    base = ["identify", "ride.csv", "--format", "csv", "--columns", COLS, "--units", UNITS,
            "--time", "Time_ms", "--flip", "phi,phidot", "--method", "direct", "--bicycle",
            "steer-by-wire", "--json", "--skip-check", "informativity"]  # fmt: skip
    rc, out, err = _cli(base, sbw_csv)
    assert rc == 0, err
    assert "split into" in err and "constant-speed stretch" in err
    res = json.loads(out)
    assert any(abs(v - 1.07 * 1.5 + 0.13) < 0.05 for v in res["speeds"]), res["speeds"]
    assert "informativity skipped" in err
    # one speed: K2dd cannot be told from K0dd there, so --free leaves it out (direct too)
    free = "Mpd,C1pd,K0pd,Mdd,C1dp,C1dd,K0dd"
    rc, out, err = _cli([*base, "--start", "40", "--stop", "80", "--free", free], sbw_csv)
    assert rc == 0, err
    res = json.loads(out)
    assert "split into" not in err and len(res["speeds"]) == 1
    assert sorted(res["free"]) == sorted(free.split(","))


def _sim(speed, seed=0, duration=20.0, **kw):
    from bikeid.dataset.linear_loop import simulate

    kw.setdefault("rate_noise", 1e-3)
    kw.setdefault("angle_noise", 1e-4)
    return simulate(benchmark(), speed, duration=duration, seed=seed, **kw)


def _nested_h5(path: Path, run, speed_noise: float = 0.01) -> Path:
    """A user's HDF5 with nested groups, ms, degrees, km/h and roll positive left."""
    import h5py

    rng = np.random.default_rng(1)
    with h5py.File(path, "w") as f:
        f["logger/clock/time_ms"] = 1000 * run.t
        imu = f.create_group("sensors/imu")
        imu["roll"], imu["roll_rate"] = -np.degrees(run["phi"]), -np.degrees(run["phidot"])
        enc = f.create_group("sensors/steering/encoder")
        enc["angle"], enc["rate"] = np.degrees(run["delta"]), np.degrees(run["deltadot"])
        f["sensors/wheel/speed_kmh"] = 3.6 * (run["v"] + speed_noise * rng.standard_normal(run.n))
        f["actuators/steer/torque"] = run["T_delta"]
    return path


H5COLS = ("phi=sensors/imu/roll,phidot=sensors/imu/roll_rate,delta=sensors/steering/encoder/"
          "angle,deltadot=sensors/steering/encoder/rate,v=sensors/wheel/speed_kmh,"
          "T_delta=actuators/steer/torque")  # fmt: skip


@pytest.mark.parametrize(
    "kw, code, words",
    [
        # the testbed's dither: identified, then validated (~25 s with validate)
        pytest.param({}, 0, [], marks=pytest.mark.slow),
        ({"dither": 0.0, "disturbance": 0.5}, 4, ["feedback only"]),
        ({"dither": 0.0, "reference": lambda t: 0.02 * np.sin(2 * np.pi * 0.7 * t),
          "rate_noise": 0.0, "angle_noise": 0.0}, 4,
         ["distinct frequenc", "a single sinusoid has 2", "multisine"]),
    ],
)
def test_nested_hdf5_excitation_known_both_ways(tmp_path, kw, code, words):
    """A closed loop of the benchmark at 5 m/s logged into a nested HDF5: with the testbed's
    dither PEM recovers the eigenvalues within the project's accuracy goal
    (testbed.accuracy.eigen_tolerance); without dither, or with one sinusoid only, exit 4
    naming the cause.  (The sinusoid case is noise-free: sensor noise fed back through the
    controller reaches the plant as a broadband input of its own.)"""
    from bikeid.experiments.testbed.accuracy import eigen_tolerance

    _nested_h5(tmp_path / "ride.h5", _sim(5.0, **kw))
    argv = ["identify", "ride.h5", "--format", "hdf5", "--columns", H5COLS, "--units",
            UNITS, "--time", "logger/clock/time_ms", "--flip", "phi,phidot", "--json"]  # fmt: skip
    rc, out, err = _cli(argv, tmp_path)
    assert rc == code, err
    for w in words:
        assert w in err, (w, err)
    if code == 0:
        row = json.loads(out)["per_speed"][0]
        truth = eigenvalues(benchmark(), row["speed"])
        got = match_eigenvalues(_complex(row["eigenvalues"]), truth)
        assert np.all(np.abs(got - truth) <= [eigen_tolerance(z) for z in truth]), (got, truth)
        _validate_reuses_the_import_settings(tmp_path, argv)


def _validate_reuses_the_import_settings(tmp_path: Path, argv: list) -> None:
    """``validate`` reads the data as the model was identified (the model file's format,
    columns, units, time, flip) unless told otherwise; its fit equals the one it computes
    with every option repeated."""
    rc, _, err = _cli([*argv, "--out", "m.json"], tmp_path)
    assert rc == 0, err
    rc, short, err = _cli(["validate", "ride.h5", "--model", "m.json", "--json"], tmp_path)
    assert rc == 0, err
    doc = json.loads(short)
    assert "--format hdf5" in doc["settings_from_model"]
    assert "--time logger/clock/time_ms" in doc["settings_from_model"]
    full = ["validate", "ride.h5", "--model", "m.json", *argv[2:]]
    rc, long, err = _cli(full, tmp_path)
    assert rc == 0, err
    assert json.loads(long)["fit"] == doc["fit"] and json.loads(long)["settings_from_model"] == []
    # an option given again wins: the HDF5 read as a bikeid run file is refused
    rc, _, err = _cli(["validate", "ride.h5", "--model", "m.json", "--format", "bikeid"],
                      tmp_path)  # fmt: skip
    assert rc == 3, err


def test_pooled_runs_give_one_model(tmp_path):
    """The issue's three runs at a measured 4.146, 4.153 and 4.157 m/s (speed columns with
    1 cm/s sensor noise, km/h): one model at their sample-weighted mean speed (computed here
    from the written files), its eigenvalues within the accuracy goal of the Whipple model
    there; with --speed-tolerance 0 they stay three speeds."""
    from bikeid.dataset.logs import pool_speeds
    from bikeid.experiments.testbed.accuracy import eigen_tolerance

    speeds = (4.146, 4.153, 4.157)
    names = []
    for i, v in enumerate(speeds):
        _from_run(tmp_path / f"r{i}.csv", _sim(v, seed=i, duration=15.0 + 5 * i), 0.01, seed=i)
        names.append(f"r{i}.csv")
    means, ns = [], []
    for n in names:
        kmh = np.loadtxt(tmp_path / n, delimiter=",", skiprows=1)[:, 5]
        means.append(float(np.mean(kmh / 3.6)))
        ns.append(kmh.size)
    pooled = sum(m * n for m, n in zip(means, ns, strict=True)) / sum(ns)
    argv = ["identify", *names, "--format", "csv", "--columns", COLS, "--units", UNITS,
            "--time", "Time_ms", "--flip", "phi,phidot", "--json", "--out", "m.json"]  # fmt: skip
    rc, out, err = _cli(argv, tmp_path)
    assert rc == 0, err
    res = json.loads(out)
    assert res["model_files"] == ["m.json"] and len(res["per_speed"]) == 1
    assert abs(res["speeds"][0] - pooled) < 1e-6
    truth = eigenvalues(benchmark(), pooled)
    got = match_eigenvalues(_complex(res["per_speed"][0]["eigenvalues"]), truth)
    assert np.all(np.abs(got - truth) <= [eigen_tolerance(z) for z in truth]), (got, truth)
    assert len(set(pool_speeds(means, ns, 0.0))) == 3
    assert len(set(pool_speeds(means, ns, 0.25))) == 1
    assert pool_speeds([1.0, 1.2, 1.4, 3.0], [1, 1, 1, 1], 0.25) == [0, 0, 1, 2]


@pytest.mark.parametrize("text, value", [("14.4km/h", 4.0), ("5m/s", 5.0), ("5", 5.0),
                                         (" 9 km/h ", 2.5)])
def test_speed_takes_a_unit(text, value):
    from bikeid.experiments.cli.log_options import speed_arg

    assert speed_arg(text) == pytest.approx(value, rel=1e-15)


@pytest.mark.parametrize("text", ["fast", "-3", "0km/h", "5 furlongs", "1e9"])
def test_speed_without_a_speed_is_a_usage_error(text, capsys):
    assert main(["identify", "x.csv", "--format", "csv", "--speed", text]) == 2
    assert "--speed" in capsys.readouterr().err


def test_help_states_the_defaults(capsys):
    """Every option of identify with a default says it in --help; the method's is pem."""
    try:
        main(["identify", "--help"])
    except SystemExit:
        pass
    text = " ".join(capsys.readouterr().out.split())
    assert "(default: pem)" in text
    for opt in ("--speed-tolerance", "--min-stretch", "--min-speed", "--derivative", "--time",
                "--format", "--input"):  # fmt: skip
        part = text.rsplit(f"{opt} ", 1)[-1][:400]  # its own entry comes last
        assert "default" in part, opt


# -- a model over speed says its answers: v_d, v_w, v_c printed and saved -----------------
@pytest.fixture(scope="module")
def two_speed_files(tmp_path_factory):
    """15 s of the exact linear plant under the roll PID at 4 and 6 m/s (the canonical model
    over speed contains it), and the same at 4 m/s beside the steer-by-wire bicycle at 6 m/s
    (no one model over speed holds both bicycles: the data reject it)."""
    from bikeid.controllers import UniformDither, make
    from bikeid.dataset.closed_loop import simulate_run
    from bikeid.dataset.store import write_runs
    from bikeid.sim.parameters import by_name

    def run(p, v):
        return simulate_run(p, make("pid", p), speed=v, duration=15.0, plant="linear",
                            dither=UniformDither(1.0, seed=3), seed=3)  # fmt: skip

    root = tmp_path_factory.mktemp("over_speed")
    p = benchmark()
    one = write_runs(root / "one.h5", [run(p, 4.0), run(p, 6.0)])
    mixed = write_runs(root / "mixed.h5", [run(p, 4.0), run(by_name("steer-by-wire"), 6.0)])
    return one, mixed


def _critical_rows(text: str) -> dict:
    """The printed lines of v_d, v_w and v_c by name."""
    rows = {}
    for line in text.splitlines():
        name = line.strip().split(" ", 1)[0]
        if name in ("v_d", "v_w", "v_c") and " = " in line:
            rows[name] = line
    return rows


def _value_text(v) -> str:
    return "none below 30 m/s" if v is None else f"{v:.3f} m/s"


def test_model_over_speed_prints_and_saves_its_critical_speeds(two_speed_files, capsys,
                                                               tmp_path):  # fmt: skip
    """Text output and model file carry v_d, v_w, v_c.  Values: recomputed from the model read
    back (sim.linear.critical_speeds, a second path).  Intervals: on the linear plant the
    model set holds the truth, so the printed 95 % intervals must contain the benchmark's
    v_w 4.2924 and v_c 6.0243 m/s (Meijaard 2007; sim.linear), and equal the saved ones."""
    from bikeid.ident.model_file import read_model_file

    target = tmp_path / "model.json"
    assert main(["identify", str(two_speed_files[0]), "--speed-parameterized",
                 "--out", str(target)]) == 0  # fmt: skip
    text = capsys.readouterr().out
    saved = read_model_file(target)
    crit = saved.critical_speeds
    again = saved.model.critical_speeds()
    rows = _critical_rows(text)
    assert set(rows) == {"v_d", "v_w", "v_c"}
    truth = critical_speeds(benchmark())
    for name in ("v_d", "v_w", "v_c"):
        assert crit[name] == again[name]  # saved = the model's own, bit for bit
        assert _value_text(again[name]) in rows[name]
    assert "no interval" in rows["v_d"]  # intervals cover v_w and v_c only: said so
    for name in ("v_w", "v_c"):
        lo, hi = crit["intervals"][name]["interval"]
        assert f"95 % interval [{lo:.3f}, {hi:.3f}] m/s" in rows[name]
        assert lo <= truth[name] <= hi, (name, lo, hi, truth[name])
    assert crit["note"] is None and crit["vmax"] == 30.0
    # a critical speed outside the fitted 4-6 m/s is labelled extrapolated, one inside not
    for name, line in rows.items():
        v = crit[name]
        assert ("extrapolated" in line) == (v is not None and not 4.0 <= v <= 6.0), line


def test_rejected_model_over_speed_says_why_in_two_lines_and_counts_right(
    two_speed_files, capsys, tmp_path
):
    """Two bicycles in one file: the model over speed is rejected.  v_d, v_w, v_c are still
    printed (the estimates stand) and saved; the reason is two lines (what, one fix); the
    count of withheld speeds is the structure check's, saved beside it, and equals the
    number of speeds printed without interval rows."""
    from bikeid.ident.model_file import read_model_file
    from bikeid.ident.structure import FIX_LONGER, FIX_PER_SPEED
    from bikeid.ident.uncertainty import PREDICTOR_BOUNDARY_TOL, predictor_radius

    target = tmp_path / "model.json"
    assert main(["identify", str(two_speed_files[1]), "--speed-parameterized",
                 "--out", str(target)]) == 0  # fmt: skip
    text = capsys.readouterr().out
    saved = read_model_file(target)
    check = saved.results["structure_check"]
    assert check["speed_model_rejected"] is True
    rows = _critical_rows(text)
    again = saved.model.critical_speeds()
    for name in ("v_d", "v_w", "v_c"):
        assert saved.critical_speeds[name] == again[name]
        assert _value_text(again[name]) in rows[name]
    for name in ("v_w", "v_c"):
        assert "no interval: withheld, the data reject the model over speed" in rows[name]
    notes = [n for n in text.splitlines() if n.startswith("note: ")]
    i = next(k for k, n in enumerate(notes) if "the data reject the model over speed" in n)
    what, fix = notes[i], notes[i + 1]
    n_rej, n_held = len(check["rejected_speeds"]), len(check["withheld_speeds"])
    assert n_held == 2 and text.count("95 % Re") == 0  # every speed withheld, none printed
    assert f"at any of the {n_held} speeds" in what
    assert f"reject the model over speed at {n_rej} of {n_held} speeds" in what
    # the one fix that applies: a longer record where a per-speed fit ended on its
    # predictor's stability boundary (recomputed from the saved per-speed fits), else
    # the per-speed fit
    boundary = any(
        r is not None and r > 1.0 - PREDICTOR_BOUNDARY_TOL
        for r in map(predictor_radius, saved.model.per_speed.values())
    )
    assert fix == f"note: fix: {FIX_LONGER if boundary else FIX_PER_SPEED}"
    assert not any("Fix:" in n for n in notes)  # no second, long copy of the reason
    assert saved.critical_speeds["intervals"] is None
    assert saved.critical_speeds["note"] == f"{what[6:]}\n{fix[6:]}"


def test_withheld_counts_rejecting_speeds_against_all():
    """One speed of three rejects a model over speed: all three lose their intervals, and
    the note counts 1 of 3 (not "rejected at 3", not "withheld at 1"); no per-speed fit
    ended on its boundary, so the fix is the per-speed fit."""
    from bikeid.experiments.cli.identify import _withheld
    from bikeid.ident.structure import FIX_PER_SPEED, StructureCheck

    row = {"kind": "independence", "output": "phi", "statistic": 90.0, "dof": 25,
           "p_value": 1e-9, "rejected": True, "advisory": False}  # fmt: skip
    check = StructureCheck(level=0.01, per_test_level=0.01 / 12, n_tests=12,
                           tests={3.0: [row], 4.0: [], 5.0: []}, rejected_speeds=(3.0,),
                           speed_model_rejected=True,
                           withheld_speeds=(3.0, 4.0, 5.0))  # fmt: skip

    class Over:  # a model over speed whose per-speed fits are not on their boundary
        per_speed: dict = {}

    w = _withheld(check, Over())
    assert "at any of the 3 speeds" in w["what"]
    assert "at 1 of 3 speeds (3 m/s;" in w["what"]
    assert "(phi), p = 1e-09" in w["what"]
    assert w["fix"] == FIX_PER_SPEED
    assert (w["rejected_speeds"], w["withheld_speeds"]) == ([3.0], [3.0, 4.0, 5.0])


def test_direct_model_over_speed_prints_its_critical_speeds_and_why_no_interval(
    sweeps, capsys, tmp_path
):
    """Least squares gives one model over all speeds, so it has critical speeds: printed
    (each equal to the saved model's own, recomputed after loading), saved, and said to have
    no interval (the method gives none).  On noise-free data the weave speed is within
    0.15 m/s of the benchmark's 4.2924 (the tolerance of the PEM test above)."""
    from bikeid.ident.model_file import read_model_file

    _, ideal = sweeps
    target = tmp_path / "direct.json"
    assert main(["identify", "--method", "direct", str(ideal), "--out", str(target)]) == 0
    rows = _critical_rows(capsys.readouterr().out)
    saved = read_model_file(target)
    again = saved.model.critical_speeds()
    for name in ("v_d", "v_w", "v_c"):
        assert saved.critical_speeds[name] == again[name]
        assert _value_text(again[name]) in rows[name]
    assert "no interval: this method gives none" in rows["v_w"]
    assert saved.critical_speeds["note"].startswith("no intervals: this method gives none")
    assert abs(again["v_w"] - critical_speeds(benchmark())["v_w"]) < 0.15


def test_the_same_refusal_at_several_speeds_is_one_note(monkeypatch):
    """Per-speed fits refused alike (e.g. each on its predictor's stability boundary): one
    note naming how many speeds, not one line per speed; every speed without interval."""
    from bikeid.experiments.cli.identify import _intervals
    from bikeid.ident import uncertainty
    from bikeid.sim.errors import UntrustworthyResult

    def refuse(model, *args, **kwargs):
        raise UntrustworthyResult(f"the fit ended on the boundary ({model})")

    monkeypatch.setattr(uncertainty, "eigenvalue_intervals", refuse)
    speeds = [3.0, 4.0, 5.0, 6.0, 7.0]
    iv = _intervals(dict.fromkeys(speeds, "m"), None, None)
    assert iv["eigenvalues"] == [None] * 5
    assert iv["notes"] == ["no eigenvalue intervals at 5 speeds (3-7 m/s): the fit ended on "
                           "the boundary (m)"]  # fmt: skip
    iv = _intervals({3.0: "a", 4.0: "b"}, None, None)  # different reasons: one note each
    assert iv["notes"] == [
        "no eigenvalue intervals at 3 m/s: the fit ended on the boundary (a)",
        "no eigenvalue intervals at 4 m/s: the fit ended on the boundary (b)",
    ]


def test_noise_model_option_chooses_the_innovation_gain(sweeps, capsys, tmp_path):
    """``--noise-model``: the default (``free``, the Kalman gain) fits the Kalman gain of
    fitted noise covariances, whose one-step predictor is stable by construction; ``gain``
    fits K's entries free (its predictor is stable, if at all, by the fit's bound).  Checked
    on the saved models (each speed's ``noise_model``, and the spectral radius of Ad - K C,
    computed here, below 1).  ``none`` (output error) on these runs, whose plant is
    open-loop unstable at 3 m/s, a speed-parameterized model and the other methods refuse
    with exit 3, a message naming the cause and the fix (for output error: --noise-model
    kalman, followed by the default run above), and no file written."""
    from bikeid.experiments.cli import main
    from bikeid.ident.model_file import load_model
    from bikeid.sim.errors import EXIT_INPUT

    noisy, _ = sweeps
    for choice, kind in ((None, "kalman"), ("gain", "gain")):
        target = tmp_path / f"{choice}.json"
        extra = [] if choice is None else ["--noise-model", choice]
        _identify(capsys, "--method", "pem", noisy, *extra, "--out", target)
        for v in SPEEDS:  # per-speed pem over several speeds: one file per speed
            m = load_model(tmp_path / f"{choice}-v{v:g}.json")
            assert m.noise_model == kind
            Ad, _, C, K = m.predictor()
            assert np.max(np.abs(np.linalg.eigvals(Ad - K @ C))) < 1.0
    for argv, phrase in (
        (["--method", "pem", "--noise-model", "none"], "output error simulates the plant"),
        (["--method", "pem", "--noise-model", "none"], "(--noise-model kalman, a predictor"),
        (["--method", "direct", "--noise-model", "gain"], "--noise-model applies to --method pem"),
        (["--method", "pem", "--speed-parameterized", "--noise-model", "kalman"],
         "per-speed noise model"),
    ):  # fmt: skip
        out = tmp_path / "refused.json"
        assert main(["identify", str(noisy), *argv, "--out", str(out)]) == EXIT_INPUT
        err = [ln for ln in capsys.readouterr().err.splitlines() if "error:" in ln]
        assert len(err) == 1 and phrase in err[0], err
        assert not out.exists()
