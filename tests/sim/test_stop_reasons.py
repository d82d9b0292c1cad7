"""One stop-reason mechanism (``sim.integrate.Stop``), carried from the integrator to runs,
sweeps, the stabilization table, the estimators and the accuracy study.

Each verdict is checked on a case where the answer is known both ways: a numerical blow-up
(step too coarse: |lambda_max| h beyond RK4's stability limit, an analytic property of the
linearized plant) against the same run at the default step (no stop at all), and genuine
falls timed against the adaptive DOP853 reference (``simulate_reference``).
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import bikeid.sim.integrate as integrate
from bikeid.controllers.pid import PID
from bikeid.dataset.closed_loop import simulate_run
from bikeid.dataset.run import Run, run_stop
from bikeid.dataset.sensors import Sensors
from bikeid.experiments.testbed.sweep import (
    SweepSpec,
    parts_dir,
    run_sweep,
    stabilization_counts,
    stabilization_markdown,
    stabilization_table,
)
from bikeid.ident.signals import check_complete, check_sampling
from bikeid.sim.integrate import (
    STOP_CAUSES,
    Stop,
    rk4_amplification,
    simulate,
    simulate_reference,
)
from bikeid.sim.linear import eigenvalues
from bikeid.sim.nonlinear import WhippleBicycle
from bikeid.sim.parameters import benchmark

#: the issue's case: 15 m/s, roll rate 10 deg/s, one RK4 step of 0.1 s per sample
COARSE = dict(dt=0.1, substeps=1)


@pytest.fixture(scope="module")
def bike() -> WhippleBicycle:
    return WhippleBicycle(benchmark())


def _quiet(fn, *args, **kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return fn(*args, **kwargs)


def test_stop_record_validates_and_round_trips():
    assert {c for c, k in STOP_CAUSES.items() if k.physical} == {
        "roll_limit",
        "steer_limit",
        "wheel_unloaded",
    }
    s = Stop("step_too_coarse", 0.5, "msg")
    assert s.physical is False and Stop.from_dict(s.as_dict()) == s
    with pytest.raises(ValueError, match="unknown stop cause"):
        Stop("tipped", 1.0, "x")
    with pytest.raises(ValueError, match="physical=True"):
        Stop("roll_limit", 1.0, "x", physical=False)


@given(
    cause=st.sampled_from(sorted(STOP_CAUSES)),
    t=st.floats(0.0, 1e6, allow_nan=False),
    msg=st.text(max_size=40),
)
def test_stop_round_trips_through_json(cause, t, msg):
    """What a run stores (meta["stop"], JSON) rebuilds the same stop, with ``physical`` taken
    from the cause table whatever the caller passed."""
    import json

    s = Stop(cause, t, msg)
    back = Stop.from_dict(json.loads(json.dumps(s.as_dict())))
    assert back == s and back.physical is STOP_CAUSES[cause].physical


def test_rk4_amplification_matches_the_stability_region():
    """RK4's stability region (Hairer & Wanner II, Fig. IV.2.1): on the negative real axis it
    ends at z = -2.7853, the real root of R(z) = 1 (z (z^3/24 + z^2/6 + z/2 + 1) = 0); on
    the imaginary axis at 2.8284 (2 sqrt 2); along 120 deg, the direction of lightly damped
    modes, it ends before |z| = 2.7, which a test on |lambda h| alone would miss."""
    roots = np.roots([1 / 24, 1 / 6, 1 / 2, 1])  # R(z) - 1 = z * (this cubic)
    zr = min(r.real for r in roots if abs(r.imag) < 1e-9)
    assert zr == pytest.approx(-2.7853, abs=1e-4)
    assert rk4_amplification(-2.78) < 1 < rk4_amplification(-2.79)
    assert rk4_amplification(2.82j) < 1 < rk4_amplification(2.83j)
    direction = np.exp(2j * np.pi / 3)
    assert rk4_amplification(2.7 * direction) > 1


def test_coarse_step_is_a_numerical_blow_up_not_a_fall(bike):
    """The issue's case stopped with "fell at 0.38 s".  The fastest eigenvalue of the
    linearized benchmark at 15 m/s is the caster, -35.8 1/s (sim.linear), so one 0.1 s RK4
    step is -3.58, outside RK4's stability region: a numerical blow-up.  At the default
    step the same run completes its 20 s, which confirms it."""
    x0 = bike.state(15.0, phidot=math.radians(10.0))
    lams = eigenvalues(benchmark(), 15.0)
    assert np.max(rk4_amplification(lams[lams.real < 0] * 0.1)) > 1
    with pytest.warns(RuntimeWarning, match="not a fall"):
        tr = simulate(bike, x0, 20.0, **COARSE)
    assert tr.stop.cause == "step_too_coarse" and not tr.stop.physical
    assert tr.fell_at is None
    assert "--dt" in tr.stop.message and "--substeps" in tr.stop.message
    assert tr.t[-1] <= tr.stop.time
    fine = simulate(bike, x0, 20.0)
    assert fine.stop is None and fine.t[-1] == pytest.approx(20.0)


def test_half_step_check_alone_catches_the_blow_up(bike, monkeypatch):
    """With the eigenvalue test switched off, re-integrating the last sample with half the
    step must still call the same run numerical (its roll/steer move by O(1) rad)."""
    monkeypatch.setattr(integrate, "rk4_amplification", lambda z: np.zeros(np.shape(z)))
    tr = _quiet(simulate, bike, bike.state(15.0, phidot=math.radians(10.0)), 20.0, **COARSE)
    assert tr.stop.cause == "step_too_coarse" and "halving" in tr.stop.message
    assert tr.fell_at is None


def test_genuine_fall_is_roll_limit_at_the_reference_time(bike):
    """Uncontrolled at 2 m/s (below the weave speed 4.29 m/s, Meijaard 2007) with 2 deg of
    lean, the benchmark falls.  With a 25 deg fall limit: a ``roll_limit`` stop at the
    time DOP853 (rtol = atol = 1e-12, exact event location) finds, within 1 ms: the RK4
    crossing is interpolated linearly within its 5 ms step, error ~ h^2 phi'' / (8 phi')
    ~ 1e-5 s.  With the default 60 deg limit the front wheel's load reaches zero first
    (at roll ~ -40 deg, as the bicycle drops), at the same time as the DOP853 event
    within 1 ms (a linear interpolation of the force in the step, as for roll)."""
    x0 = bike.state(2.0, phi=math.radians(2.0))
    limit = math.radians(25.0)
    tr = simulate(bike, x0, 20.0, fall_limit=limit)
    ref = simulate_reference(bike, x0, 20.0, fall_limit=limit)
    assert tr.stop.cause == ref.stop.cause == "roll_limit" and tr.stop.physical
    assert tr.fell_at == tr.stop.time
    assert abs(tr.stop.time - ref.stop.time) <= 1e-3
    tr = simulate(bike, x0, 20.0)
    ref = simulate_reference(bike, x0, 20.0)
    assert tr.stop.cause == ref.stop.cause == "wheel_unloaded" and tr.stop.physical
    assert "front wheel" in tr.stop.message
    assert abs(tr.stop.time - ref.stop.time) <= 1e-3


def test_steer_limit_stops_a_folding_front_wheel(bike):
    """A constant 5 N m steer torque at 1 m/s turns the front frame through 90 deg in
    0.47 s while the roll is still -16 deg and both wheels stay loaded (>= 146 N); the
    crossing agrees with the DOP853 event within 1 ms (linear interpolation in a 5 ms
    step, as above; observed 1.4e-5 s)."""
    x0 = bike.state(1.0)
    tr = simulate(bike, x0, 3.0, inputs={"T_delta": 5.0})
    ref = simulate_reference(bike, x0, 3.0, inputs={"T_delta": 5.0})
    assert tr.stop.cause == ref.stop.cause == "steer_limit"
    assert abs(tr.stop.time - ref.stop.time) <= 1e-3
    assert np.all(np.abs(tr.signal("delta")) <= math.pi / 2)
    assert np.min(tr.normal_forces) > 100.0


def test_nonfinite_controller_is_not_a_fall(bike):
    tr = simulate(bike, bike.state(5.0), 2.0, controller=lambda t, y: math.nan if t >= 0.5 else 0)
    assert tr.stop.cause == "controller_nonfinite" and tr.fell_at is None
    assert tr.stop.time == pytest.approx(0.5)


def test_cli_simulate_names_the_cause_and_writes_nothing_after_it(tmp_path, capsys):
    from bikeid.experiments.cli import main

    out = tmp_path / "x.csv"
    args = ["simulate", "--speed", "15", "--phidot0", "10", "--duration", "20", "--dt", "0.1",
            "--substeps", "1", "--out", str(out)]  # fmt: skip
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        assert main(args) == 4  # a numerical failure: no trustworthy answer (sim.errors)
    msg = capsys.readouterr().err
    msg = "\n".join(x for x in msg.splitlines() if not x.startswith("note: ")) + "\n"
    assert msg.count("\n") == 1 and msg.startswith("bikeid simulate: error: ")  # notes aside
    assert "not a fall [step_too_coarse]" in msg and "fell" not in msg.split("]")[0]
    data = np.loadtxt(out, delimiter=",", skiprows=2)
    # samples before the stop at 0.255 s (the blow-up unloads a wheel first; the step
    # check then calls it numerical)
    assert data.shape[0] == 3 and data[-1, 0] == pytest.approx(0.2)


# -- runs -------------------------------------------------------------------------------------
class _NanAfter:
    """A PID that returns NaN from ``t_bad`` on: a numerical controller failure."""

    def __init__(self, t_bad: float):
        self.pid = PID(0.0, 0.0, 0.0, sample_time=0.01)
        self.t_bad = t_bad
        self.sample_time = 0.01

    @property
    def reference(self):
        return self.pid.reference

    def reset(self):
        self.pid.reset()

    def describe(self):
        return {"name": "nan-after", "t_bad": self.t_bad}

    def __call__(self, t, y):
        return math.nan if t >= self.t_bad else 0.0


def test_run_records_numerical_stop_and_estimators_refuse_it():
    run = simulate_run(benchmark(), _NanAfter(0.5), 5.0, duration=2.0, sensors=Sensors.ideal())
    stop = run.meta["stop"]
    assert stop["cause"] == "controller_nonfinite" and stop["physical"] is False
    assert run.meta["fell_at"] is None and run.t[-1] < 0.5
    with pytest.raises(ValueError, match="controller_nonfinite.*numerical failure, not a fall"):
        check_sampling(run, "pem.fit")
    from bikeid.ident import direct

    with pytest.raises(ValueError, match="direct.identify: run 0 .*ended early"):
        direct.identify([run], benchmark())


def test_fallen_run_records_physical_stop_and_complete_run_passes():
    """Uncontrolled at 2 m/s the benchmark falls (weave-unstable; a wheel unloads before
    |roll| reaches 60 deg, as above); at 5 m/s with a PID it completes (test_sweep's
    upright cases)."""
    fell = simulate_run(benchmark(), PID(0.0, 0.0, 0.0, sample_time=0.01), 2.0, duration=20.0,
                        sensors=Sensors.ideal(), initial={"phidot": 0.3})  # fmt: skip
    assert fell.meta["stop"]["cause"] == "wheel_unloaded"
    assert fell.meta["fell_at"] == fell.meta["stop"]["time"]
    with pytest.raises(ValueError, match="wheel_unloaded \\(a fall"):
        check_complete([fell], "x")
    ok = simulate_run(benchmark(), PID(sample_time=0.01), 5.0, duration=1.0)
    assert ok.meta["stop"] is None and run_stop(ok) is None
    check_complete(ok, "x")
    legacy = Run(t=ok.t, signals=ok.signals, meta={"fell_at": 0.7})  # written before "stop"
    assert run_stop(legacy)["cause"] == "roll_limit"


# -- sweeps and stabilization -------------------------------------------------------------
#: a roll chirp of 1e300 rad asks for a non-finite torque: a numerical failure at once
HUGE = dict(chirp_amplitude=1e300, dither=0.0, sensors="ideal")


def test_sweep_counts_numerical_failures_apart(tmp_path):
    spec = SweepSpec("pid", speeds=(5.0,), seeds=(0,), duration=1.0, **HUGE)
    rep = _quiet(run_sweep, spec, tmp_path / "h.h5", progress=False)
    assert not rep.fell and list(rep.failed) == ["pid_v005.000_s0"]
    assert "1 run(s) ended early for a numerical reason" in rep.summary()
    ok = run_sweep(SweepSpec("pid", (5.0,), (0,), 1.0), tmp_path / "ok.h5", progress=False)
    assert not ok.fell and not ok.failed and "numerical reason" not in ok.summary()


def test_stabilization_never_calls_a_failed_run_upright():
    rows = _quiet(stabilization_table, [5.0], duration=1.0, controllers=["pid"],
                  progress=False, reference="chirp", **HUGE)  # fmt: skip
    (row,) = rows
    assert not row["upright"] and row["stop"]["physical"] is False
    assert row["rms_error_deg"] is None and row["fell_at"] is None
    assert stabilization_counts(rows) == {"upright": 0, "fell": 0, "failed": 1, "error": 0}
    assert "numerical failure" in stabilization_markdown(rows)
    up = stabilization_table([5.0], duration=1.0, controllers=["pid"], progress=False,
                             reference="zero", dither=0.0, sensors="ideal")  # fmt: skip
    assert stabilization_counts(up) == {"upright": 1, "fell": 0, "failed": 0, "error": 0}


def test_sweep_deletes_only_its_own_files(tmp_path):
    out = tmp_path / "s.h5"
    parts = parts_dir(out)
    parts.mkdir()
    (parts / "notes.txt").write_text("mine")
    (parts / "other.h5").write_bytes(b"not a run of this sweep")
    spec = SweepSpec("pid", speeds=(5.0,), seeds=(0,), duration=1.0)
    run_sweep(spec, out, progress=False)
    assert sorted(p.name for p in parts.iterdir()) == ["notes.txt", "other.h5"]
    (parts / "notes.txt").unlink()
    (parts / "other.h5").unlink()
    run_sweep(SweepSpec("pid", speeds=(5.0, 6.0), seeds=(0,), duration=1.0), out,
              progress=False)  # fmt: skip
    assert not parts.exists()  # empty after the sweep: removed


def test_refused_sweep_leaves_no_lock(tmp_path):
    out = tmp_path / "s.h5"
    run_sweep(SweepSpec("pid", speeds=(5.0,), seeds=(0,), duration=1.0), out, progress=False)
    with pytest.raises(ValueError, match="different settings"):
        run_sweep(SweepSpec("pid", (5.0,), (0,), 2.0), out, progress=False)
    assert not parts_dir(out).exists()


def test_accuracy_skips_early_ended_runs_with_a_message():
    from bikeid.experiments.testbed.accuracy import identify_controller

    run = simulate_run(benchmark(), _NanAfter(0.5), 5.0, duration=2.0, sensors=Sensors.ideal())
    log: list[str] = []
    res = identify_controller([run], benchmark(), methods=(), log=log.append)
    assert any("skipping 1 of 1 run(s)" in m and "controller_nonfinite" in m for m in log)
    assert res["fell"] == {} and res["failed"][5.0]["cause"] == "controller_nonfinite"
