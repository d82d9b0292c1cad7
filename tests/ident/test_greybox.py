"""Grey-box PEM of the Whipple matrices (``ident.greybox``) against a known truth.

Truth: the linear benchmark bicycle (Meijaard 2007, ``sim.linear.canonical_matrices``) in the
linear closed loop of ``dataset.linear_loop`` (exact ZOH; default PID, uniform dither 1 N m
held 50 ms, unlogged steer disturbance 0.5 N m, sensor noise 1e-3 rad / 1e-2 rad/s), 30 s at
2, 4, 6 and 8 m/s (below v_w, near it, between v_w and v_c, above v_c).  Tolerances are
stated in standard errors of the estimator itself (z-scores), so they do not depend on how
informative the data are.
"""

from __future__ import annotations

import numpy as np
import pytest

from bikeid.dataset.linear_loop import simulate
from bikeid.ident import greybox, pem
from bikeid.ident.canonical import theta_from_matrices
from bikeid.ident.direct import parse_entry
from bikeid.sim.errors import InputError, UntrustworthyResult
from bikeid.sim.linear import canonical_matrices, lateral_force_vector, state_space
from bikeid.sim.parameters import benchmark

P = benchmark()
CM = canonical_matrices(P)
SPEEDS = (2.0, 4.0, 6.0, 8.0)
#: 4 sigma on each of <= 9 entries: a correct estimator fails this with probability ~6e-4.
Z_MAX = 4.0


def true_entry(name: str) -> float:
    m, r, c = parse_entry(name)
    return float(getattr(CM, m)[r, c])


@pytest.fixture(scope="module")
def runs():
    return [
        simulate(P, v, duration=30, seed=i, dither=1.0, dither_hold=5, disturbance=0.5,
                 angle_noise=1e-3, rate_noise=1e-2)
        for i, v in enumerate(SPEEDS)
    ]  # fmt: skip


@pytest.fixture(scope="module")
def joint(runs):
    """Moore & Hubbard's free set over all four speeds, started 10-40 % away from the truth."""
    start = {"Mpd": 0.8 * true_entry("Mpd"), "K0dd": 1.3 * true_entry("K0dd"),
             "K2dd": 0.6 * true_entry("K2dd"), "C1dd": 1.2 * true_entry("C1dd")}  # fmt: skip
    return greybox.fit(runs, reference=P, start=start)


def test_theta_jacobian_matches_finite_differences():
    """Second method: central differences (step 1e-6 of the entry) agree with the analytic
    d theta / d entry to 1e-6 relative (the difference error is O(h^2) ~ 1e-12, round-off
    ~1e-16 / 1e-6 = 1e-10 of theta's scale); at the benchmark theta equals
    ``theta_from_matrices`` exactly."""
    free = ("Mpd", "Mdd", "C1pd", "C1dp", "K0pd", "K0pp", "K2dd", "K2pd")
    v = 5.0
    vals = {n: true_entry(n) for n in greybox.ALL_ENTRIES if not n.startswith("H")}
    theta, jac = greybox.theta_jacobian(CM, v, free)
    assert np.array_equal(theta, theta_from_matrices(CM, v))
    for j, n in enumerate(free):
        h = 1e-6 * max(1.0, abs(vals[n]))
        cols = []
        for s in (+1, -1):
            moved = dict(vals)
            moved[n] += s * h
            for a, b in (("Mdp", "Mpd"), ("K0dp", "K0pd")):
                moved[a] = moved[b]
            cols.append(theta_from_matrices(greybox._matrices(moved, CM.g), v))
        fd = (cols[0] - cols[1]) / (2 * h)
        scale = np.maximum(np.abs(jac[:, j]), 1e-3 * np.max(np.abs(jac[:, j])))
        assert np.max(np.abs(fd - jac[:, j]) / scale) < 1e-6, n


