"""Controllers on the linear benchmark model: placement, stability, tracking, interface.

Independent sources: Meijaard 2007 matrices (sim.linear), the reference sheet
/work/shared/reference/controllers.md (§3.3 uncontrollable speed, §4.3 PID ranges, §4.4
placement gains), the measured steer-by-wire logs, and a second simulation method
(python-control's continuous-time ``forced_response``) for the sampled loops.
"""

from __future__ import annotations

import gzip
import json
import math
import os
from pathlib import Path

import control
import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from scipy.optimize import brentq

from bikeid.controllers import make
from bikeid.controllers.base import GainSchedule
from bikeid.controllers.excitation import ChirpReference, StepReference
from bikeid.controllers.fuzzy import FuzzyController
from bikeid.controllers.pid import PID
from bikeid.controllers.pole_placement import (
    SLOW_POLES,
    TRACKING_POLES,
    PolePlacement,
    augmented_system,
    place_with_integral,
    roll_zeros,
    tracking_poles,
)
from bikeid.controllers.steer_into_lean import SteerIntoLean
from bikeid.dataset.linear_loop import simulate
from bikeid.sim.linear import canonical_matrices, state_matrices, state_space
from bikeid.sim.parameters import benchmark, steer_by_wire

P = benchmark()
SPEEDS = (1.5, 4.0, 8.0, 15.0)
#: Tracking reference for the closed-loop tests: 3 deg, 0.02 -> 0.2 Hz over 30 s.
REF = ChirpReference(math.radians(3.0), 0.02, 0.2, 30.0, start=1.0)
T_END = 31.0
SKIP = 3.0  # s: initial-condition transient excluded from the RMS


def _b(v: float) -> tuple[np.ndarray, np.ndarray]:
    A, B = state_matrices(P, v)
    return A, B[:, 1:2]


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x**2)))


#: The closed-loop tracking tests run the controllers at 1 kHz (as documented in
#: controllers.md), not at the 100 Hz default sample time.
TRACK_DT = 0.001


def _linear_run(p, v, ctrl, t_end, x0=(0.0, 0.0, 0.0, 0.0)):
    """The exact-ZOH linear engine (``dataset.linear_loop``) from t = 0 to ``t_end``
    inclusive at the controller's sample time, no dither and no noise; it raises
    ValueError if |phi| or |delta| leaves 1 rad (the bicycle fell)."""
    dt = ctrl.sample_time
    return simulate(p, v, duration=t_end + dt, controller=ctrl, dither=0.0, x0=x0)


# -- pole placement ------------------------------------------------------------------------
@pytest.mark.parametrize("v", [1.0, 2.0, 3.0, 5.0, 10.0, 15.0])
@pytest.mark.parametrize("which", ["slow", "tracking"])
def test_placement_gives_requested_poles(v, which):
    """eig(Aa - Ba Ka) equals the requested poles (the fixed -2..-6 set and the default
    speed-dependent set).  Tolerance from Bauer-Fike: a backward error of
    eps * ||[Aa, Ba Ka]|| moves an eigenvalue by at most cond(V) times that, V the
    closed-loop eigenvector matrix; factor 100 for the solver's own error."""
    A, B = _b(v)
    poles = SLOW_POLES if which == "slow" else tracking_poles(A, B)
    K, kI = place_with_integral(A, B, poles)
    Aa, Ba = augmented_system(A, B)
    Acl = Aa - Ba @ np.r_[K, -kI][None, :]
    lam, V = np.linalg.eig(Acl)
    tol = 100 * np.finfo(float).eps * np.linalg.cond(V) * np.linalg.norm(Acl, 2)
    err = max(min(abs(lam - p)) for p in poles)
    assert err <= tol, (err, tol)


