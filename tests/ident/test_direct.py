"""ident.direct: Moore & Hubbard regressions on exact linear-simulator data."""

import numpy as np
import pytest

from bikeid.dataset.linear_loop import simulate
from bikeid.ident.direct import identify, vaf_moore, vaf_variance
from bikeid.sim.linear import canonical_matrices, eigenvalues
from bikeid.sim.parameters import benchmark

P = benchmark()
CM = canonical_matrices(P)


@pytest.fixture(scope="module")
def two_speed_runs():
    return [simulate(P, v, duration=20, seed=i, dither=1.0, dither_hold=5) for i, v in
            enumerate((3.0, 6.0))]  # fmt: skip


def test_paper_free_sets_recover_benchmark(two_speed_runs):
    """Noise-free truth + exact accelerations: Moore's free sets return Meijaard's
    matrices to round-off (1e-10 relative, float64 least squares at cond ~ 10)."""
    res = identify(two_speed_runs, P, source="truth")
    for m in ("M", "C1", "K0", "K2"):
        assert np.allclose(getattr(res, m), getattr(CM, m), rtol=1e-10, atol=1e-10)
    assert res.vaf_moore["steer"] == pytest.approx(1.0, abs=1e-10)
    assert "HdF not estimated" in res.notes[0]


def test_state_space_matches_sim_linear(two_speed_runs):
    """The identified model's A equals sim.linear's at the truth (second method)."""
    res = identify(two_speed_runs, P, source="truth")
    ev = np.sort_complex(np.linalg.eigvals(np.asarray(res.state_space(5.0).A)))
    assert np.allclose(ev, np.sort_complex(eigenvalues(P, 5.0)), atol=1e-8)


def test_lateral_force_entry_recovered():
    """With a logged lateral force, HdF is estimated and equals lateral_force_vector's."""
    from bikeid.sim.linear import lateral_force_vector

    runs = [simulate(P, v, duration=20, seed=i, lateral_force=5.0) for i, v in enumerate((3, 6))]
    H = lateral_force_vector(P, 0.5, -1.0)
    res = identify(runs, P, H=(H[0], 0.0), source="truth")
    assert res.free["HdF"] == pytest.approx(H[1], rel=1e-9)


def test_vaf_definitions_t11():
    """T11: Moore's VAF is the NRMSE fit; for zero-mean error VAF_var = 1 - (1 - VAF)^2."""
    rng = np.random.default_rng(0)
    y = rng.normal(size=1000)
    y -= y.mean()
    e = rng.normal(scale=0.3, size=1000)
    e -= e.mean()
    m, v = vaf_moore(y, y + e), vaf_variance(y, y + e)
    assert m == pytest.approx(1 - np.linalg.norm(e) / np.linalg.norm(y), rel=1e-14)
    assert v == pytest.approx(1 - (1 - m) ** 2, rel=1e-12)


def test_bad_inputs_raise(two_speed_runs):
    with pytest.raises(ValueError, match="not in the roll row"):
        identify(two_speed_runs, P, free_roll=("Mdd",), source="truth")
    with pytest.raises(ValueError, match="symmetry"):
        identify(two_speed_runs, P, free_steer=("Mdp", "Mdd"), source="truth")
    with pytest.raises(ValueError, match="unknown matrix entry"):
        identify(two_speed_runs, P, free_steer=("Xdd",), source="truth")
    with pytest.raises(ValueError, match="HdF"):
        identify(two_speed_runs, P, free_steer=("Mdd", "HdF"), source="truth")


def test_attenuation_scalar_formula_t4():
    """T4: one free entry (C1dd), white noise on deltadot only, all else exact:
    plim C1dd_hat = C1dd var(x) / (var(x) + var(n)), x = v deltadot.  Tolerance: 4
    standard errors of the regression (reported covariance) plus the finite-sample
    spread of the variance ratio (~1/sqrt(N))."""
    from bikeid.dataset.run import Run

    runs = []
    rng = np.random.default_rng(5)
    ratios = []
    for i, v in enumerate((3.0, 5.0)):
        r = simulate(P, v, duration=60, seed=10 + i, dither=1.0, dither_hold=5)
        s = dict(r.truth)
        sx = np.std(v * s["deltadot"])
        n = rng.normal(scale=sx / v, size=r.n)  # sigma_n = sigma_x (ratio 1)
        s["deltadot"] = s["deltadot"] + n
        ratios.append((np.var(v * r.truth["deltadot"]), np.var(v * n)))
        runs.append(Run(t=r.t, signals=s, meta=r.meta))
    sx2 = sum(a for a, _ in ratios)
    sn2 = sum(b for _, b in ratios)
    res = identify(runs, P, free_roll=("Mpd",), free_steer=("C1dd",))
    expect = CM.C1[1, 1] * sx2 / (sx2 + sn2)
    assert expect == pytest.approx(0.5 * CM.C1[1, 1], rel=0.05)
    assert abs(res.free["C1dd"] - expect) < 4 * res.stderr["C1dd"] + 0.03 * abs(expect)


