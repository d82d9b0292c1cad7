"""Fixed-step integration, sampled control, input effects and fall detection."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bikeid.sim.effects import ActuatorLag, InputDelay, TorqueGain
from bikeid.sim.integrate import simulate, simulate_many, simulate_reference
from bikeid.sim.linear import state_matrices
from bikeid.sim.nonlinear import WhippleBicycle
from bikeid.sim.parameters import benchmark
from bikeid.sim.sampling import zoh


@pytest.fixture(scope="module")
def bike() -> WhippleBicycle:
    return WhippleBicycle(benchmark())


def roll_rate_feedback(t, y):
    """T_delta = +10 phidot (steer into the fall, Meijaard signs): closed-loop linear
    eigenvalues at 5 m/s are -14.0, -1.56 +- 9.52j, -0.07 (sim.linear)."""
    return 10.0 * y[4]


@pytest.fixture(scope="module")
def closed_loop(bike):
    x0 = bike.state(5.0, phi=math.radians(5.0), phidot=0.3, deltadot=-0.2)
    ref = simulate_reference(bike, x0, 6.0, controller=roll_rate_feedback)
    runs = {n: simulate(bike, x0, 6.0, controller=roll_rate_feedback, substeps=n) for n in (1, 2)}
    return ref, runs


def test_rk4_default_step_matches_reference(closed_loop):
    """At the default step (dt/2 = 5 ms) every signal stays within 1e-6 (rad, rad/s,
    m/s) of the DOP853 rtol=1e-12 reference; the bound is ~10x the observed error."""
    ref, runs = closed_loop
    err = np.max(np.abs(runs[2].y - ref.y))
    assert err < 1e-6, err


def test_rk4_converges_at_fourth_order(closed_loop):
    """Halving the step divides the global error by 2^4 = 16 (classical RK4); allow 10..22."""
    ref, runs = closed_loop
    e1 = np.max(np.abs(runs[1].y - ref.y))
    e2 = np.max(np.abs(runs[2].y - ref.y))
    assert 10.0 < e1 / e2 < 22.0, (e1, e2)


def _linear_zoh(p, v, u, dt, B_cols):
    """Exact zero-order-hold response of the Meijaard linear model, x(0) = 0."""
    A, B = state_matrices(p, v, lateral_force_point=(p.xB, p.zB))
    Ad, Bd = zoh(A, B[:, B_cols], dt)
    n = A.shape[0]
    x = np.zeros((len(u), n))
    for k in range(len(u) - 1):
        x[k + 1] = Ad @ x[k] + Bd @ u[k]
    return x


def test_small_inputs_follow_linear_model(bike):
    """Open-loop T_delta, T_phi and F (held per sample) at 5 m/s, amplitudes giving
    ~1e-3 rad: the nonlinear response equals the exact ZOH linear response up to the
    quadratic terms, relative size ~1e-3 of the peak; bound 1e-2 of the peak."""
    dt, T = 0.01, 3.0
    n = int(T / dt) + 1
    t = dt * np.arange(n)
    u = np.column_stack(
        [0.01 * np.sin(2 * t), 0.05 * (t > 0.5), 0.2 * np.cos(3 * t) * (t < 1.5)]
    )  # T_delta, T_phi, F
    p = benchmark()
    tr = simulate(bike, bike.state(5.0), T, inputs={"T_delta": u[:, 0], "T_phi": u[:, 1],
                                                    "F": u[:, 2]})  # fmt: skip
    lin = _linear_zoh(p, 5.0, u[:, [1, 0, 2]], dt, [0, 1, 2])
    got = np.column_stack([tr.signal(s) for s in ("phi", "delta", "phidot", "deltadot")])
    peak = np.max(np.abs(lin), axis=0)
    assert np.all(peak > 1e-4)
    assert np.all(np.max(np.abs(got - lin), axis=0) < 1e-2 * peak)
    np.testing.assert_allclose(tr.inputs[:, :3], u, atol=0)


def test_fall_is_detected_and_timed(bike):
    """Uncontrolled at 2 m/s (below the weave speed v_w = 4.29 m/s, Meijaard 2007: the
    weave mode is unstable) the bicycle falls.  The run stops cleanly, with fell_at
    (linear interpolation within the 5 ms plant step: error ~ h^2 phi''/8 ~ 1e-5 s)
    within 1 ms of the reference's event time, and no sample beyond the limit."""
    x0 = bike.state(2.0, phi=math.radians(2.0))
    limit = math.radians(30.0)
    tr = simulate(bike, x0, 20.0, fall_limit=limit)
    ref = simulate_reference(bike, x0, 20.0, fall_limit=limit)
    assert tr.fell_at is not None and ref.fell_at is not None
    assert abs(tr.fell_at - ref.fell_at) <= 1e-3
    assert tr.t[-1] <= tr.fell_at < tr.t[-1] + 0.01 + 1e-12
    assert np.all(np.abs(tr.signal("phi")) <= limit)
    assert "fell" in tr.stop_reason and f"{tr.fell_at:.3f}" in tr.stop_reason