@pytest.mark.parametrize(
    "v, K_ref, kI_ref",
    [
        (1.0, (-273.9, 11.15, -60.5, 2.15), -263.0),
        (5.0, (-17.7, 21.18, -1.53, 0.89), -7.1),
        (15.0, (0.1, -62.2, 12.0, -6.10), -0.8),
    ],
)
def test_placement_matches_reference_table(v, K_ref, kI_ref):
    """controllers.md §4.4 (poles -2..-6), printed to 3-4 significant digits: agree to
    the last printed digit (half a unit, plus 1 % for rounding of the table's inputs)."""
    K, kI = place_with_integral(*_b(v), SLOW_POLES)
    for got, want in zip([*K, kI], [*K_ref, kI_ref], strict=True):
        dec = len(f"{want}".split(".")[1]) if "." in f"{want}" else 0
        assert abs(got - want) <= 0.5 * 10**-dec + 0.01 * abs(want), (got, want)


def test_uncontrollable_speed_raises():
    """phi/T and delta/T share the zero s* = -sqrt(-g K0_pp / M_pp) where P_phidelta(s*)
    = 0; controllers.md §3.3 gives v_u = 1.4110 m/s and s* = -3.1347.  There placement
    must raise, naming (near) uncontrollability and the PBH measure."""
    cm = canonical_matrices(P)
    s = -math.sqrt(-cm.g * cm.K0[0, 0] / cm.M[0, 0])
    f = lambda v: (  # noqa: E731
        cm.M[0, 1] * s * s + v * cm.C1[0, 1] * s + cm.g * cm.K0[0, 1] + v * v * cm.K2[0, 1]
    )
    vu = brentq(f, 1.0, 2.0, xtol=1e-15)
    assert abs(vu - 1.4110) < 5e-5 and abs(s + 3.1347) < 5e-5
    with pytest.raises(ValueError, match="uncontrollable.*PBH"):
        PolePlacement(design_speed=vu)
    # 1 % away the design is fine (§3.3: accurate at 1.40 m/s)
    PolePlacement(design_speed=1.40)


def test_chen_dao_ordered_model_gives_same_gains():
    """A model in Chen & Dao order [phi, phidot, delta, deltadot] (labelled, or declared
    with state_order) must give the same gains as the bikeid-ordered linearization."""
    v = 5.0
    sys_b = state_space(P, v, inputs=("T_delta",))
    perm = [0, 2, 1, 3]  # Chen & Dao state k is bikeid state perm[k]
    sys_cd = control.ss(
        sys_b.A[np.ix_(perm, perm)], sys_b.B[perm], np.eye(4), np.zeros((4, 1)),
        states=["phi", "phidot", "delta", "deltadot"],
    )  # fmt: skip
    want = PolePlacement(design_speed=v).current_gains(v)
    got_lab = PolePlacement(model=sys_cd, design_speed=v).current_gains(v)
    unl = control.ss(sys_cd.A, sys_cd.B, np.eye(4), np.zeros((4, 1)))
    got_decl = PolePlacement(model=unl, state_order="chen_dao", design_speed=v).current_gains(v)
    np.testing.assert_allclose(got_lab, want, rtol=1e-9)
    np.testing.assert_allclose(got_decl, want, rtol=1e-9)
    with pytest.raises(ValueError, match="state order"):
        PolePlacement(model=unl, design_speed=v)


def test_scheduled_placement_is_stable_over_speed():
    """Interpolated grid gains must keep the continuous linear loop stable at every speed
    1-15 m/s on a 0.01 m/s grid (including 1.41 m/s between grid points)."""
    pp = PolePlacement()
    worst = -np.inf
    for v in np.arange(1.0, 15.0001, 0.01):
        A, B = _b(v)
        g = np.array(pp.current_gains(v))
        Aa, Ba = augmented_system(A, B)
        worst = max(worst, np.linalg.eigvals(Aa - Ba @ np.r_[g[:4], -g[4]][None, :]).real.max())
    assert worst < -0.5, worst