# --- tailor-made instruments (ident.tailored_iv) on the nonlinear closed loop ---------------


def _pid_runs(speeds, seed=0, sensors="default", chirp_deg=1.5, duration=50.0):
    from bikeid.experiments.testbed.sweep import SweepSpec, simulate_task

    spec = SweepSpec("pid", tuple(speeds), (seed,), duration, reference="chirp",
                     chirp_amplitude=np.radians(chirp_deg), dither=1.0, dither_hold=0.02,
                     sensors=sensors, sensor_rate=100.0, sample_time=0.01)  # fmt: skip
    return [simulate_task(spec, t) for t in spec.tasks()]


def test_fit_controller_recovers_pid_law():
    """The PID (controllers/pid.py: u = Kp e + Ki I - Kd phidot, I += e dt after the output)
    differenced once is exactly u[k] = u[k-1] - Kp phi[k] + (Kp - Ki dt) phi[k-1]
    - Kd phidot[k] + Kd phidot[k-1] + Kp r[k] - (Kp - Ki dt) r[k-1]: ARX(1, 1) must return
    these coefficients (float64 least squares on an exact relation: 1e-6 relative)."""
    from bikeid.controllers.pid import DEFAULT_PID_GAINS
    from bikeid.ident.tailored_iv import fit_controller

    kp, ki, kd = DEFAULT_PID_GAINS
    run = _pid_runs((5.0,), duration=20.0)[0]
    c = fit_controller(run)
    dt = 0.01
    assert c.vaf == pytest.approx(1.0, abs=1e-9)
    assert c.a == pytest.approx([1.0], abs=1e-7)
    assert c.b[:, 0] == pytest.approx([-kp, kp - ki * dt], rel=1e-6)  # phi
    assert c.b[:, 2] == pytest.approx([-kd, kd], rel=1e-6)  # phidot
    assert c.c == pytest.approx([kp, -(kp - ki * dt)], rel=1e-6)  # reference
    assert np.abs(c.b[:, [1, 3]]).max() < 1e-6 * abs(kd)  # delta, deltadot unused


def test_simulated_instruments_reproduce_noise_free_loop():
    """Second method: with the true model (sim.linear) and the fitted controller, the
    simulated instruments are the noise-free response of the loop to the dither and
    reference.  On a run with ideal sensors (0.5 deg chirp at 5 m/s, linear range) they
    must match the nonlinear plant's truth to VAF > 0.999 in phi and delta (the remaining
    difference is the plant's nonlinearity, O(angle^2) ~ 1e-4, and the start from rest)."""
    from bikeid.ident.direct import vaf_variance
    from bikeid.ident.tailored_iv import simulate_instruments

    run = _pid_runs((5.0,), sensors="ideal", chirp_deg=0.5, duration=20.0)[0]
    sim = simulate_instruments(run, CM)
    for k in ("phi", "delta"):
        assert vaf_variance(run.true(k)[100:], sim[k][100:]) > 0.999


def test_run_clustered_covariance_matches_white_formula_for_white_errors():
    """T6 setting (white noise on the logged torque only: regressand noise, LS unbiased and
    the paper's sigma^2 (G'G)^-1 exact): the run-clustered sandwich must agree with it.
    20 runs = 20 clusters, so the clustered standard error itself scatters by
    ~1/sqrt(2 * 19) = 16 %; allowed ratio 0.55-1.45 (about 3 of those)."""
    from bikeid.dataset.run import Run

    rng = np.random.default_rng(7)
    runs = []
    for i in range(20):
        r = simulate(P, 3.0 + 0.2 * i, duration=8, seed=100 + i, dither=1.0, dither_hold=5)
        s = dict(r.truth)
        s["T_delta"] = s["T_delta"] + rng.normal(scale=0.5, size=r.n)
        runs.append(Run(t=r.t, signals=s, meta=r.meta))
    white = identify(runs, P)
    clustered = identify(runs, P, covariance="run")
    assert white.free == clustered.free
    for n in white.free:
        if n in ("Mdd", "C1dp", "C1dd", "K0dd", "K2dd"):
            assert 0.55 < clustered.stderr[n] / white.stderr[n] < 1.45, n
