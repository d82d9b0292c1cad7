"""``bikeid identify`` on sweep files, as a user runs it: identified vs true eigenvalues.

Truth: the linearization (Meijaard 2007 Appendix A, ``sim.linear``) of the bicycle stored in
the runs' metadata, recomputed here independently of the command.
"""

import json

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


def test_pem_per_speed_and_speed_model_match_truth(sweeps, capsys):
    """PEM on 30 s of noisy closed-loop data per speed. Tolerances: the issue's accuracy goal
    (2 %, or 0.05 1/s where |lambda| < 2.5) met by ``bikeid accuracy`` from 50 s runs; here
    runs are 30 s (standard errors ~sqrt(50/30) = 1.3x larger), so 1.5x that goal. Critical
    speeds: the goal is 0.05 m/s from 29 speeds; from 4 speeds we allow 0.15 m/s."""
    noisy, _ = sweeps
    p = benchmark()
    out = _identify(capsys, "--method", "pem", noisy, "--speed-parameterized")
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
    # the 95 % intervals are profile intervals around the printed values; where the
    # standard error is a small fraction of the value (under 1 % here) the speed is nearly
    # linear in the parameters over the interval, so each end is within 5 % of the
    # first-order half-width 1.96 SE (ident.uncertainty.z_value(0.95) = 1.959964); they say
    # what they are calibrated on
    iv = out["intervals"]
    assert "linear plant only" in iv["calibration"] and iv["level"] == 0.95
    assert iv["critical_speeds"]["method"] == "profile"
    for name in ("v_w", "v_c"):
        c = iv["critical_speeds"][name]
        assert c["value"] == pytest.approx(cs[name], rel=1e-12)
        assert c["std"] < 0.01 * c["value"]
        lo, hi = c["interval"]
        assert hi - c["value"] == pytest.approx(1.959964 * c["std"], rel=0.05)
        assert c["value"] - lo == pytest.approx(1.959964 * c["std"], rel=0.05)
    for row in out["per_speed"]:
        ei = row["eigenvalue_intervals"]
        centres = [complex(e["value"]["re"], e["value"]["im"]) for e in ei["eigenvalues"]]
        np.testing.assert_allclose(np.sort_complex(centres), _complex(row["eigenvalues"]),
                                   rtol=1e-10)  # fmt: skip


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