@pytest.mark.parametrize(
    "v, want",
    [(1.0, (-1.71, -12.9)), (2.0, (-5.0, -24.2)), (5.0, (-13.7, -59.3)), (15.0, (-41.9, -177))],
)
def test_roll_zeros_match_reference_sheet_and_python_control(v, want):
    """Zeros of phi/T: controllers.md §4.2 table (printed to 3 significant digits: half a
    unit of the last digit) and python-control's ``zeros`` of the phi output (1e-9)."""
    A, B = _b(v)
    got = np.sort(roll_zeros(A, B).real)[::-1]
    assert np.all(np.abs(roll_zeros(A, B).imag) == 0)
    for g, w in zip(got, want, strict=True):
        dec = len(f"{w}".split(".")[1]) if "." in f"{w}" else 0
        assert abs(g - w) <= 0.5 * 10**-dec, (g, w)
    ct = np.sort(control.zeros(control.ss(A, B, [[1.0, 0, 0, 0]], 0)).real)[::-1]
    np.testing.assert_allclose(got, ct, rtol=1e-9)


def test_roll_zero_crosses_at_analytic_speed():
    """controllers.md §4.2: phi/T has a right-half-plane zero only below
    v = sqrt(-g K0_phidelta / K2_phidelta) = 0.577 m/s; there one zero is exactly 0, and
    the default poles mirror a right-half-plane zero (no unstable cancellation)."""
    cm = canonical_matrices(P)
    v0 = math.sqrt(-cm.g * cm.K0[0, 1] / cm.K2[0, 1])
    assert abs(v0 - 0.577) < 5e-4
    assert min(abs(roll_zeros(*_b(v0)))) < 1e-9
    A, B = _b(0.5)
    z = roll_zeros(A, B)
    assert max(z.real) > 0.3  # §4.2: +0.358 at 0.5 m/s
    assert np.all(tracking_poles(A, B).real <= -0.5)


@settings(max_examples=40, deadline=None)
@given(v=st.floats(0.7, 16.0))
def test_tracking_poles_are_distinct_and_placeable(v):
    """Property: at any speed the default poles are stable, pairwise >= 1.9 % apart (the
    2 % separation rule; place refuses repeated poles) and placement succeeds to its own
    1e-4 check, except within 0.5 % of the uncontrollable speed 1.4110 m/s (§3.3)."""
    assume(abs(v - 1.4110) > 0.005 * 1.4110)
    A, B = _b(v)
    p = tracking_poles(A, B)
    assert np.all(p.real < 0)
    for i in range(5):
        for j in range(i):
            assert abs(p[i] - p[j]) >= 0.019 * max(abs(p[i]), abs(p[j])), (v, p)
    place_with_integral(A, B, p)


@pytest.mark.parametrize("v", [1.0, 2.0])
def test_cancelled_zeros_decouple_steer_from_roll(v):
    """Where both roll zeros get poles (v < 2.5 m/s), steer must drop out of the roll
    acceleration: with phidot' = a . x + b_phi T, K_delta = a_delta / b_phi and
    K_deltadot = a_deltadot / b_phi (module docstring), and then d1 = b_phi K_phi - a_phi,
    d2 = b_phi K_phidot - a_phidot, d0 = b_phi kI are the coefficients of
    prod(s - p) over the three free poles.  Rounding only: 1e-7 relative."""
    A, B = _b(v)
    K, kI = place_with_integral(A, B, tracking_poles(A, B))
    a, b = A[2], B[2, 0]
    np.testing.assert_allclose([K[1], K[3]], [a[1] / b, a[3] / b], rtol=1e-7)
    d = np.poly(TRACKING_POLES).real
    np.testing.assert_allclose([b * K[2] - a[2], b * K[0] - a[0], b * kI], d[1:], rtol=1e-7)


