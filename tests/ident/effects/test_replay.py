"""Replaying the logged steer command: a model evaluated without knowing the controller.

Known answers: on a loop whose controller is known, replaying the commands the loop
produced must reproduce the closed-loop simulation (linear model: to round-off; nonlinear
plant by defect correction: to the integrator's accuracy)."""

import json
import math
import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from bikeid.dataset.windows import Window
from bikeid.ident.effects.experiment_model import ExperimentModel
from bikeid.sim.linear import eigenvalues

DATA = os.environ.get("BIKEID_DATA")


def _windows(n_win=3, v=3.0, n=120):
    """Decay starts like the logs' (steer opposite to the roll rate); outputs unused."""
    rng = np.random.default_rng(4)
    out = []
    for j in range(n_win):
        s = 1.0 if j % 2 else -1.0
        z = np.zeros(n)
        phi, delta = z.copy(), z.copy()
        phidot, deltadot = z.copy(), z.copy()
        phi[:] = rng.normal(0, 0.01)
        delta[:] = -s * 0.03
        phidot[:] = s * rng.uniform(0.4, 0.9)
        deltadot[:] = s * 0.8
        vs = np.full(n, 1.066 * v - 0.128)
        out.append(Window("syn", v, 100 * j, phi, delta, phidot, deltadot, vs, z.copy(),
                          np.zeros(20)))  # fmt: skip
    return out


@pytest.mark.parametrize(
    "effects",
    [{}, {"steer_viscous_damping": 0.4, "steer_stiffness": 1.0},
     {"command_gain": 1.2, "input_delay": 0.02, "actuator_lag": 0.015}],
)  # fmt: skip
def test_replay_equals_loop_on_the_linear_model(effects):
    """Replaying the raw commands the loop produced (applied torque / gain; the delay and
    lag act on the replayed command as on the looped one) gives the closed-loop outputs to
    1e-12 relative: the same discrete-time recursion, only the command's source differs."""
    m = ExperimentModel(effects=effects)
    ws = _windows()
    loop = m.simulate(ws)
    # the raw command of the loop is the law on the (measured-equivalent) roll rate
    raw = [m.K * (m.V - np.mean(w.v_sensor)) * s["phidot"] for w, s in zip(ws, loop, strict=True)]
    rep = m.simulate([replace(w, T_logged=r, drive="logged") for w, r in zip(ws, raw, strict=True)])
    for a, b in zip(loop, rep, strict=True):
        for c in ("phi", "delta", "phidot", "deltadot", "T"):
            np.testing.assert_allclose(b[c], a[c], rtol=1e-12, atol=1e-12 * np.abs(a[c]).max())


def test_replay_of_an_unstable_model_is_simulated_not_refused():
    """At 1.5 m/s the uncontrolled bicycle is unstable (an eigenvalue with positive real
    part): replaying a zero command from a push grows over 3 s instead of raising, and equals
    the analytic free response x(t) = expm(A t) x0 of the Whipple model (sim.linear) to 1e-9
    relative (the experiment model's exact zero-order-hold discretization of the same A)."""
    from scipy.linalg import expm

    from bikeid.sim.linear import state_matrices

    m = ExperimentModel()
    ws = [replace(w, T_logged=np.zeros(w.n), drive="logged") for w in _windows(1, v=1.5, n=300)]
    out = m.simulate(ws)[0]
    v = m.true_speed(float(np.mean(ws[0].v_sensor)))
    assert max(eigenvalues(m.plant_params(), v).real) > 0
    A, _ = state_matrices(m.plant_params(), v)
    x0 = ws[0].state0()
    for k in (100, 200, 299):
        x = expm(A * k * 0.01) @ x0
        got = np.array([out[c][k] for c in ("phi", "delta", "phidot", "deltadot")])
        np.testing.assert_allclose(got, x, rtol=1e-9, atol=1e-9 * np.abs(x).max())
    assert np.abs(out["phi"][-1]) > 10 * np.abs(out["phi"][0])


def test_replay_needs_the_logged_command():
    w = replace(_windows(1)[0], drive="logged")
    with pytest.raises(ValueError, match="T_logged"):
        ExperimentModel().simulate([w])


