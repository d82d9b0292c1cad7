"""``bikeid identify`` on sweep files, as a user runs it: identified vs true eigenvalues.

Truth: the linearization (Meijaard 2007 Appendix A, ``sim.linear``) of the bicycle stored in
the runs' metadata, recomputed here independently of the command.
"""

import json

import numpy as np
import pytest

from bikeid.experiments.cli import main
from bikeid.experiments.sweep import SweepSpec, run_sweep
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