def _loop(ctrl: PolePlacement, v: float) -> control.InputOutputSystem:
    """The linear closed loop assembled by python-control's ``interconnect`` from the
    plant (``sim.linear.state_space``) and the law written out from its definition:
    inputs r, rd (reference and rate), d (torque disturbance), n_* (sensor noise)."""
    plant = state_space(P, v, inputs=("T_delta",))
    K = np.array(ctrl.current_gains(v)[:4])
    kI = ctrl.current_gains(v)[4]
    ff = [K[0], K[2]] if ctrl.law == "servo" else [0.0, 0.0]
    meas = ["phi_m", "delta_m", "phidot_m", "deltadot_m"]
    law = control.ss(
        [[0.0]], [[1.0, 0.0, -1.0, 0.0, 0.0, 0.0]], [[kI]], [[*ff, *(-K)]],
        inputs=["r", "rd", *meas], outputs=["u"], states=["xi"],
    )  # fmt: skip
    parts = [plant, law, control.summing_junction(["u", "d"], "T_delta")]
    for s in ("phi", "delta", "phidot", "deltadot"):
        parts.append(control.summing_junction([s, f"n_{s}"], f"{s}_m"))
    inputs = ["r", "rd", "d", "n_phi", "n_delta", "n_phidot", "n_deltadot"]
    return control.interconnect(parts, inplist=inputs, outlist=["phi"])


@pytest.mark.parametrize("v", [1.0, 2.0])
@pytest.mark.parametrize("law", ["chen_dao", "servo"])
def test_tracking_design_frequency_response(v, law):
    """python-control's frequency response of the assembled loop equals the module's
    closed forms at 0.01-5 Hz: chen_dao d0 / Delta3(s); servo
    1 - (s^3 - a_phidot s^2 - a_phi s) / Delta3(s).  Rounding only: 1e-7."""
    ctrl = PolePlacement(design_speed=v, law=law)
    w = 2 * np.pi * np.geomspace(0.01, 5.0, 40)
    H = _loop(ctrl, v)(1j * w)
    Hr = H[0, 0] + 1j * w * H[0, 1]
    A = _b(v)[0]
    d3 = np.polyval(np.poly(TRACKING_POLES), 1j * w)
    if law == "chen_dao":
        want = np.poly(TRACKING_POLES)[-1] / d3
    else:
        s = 1j * w
        want = 1 - (s**3 - A[2, 2] * s**2 - A[2, 0] * s) / d3
    np.testing.assert_allclose(Hr, want, rtol=1e-7, atol=1e-9)


def _predicted_rms_deg(ctrl: PolePlacement, v: float, dt: float = 0.01) -> float:
    """RMS roll error [deg] predicted by the linear loop (python-control, no simulation)
    for the stabilization settings: 3 deg chirp 0.05-0.5 Hz (quasi-stationary: the error
    at instantaneous frequency f is |1 - H(j 2 pi f)| A / sqrt(2), averaged over the
    linear sweep), plus uniform +-1 N m dither held dt and Sensors.default noise (1e-3 rad
    on angles, 1e-2 rad/s on rates), white at 1/dt Hz: variance sigma^2 dt 2 int_0^{1/2dt}
    |H|^2 df.  Independent of each other, so the squares add."""
    loop = _loop(ctrl, v)
    f = np.linspace(0.05, 0.5, 2001)
    w = 2 * np.pi * f
    H = loop(1j * w)
    track2 = math.radians(3.0) ** 2 * np.mean(np.abs(1 - H[0, 0] - 1j * w * H[0, 1]) ** 2) / 2
    fn = np.linspace(0.0, 0.5 / dt, 20001)
    Hn = np.abs(loop(2j * np.pi * fn)[0, 2:]) ** 2
    var = np.array([1.0 / 3, 1e-6, 1e-6, 1e-4, 1e-4]) * dt
    noise2 = float(np.sum(2 * np.trapezoid(Hn * var[:, None], fn, axis=1)))
    return math.degrees(math.sqrt(track2 + noise2))


def _stabilization_cell(v: float, monkeypatch=None, **pole_options) -> dict:
    """One cell of ``bikeid stabilization`` (same code path, ``experiments.testbed.sweep``), 50 s;
    ``pole_options`` are added to the registry's PolePlacement (needs ``monkeypatch``)."""
    import bikeid.controllers.registry as registry
    from bikeid.experiments.testbed import sweep

    if pole_options:
        orig = registry._FACTORIES["pole-placement"]
        monkeypatch.setitem(
            registry._FACTORIES, "pole-placement", lambda p, **kw: orig(p, **kw, **pole_options)
        )
    # the stabilization table's settings: 3 deg chirp at every speed, dither held 10 ms
    spec = sweep.SweepSpec(
        "pole", (v,), (0,), 50.0, chirp_amplitude=np.radians(3.0), dither_hold=0.01
    )
    return sweep.stabilization_task(spec, spec.tasks()[0])


