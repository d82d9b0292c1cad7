"""Normal contact forces of the nonlinear Whipple bicycle and the ``wheel_unloaded`` stop.

The forces come from the equations of motion (``scripts/derive_whipple.py``: Newton-Euler
for the whole bicycle with the accelerations of ``mass_forcing``).  Each is checked against
a source that does not use that computation:

- upright at rest and in steady straight running: the static loads of the Meijaard 2007
  Table 1 bicycle, computed here from the table's masses and positions;
- straight running with a drive torque: the analytic rigid-body result (longitudinal
  acceleration from the power balance, moment balance about the rear contact);
- dynamic states (falling, with inputs and effects): vertical Newton's law with the
  mass-centre height from the potential energy, and the moment of momentum about a fixed
  point, both differentiated numerically along DOP853 solutions;
- the stop: the DOP853 event of the reference integrator and the force at that time.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from bikeid.sim import _whipple_generated as gen
from bikeid.sim.effects import RollDamping, SteerDamping
from bikeid.sim.integrate import STOP_CAUSES, simulate, simulate_reference
from bikeid.sim.nonlinear import WhippleBicycle
from bikeid.sim.parameters import benchmark

# Meijaard 2007 Table 1: masses [kg] and mass-centre x [m] of R, B, H, F; w, g, radii.
MASSES = {"R": (2.0, 0.0), "B": (85.0, 0.3), "H": (4.0, 0.9), "F": (3.0, 1.02)}
W, G, RR, RF = 1.02, 9.81, 0.3, 0.35
M_TOTAL = sum(m for m, _ in MASSES.values())  # 94 kg
X_CM = sum(m * x for m, x in MASSES.values()) / M_TOTAL  # 0.342128 m
Z_CM = (2.0 * -RR + 85.0 * -0.9 + 4.0 * -0.7 + 3.0 * -RF) / M_TOTAL  # z down [m]


@pytest.fixture(scope="module")
def bike() -> WhippleBicycle:
    return WhippleBicycle(benchmark())


def test_static_loads_match_table_1(bike):
    """At rest and coasting straight at 5 m/s (or held at 8 m/s) nothing accelerates, so the
    loads are the static split of m g; the equations are evaluated in double precision
    (~1e-13 relative), tolerance 1e-9."""
    n_rear = M_TOTAL * G * (W - X_CM) / W
    n_front = M_TOTAL * G * X_CM / W
    assert n_front == pytest.approx(309.304, abs=1e-3)  # the reference's printed value
    for v, mode in ((0.0, "coast"), (5.0, "coast"), (8.0, "held")):
        nr, nf = bike.contact_forces(bike.state(v), mode=mode)
        assert nr == pytest.approx(n_rear, rel=1e-9)
        assert nf == pytest.approx(n_front, rel=1e-9)


def test_drive_torque_shifts_load_as_the_rigid_body_balance_says(bike):
    """Straight upright running with a rear drive torque T_R (positive brakes): power
    balance (m + IRyy/rR^2 + IFyy/rF^2) a = -T_R / rR; moment balance about the rear
    contact (inertial forces at the mass-centre height h, wheel spin-up torques)
    N_F w = m g x_cm - a (m h + IRyy/rR + IFyy/rF), N_R = m g - N_F.  Pure algebra, so
    tolerance 1e-9 relative."""
    i_r, i_f = 0.12, 0.28  # Table 1 IRyy, IFyy [kg m^2]
    h = -Z_CM
    for T_R in (-60.0, 40.0):
        a = -T_R / RR / (M_TOTAL + i_r / RR**2 + i_f / RF**2)
        n_front = (M_TOTAL * G * X_CM - a * (M_TOTAL * h + i_r / RR + i_f / RF)) / W
        nr, nf = bike.contact_forces(bike.state(5.0), inputs=(0.0, 0.0, 0.0, T_R))
        assert nf == pytest.approx(n_front, rel=1e-9)
        assert nr == pytest.approx(M_TOTAL * G - n_front, rel=1e-9)


# -- dynamic states, checked by momenta differentiated numerically ----------------------------
INPUTS = np.array([3.0, -8.0, 25.0, 0.0])  # T_delta [N m], T_phi [N m], F [N], T_R [N m]
EFFECTS = [SteerDamping(2.0), RollDamping(5.0)]


def _dynamic_states(bike):
    """(state, inputs, effects): a violent fall near the rear wheel's unloading, and a
    milder state with all inputs and plant effects acting."""
    y1 = bike.state(5.0, phi=math.radians(45.0), delta=0.3, phidot=1.0, deltadot=4.0)
    y2 = bike.state(4.0, phi=math.radians(12.0), delta=-0.1, phidot=-0.5, deltadot=2.0, psi=0.7)
    return [(y1, np.zeros(4), None), (y2, INPUTS, EFFECTS)]


def _around(bike, y0, inputs, effects, h):
    """States at t = -2h, -h, 0, h, 2h by DOP853 (rtol 1e-13), inputs held."""

    def f(t, y):
        return bike.rhs(y, inputs, effects=effects)[0]

    out = {0: np.asarray(y0, float)}
    for sign in (1, -1):
        sol = solve_ivp(f, (0.0, sign * 2 * h), y0, method="DOP853", rtol=1e-13, atol=1e-13,
                        t_eval=[sign * h, sign * 2 * h])  # fmt: skip
        out[sign], out[2 * sign] = sol.y[:, 0], sol.y[:, 1]
    return [out[k] for k in (-2, -1, 0, 1, 2)]


def _momentum(bike, y):
    q5 = bike.pitch(y[3], y[5])
    u = bike.all_speeds(y[3], q5, y[5], y[7], y[8], y[9])
    out = np.empty(12)
    gen.momentum(y[2], y[3], q5, y[5], u, bike.p, out)
    c = np.empty(4)
    gen.contact(y[2], y[3], q5, y[5], u, bike.p, c)
    return out, np.array([c[2], c[3], 0.0])


def test_vertical_newton_law_from_mass_centre_heights(bike):
    """N_R + N_F = m g + d^2(sum m_i h_i)/dt^2 with sum m_i h_i = potential energy / g (an
    independent function: the energy), differentiated by the 5-point stencil with
    h = 1 ms along DOP853 solutions.  The difference shrinks as h^4 (violent state:
    0.29, 0.017, 1.1e-3, 6.6e-5 N at h = 10, 5, 2.5, 1.25 ms), so at 1 ms it is ~3e-5 N,
    above the integration error 1e-13 |PE| / h^2 / g ~ 1e-5 N; tolerance 1e-3 N (1e-6 of
    m g)."""
    h = 1e-3
    for y0, r, eff in _dynamic_states(bike):
        pe = [bike.energy(y)[1] for y in _around(bike, y0, r, eff, h)]
        d2 = (-pe[0] + 16 * pe[1] - 30 * pe[2] + 16 * pe[3] - pe[4]) / (12 * h**2)
        nr, nf = bike.contact_forces(y0, r, effects=eff)
        assert abs(nr + nf - (M_TOTAL * G + d2 / G)) < 1e-3
        assert abs(nr + nf - M_TOTAL * G) > 10.0  # a genuinely dynamic state


def test_each_force_from_numerically_differentiated_momenta(bike):
    """Each force separately: with P0 the rear contact at t = 0 (a point fixed in the
    ground), dH_P0/dt = moment of gravity, F, T_phi (and the roll effect, a torque about
    the yaw frame's x axis) + r x (-N_F z) + (vertical moment of the tangential forces),
    and dL_z/dt = m g - N_R - N_F.  H_P0 = H_rear contact + (rear contact - P0) x L from
    the velocity-level ``momentum`` function, differentiated by the 5-point stencil
    (h = 1 ms): error ~h^4 as above (0.052, 3.2e-3, 2.0e-4 N at h = 5, 2.5, 1.25 ms for
    N_R), ~1e-4 N at 1 ms; tolerance 1e-3 N (moments: 1e-3 N times the wheelbase).  Both
    horizontal moment components are checked (only N_F enters them)."""
    h = 1e-3
    for y0, r, eff in _dynamic_states(bike):
        ys = _around(bike, y0, r, eff, h)
        H, L = [], []
        for y in ys:
            mom, _ = _momentum(bike, y)
            d = np.array([y[0] - y0[0], y[1] - y0[1], 0.0])
            L.append(mom[:3])
            H.append(mom[3:6] + np.cross(d, mom[:3]))
        dH = (H[0] - 8 * H[1] + 8 * H[3] - H[4]) / (12 * h)
        dL = (L[0] - 8 * L[1] + 8 * L[3] - L[4]) / (12 * h)
        mom, rf = _momentum(bike, y0)
        first, pf = mom[6:9], mom[9:12]
        psi, phidot = y0[2], y0[7]
        ax, ay = (
            np.array([math.cos(psi), math.sin(psi), 0.0]),
            np.array([-math.sin(psi), math.cos(psi), 0.0]),
        )
        t_roll = r[1] - (eff[1].c * phidot if eff else 0.0)
        known = np.cross(first, [0.0, 0.0, G]) + np.cross(pf, r[2] * ay) + t_roll * ax
        nr, nf = bike.contact_forces(y0, r, effects=eff)
        lever = np.hypot(rf[0], rf[1])
        front = np.cross(rf, [0.0, 0.0, -nf])
        np.testing.assert_allclose((dH - known)[:2], front[:2], rtol=0, atol=1e-3 * lever)
        assert nr == pytest.approx(M_TOTAL * G - nf - dL[2], abs=1e-3)


# -- stops --------------------------------------------------------------------------------------
def test_cause_is_physical_and_named():
    assert STOP_CAUSES["wheel_unloaded"].physical


def test_falling_run_stops_when_the_rear_wheel_unloads(bike):
    """Coasting at 5 m/s from 25 deg of lean the benchmark wobbles for ~3 s, then falls; the
    steer snaps over and the rear wheel lifts off (its load crosses zero) before |steer|
    reaches 90 deg (before this cause existed the run ended at 3.374 s, steer_limit, with
    the step check failing).  The RK4 crossing is interpolated linearly within the 5 ms
    step; the DOP853 event is exact: they agree within 1 ms (observed 0.27 ms: the load
    falls ~5e4 N/s, curving).  At the event time the load is 0 to the event's root-finding
    accuracy (tolerance 1e-3 N)."""
    x0 = bike.state(5.0, phi=math.radians(25.0))
    tr = simulate(bike, x0, 5.0)
    ref = simulate_reference(bike, x0, 5.0)
    for run in (tr, ref):
        assert run.stop.cause == "wheel_unloaded" and run.stop.physical
        assert "rear wheel" in run.stop.message and run.fell_at == run.stop.time
        assert np.max(np.abs(run.signal("delta"))) < math.pi / 2
        assert np.max(np.abs(run.signal("phi"))) < math.radians(60.0)
        assert np.all(run.normal_forces > 0)  # loaded at every sample before the stop
    assert abs(tr.stop.time - ref.stop.time) <= 1e-3
    assert 3.0 < ref.stop.time < 3.374
    # load at the reference stop time, integrating from the last sample
    y, t_last = ref.states[-1], ref.t[-1]
    sol = solve_ivp(lambda t, yy: bike.rhs(yy)[0], (t_last, ref.stop.time), y,
                    method="DOP853", rtol=1e-13, atol=1e-13)  # fmt: skip
    assert abs(bike.contact_forces(sol.y[:, -1])[0]) < 1e-3
    assert bike.contact_forces(y)[0] > 100.0


def test_run_that_stays_up_never_stops(bike):
    """5 m/s is inside the benchmark's self-stable band (4.29-6.02 m/s): from 0.5 deg the
    bicycle recovers and the loads stay within 1 % of the static ones."""
    tr = simulate(bike, bike.state(5.0, phi=math.radians(0.5)), 10.0)
    assert tr.stop is None and tr.fell_at is None
    static = np.array([M_TOTAL * G * (W - X_CM) / W, M_TOTAL * G * X_CM / W])
    np.testing.assert_allclose(tr.normal_forces, np.broadcast_to(static, (len(tr.t), 2)),
                               rtol=1e-2)  # fmt: skip
    assert np.array_equal(tr.columns()["N_front"], tr.normal_forces[:, 1])


def test_input_jump_unloading_the_front_wheel_stops_at_the_sample(bike):
    """A drive torque of -200 N m asks for a = 200/0.3/(94 + 0.12/0.09 + 0.28/0.1225)
    = 6.9 m/s^2, more than the wheelie limit (N_F = 0 at a = 3.6 m/s^2 by the balance
    above), so the front wheel lifts at the first sample; -50 N m (1.7 m/s^2) does not."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # a physical stop: no warning
        tr = simulate(bike, bike.state(5.0), 1.0, inputs={"T_R": -200.0})
        ref = simulate_reference(bike, bike.state(5.0), 1.0, inputs={"T_R": -200.0})
    for run in (tr, ref):
        assert run.stop.cause == "wheel_unloaded" and run.stop.time == 0.0
        assert "front wheel" in run.stop.message
    ok = simulate(bike, bike.state(5.0), 1.0, inputs={"T_R": -50.0})
    assert ok.stop is None and np.all(ok.normal_forces[:, 1] > 0)


def test_cli_simulate_reports_the_unloaded_wheel(tmp_path, capsys):
    """``bikeid simulate`` prints the stop naming the wheel; its JSON carries cause and time
    and the normal forces (the same run as above: rear wheel at 3.334 s)."""
    import json

    from bikeid.experiments.cli import main

    out = tmp_path / "fall.json"
    args = ["simulate", "--speed", "5", "--phi0", "25", "--duration", "5", "--out", str(out)]
    assert main(args) == 0
    msg = capsys.readouterr().out
    assert "rear wheel" in msg and "[wheel_unloaded]" in msg
    data = json.loads(out.read_text())
    stop = data["meta"]["stop"]
    assert stop["cause"] == "wheel_unloaded" and stop["physical"] is True
    assert stop["time"] == pytest.approx(3.334, abs=1e-3)
    assert data["meta"]["fell_at"] == stop["time"]
    assert min(data["signals"]["N_rear"]) > 0


def test_recorded_forces_are_those_of_each_sample(bike):
    """``Trajectory.normal_forces[k]`` is the force at the sample's state with the inputs
    then acting (after the input effects) and the plant effects: the same function
    evaluated afterwards gives the same numbers to round-off (1e-9 N), for RK4 and the
    DOP853 reference, with feedback, an open-loop roll torque, a lag and steer damping."""
    from bikeid.sim.effects import ActuatorLag

    x0 = bike.state(4.0, phi=0.05)
    kw = dict(
        controller=lambda t, y: 10.0 * y[4],
        inputs={"T_phi": 2.0, "F": -5.0},
        effects=[ActuatorLag(0.03), SteerDamping(1.0)],
    )
    for run in (simulate(bike, x0, 1.0, **kw), simulate_reference(bike, x0, 1.0, **kw)):
        again = [
            bike.contact_forces(y, u, effects=[SteerDamping(1.0)])
            for y, u in zip(run.states, run.inputs, strict=True)
        ]
        np.testing.assert_allclose(run.normal_forces, again, rtol=0, atol=1e-9)
