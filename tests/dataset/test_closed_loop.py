"""The linear closed-loop engine (``dataset.linear_loop``) against independent methods.

- ``scipy.signal.cont2discrete`` + ``scipy.signal.dlsim`` of the same sampled loop written
  out by hand (second method, no code shared with the engine);
- its own per-sample Python path (the controller object called every sample) against its
  compiled path (the controller's linear law);
- the vectorized steer-by-wire fast path
``ident.effects.experiment_model.ExperimentModel.simulate``;
- the equations of motion (exact accelerations).

Round-off tolerances: the compared computations perform the same arithmetic in a
different order, so they differ by a few ulps per step (~1e-16 relative); the loops are
stable (spectral radius < 1), so these errors do not grow geometrically and stay below
N eps ~ 3000 x 2.2e-16 ~ 1e-12 times the signal scale even if every step's error added up.
The tolerances below (1e-10 absolute on signals of order 1e-2..1) keep a factor >= 10
above that bound and are still 6 orders of magnitude below any modelling difference (a
one-sample delay of the torque changes phi by ~1e-4 rad here).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.signal import cont2discrete, dlsim

from bikeid.controllers import PID, PolePlacement, SteerIntoLean, make
from bikeid.controllers.excitation import ChirpReference, StepReference, UniformDither
from bikeid.controllers.pole_placement import SLOW_POLES
from bikeid.dataset.closed_loop import simulate_run
from bikeid.dataset.linear_loop import closed_loop_matrix, simulate
from bikeid.dataset.sensors import Channel, Sensors
from bikeid.dataset.windows import Window
from bikeid.ident.effects.experiment_model import ExperimentModel
from bikeid.sim.effects import SteerDamping
from bikeid.sim.linear import canonical_matrices, lateral_force_vector, state_matrices
from bikeid.sim.parameters import benchmark, steer_by_wire

P = benchmark()
STATE = ("phi", "delta", "phidot", "deltadot")
ROUND_OFF = 1e-10  # module docstring


def _dlsim_pid_loop(p, v, kp, ki, kd, dt, run):
    """The sampled PID loop as one discrete LTI system, z = [x (4), xi], simulated by
    scipy.signal.dlsim with the run's own dither, disturbance and measurement noise.

    u = kp (r - phi_m) + ki xi - kd phidot_m + d,   x+ = Ad x + Bd (u + w),
    xi+ = xi + dt (r - phi_m),   phi_m = phi + n_phi,  phidot_m = phidot + n_phidot."""
    A, B = state_matrices(p, v)
    Ad, Bd, *_ = cont2discrete((A, B[:, 1:2], np.eye(4), np.zeros((4, 1))), dt, method="zoh")
    bd = Bd[:, 0]
    K = np.array([-kp, 0.0, -kd, 0.0])  # u = K x_m + ki xi + ...
    Phi = np.zeros((5, 5))
    Phi[:4, :4] = Ad + np.outer(bd, K)
    Phi[:4, 4] = bd * ki
    Phi[4, 0] = -dt
    Phi[4, 4] = 1.0
    # inputs e = [d, w, r, n_phi, n_delta, n_phidot, n_deltadot]
    G = np.zeros((5, 7))
    G[:4, 0] = bd
    G[:4, 1] = bd
    G[:4, 2] = bd * kp
    G[:4, 3:7] = np.outer(bd, K)
    G[4, 2] = dt
    G[4, 3] = -dt
    Cz = np.zeros((5, 5))
    Cz[:4, :4] = np.eye(4)
    Cz[4, :4] = K
    Cz[4, 4] = ki
    Dz = np.zeros((5, 7))
    Dz[4, 0] = 1.0
    Dz[4, 2] = kp
    Dz[4, 3:7] = K
    noise = np.column_stack([run[s] - run.true(s) for s in STATE])
    w = run.true("T_delta") - run["T_delta"]  # applied - logged (no logging noise here)
    e = np.column_stack([run.dither, w, run.reference, noise])
    x0 = np.r_[[run.true(s)[0] for s in STATE], 0.0]
    _, y, _ = dlsim((Phi, G, Cz, Dz, dt), e, x0=x0)
    return y[:, :4], y[:, 4]


@pytest.mark.parametrize("gains", [(-200.0, -500.0, -80.0), (-150.0, -300.0, -60.0)])
@pytest.mark.parametrize("v", [2.0, 6.0])
def test_pid_engine_matches_dlsim(gains, v):
    """controllers.PID through the engine's compiled path equals scipy's discrete LTI
    simulation of the same loop (the former RollPID equations) to round-off, with dither,
    disturbance and measurement noise circulating.  This is what carries every existing
    identification test from ``sim.linear_sim`` + RollPID(kp, ki, kd) to the engine +
    PID(kp, ki, kd): the same loop, bit-identical data (checked at the move)."""
    dt = 0.01
    run = simulate(P, v, duration=20, controller=PID(*gains, sample_time=dt), seed=4,
                   dither=1.0, dither_hold=5, disturbance=0.3, angle_noise=1e-3,
                   rate_noise=1e-2)  # fmt: skip
    assert run.meta["engine"] == "compiled"
    X, U = _dlsim_pid_loop(P, v, *gains, dt, run)
    for i, s in enumerate(STATE):
        np.testing.assert_allclose(run.true(s), X[:, i], rtol=0, atol=ROUND_OFF, err_msg=s)
    np.testing.assert_allclose(run["T_delta"], U, rtol=0, atol=1e3 * ROUND_OFF)  # gains ~1e2


CHIRP = ChirpReference(0.03, 0.1, 0.5, 20.0)
CASES = {
    "pid-step": (P, 4.0, lambda: PID(reference=StepReference([1.0], [0.02]))),
    "pid-derr-chirp": (P, 5.0, lambda: PID(derivative="error",
                                           reference=CHIRP)),
    "pole-servo-chirp": (P, 5.0, lambda: PolePlacement(design_speed=5.0,
                                                       reference=CHIRP)),
    "pole-servo-no-rate": (P, 3.0, lambda: PolePlacement(design_speed=3.0,
                                                         reference=lambda t: 0.02 * math.sin(t))),
    "pole-chen_dao": (P, 6.0, lambda: PolePlacement(SLOW_POLES, design_speed=6.0)),
    "sil-sbw": (steer_by_wire(), 3.0, lambda: SteerIntoLean()),
}  # fmt: skip


@pytest.mark.parametrize("name", list(CASES))
def test_python_path_matches_compiled_path(name):
    """The controller object called every sample (Python path) and its linear law in
    compiled code give the same run to round-off (the controller integrates over
    t_k - t_k-1, the compiled loop over dt: ulps apart), with noise circulating.  Largest
    measured gap 6e-12 (servo law, reference without a rate: the backward difference
    divides by t_k - t_k-1, whose round-off ulp(20 s) = 3.6e-15 s is 3.6e-13 of dt), 20x
    below the tolerance."""
    p, v, build = CASES[name]
    kw = dict(duration=20, seed=7, dither=0.5, dither_hold=2, angle_noise=1e-3,
              rate_noise=1e-2, x0=(0.02, 0.0, 0.1, 0.0))  # fmt: skip
    a = simulate(p, v, controller=build(), path="compiled", **kw)
    b = simulate(p, v, controller=build(), path="python", **kw)
    assert (a.meta["engine"], b.meta["engine"]) == ("compiled", "python")
    for s in (*STATE, "T_delta", "phiddot", "deltaddot", "psi"):
        scale = max(1.0, float(np.abs(a.true(s)).max()))
        np.testing.assert_allclose(b.true(s), a.true(s), rtol=0, atol=ROUND_OFF * scale,
                                   err_msg=s)  # fmt: skip
    np.testing.assert_allclose(b.reference, a.reference, rtol=0, atol=0)


def test_exact_accelerations_satisfy_equations_of_motion():
    """truth phiddot, deltaddot are q''(t_k+): M q'' + v C1 q' + (g K0 + v^2 K2) q equals
    the applied [T_phi, T_delta] + H F to round-off (Meijaard 2007 eq. A1)."""
    v, xf = 4.0, (0.5, -1.0)
    run = simulate(P, v, duration=5, seed=2, dither=1.0, disturbance=0.5, roll_torque=1.0,
                   lateral_force=5.0, lateral_force_point=xf)  # fmt: skip
    cm = canonical_matrices(P)
    q = np.vstack([run.true("phi"), run.true("delta")])
    qd = np.vstack([run.true("phidot"), run.true("deltadot")])
    qdd = np.vstack([run.true("phiddot"), run.true("deltaddot")])
    lhs = cm.M @ qdd + v * cm.C1 @ qd + (cm.g * cm.K0 + v**2 * cm.K2) @ q
    rhs = np.vstack([run.true("T_phi"), run.true("T_delta")])
    rhs = rhs + np.outer(lateral_force_vector(P, *xf), run.true("F"))
    np.testing.assert_allclose(lhs, rhs, rtol=0, atol=1e-11 * np.abs(rhs).max())


def _window(vs: float, x0, n: int) -> Window:
    """A synthetic free-decay window: constant arrays equal to x0 (so its ``state0()``, a
    quadratic fit over the first 5 samples, is x0 to round-off), sensor speed vs."""
    z = np.zeros(n)
    return Window(
        file="synthetic", speed=vs, start=0,
        phi=z + x0[0], delta=z + x0[1], phidot=z + x0[2], deltadot=z + x0[3],
        v_sensor=z + vs, T_ext=z.copy(), hist=np.zeros(20),
    )  # fmt: skip


@pytest.mark.parametrize(
    ("vs", "x0"),
    [(2.0, (0.05, -0.1, 0.4, 1.0)), (3.5, (0.0, 0.05, -0.6, -1.2)), (5.0, (-0.03, 0.0, 0.2, 0.5))],
)
def test_experiment_model_fast_path_matches_engine(vs, x0):
    """ExperimentModel().simulate (no effects: steer-by-wire bicycle, T = K (V - v_s) phidot
    sampled every 10 ms, ZOH, plant at the calibrated treadmill speed) equals the engine's
    run of SteerIntoLean(K=2, V=6.5) scheduled on the sensor speed v_s, from the same
    initial state, to round-off (matrix exponentials by two implementations)."""
    model = ExperimentModel()
    assert (model.K, model.V) == (2.0, 6.5)
    n = 400
    w = _window(vs, x0, n)
    out = model.simulate([w])[0]
    ctrl = SteerIntoLean(2.0, 6.5, design_speed=vs, sample_time=0.01)
    run = simulate(steer_by_wire(), model.true_speed(vs), duration=n * 0.01, controller=ctrl,
                   dither=0.0, x0=w.state0())  # fmt: skip
    assert run.n == n
    for s in STATE:
        np.testing.assert_allclose(out[s], run.true(s), rtol=0, atol=ROUND_OFF, err_msg=s)
    np.testing.assert_allclose(out["T"], run.true("T_delta"), rtol=0, atol=ROUND_OFF)
    assert np.abs(run.true("phidot")).max() > 0.05  # a real decay, not a zero signal


def test_closed_loop_matrix_is_the_sampled_loop():
    """Noise-free, no dither: z[k+1] = Acl z[k] reproduces the run (second method)."""
    ctrl = PID()
    run = simulate(P, 5.0, duration=2, controller=ctrl, dither=0.0, x0=(0.01, 0.0, 0.1, 0.0))
    Acl = closed_loop_matrix(P, 5.0, ctrl, run.dt)
    z = np.r_[0.01, 0.0, 0.1, 0.0, 0.0]
    for k in range(run.n):
        np.testing.assert_allclose([run.true(s)[k] for s in STATE], z[:4], rtol=0,
                                   atol=ROUND_OFF)  # fmt: skip
        z = Acl @ z


def test_engine_refuses_bad_setups():
    with pytest.raises(ValueError, match="does not stabilize"):
        simulate(P, 2.0, duration=1, controller=PID(0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="sample_time"):
        simulate(P, 4.0, duration=1, dt=0.01, controller=PID(sample_time=0.001))
    with pytest.raises(ValueError, match="linear law"):
        simulate(P, 4.0, duration=1, controller=make("fuzzy"), path="compiled")
    with pytest.raises(ValueError, match="path"):
        simulate(P, 4.0, duration=1, path="fast")
    with pytest.raises(ValueError, match="dither_hold"):
        simulate(P, 4.0, duration=1, dither_hold=0)


def test_defaults_and_metadata():
    """Default: PID at DEFAULT_SAMPLE_TIME (0.01 s); the controller period equals the
    logging period in the metadata; the fuzzy controller runs on the Python path."""
    run = simulate(P, 4.0, duration=1)
    assert run.dt == pytest.approx(0.01, rel=1e-12)
    assert run.meta["controller"]["name"] == "pid"
    assert run.meta["sampling"] == {"controller_period": 0.01, "logging_period": 0.01,
                                    "dither_hold": 0.01}  # fmt: skip
    fz = simulate(P, 5.0, duration=2, controller=make("fuzzy"), dither=0.5)
    assert fz.meta["engine"] == "python"
    assert np.abs(fz.true("phi")).max() < 0.1


# -- one closed-loop vocabulary: simulate_run(..., plant="linear") ---------------------------
class _Samples:
    """A signal given by its values on the controller grid (held), as a callable of t."""

    def __init__(self, values: np.ndarray, dt: float) -> None:
        self.values, self.dt = values, dt

    def __call__(self, t: float) -> float:
        k = int(round(t / self.dt))
        return float(self.values[k]) if k < self.values.size else 0.0


@pytest.mark.parametrize("name", ["pid", "pole-placement", "steer-into-lean", "fuzzy"])
def test_simulate_run_linear_is_the_linear_engine(name):
    """``simulate_run(..., plant="linear")`` (controller, reference, dither and lateral force
    as objects, ideal sensors) against ``linear_loop.simulate`` (the same inputs given as
    its scalar vocabulary: its own seeded dither and force, replayed into the objects) on
    the same initial state: equal to round-off (module docstring: ROUND_OFF).  For the
    linear laws the old engine runs its compiled loop, so two implementations are compared;
    the fuzzy controller compares the Python paths."""
    dt, v, dur = 0.01, 5.0, 10.0

    def ref():
        return ChirpReference(math.radians(2.0), 0.05, 0.5, dur)

    old = simulate(
        P, v, duration=dur, controller=make(name, P, sample_time=dt), seed=3, dither=0.5,
        dither_hold=5, lateral_force=2.0, lateral_force_point=(P.xB, P.zB), reference=ref(),
        x0=(0.01, 0, 0, 0),
    )  # fmt: skip
    new = simulate_run(
        P, make(name, P, sample_time=dt), v, dur, reference=ref(),
        dither=_Samples(old.dither, dt), sensors=Sensors.ideal(100.0),
        lateral_force=_Samples(old.true("F"), dt), initial={"phi": 0.01}, plant="linear",
    )  # fmt: skip
    n = old.n
    assert new.n == n + 1  # simulate_run also records t = duration
    np.testing.assert_array_equal(new.t[:n], old.t)
    for s in (*STATE, "psi", "psidot", "T_delta"):
        np.testing.assert_allclose(new[s][:n], old[s], rtol=0, atol=ROUND_OFF, err_msg=s)
    for s in (*STATE, "T_delta", "F", "phiddot", "deltaddot"):
        np.testing.assert_allclose(new.true(s)[:n], old.true(s), rtol=0, atol=ROUND_OFF,
                                   err_msg=s)  # fmt: skip
    np.testing.assert_array_equal(new.dither[:n], old.dither)
    np.testing.assert_array_equal(new.reference[:n], old.reference)
    assert new.meta["plant"]["model"] == "whipple-linear"
    assert np.abs(old.true("phi")).max() > 0.01  # a run that moves, not the rest state


def test_simulate_run_linear_and_nonlinear_share_the_objects():
    """The same controller, dither and sensors objects drive both plants.

    - Sensors: the measurement noise (measured - true) is drawn from the sensor object and
      the seed only, so it is identical on both plants (exact).
    - Physics: at these small angles (|delta| < 0.01 rad) the nonlinear plant differs from
      its linearization by terms of order angle^2 ~ 1e-4 relative (observed 2e-5, which
      includes the nonlinear integrator's error); a bound of 1e-3 relative still fails for
      a wrong plant (e.g. a torque one sample late changes phi by ~1e-2 relative here).
    """
    sensors = Sensors({"phi": Channel(std=1e-3), "deltadot": Channel(std=1e-2)}, rate=100.0)
    runs = {
        plant: simulate_run(P, PID(sample_time=0.01), 5.0, 10.0,
                            dither=UniformDither(0.2, 0.05, seed=1), sensors=sensors, seed=4,
                            plant=plant)  # fmt: skip
        for plant in ("linear", "nonlinear")
    }
    lin, non = runs["linear"], runs["nonlinear"]
    np.testing.assert_array_equal(lin.t, non.t)
    np.testing.assert_array_equal(lin.dither, non.dither)
    for s in ("phi", "deltadot"):
        noise = lin[s] - lin.true(s)
        np.testing.assert_allclose(noise, non[s] - non.true(s), rtol=0, atol=1e-15)
        assert 0.5 < np.std(noise) / sensors.channel(s).std < 1.5  # the noise is there
    for s in ("phi", "delta", "phidot", "T_delta"):
        scale = np.abs(non.true(s)).max()
        assert np.abs(lin.true(s) - non.true(s)).max() < 1e-3 * scale, s


def test_simulate_run_linear_refuses_what_it_cannot_do():
    c = PID(sample_time=0.01)
    with pytest.raises(ValueError, match="plant="):
        simulate_run(P, c, 5.0, 1.0, plant="quadratic")
    with pytest.raises(ValueError, match="holds the speed"):
        simulate_run(P, c, 5.0, 1.0, mode="coast", plant="linear")
    for plant in ("linear", "nonlinear"):  # an unknown mode is named, not called 'coast'
        with pytest.raises(ValueError, match="mode 'drift' unknown; use 'coast' or 'held'"):
            simulate_run(P, c, 5.0, 1.0, mode="drift", plant=plant)
    with pytest.raises(ValueError, match="integrator options"):
        simulate_run(P, c, 5.0, 1.0, substeps=4, plant="linear")
    with pytest.raises(ValueError, match="no effects"):
        simulate_run(P, c, 5.0, 1.0, effects=[SteerDamping(1.0)],
                     plant="linear")  # fmt: skip
    with pytest.raises(ValueError, match="small-angle range"):
        simulate_run(P, PID(0.0, 0.0, 0.0), 2.0, 20.0, initial={"phi": 0.05}, plant="linear")