@pytest.mark.parametrize("v", [1.5, 4.0, 8.0, 15.0])
@pytest.mark.parametrize("law", ["servo", "chen_dao"])
def test_pole_placement_stabilization_run_matches_linear_prediction(v, law, monkeypatch):
    """The stabilization-table run (nonlinear Whipple plant, 100 Hz controller and
    sensors, noise, dither, 3 deg chirp) with the default poles stays upright and its RMS
    roll error is within 10 % of the linear prediction ``_predicted_rms_deg``.  The 10 %
    covers what the prediction leaves out: the zero-order hold's dt/2 = 5 ms delay (phase
    2 pi 0.5 Hz 5 ms = 0.016 rad at the sweep's end, ~2 % of the error there), the
    quasi-stationary chirp approximation, one 50 s noise realization (~5000 samples) and
    the O(phi^2) nonlinear terms at 3 deg (0.3 %).  The servo default must also meet the
    brief's 1 deg; the paper's law (same poles) cannot: its lag gives ~1.4 deg."""
    options = {} if law == "servo" else {"law": "chen_dao"}
    row = _stabilization_cell(v, monkeypatch, **options)
    assert row["upright"] and row["error"] is None, row
    want = _predicted_rms_deg(PolePlacement(design_speed=v, sample_time=0.01, law=law), v)
    assert abs(row["rms_error_deg"] - want) <= 0.10 * want, (row["rms_error_deg"], want)
    if law == "servo":
        assert row["rms_error_deg"] < 1.0
    else:
        assert row["rms_error_deg"] > 1.0


def test_pole_placement_stabilization_at_1_m_s_torque():
    """At 1 m/s (the hardest speed, controllers.md §4.2) the default stays upright with a
    physically reasonable peak torque: the brief allows tens of N m; the ideal torque for
    the 3 deg chirp is ~7 N m (|phi/T| = 0.0076 rad/N m at 0.5 Hz, §4.2 poles and zeros)
    and sensor noise through the gains adds ~3 N m RMS (K_phidot 1e-2 rad/s + K_phi 1e-3
    rad), so < 30 N m."""
    row = _stabilization_cell(1.0)
    assert row["upright"] and row["peak_torque"] < 30.0, row
    want = _predicted_rms_deg(PolePlacement(design_speed=1.0, sample_time=0.01), 1.0)
    assert abs(row["rms_error_deg"] - want) <= 0.10 * want, (row["rms_error_deg"], want)


# -- PID -----------------------------------------------------------------------------------
def test_default_pid_stabilizes_1_to_15():
    """controllers.md §4.3: (Kp, Ki, Kd) = (-200, -500, -80) stabilizes the linear
    benchmark at every speed 1-15 m/s (worst decay ~1.07 s^-1 at 15 m/s)."""
    kp, ki, kd = PID().gains
    worst = -np.inf
    for v in np.arange(1.0, 15.0001, 0.05):
        A, B = _b(v)
        Acl = np.zeros((5, 5))  # states x, xi;  T = -kp phi + ki xi - kd phidot
        Acl[:4, :4] = A - B @ np.array([[kp, 0.0, kd, 0.0]])
        Acl[:4, 4:] = ki * B
        Acl[4, 0] = -1.0
        worst = max(worst, np.linalg.eigvals(Acl).real.max())
    assert worst < -1.0, worst