def test_joint_fit_recovers_free_entries(joint):
    """Every free entry within Z_MAX standard errors of the benchmark value; fixed entries
    exactly at it; the free set is well conditioned (< MAX_CONDITION) over four speeds."""
    assert set(joint.free) == set(greybox.DEFAULT_FREE)
    for n, val in joint.free.items():
        z = (val - true_entry(n)) / joint.stderr[n]
        assert abs(z) < Z_MAX, (n, val, true_entry(n), joint.stderr[n])
        assert joint.stderr[n] < 0.2 * abs(true_entry(n)), n  # informative, not just wide
    for n, val in joint.fixed.items():
        assert val == true_entry(n), n
    assert joint.M[1, 0] == joint.M[0, 1] and joint.K0[1, 0] == joint.K0[0, 1]  # symmetric
    assert 1.0 <= joint.condition < greybox.MAX_CONDITION
    assert joint.dropped == ()
    # the weakest direction is a unit vector over the free entries; its main entries listed
    w = np.array([joint.weakest[n] for n in joint.free])
    assert np.linalg.norm(w) == pytest.approx(1.0)
    assert joint.least_determined and all(abs(joint.weakest[n]) > 0.2
                                          for n in joint.least_determined)  # fmt: skip
    assert all(f >= 1.0 - 1e-9 for f in joint.inflation.values())  # VIF >= 1 by definition


def test_state_space_matches_the_linear_model(joint):
    """The python-control model at v is sim.linear's state space of the estimated matrices
    (same A, the T_delta column of B), states in bikeid's order."""
    for v in (3.0, 7.0):
        sys = joint.state_space(v)
        ref = state_space(joint.canonical(), v)
        assert np.allclose(sys.A, ref.A, atol=0) and np.allclose(sys.B[:, 0], ref.B[:, 1])
        assert list(sys.state_labels) == ["phi", "delta", "phidot", "deltadot"]
        assert np.allclose(np.sort_complex(np.linalg.eigvals(sys.A)),
                           np.sort_complex(joint.eigenvalues(v)))  # fmt: skip


def test_unidentifiable_set_refused_with_condition(runs):
    """K0dd and K2dd free at one speed: g q and v^2 q are the same regressor, so the Fisher
    information is singular (condition number limited only by round-off, > 1e6); refused
    with the number in the message.  With drop_unidentifiable one of the pair is fixed
    (at the reference) and the rest fitted, condition back below the threshold."""
    free = ("Mdd", "K0dd", "K2dd")
    with pytest.raises(UntrustworthyResult, match=r"condition number (\S+)") as info:
        greybox.fit(runs[1], free, P)
    cond = float(str(info.value).split("condition number ")[1].split()[0])
    assert cond > 1e6
    assert "K0dd" in str(info.value) and "K2dd" in str(info.value)
    m = greybox.fit(runs[1], free, P, drop_unidentifiable=True)
    assert len(m.dropped) == 1 and m.dropped[0] in ("K0dd", "K2dd")
    assert m.fixed[m.dropped[0]] == true_entry(m.dropped[0])
    assert m.condition < greybox.MAX_CONDITION
    assert any("K0dd" in s or "K2dd" in s for s in m.notes)


def test_joint_beats_per_speed_standard_errors(runs, joint):
    """The matrices do not depend on speed, so pooling four speeds must give a smaller
    standard error on every entry than any single speed (same free set, identifiable at one
    speed: K2dd fixed) - and the per-speed estimates scatter around the truth consistently
    with their own standard errors (|z| < Z_MAX)."""
    free = tuple(n for n in greybox.DEFAULT_FREE if n != "K2dd")
    pooled = greybox.fit(runs, free, P)
    for r in runs:
        single = greybox.fit(r, free, P)
        for n in free:
            assert pooled.stderr[n] < single.stderr[n], (r.speed, n)
            # freeing K2dd too costs the pooled fit little: still better than one speed
            assert joint.stderr[n] < single.stderr[n], (r.speed, n)
            assert abs(single.free[n] - true_entry(n)) < Z_MAX * single.stderr[n], (r.speed, n)