def test_non_finite_controller_stops_cleanly(bike):
    def bad(t, y):
        return float("nan") if t >= 0.5 else 0.0

    tr = simulate(bike, bike.state(5.0), 2.0, controller=bad)
    assert tr.fell_at is None and "non-finite" in tr.stop_reason
    assert abs(tr.t[-1] - 0.5) < 1e-12 and np.all(np.isfinite(tr.y))


def test_input_effects_delay_gain_lag(bike):
    """Constant command 0.1 N m: delay of 3 samples shifts it, gain scales it, and a
    first-order lag gives gain * 0.1 * (1 - exp(-(t - delay)/tau)) at the samples."""
    tau, gain, delay = 0.05, 0.8, 0.03
    tr = simulate(
        bike, bike.state(5.0), 0.5, controller=lambda t, y: 0.1,
        effects=[InputDelay(delay), TorqueGain(gain), ActuatorLag(tau)],
    )  # fmt: skip
    s = np.clip(tr.t - delay, 0.0, None)
    expected = gain * 0.1 * (1.0 - np.exp(-s / tau))
    np.testing.assert_allclose(tr.inputs[:, 0], expected, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(tr.command, 0.1)


def test_input_delay_must_be_whole_samples(bike):
    with pytest.raises(ValueError, match="multiple of the controller sample time"):
        simulate(bike, bike.state(5.0), 0.1, effects=[InputDelay(0.015)])


def test_measure_hook_feeds_controller(bike):
    """The controller sees measure(y); the true signals stay unbiased."""
    seen = []

    def ctrl(t, y):
        seen.append(y[4])
        return 0.0

    def biased(y):
        y[4] += 0.1
        return y

    tr = simulate(bike, bike.state(5.0, phidot=0.2), 0.2, controller=ctrl, measure=biased)
    np.testing.assert_allclose(tr.measured[:, 4], tr.y[:, 4] + 0.1, atol=1e-15)
    np.testing.assert_allclose(seen, tr.measured[:, 4], atol=0)


def test_simulate_many_equals_single_runs(bike):
    runs = [dict(bike=bike, x0=bike.state(v, phi=0.05), duration=1.0) for v in (3.0, 5.0)]
    many = simulate_many(runs)
    for r, tr in zip(runs, many, strict=True):
        single = simulate(r["bike"], r["x0"], r["duration"])
        np.testing.assert_array_equal(tr.y, single.y)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(duration=0.105), "whole number of samples"),
        (dict(mode="fast"), "mode"),
        (dict(substeps=0), "substeps"),
        (dict(inputs=np.zeros((3, 4))), "shape"),
        (dict(inputs={"T_x": 1.0}), "unknown input"),
        (dict(mode="held", inputs={"T_R": 1.0}), "held mode"),
    ],
)
def test_bad_arguments(bike, kwargs, match):
    args = dict(duration=0.1)
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        simulate(bike, bike.state(5.0), **args)


def test_cli_simulate_reports_fall_in_one_line(tmp_path, capsys):
    """`bikeid simulate` writes the run up to the fall and reports the fall time."""
    from bikeid.experiments.cli import main

    out = tmp_path / "run.csv"
    rc = main(["simulate", "--speed", "2", "--duration", "10", "--phi0", "2", "--out", str(out)])
    msg = capsys.readouterr().out.strip()
    assert rc == 0 and len(msg.splitlines()) == 1 and "fell" in msg
    bike = WhippleBicycle(benchmark())
    tr = simulate(bike, bike.state(2.0, phi=math.radians(2.0)), 10.0)
    assert f"t={tr.fell_at:.3f} s" in msg
    data = np.loadtxt(out, delimiter=",", skiprows=2)
    assert data.shape[0] == len(tr.t)
    # same simulation, so the only difference is the CSV's 12 significant digits ("%.12g"):
    # rounding <= half a unit of the 12th digit, 5e-12 relative; rtol one unit, 1e-11
    np.testing.assert_allclose(data[:, 2], tr.signal("phi"), rtol=1e-11)


def test_cli_simulate_json_roll_rate_feedback(tmp_path):
    """Roll-rate feedback K = 10 at 5 m/s keeps the benchmark upright for 5 s."""
    import json

    from bikeid.experiments.cli import main

    out = tmp_path / "run.json"
    args = ["simulate", "--speed", "5", "--duration", "5", "--phi0", "5", "--roll-rate-gain",
            "10", "--out", str(out)]  # fmt: skip
    assert main(args) == 0
    run = json.loads(out.read_text())
    assert run["meta"]["fell_at"] is None
    assert abs(run["signals"]["phi"][-1]) < abs(run["signals"]["phi"][0])