# -- closed-loop tracking ------------------------------------------------------------------
def _continuous_rms_error(ctrl, v: float) -> float:
    """RMS tracking error of the *continuous-time* loop (second method), same reference."""
    A, B = _b(v)
    t = np.arange(0.0, T_END + 1e-9, 1e-3)
    r, rd = REF.sample(t), np.array([REF.rate(x) for x in t])
    if isinstance(ctrl, PID):
        kp, ki, kd = ctrl.gains
        Kx = np.array([[kp, 0.0, kd, 0.0]])
        Br = np.hstack([kp * B, (kd if ctrl.derivative == "error" else 0.0) * B])
        ki_ = ki
    else:
        g = ctrl.current_gains(v)
        Kx, ki_ = np.array([g[:4]]), g[4]
        # servo: T = -K (x - [r, 0, rd, 0]) + kI xi; chen_dao: no feedforward
        Br = np.hstack([g[0] * B, g[2] * B]) if ctrl.law == "servo" else np.zeros((4, 2))
    Acl = np.zeros((5, 5))
    Acl[:4, :4] = A - B @ Kx
    Acl[:4, 4:] = ki_ * B
    Acl[4, 0] = -1.0
    Bcl = np.vstack([Br, [1.0, 0.0]])
    x0 = np.r_[math.radians(1.0), 0, 0, 0, 0]
    res = control.forced_response(control.ss(Acl, Bcl, np.eye(5), 0), t, np.vstack([r, rd]), x0)
    m = t > SKIP
    return _rms(r[m] - res.outputs[0][m])


TRACKERS = {
    "pid": lambda: PID(reference=REF, sample_time=TRACK_DT),
    "pid-derr": lambda: PID(reference=REF, derivative="error", sample_time=TRACK_DT),
    "pole-placement": lambda: PolePlacement(reference=REF, sample_time=TRACK_DT),
    "pole-placement-paper": lambda: PolePlacement(SLOW_POLES, reference=REF,
                                                  sample_time=TRACK_DT),
    "fuzzy": lambda: FuzzyController(reference=REF, sample_time=TRACK_DT),
}
#: RMS error / RMS reference bounds.  PID (D on meas.) and the paper's pole-placement law
#: lag the reference (controllers.md §4.3: bandwidth ~0.7 Hz; Chen & Dao Fig. 7 "delay
#: time"); the default pole placement (servo, roll-zero poles) leaves the error
#: (s^3 - a_phidot s^2 - a_phi s) / Delta3(s) of the module docstring, 1.6-2.5 % here.
#: The bounds are the continuous-loop values (second method) with ~15 % headroom.
BOUND = {
    "pid": 0.17,
    "pid-derr": 0.07,
    "pole-placement": 0.03,
    "pole-placement-paper": 0.95,
    "fuzzy": 0.2,
}


@pytest.mark.parametrize("name", list(TRACKERS))
@pytest.mark.parametrize("v", SPEEDS)
def test_controller_tracks_roll_reference(name, v):
    """Upright and tracking a 3 deg, 0.02-0.2 Hz roll chirp from a 1 deg initial lean, with
    the sampled (1 kHz ZOH) loop.  For the linear laws the RMS error must also agree with
    the continuous-time loop (forced_response): the ZOH adds a dt/2 = 0.5 ms delay, i.e. a
    phase error <= 2 pi 0.2 Hz 0.5 ms = 6e-4 rad, so 5 % + 0.2 % of the reference RMS."""
    ctrl = TRACKERS[name]()
    res = _linear_run(P, v, ctrl, T_END, x0=(math.radians(1.0), 0.0, 0.0, 0.0))
    m = res.t > SKIP
    ref_rms = _rms(res.reference[m])
    err = _rms(res.reference[m] - res.true("phi")[m])
    assert err < BOUND[name] * ref_rms, (err / ref_rms, BOUND[name])
    if name != "fuzzy":
        ct_err = _continuous_rms_error(ctrl, v)
        assert abs(err - ct_err) <= 0.05 * ct_err + 0.002 * ref_rms, (err, ct_err)


def test_pid_step_has_no_steady_state_error():
    """Integral action: a 2 deg step is held exactly (linear loop, eigenvalues < -1 s^-1,
    so after 15 s the transient is below e^-15 of its start)."""
    ctrl = PID(reference=StepReference([0.5], [math.radians(2.0)]), sample_time=TRACK_DT)
    res = _linear_run(P, 5.0, ctrl, 16.0)
    assert abs(res.true("phi")[-1] - math.radians(2.0)) < 1e-6


