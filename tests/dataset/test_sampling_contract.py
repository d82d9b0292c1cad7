"""The sampling contract: the logged steer torque is the torque the plant held.

Bug this guards (found with the defaults of the time: controllers at 1 ms, sensors at
100 Hz): ``simulate_run(benchmark(), make("pid", p), 5, 30, dither=UniformDither(1.0,
seed=1))`` then ``pem.fit`` gave the weave +0.066 +- 4.313j 1/s for the true
-0.775 +- 4.465j (unstable for stable), silently, because the logged torque was every
10th controller output while the applied torque changed every 1 ms.  Now every
controller defaults to the logging period (``controllers.DEFAULT_SAMPLE_TIME``) and the
estimators refuse runs whose controller period or dither hold is not a whole multiple of
the run's sample period (``ident.signals.check_sampling``).

Truth: ``sim.linear.eigenvalues`` of the benchmark at 5 m/s (Meijaard 2007: weave
-0.775 +- 4.465j 1/s).
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bikeid.controllers import DEFAULT_SAMPLE_TIME, UniformDither, make
from bikeid.dataset.closed_loop import simulate_run
from bikeid.dataset.linear_loop import simulate as simulate_linear
from bikeid.dataset.run import Run
from bikeid.dataset.sensors import Sensors
from bikeid.ident import pem
from bikeid.ident.canonical import canonical_ab
from bikeid.ident.direct import identify
from bikeid.ident.signals import check_sampling, prepare
from bikeid.ident.tailored_iv import identify_tailored
from bikeid.sim.linear import eigenvalues
from bikeid.sim.parameters import benchmark

P = benchmark()
V = 5.0
DURATION = 60.0
#: Deterministic floor of the weave error [1/s]: the nonlinear plant (the truth is its
#: linearization) and the sensor noise in the regressors.  On the runs with the smallest
#: statistical error (steer-into-lean, delta-method sigma ~0.002 1/s) the deviation was
#: <= 0.009 1/s over two seeds; doubled.
FLOOR = 0.02
#: Standard errors allowed per component (real, imaginary): two-sided normal p = 6e-5,
#: 8e-4 after Bonferroni over 4 controllers x 2 components x (run, seeds) tried.
K_SIGMA = 4.0


def _weave(theta: np.ndarray) -> complex:
    ev = np.linalg.eigvals(canonical_ab(theta)[0])
    return complex(ev[np.argmax(ev.imag)])


def _weave_and_sigma(model) -> tuple[complex, np.ndarray]:
    """The weave eigenvalue and its delta-method standard errors (real, imag) [1/s] from
    the PEM covariance (forward differences, step 1e-6 relative: truncation ~1e-6 of the
    derivative, negligible against the sigma it scales)."""
    w = _weave(model.theta)
    J = np.zeros((2, model.theta.size))
    for i in range(model.theta.size):
        h = 1e-6 * max(1.0, abs(model.theta[i]))
        th = model.theta.copy()
        th[i] += h
        d = (_weave(th) - w) / h
        J[:, i] = d.real, d.imag
    return w, np.sqrt(np.diag(J @ model.covariance @ J.T))


def _true_weave() -> complex:
    ev = eigenvalues(P, V)
    return complex(ev[np.argmax(ev.imag)])


def _within(w: complex, sigma: np.ndarray) -> bool:
    t = _true_weave()
    return (abs(w.real - t.real) <= K_SIGMA * sigma[0] + FLOOR
            and abs(w.imag - t.imag) <= K_SIGMA * sigma[1] + FLOOR)  # fmt: skip


def test_true_weave_is_meijaard():
    t = _true_weave()
    assert t.real == pytest.approx(-0.775, abs=1e-3) and t.imag == pytest.approx(4.465, abs=1e-3)


@pytest.mark.parametrize("name", ["pid", "pole-placement", "fuzzy", "steer-into-lean"])
def test_default_run_gives_the_true_weave(name):
    """Public API with default arguments (controller, sensors 100 Hz, dither hold): the
    periods match, and PEM's weave at 5 m/s is within 4 standard errors + FLOOR of the
    truth, per component.  (Steer-into-lean stabilizes the benchmark at 5 m/s: the weave is
    self-stable there, and the law only adds roll-rate damping.)"""
    run = simulate_run(P, make(name, P), V, DURATION, dither=UniformDither(1.0, seed=1))
    assert run.meta["fell_at"] is None
    assert run.meta["sampling"] == {"controller_period": DEFAULT_SAMPLE_TIME,
                                    "logging_period": 0.01, "dither_hold": 0.01}  # fmt: skip
    w, sigma = _weave_and_sigma(pem.fit(run))
    assert w.real < 0
    assert _within(w, sigma), (w, sigma, _true_weave())


@pytest.fixture(scope="module")
def fast_controller_run() -> Run:
    """The refused setup: a 1 ms PID (asked for explicitly), sensors at 100 Hz."""
    return simulate_run(P, make("pid", P, sample_time=0.001), V, DURATION,
                        dither=UniformDither(1.0, seed=1))  # fmt: skip


def test_fast_controller_run_records_both_periods(fast_controller_run):
    s = fast_controller_run.meta["sampling"]
    assert (s["controller_period"], s["logging_period"]) == (0.001, 0.01)


def test_fast_controller_run_is_refused_by_every_estimator(fast_controller_run):
    """The message names both periods and the fix."""
    run = fast_controller_run
    msg = r"run 0 logs T_delta every 10 ms .*controller period is 1 ms.*sample_time=0.01"
    with pytest.raises(ValueError, match="pem.fit: " + msg):
        pem.fit(run)
    run2 = simulate_run(P, make("pid", P, sample_time=0.001), 6.0, 2.0,
                        dither=UniformDither(1.0, seed=2))  # fmt: skip
    with pytest.raises(ValueError, match="pem.fit_speed_model: " + msg):
        pem.fit_speed_model([run, run2])
    with pytest.raises(ValueError, match="direct.identify: " + msg):
        identify(prepare(run), P)
    with pytest.raises(ValueError, match="tailored_iv.identify_tailored: " + msg):
        identify_tailored([run], P, prepare=prepare)


def test_the_refused_run_would_fail_the_accuracy_check(fast_controller_run):
    """The check above is not vacuous: with the refusal bypassed (metadata stripped, as a
    file written before the contract would be) PEM's weave on the 1 ms run misses the same
    tolerance (reference run: -0.355 + 4.477j, 15 standard errors off in the real part)."""
    run = fast_controller_run
    meta = {k: v for k, v in run.meta.items() if k not in ("sampling", "controller")}
    stripped = Run(t=run.t, signals=run.signals, dither=run.dither, meta=meta)
    w, sigma = _weave_and_sigma(pem.fit(stripped))
    assert not _within(w, sigma), (w, sigma)


def test_old_files_are_checked_from_the_controller_metadata(fast_controller_run):
    """Runs written before meta['sampling'] existed: the controller's sample_time in its
    description is used instead."""
    run = fast_controller_run
    meta = {k: v for k, v in run.meta.items() if k != "sampling"}
    with pytest.raises(ValueError, match="controller period is 1 ms"):
        check_sampling(Run(t=run.t, signals=run.signals, meta=meta), "pem.fit")


def test_dither_held_shorter_than_the_logging_period_is_refused():
    run = simulate_run(P, make("pid", P), V, 1.0, dither=UniformDither(1.0, hold=0.005, seed=1))
    with pytest.raises(ValueError, match="dither hold is 5 ms"):
        check_sampling(run, "pem.fit")


def test_matching_and_multiple_periods_pass():
    """Controller and dither at whole multiples of the logging period, the linear engine,
    a 200 Hz setup, and measured data (no controller metadata) pass."""
    check_sampling(simulate_run(P, make("pid", P), V, 1.0,
                                dither=UniformDither(1.0, hold=0.05, seed=1)), "x")  # fmt: skip
    check_sampling(simulate_run(P, make("pid", P, sample_time=0.005), V, 1.0,
                                sensors=Sensors.default(rate=200.0),
                                dither=UniformDither(1.0, hold=0.005, seed=1)), "x")  # fmt: skip
    check_sampling(simulate_linear(P, V, duration=1.0, dither_hold=3), "x")
    t = np.arange(10) * 0.01
    z = np.zeros(10)
    measured = Run(t=t, signals={k: z for k in ("phi", "delta", "phidot", "deltadot", "v",
                                                "T_delta")}, meta={"source": "measured"})
    check_sampling(measured, "x")


def _run_with(dt: float, controller_period: float) -> Run:
    t = np.arange(5) * dt
    z = np.zeros(5)
    sig = {k: z for k in ("phi", "delta", "phidot", "deltadot", "v", "T_delta")}
    meta = {"sampling": {"controller_period": controller_period, "logging_period": dt,
                         "dither_hold": None}}  # fmt: skip
    return Run(t=t, signals=sig, meta=meta)


@settings(max_examples=60, deadline=None)
@given(dt=st.sampled_from([0.001, 0.002, 0.005, 0.01, 0.02]), k=st.integers(1, 20),
       frac=st.floats(0.01, 0.99))  # fmt: skip
def test_refused_exactly_when_not_a_whole_multiple(dt, k, frac):
    """Property: a controller period k dt passes; (k - frac) dt, between two multiples or
    below one sample, is refused with both periods in the message."""
    check_sampling(_run_with(dt, k * dt), "pem.fit")
    with pytest.raises(ValueError, match=f"logging period {dt:g} s"):
        check_sampling(_run_with(dt, (k - frac) * dt), "pem.fit")