def _eig_se(theta: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues of canonical theta and their standard errors (|d lambda| linearized by
    central differences on theta, eigenvalues matched by nearest neighbour)."""
    from bikeid.ident.canonical import canonical_ab

    lam = np.sort_complex(np.linalg.eigvals(canonical_ab(theta)[0]))
    J = np.zeros((4, 10), complex)
    for j in range(10):
        h = 1e-6 * max(1.0, abs(theta[j]))
        e = np.zeros(10)
        e[j] = h
        lp = np.linalg.eigvals(canonical_ab(theta + e)[0])
        lm = np.linalg.eigvals(canonical_ab(theta - e)[0])
        lp = np.array([lp[np.argmin(abs(lp - z))] for z in lam])
        lm = np.array([lm[np.argmin(abs(lm - z))] for z in lam])
        J[:, j] = (lp - lm) / (2 * h)
    var = np.einsum("ij,jk,ik->i", J.real, cov, J.real) + np.einsum(
        "ij,jk,ik->i", J.imag, cov, J.imag
    )
    return lam, np.sqrt(var)


def test_eigenvalues_agree_with_canonical_pem(runs, joint):
    """Second estimator on the same data: the canonical PEM per speed (10 free parameters)
    and the grey-box (8 shared entries) estimate the same eigenvalues; their difference is
    within Z_MAX combined standard errors (sqrt(se_pem^2 + se_grey^2): conservative, the two
    estimates are positively correlated), and both are within Z_MAX of the truth."""
    from bikeid.sim.linear import eigenvalues

    for r in runs:
        v = r.speed
        m = pem.fit(r)
        lam_p, se_p = _eig_se(m.theta, m.covariance)
        lam_g, se_g = _eig_se(joint.theta(v), joint.theta_covariance(v))
        true = np.sort_complex(eigenvalues(P, v))
        for z, s in zip(lam_p, se_p, strict=True):
            zg = lam_g[np.argmin(abs(lam_g - z))]
            sg = se_g[np.argmin(abs(lam_g - z))]
            assert abs(zg - z) < Z_MAX * np.hypot(s, sg), (v, z, zg, s, sg)
            zt = true[np.argmin(abs(true - zg))]
            assert abs(zg - zt) < Z_MAX * sg + 1e-9, (v, zg, zt, sg)


def test_bad_input_is_refused(runs):
    """Clear one-line InputErrors: unknown entry, lateral-force entry without a lateral force,
    a tied symmetric cell, a run with a roll torque logged."""
    with pytest.raises(InputError, match="unknown matrix entry 'Kxx'"):
        greybox.fit(runs[0], ("Kxx",), P)
    with pytest.raises(InputError, match="F is zero in every run"):
        greybox.fit(runs[0], ("HdF",), P)
    with pytest.raises(InputError, match="tied to"):
        greybox.fit(runs[0], ("Mdp",), P)
    rolled = simulate(P, 5.0, duration=2, seed=1, roll_torque=1.0)
    with pytest.raises(InputError, match="T_phi is nonzero"):
        greybox.fit(rolled, ("Mdd",), P)


@pytest.fixture(scope="module")
def forced_runs():
    """The same loop with a uniform lateral force of 5 N at (0.5, -1.0) m (logged)."""
    return [
        simulate(P, v, duration=30, seed=10 + i, dither=1.0, dither_hold=5, disturbance=0.5,
                 lateral_force=5.0, angle_noise=1e-3, rate_noise=1e-2)
        for i, v in enumerate(SPEEDS)
    ]  # fmt: skip


def test_lateral_force_gradient_matches_finite_differences():
    """Second method for the superposed (T_delta, F) predictor: J'r from the kernel's two
    passes equals the central-difference gradient of 0.5 |r(x)|^2 (x0 re-projected at each
    point, which variable projection makes exact) to 1e-4 relative (difference error ~h^2)."""
    from bikeid.ident.predictor import initial_gain, output_matrix, run_data

    rs = [simulate(P, v, duration=5, seed=3, dither=1.0, dither_hold=5, lateral_force=5.0,
                   angle_noise=1e-3, rate_noise=1e-2) for v in (3.0, 6.0)]  # fmt: skip
    data = run_data(rs, greybox.DEFAULT_OUTPUTS)
    C = output_matrix(greybox.DEFAULT_OUTPUTS)[0]
    free = ("Mpd", "K0dd", "K2dd", "C1dd", "HpF", "HdF")
    vals = {n: true_entry(n) for n in greybox.ALL_ENTRIES if not n.startswith("H")}
    vals["HpF"], vals["HdF"] = lateral_force_vector(P, 0.5, -1.0)
    vals["Mdp"], vals["K0dp"] = vals["Mpd"], vals["K0pd"]
    Ks = [initial_gain(theta_from_matrices(CM, d.v), d.dt, C, [d], np.var(d.y, axis=0), True)
          for d in data]  # fmt: skip
    w = 1 / np.sqrt(np.mean([np.var(d.y, axis=0) for d in data], axis=0))
    forces = [np.asarray(r["F"], float) for r in rs]
    prob = greybox._GreyProblem(data, [0, 1], Ks, vals, free, True, CM.g, True, w,
                                greybox.DEFAULT_OUTPUTS, forces)  # fmt: skip
    x = np.concatenate([[vals[n] * 1.02 for n in free]] + [K.ravel() for K in Ks])
    _, _, grad = prob.normal_equations(x)
    for j in list(range(len(free))) + [len(free) + 5, len(free) + 16 + 9]:
        h = 1e-6 * max(1.0, abs(x[j]))
        e = np.zeros_like(x)
        e[j] = h
        fp, fm = (0.5 * float(np.sum(prob.residual(x + s * e) ** 2)) for s in (1, -1))
        fd = (fp - fm) / (2 * h)
        assert abs(fd - grad[j]) <= 1e-4 * max(abs(grad[j]), 1e-3 * np.max(np.abs(grad))), j


def test_lateral_force_column_recovered(forced_runs):
    """With a logged lateral force the default free set adds HdF (Moore & Hubbard's); HdF,
    and HpF when also freed, are recovered within Z_MAX standard errors of
    ``sim.linear.lateral_force_vector`` at the logged point, from a start of HdF = 0, as are
    the matrix entries; the state space gets the F column M^-1 H."""
    H = lateral_force_vector(P, *forced_runs[0].meta["lateral_force_point"])
    m = greybox.fit(forced_runs, greybox.DEFAULT_FREE + ("HpF", "HdF"), P,
                    start={"HdF": 0.0})  # fmt: skip
    for n, val in m.free.items():
        truth = H["pd".index(n[1])] if n.startswith("H") else true_entry(n)
        assert abs(val - truth) < Z_MAX * m.stderr[n], (n, val, truth, m.stderr[n])
    sys = m.state_space(5.0, inputs=("T_delta", "F"))
    assert np.allclose(sys.B[2:, 1], np.linalg.solve(m.M, m.H))
    assert "HdF" in greybox.fit(forced_runs[:2], reference=P).free


def test_cli_identify_greybox(runs, tmp_path, capsys):
    """``bikeid identify --method greybox``: over four speeds the JSON holds the free entries
    within Z_MAX standard errors of the truth and the true eigenvalues beside the identified
    ones; at one speed with K0dd and K2dd free it exits 4 with one line naming the condition
    number, and ``--drop-unidentifiable`` fixes one of them instead (exit 0)."""
    import json

    from bikeid.dataset.store import write_runs
    from bikeid.experiments.cli import main

    path, one = tmp_path / "runs.h5", tmp_path / "one.h5"
    write_runs(path, runs)
    write_runs(one, runs[1:2])
    capsys.readouterr()
    assert main(["identify", "--method", "greybox", str(path), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    for n, d in out["free"].items():
        assert abs(d["value"] - true_entry(n)) < Z_MAX * d["stderr"], n
    assert len(out["per_speed"]) == len(SPEEDS) and "true_eigenvalues" in out["per_speed"][0]
    # saved like every model: the file holds the same estimates (exact float round trip),
    # and ``bikeid validate --model`` takes it.  Reference: a free canonical PEM fitted on
    # the same 4 m/s run; the true-structure grey-box predicts 10 steps ahead as well as it
    # (measured: within 1.0 percentage points at 4 m/s, 1.9 over 2-8 m/s; tolerance 3)
    target = tmp_path / "model.json"
    assert main(["identify", "--method", "greybox", str(path), "--out", str(target)]) == 0
    capsys.readouterr()
    from bikeid.ident.model_file import load_model

    saved = load_model(target)
    assert isinstance(saved, greybox.GreyboxModel)
    assert {n: d["value"] for n, d in out["free"].items()} == saved.free
    assert main(["validate", str(one), "--model", str(target), "--json"]) == 0
    val = json.loads(capsys.readouterr().out)
    from bikeid.ident.validation_report import validate_model

    ref = validate_model(pem.fit(runs[1]), runs[1:2]).fit_k_step
    assert all(abs(val["fit_k_step"][o] - ref[o]) < 3.0 for o in ref), (val, ref)
    args = ["identify", "--method", "greybox", str(one), "--free", "Mdd,K0dd,K2dd",
            "--quiet"]  # no stage lines: the refusal is the only line on stderr
    assert main(args) == 4
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "condition number" in err and "K2dd" in err
    assert main([*args, "--drop-unidentifiable", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert len(out["dropped"]) == 1 and out["condition"] < greybox.MAX_CONDITION