# -- steer into lean -----------------------------------------------------------------------
def _data_dir() -> Path | None:
    for cand in (os.environ.get("BIKEID_DATA"), "../shared/data", "/work/shared/data"):
        if cand and (Path(cand) / "tudelft-sbw" / "eigen").is_dir():
            return Path(cand) / "tudelft-sbw" / "eigen"
    return None


@pytest.mark.skipif(_data_dir() is None, reason="measured data not found (set BIKEID_DATA)")
def test_steer_into_lean_reproduces_logged_command():
    """The logged sil_command is the controller's output for the logged speed and lean
    rate (README: K = 2, V = 6.5).  Logs print ~6 significant digits: 1e-4 N m."""
    files = sorted(_data_dir().glob("*.log.gz"))
    assert files
    ctrl = SteerIntoLean()
    with gzip.open(files[0], "rt") as fh:
        header = fh.readline().strip().split(",")
        rows = [line.strip().split(",") for _, line in zip(range(3000), fh, strict=False)]
    ci = {k: i for i, k in enumerate(header)}
    worst = 0.0
    for k, row in enumerate(rows):
        if not row[ci["sil_command"]].strip():
            continue
        y = [0.0] * 8
        y[0], y[4] = float(row[ci["speed"]]), float(row[ci["lean_rate"]])
        u = ctrl(k * 0.01, y)
        worst = max(worst, abs(u - float(row[ci["sil_command"]])))
    assert worst < 1e-4


def test_steer_into_lean_stabilizes_sbw_bicycle():
    """On the steer-by-wire bicycle's linear model the law is roll-rate feedback
    Kd = -K (V - v): closed-loop eigenvalues must be stable at the logged speeds
    1.5-4.5 m/s, and the sampled loop (100 Hz) must decay from a 2 deg lean."""
    sbw = steer_by_wire()
    ctrl = SteerIntoLean()
    for v in (1.5, 2.5, 3.5, 4.5):
        A, B = state_matrices(sbw, v)
        Acl = A - B[:, 1:2] @ np.array([[0.0, 0.0, ctrl.roll_rate_gain(v), 0.0]])
        rate = np.linalg.eigvals(Acl).real.max()
        assert rate < 0, (v, rate)
        res = _linear_run(sbw, v, ctrl, 30.0, x0=(math.radians(2.0), 0, 0, 0))
        # decays at least like the slowest eigenvalue allows (factor 2 for modal mixing)
        assert abs(res.true("phi")[-1]) < 2 * math.radians(2.0) * math.exp(rate * 25.0) + 1e-9


# -- anti-windup and interface -------------------------------------------------------------
def test_clamping_freezes_integral_while_saturated():
    """Constant error e with the output saturated: conditional integration must not
    integrate (clamp), so the integral stays exactly at zero."""
    c = PID(saturation=1.0, reference=lambda t: 0.5)
    for k in range(100):
        c(k * 1e-3, [5.0, 0.0, 0, 0, 0.0, 0, 0, 0])
    assert c.integral == 0.0


def test_backcalculation_settles_at_analytic_value():
    """Back-calculation: I' = e + (T_sat - T) / (Ki Tt) settles where
    T - T_sat = e Ki Tt, i.e. I* = (T_sat + e Ki Tt - Kp e) / Ki."""
    kp, ki, kd, tt, e, s = -200.0, -500.0, -80.0, 0.05, 0.1, 5.0
    c = PID(kp, ki, kd, anti_windup="backcalc", tracking_time=tt, saturation=s,
            reference=lambda t: e)  # fmt: skip
    for k in range(20000):
        u = c(k * 1e-3, [5.0, 0.0, 0, 0, 0.0, 0, 0, 0])
    target = (-s + e * ki * tt - kp * e) / ki  # output saturates at -s (negative gains)
    assert abs(u + s) < 1e-12
    assert abs(c.integral - target) < 1e-6 * abs(target)