@pytest.mark.skipif(not DATA, reason="needs the measured data ($BIKEID_DATA)")
def test_cli_replay_on_the_measured_logs(tmp_path):
    """`measured evaluate --drive logged --json` gives the closed-loop mode's summary fields,
    says what drove the model, and its nominal errors differ from the loop's (a different
    experiment: no feedback corrects the model's drift)."""
    model = tmp_path / "m.json"
    model.write_text(json.dumps({"bicycle": "steer-by-wire", "plant": "linear",
                                 "effects": {"steer_viscous_damping": 0.32},
                                 "fit_speeds": [2.5, 4.5]}))  # fmt: skip
    exe = Path(sys.executable).parent / "bikeid"
    res = {}
    for mode in ("loop", "logged"):
        p = subprocess.run([str(exe), "measured", "evaluate", "--model", str(model), "--data",
                            DATA, "--drive", mode, "--json"], capture_output=True, text=True,
                           timeout=600)  # fmt: skip
        assert p.returncode == 0, p.stderr
        res[mode] = json.loads(p.stdout)
    assert res["logged"]["input"] == "logged" and res["loop"]["input"] == "loop"
    for k in ("error_before", "error_after"):
        assert math.isfinite(res["logged"]["summary"][k])
        assert res["logged"]["summary"][k] != res["loop"]["summary"][k]
    assert {f["file"] for f in res["logged"]["files"]} == {f["file"] for f in res["loop"]["files"]}


def test_identified_plant_model_replay_equals_the_nominal_when_it_is_the_nominal():
    """evaluate_plant_model on a canonical model whose theta is the steer-by-wire Whipple
    model's at the windows' speed (ident.canonical.theta_from_matrices) gives the same error
    as the nominal (sim.linear's state space): two code paths, one model, agreement to 1e-9;
    a perturbed model (b2 +20 %) gives a different, larger error (both ways)."""
    from bikeid.ident.canonical import theta_from_matrices
    from bikeid.ident.effects.pipeline import evaluate_plant_model
    from bikeid.ident.pem import CanonicalModel
    from bikeid.sim.linear import canonical_matrices
    from bikeid.sim.parameters import steer_by_wire

    v = 3.0
    ws = []
    for w in _windows(3, v=v, n=150):
        t = np.arange(w.n) * 0.01
        ws.append(replace(w, T_logged=0.8 * np.sin(2 * np.pi * 1.1 * t), drive="logged"))
    # "measured" outputs: the nominal's own replay plus a slow deterministic misfit, so both
    # errors are O(0.1) and finite (a constant signal has no NRMSE)
    sims = ExperimentModel().simulate(ws)
    ws = [replace(w, **{c: s[c] + 0.1 * np.ptp(s[c]) * np.sin(np.arange(w.n) * 0.02)
                        for c in ("phi", "delta", "phidot", "deltadot")})
          for w, s in zip(ws, sims, strict=True)]  # fmt: skip
    theta = theta_from_matrices(canonical_matrices(steer_by_wire()), v)
    exact = CanonicalModel(theta, np.zeros((10, 10)), np.zeros((4, 4)), 0.01, v, np.eye(4))
    out = evaluate_plant_model(exact, ws)
    assert out["summary"]["error_after"] == pytest.approx(out["summary"]["error_before"],
                                                          rel=1e-9, abs=1e-12)  # fmt: skip
    bad = CanonicalModel(theta * np.r_[np.ones(9), 1.2], np.zeros((10, 10)), np.zeros((4, 4)),
                         0.01, v, np.eye(4))  # fmt: skip
    out_bad = evaluate_plant_model(bad, ws)
    assert out_bad["summary"]["error_after"] > out_bad["summary"]["error_before"] + 0.01
    with pytest.raises(ValueError, match="model's speed"):
        evaluate_plant_model(replace(exact, speed=5.0), ws)


@pytest.mark.skipif(not DATA, reason="needs the measured data ($BIKEID_DATA)")
def test_cli_identified_model_evaluates_by_replay_only(tmp_path):
    """A model of `bikeid identify --out` (direct, on the steer-by-wire eigen logs) evaluates
    on the logs with --drive logged (summary fields present, finite) and is refused without
    it (exit 3, naming the fix): a plant model knows no controller.  The push logs' torque is
    the balance law, so identify refuses them by default (exit 4, tested in
    tests/ident/test_informativity.py); this test is about the replay path and skips that
    check explicitly (identify then says so in a note)."""
    exe = Path(sys.executable).parent / "bikeid"
    model = tmp_path / "direct.json"
    p = subprocess.run([str(exe), "identify", str(Path(DATA) / "tudelft-sbw" / "eigen"),
                        "--format", "sbw", "--method", "direct", "--out", str(model),
                        "--skip-check", "informativity"],
                       capture_output=True, text=True, timeout=600)  # fmt: skip
    assert p.returncode == 0, p.stderr
    assert "informativity" in p.stderr  # the skipped check is named, never silent
    base = [str(exe), "measured", "evaluate", "--model", str(model), "--data", DATA]
    p = subprocess.run(base + ["--drive", "logged", "--json"], capture_output=True, text=True,
                       timeout=600)  # fmt: skip
    assert p.returncode == 0, p.stderr
    s = json.loads(p.stdout)["summary"]
    assert math.isfinite(s["error_before"]) and math.isfinite(s["error_after"])
    p = subprocess.run(base, capture_output=True, text=True, timeout=600)
    assert p.returncode == 3 and "--drive logged" in p.stderr