def test_zoh_repeat_and_reset():
    c = PID(reference=lambda t: 0.1)
    y = [5.0, 0.0, 0, 0, 0.0, 0, 0, 0]
    u0 = c(0.0, y)
    assert c(0.0, [5.0, 0.3, 0, 0, 1.0, 0, 0, 0]) == u0  # held, state untouched
    c(1e-3, y)
    assert c.integral > 0
    with pytest.raises(ValueError, match="reset"):
        c(0.0, y)
    c.reset()
    assert c.integral == 0.0 and c(0.0, y) == u0


def test_schedule_interpolates_linearly():
    s = GainSchedule([1.0, 3.0], [(0.0, 10.0), (2.0, 30.0)])
    assert s(2.0) == (1.0, 20.0) and s(0.0) == (0.0, 10.0) and s(9.0) == (2.0, 30.0)
    with pytest.raises(ValueError, match="increasing"):
        GainSchedule([3.0, 1.0], [(0.0,), (1.0,)])


@pytest.mark.parametrize("name", ["pid", "pole-placement", "fuzzy", "steer-into-lean"])
def test_registry_and_describe(name):
    c = make(name, P, saturation=20.0)
    d = json.loads(json.dumps(c.describe()))
    assert d["saturation"] == 20.0 and d["sample_time"] == c.sample_time and d["gains"]


def test_bad_input_is_rejected():
    with pytest.raises(ValueError, match="unknown controller"):
        make("lqr")
    with pytest.raises(ValueError, match="sample_time"):
        PID(sample_time=0.0)
    with pytest.raises(ValueError, match="derivative"):
        PID(derivative="both")
    with pytest.raises(ValueError, match="distinct"):
        place_with_integral(*_b(5.0), [-3, -3, -4, -5, -6])
    with pytest.raises(ValueError, match="design_speed"):
        PolePlacement(model=state_space(P, 5.0, inputs=("T_delta",)))
    with pytest.raises(ValueError, match="law must be"):
        PolePlacement(design_speed=5.0, law="paper")
    with pytest.raises(ValueError, match="need 3"):
        PolePlacement(design_speed=5.0, free_poles=(-6, -8))
    with pytest.raises(ValueError, match="relative degree 2"):
        roll_zeros(np.eye(4), np.array([0.0, 0.0, 0.0, 1.0]))


# -- nonlinear plant -----------------------------------------------------------------------
@pytest.mark.parametrize("name", ["pid", "pole-placement", "fuzzy"])
@pytest.mark.parametrize("v", SPEEDS)
def test_controller_tracks_on_nonlinear_plant(name, v):
    """Same chirp on the nonlinear Whipple plant (sim.integrate, RK4, speed held): upright
    and within the same RMS bounds as the linear loop (3 deg keeps the nonlinear terms,
    O(phi^2) ~ 0.3 %, far below the bounds' headroom)."""
    from bikeid.sim.integrate import simulate as simulate_nonlinear
    from bikeid.sim.nonlinear import WhippleBicycle

    bike = WhippleBicycle(P)
    ctrl = TRACKERS[name]()
    tr = simulate_nonlinear(
        bike, bike.state(v, phi=math.radians(1.0)), T_END, controller=ctrl,
        dt=ctrl.sample_time, mode="held",
    )  # fmt: skip
    assert tr.fell_at is None
    m = tr.t > SKIP
    r = REF.sample(tr.t)[m]
    assert _rms(r - tr.y[m, 1]) < BOUND[name] * _rms(r)


def test_non_finite_torque_is_refused_not_passed_on():
    """A gain that overflows gives +-inf torque; with no saturation it would reach the plant.
    The controller refuses it (NaN was refused already) instead of returning -inf."""
    from bikeid.controllers import PID

    c = PID(kp=1e308)
    y = np.array([5.0, 5.0, 0, 0, 0, 0, 0, -15.0])  # roll 5 rad: kp * e overflows
    with np.errstate(over="ignore"), pytest.raises(ValueError, match="non-finite steer torque"):
        c(0.0, y)
    c.reset()
    assert np.isfinite(c(0.0, np.array([5.0, 1e-300, 0, 0, 0, 0, 0, -15.0])))  # finite: kept
