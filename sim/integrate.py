"""Fixed-step simulation of the nonlinear Whipple bicycle with a sampled controller.

The controller ``u = controller(t, y)`` (``y`` the measurement vector in
:data:`sim.conventions.MEASURED` order, ``u`` the steer torque T_delta [N m]) runs
at its own sample time ``dt`` with zero-order hold; the plant advances between
samples with ``substeps`` classical Runge-Kutta (RK4) steps of ``dt / substeps``
in a numba kernel.  Sample k at t_k = k dt: measure the state, call the controller,
hold the command over [t_k, t_k+1).

Per sample the steer torque reaching the plant is
``T_delta = lag(gain * delayed(controller + open-loop T_delta))`` (input effects of
:mod:`sim.effects`; the first-order lag is evaluated exactly within the sample).
Open-loop inputs (T_delta, T_phi, F, T_R) are given on the sample grid and held.

``method="reference"`` integrates each sample interval with
``scipy.integrate.solve_ivp`` (DOP853, rtol = atol = 1e-12 by default) instead:
the high-accuracy reference for tests.

Stop reasons.  A run that ends early carries one :class:`Stop` (``Trajectory.stop``):
its ``cause`` (a key of :data:`STOP_CAUSES`), time [s], one-line message and whether it is
``physical``.  Physical stops, whichever comes first: ``wheel_unloaded`` (a wheel's normal
contact force reaches 0, so the wheel lifts off and the Whipple model, whose wheels
never leave the ground, ends; the message names the rear or front wheel),
``roll_limit`` (|roll| over ``fall_limit``, default 60 deg) and ``steer_limit`` (|steer|
over 90 deg); ``Trajectory.fell_at`` is their time and is None otherwise.  The normal
forces are evaluated (from the equations of motion, :mod:`sim.nonlinear`) at the start
of every sample interval, with the inputs then acting, and at the end of every RK4 step
(a stop at a sample instant if a jump of the inputs unloads a wheel); the stop time of a
crossing, like the limit crossings, is interpolated linearly within the RK4 step
(``method="reference"``: located by a DOP853 event).  ``Trajectory.normal_forces`` holds
them at every sample.  Numerical stops, never reported as falls: ``controller_nonfinite``,
``nonfinite_state`` and ``step_too_coarse``.  Every RK4 stop at a limit, an unloaded
wheel or a non-finite state is checked against the step first: if a decaying mode lambda
of the linearized Whipple plant at the current speed has lambda h outside RK4's
stability region (:func:`rk4_amplification` > 1), or re-integrating the last sample
interval with half the step moves roll or steer by more than :data:`STEP_CHECK_TOL`, the stop is
``step_too_coarse`` with the fix (smaller dt or more substeps).

State order, inputs and signs: :mod:`sim.nonlinear`.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numba import njit

from .conventions import MEASURED
from .effects import InputChain, input_chain, plant_vector
from .errors import check_memory
from .nonlinear import (
    INPUTS,
    WhippleBicycle,
    invalidate_stale_caches,
    outputs,
    rhs,
    rhs_contact,
)
from .parameters import BicycleParameters

__all__ = [
    "STOP_CAUSES",
    "Stop",
    "Trajectory",
    "simulate",
    "simulate_many",
    "simulate_reference",
]

DEFAULT_DT = 0.01
DEFAULT_SUBSTEPS = 2
DEFAULT_FALL_LIMIT = math.radians(60.0)
#: |steer| [rad] beyond which a run stops (``steer_limit``): the front wheel is across
#: the frame, no longer a bicycle being ridden.
STEER_LIMIT = math.pi / 2


def rk4_amplification(z: np.ndarray) -> np.ndarray:
    """|R(z)| of RK4, R(z) = 1 + z + z^2/2 + z^3/6 + z^4/24 (z = lambda h).

    A decaying mode (Re lambda < 0) is integrated stably only where |R(z)| <= 1 (Hairer &
    Wanner, Solving ODEs II, Fig. IV.2.1): 2.785 on the negative real axis but only about
    2.6 at 120 deg, the direction of lightly damped modes, so the test is on R itself.

    Parameters
    ----------
    z : array_like of complex
        lambda h.

    Returns
    -------
    ndarray
        |R(z)|.
    """
    z = np.asarray(z, dtype=complex)
    return np.abs(1 + z + z**2 / 2 + z**3 / 6 + z**4 / 24)


#: Half-step check: a stop is ``step_too_coarse`` if re-integrating its sample interval
#: with half the RK4 step changes roll or steer by more than this [rad].  At the default
#: step (5 ms) the difference is ~(lambda h)^5 / 120 |x| <= 2e-6 rad at 15 m/s near a fall
#: (|lambda| = 35.8 1/s); an unstable step gives O(1) rad; 0.01 rad (0.6 deg) lies between.
STEP_CHECK_TOL = 0.01

_OK, _FELL, _NONFINITE, _STEER, _UNLOADED = 0, 1, 2, 3, 4
#: Wheel names by the index of the normal-force vector [N_rear, N_front].
WHEELS = ("rear", "front")


@dataclass(frozen=True)
class StopCause:
    """One kind of early end: whether it is ``physical`` and what it means."""

    physical: bool
    meaning: str


#: Every reason a run can end early, by cause name.  Adding one is one entry here plus
#: its detection.
STOP_CAUSES: dict[str, StopCause] = {
    "wheel_unloaded": StopCause(
        True,
        "a wheel's normal contact force reached 0: the wheel lifts off, the Whipple "
        "model (bilateral contact) no longer holds",
    ),
    "roll_limit": StopCause(True, "|roll| exceeded the fall limit: the bicycle fell"),
    "steer_limit": StopCause(True, "|steer| exceeded 90 deg: the front wheel folded"),
    "nonfinite_state": StopCause(
        False, "the state became non-finite (or the pitch had no solution)"
    ),
    "step_too_coarse": StopCause(
        False, "the RK4 step is too coarse for the dynamics: a numerical blow-up"
    ),
    "controller_nonfinite": StopCause(False, "the controller returned a non-finite torque"),
}


@dataclass(frozen=True)
class Stop:
    """Why and when a run ended early.

    Attributes
    ----------
    cause : str
        A key of :data:`STOP_CAUSES`.
    time : float
        Time of the stop [s] (the limit or zero-load crossing, interpolated within the
        RK4 step; the sample at which the controller failed, or at which a jump of the
        inputs unloaded a wheel).
    message : str
        One line for the user, with the fix for numerical causes.
    physical : bool
        True for a physical end (a fall); False for a numerical failure.  Derived from
        :data:`STOP_CAUSES`; given explicitly it must agree.

    Raises
    ------
    ValueError
        On construction, if ``cause`` is unknown or ``physical`` contradicts it.
    """

    cause: str
    time: float
    message: str
    physical: bool | None = None

    def __post_init__(self) -> None:
        if self.cause not in STOP_CAUSES:
            raise ValueError(f"unknown stop cause {self.cause!r}; causes are {sorted(STOP_CAUSES)}")
        physical = STOP_CAUSES[self.cause].physical
        if self.physical is not None and bool(self.physical) != physical:
            raise ValueError(f"stop cause {self.cause!r} has physical={physical}")
        object.__setattr__(self, "physical", physical)
        object.__setattr__(self, "time", float(self.time))

    def as_dict(self) -> dict[str, Any]:
        """The stop as a JSON-serializable dict.

        Returns
        -------
        dict
            ``cause``, ``time`` [s], ``message``, ``physical``.
        """
        return {
            "cause": self.cause,
            "time": self.time,
            "message": self.message,
            "physical": self.physical,
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> Stop:
        """Rebuild a stop from :meth:`as_dict` output.

        Parameters
        ----------
        d : mapping
            With ``cause``, ``time`` [s] and ``message`` (``physical`` optional).

        Returns
        -------
        Stop

        Raises
        ------
        ValueError
            If a key is missing or the cause is unknown.
        """
        try:
            return cls(d["cause"], d["time"], d["message"], d.get("physical"))
        except KeyError as exc:
            raise ValueError(f"stop record lacks {exc}; need cause, time, message") from None
        except TypeError as exc:  # e.g. time None, or not a mapping
            raise ValueError(f"malformed stop record {d!r}: {exc}") from None


@dataclass
class Trajectory:
    """A simulated run on the controller sample grid.

    Returned by :func:`simulate`.  N is the number of samples kept: duration/dt + 1,
    or fewer if the run stopped early (the last sample is the one before the stop).

    Attributes
    ----------
    t : (N,) ndarray
        Sample times [s], t_k = k dt.
    y : (N, 8) ndarray
        True measurements, :data:`sim.conventions.MEASURED` order
        [v, phi, delta, psi, phidot, deltadot, psidot, thetaRdot]
        [m/s, rad, rad, rad, rad/s, rad/s, rad/s, rad/s]; Meijaard signs (positive
        to the right; v = -rR thetaRdot by definition).
    measured : (N, 8) ndarray
        What the controller saw (``measure`` hook applied; = y without one).
    theta : (N,) ndarray
        Rear-frame pitch from upright [rad], positive nose up.
    rear, front : (N, 2) ndarray
        Rear / front contact points (x, y) in the inertial ground frame N [m]
        (x forward at zero yaw, y right).
    inputs : (N, 4) ndarray
        Inputs acting at each sample instant [T_delta, T_phi, F, T_R]
        [N m, N m, N, N m] (T_delta after input effects; T_R the drive torque in
        held mode).
    normal_forces : (N, 2) ndarray
        Normal contact forces [N_rear, N_front] [N] at each sample, with the inputs
        and effects acting then (:meth:`sim.nonlinear.WhippleBicycle.contact_forces`):
        the ground's upward push on each wheel, > 0 while the run lasts.
    command : (N,) ndarray
        The controller's steer-torque command [N m] (0 without one).
    states : (N, 10) ndarray
        Integration states (:data:`sim.nonlinear.STATE`).
    fell_at : float or None
        Time [s] of a physical stop (``wheel_unloaded``, ``roll_limit`` or
        ``steer_limit``), else None; never set for a numerical failure.
    stop_reason : str or None
        None, or why the run ended early (``stop.message``).
    energy : (N,) ndarray or None
        Total energy (kinetic + potential) [J] if requested, else None.
    meta : dict
        Settings of the run: ``mode``, ``dt`` [s], ``substeps``, ``method``,
        ``fall_limit`` [rad], ``bicycle`` (name) and ``lateral_force_point``
        (x_F, z_F) [m].
    stop : Stop or None
        Why the run ended early (:class:`Stop`), None if it ran its whole duration.
    """

    t: np.ndarray
    y: np.ndarray
    measured: np.ndarray
    theta: np.ndarray
    rear: np.ndarray
    front: np.ndarray
    inputs: np.ndarray
    normal_forces: np.ndarray
    command: np.ndarray
    states: np.ndarray
    fell_at: float | None = None
    stop_reason: str | None = None
    energy: np.ndarray | None = None
    meta: dict[str, Any] = field(default_factory=dict)
    stop: Stop | None = None

    def signal(self, name: str) -> np.ndarray:
        """One true signal by name.

        Parameters
        ----------
        name : str
            A :data:`sim.conventions.MEASURED` name, an input of
            :data:`sim.nonlinear.INPUTS` (``T_delta``, ``T_phi``, ``F``, ``T_R``),
            ``theta`` (pitch), a contact coordinate ``x``, ``y`` (rear) or ``xF``,
            ``yF`` (front), or a normal contact force ``N_rear``, ``N_front`` [N].

        Returns
        -------
        (N,) ndarray
            The signal in SI units (:data:`sim.conventions.UNITS`).

        Raises
        ------
        ValueError
            If the name is unknown.
        """
        if name in MEASURED:
            return self.y[:, MEASURED.index(name)]
        if name in INPUTS:
            return self.inputs[:, INPUTS.index(name)]
        extra = {
            "theta": self.theta,
            "x": self.rear[:, 0],
            "y": self.rear[:, 1],
            "xF": self.front[:, 0],
            "yF": self.front[:, 1],
            "N_rear": self.normal_forces[:, 0],
            "N_front": self.normal_forces[:, 1],
        }
        if name not in extra:
            raise ValueError(
                f"unknown signal {name!r}; use one of {list(MEASURED) + list(INPUTS) + list(extra)}"
            )
        return extra[name]

    def columns(self) -> dict[str, np.ndarray]:
        """All signals as named columns (time first), e.g. for CSV/JSON output.

        Returns
        -------
        dict of str to (N,) ndarray
            ``t``, the MEASURED signals, ``theta``, ``x``, ``y``, ``xF``, ``yF``,
            the inputs ``T_delta``, ``T_phi``, ``F``, ``T_R``, the normal contact
            forces ``N_rear``, ``N_front`` and, if recorded, ``energy``; SI units.
        """
        cols = {"t": self.t}
        for name in (*MEASURED, "theta", "x", "y", "xF", "yF", *INPUTS, "N_rear", "N_front"):
            cols[name] = self.signal(name)
        if self.energy is not None:
            cols["energy"] = self.energy
        return cols


# -- compiled kernel -------------------------------------------------------------------------
@njit(cache=True)
def _lagged(T0, Tc, tau, s):
    if tau <= 0.0:
        return Tc
    return Tc + (T0 - Tc) * math.exp(-s / tau)


@njit(cache=True)
def _rk4_interval(y, q5g, p, ev, held, rc, T0, tau, dt, nsub, phimax, dmax, wheels, info, nc):
    """Advance ``y`` over one sample interval with ``nsub`` RK4 steps, in place.

    rc = [T_delta command, T_phi, F, T_R] held over the interval; T_delta is
    lagged from T0 with time constant tau.  info <- [status, time offset of a
    stop, T_R at the interval start, wheel (0 rear, 1 front) of a wheel_unloaded
    stop]; nc <- normal forces [N_R, N_F] [N] at the interval start.  With ``wheels``
    the normal forces are evaluated at the start of the interval and at the end of
    every step (that evaluation is also the next step's first stage, so it costs one
    extra right-hand side per interval); a force <= 0 stops the run.  Returns the
    status (0 ok, 1 |roll| > phimax, 2 non-finite, 3 |steer| > dmax, 4 wheel unloaded).
    """
    h = dt / nsub
    k1 = np.empty(10)
    k2 = np.empty(10)
    k3 = np.empty(10)
    k4 = np.empty(10)
    yt = np.empty(10)
    n0 = np.empty(2)
    n1 = np.empty(2)
    r = rc.copy()
    r[0] = _lagged(T0, rc[0], tau, 0.0)
    info[2] = rhs_contact(y, q5g, p, r, ev, held, k1, n0)
    nc[0] = n0[0]
    nc[1] = n0[1]
    if wheels and (n0[0] <= 0.0 or n0[1] <= 0.0):  # e.g. a jump of the inputs at t_k
        info[0] = _UNLOADED
        info[1] = 0.0
        info[3] = 0.0 if n0[0] <= 0.0 else 1.0
        return _UNLOADED
    for s in range(nsub):
        ts = s * h
        r[0] = _lagged(T0, rc[0], tau, ts + 0.5 * h)
        for i in range(10):
            yt[i] = y[i] + 0.5 * h * k1[i]
        rhs(yt, q5g, p, r, ev, held, k2)
        for i in range(10):
            yt[i] = y[i] + 0.5 * h * k2[i]
        rhs(yt, q5g, p, r, ev, held, k3)
        r[0] = _lagged(T0, rc[0], tau, ts + h)
        for i in range(10):
            yt[i] = y[i] + h * k3[i]
        rhs(yt, q5g, p, r, ev, held, k4)
        phi_prev = abs(y[3])
        del_prev = abs(y[5])
        finite = True
        for i in range(10):
            y[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
            if not math.isfinite(y[i]):
                finite = False
        if not finite:
            info[0] = _NONFINITE
            info[1] = ts + h
            return _NONFINITE
        # crossing times by linear interpolation within the step; the earliest one wins
        s_roll = 2.0
        s_steer = 2.0
        s_wheel = 2.0
        if abs(y[3]) > phimax:
            s_roll = (phimax - phi_prev) / (abs(y[3]) - phi_prev)
        if abs(y[5]) > dmax:
            s_steer = (dmax - del_prev) / (abs(y[5]) - del_prev)
        if wheels or s < nsub - 1:
            # end-of-step forces; the same evaluation is the next step's k1
            rhs_contact(y, q5g, p, r, ev, held, k1, n1)
            if wheels:
                for j in range(2):
                    if n1[j] <= 0.0:
                        sj = n0[j] / (n0[j] - n1[j])
                        if sj < s_wheel:
                            s_wheel = sj
                            info[3] = j
                n0[0] = n1[0]
                n0[1] = n1[1]
        if s_roll <= 1.0 or s_steer <= 1.0 or s_wheel <= 1.0:
            if s_wheel < s_roll and s_wheel < s_steer:
                info[0] = _UNLOADED
                info[1] = ts + h * s_wheel
                return _UNLOADED
            if s_roll <= s_steer:
                info[0] = _FELL
                info[1] = ts + h * s_roll
                return _FELL
            info[0] = _STEER
            info[1] = ts + h * s_steer
            return _STEER
    info[0] = _OK
    return _OK


#: The wheel check of every simulated sample (:func:`_rk4_interval`'s ``wheels``), a numpy
#: bool rather than the literal ``True``: a literal would compile a second machine-code
#: version of ``_rk4_interval`` (~10 s in a fresh environment) beside the one the step check
#: calls from Python with ``False``.
WHEEL_CHECK = np.bool_(True)


@njit(cache=True)
def _rk4_sample(k, Tc, T0, X, OUT, OL, U, NC, q5g, p, ev, held, tau, dt, nsub, phimax, dmax, info):
    """One controller sample: advance X[k] to X[k + 1], outputs into OUT[k + 1].

    Records the inputs acting at t_k in U[k] and the normal forces at t_k in NC[k].
    Returns the status of :func:`_rk4_interval` (wheel check on).
    """
    y = X[k].copy()
    rc = OL[k].copy()
    rc[0] = Tc
    nc = np.empty(2)
    status = _rk4_interval(y, q5g, p, ev, held, rc, T0, tau, dt, nsub, phimax, dmax, WHEEL_CHECK,
                           info, nc)  # fmt: skip
    U[k, 0] = T0
    U[k, 1] = OL[k, 1]
    U[k, 2] = OL[k, 2]
    U[k, 3] = info[2]
    NC[k, 0] = nc[0]
    NC[k, 1] = nc[1]
    if status == _OK:
        for i in range(10):
            X[k + 1, i] = y[i]
        outputs(y, q5g, p, OUT[k + 1])
    return status


invalidate_stale_caches([_rk4_interval, _rk4_sample], "integrate")


# -- helpers -----------------------------------------------------------------------------------
def _as_bike(bike) -> WhippleBicycle:
    if isinstance(bike, WhippleBicycle):
        return bike
    if isinstance(bike, BicycleParameters):
        return WhippleBicycle(bike)
    raise ValueError(
        f"bike must be a WhippleBicycle or BicycleParameters, got {type(bike).__name__}"
    )


def _input_array(inputs, n: int) -> np.ndarray:
    """Open-loop inputs as an (n, 4) array [T_delta, T_phi, F, T_R] on the sample grid."""
    out = np.zeros((n, 4))
    if inputs is None:
        return out
    if isinstance(inputs, Mapping):
        for name, val in inputs.items():
            if name not in INPUTS:
                raise ValueError(f"unknown input {name!r}; inputs are {list(INPUTS)}")
            arr = np.asarray(val, dtype=float)
            if arr.ndim == 0:
                arr = np.full(n, float(arr))
            if arr.shape != (n,):
                raise ValueError(
                    f"input {name!r} has shape {arr.shape}; give a scalar or one value per "
                    f"controller sample ({n},)"
                )
            out[:, INPUTS.index(name)] = arr
    else:
        arr = np.asarray(inputs, dtype=float)
        if arr.shape != (n, 4):
            raise ValueError(
                f"inputs array has shape {arr.shape}; expected ({n}, 4) columns {list(INPUTS)} "
                "on the controller sample grid"
            )
        out[:] = arr
    if not np.all(np.isfinite(out)):
        raise ValueError("open-loop inputs must be finite")
    return out


def _reference_interval(
    bike, y, q5g, ev, held, rc, T0, tau, dt, phimax, dmax, info, nc, rtol, atol
):
    from scipy.integrate import solve_ivp

    r = rc.copy()
    ydot = np.empty(10)
    nf = np.empty(2)

    def fun(s, yy):
        r[0] = _lagged(T0, rc[0], tau, s)
        rhs(yy, q5g, bike.p, r, ev, held, ydot)
        return ydot.copy()

    def normal(j):
        def event(s, yy):
            r[0] = _lagged(T0, rc[0], tau, s)
            rhs_contact(yy, q5g, bike.p, r, ev, held, ydot, nf)
            return nf[j]

        event.terminal = True
        event.direction = -1.0
        return event

    def fall(s, yy):
        return abs(yy[3]) - phimax

    def steer(s, yy):
        return abs(yy[5]) - dmax

    fall.terminal = True
    steer.terminal = True
    r[0] = T0
    info[2] = rhs_contact(y, q5g, bike.p, r, ev, held, ydot, nf)
    nc[:] = nf
    if nf[0] <= 0.0 or nf[1] <= 0.0:  # unloaded at the interval start
        info[0], info[1], info[3] = _UNLOADED, 0.0, 0.0 if nf[0] <= 0.0 else 1.0
        return _UNLOADED
    sol = solve_ivp(
        fun, (0.0, dt), y, method="DOP853", rtol=rtol, atol=atol,
        events=(fall, steer, normal(0), normal(1)),
    )  # fmt: skip
    if sol.status == -1 or not np.all(np.isfinite(sol.y[:, -1])):
        info[0], info[1] = _NONFINITE, sol.t[-1]
        return _NONFINITE
    y[:] = sol.y[:, -1]
    if sol.status == 1:
        hit = [e.size > 0 for e in sol.t_events]
        status = _FELL if hit[0] else _STEER if hit[1] else _UNLOADED
        if status == _UNLOADED:
            info[3] = 0.0 if hit[2] else 1.0
        info[0], info[1] = status, sol.t[-1]
        return status
    info[0] = _OK
    return _OK


# -- public API --------------------------------------------------------------------------------
def simulate(
    bike: WhippleBicycle | BicycleParameters,
    x0: np.ndarray,
    duration: float,
    *,
    controller: Callable[[float, np.ndarray], float] | None = None,
    dt: float = DEFAULT_DT,
    substeps: int = DEFAULT_SUBSTEPS,
    mode: str = "coast",
    inputs: np.ndarray | Mapping[str, Any] | None = None,
    measure: Callable[[np.ndarray], np.ndarray] | None = None,
    effects: Sequence[object] | None = None,
    fall_limit: float = DEFAULT_FALL_LIMIT,
    energy: bool = False,
    method: str = "rk4",
    rtol: float = 1e-12,
    atol: float = 1e-12,
) -> Trajectory:
    """Simulate the nonlinear Whipple bicycle under a sampled controller.

    See the module docstring for the sampling scheme and the input chain.

    Parameters
    ----------
    bike : WhippleBicycle or BicycleParameters
        The plant (parameters are wrapped in a :class:`WhippleBicycle` with the lateral
        force at the rear body mass centre).
    x0 : (10,) array_like
        Initial integration state in :data:`sim.nonlinear.STATE` order; build it with
        :meth:`WhippleBicycle.state`.  |roll| must not exceed ``fall_limit``.
    duration : float
        Simulated time [s], > 0 and a whole number of samples ``dt``.
    controller : callable, optional
        ``controller(t, y) -> T_delta`` [N m] with ``t`` [s] and ``y`` the (8,)
        measurement vector in MEASURED order, called every ``dt`` seconds
        (``reset()`` is called first if it exists).  None: no feedback.
    dt : float, optional
        Controller sample time [s]. Default 0.01.
    substeps : int, optional
        RK4 steps per sample (plant step dt / substeps). Default 2 (0.005 s).
    mode : {"coast", "held"}, optional
        Rear wheel free or speed held by an ideal drive torque (:mod:`sim.nonlinear`).
        Default "coast".
    inputs : (N, 4) array_like or mapping, optional
        Open-loop inputs on the sample grid, held over each sample: an (N, 4) array
        [T_delta, T_phi, F, T_R] [N m, N m, N, N m] or a dict of name -> scalar or
        (N,) array, N = duration/dt + 1.  The open-loop T_delta adds to the controller
        command before the input effects.  T_R must be zero in held mode.
    measure : callable, optional
        ``measure(y) -> y_m`` maps the true (8,) measurement vector to the (8,) vector
        the controller sees.
    effects : sequence, optional
        :mod:`sim.effects` objects (plant and input side).
    fall_limit : float, optional
        |roll| [rad] at which the bicycle is considered fallen, in (0, pi/2].
        Default 60 deg.
    energy : bool, optional
        Record total energy (kinetic + potential) [J] at every sample.
    method : {"rk4", "reference"}, optional
        ``"rk4"`` (fixed step, numba) or ``"reference"`` (``solve_ivp`` DOP853 over
        each sample interval with ``rtol``/``atol``). Default "rk4".
    rtol, atol : float, optional
        Tolerances of the reference method. Default 1e-12.

    Returns
    -------
    Trajectory
        The run on the sample grid; shorter than N samples if it stopped early:
        ``stop`` says why (:data:`STOP_CAUSES`), ``fell_at`` is set for physical
        stops only.

    Raises
    ------
    ValueError
        If ``bike``, ``mode``, ``method``, ``dt``, ``duration`` (not a whole number of
        samples), ``substeps``, ``fall_limit``, ``x0`` (shape, finiteness, roll beyond
        the fall limit) or ``inputs`` (names, shapes, finiteness, T_R in held mode) is
        invalid, or if ``measure`` returns other than 8 values.

    Notes
    -----
    An early end is described by ``Trajectory.stop`` (:class:`Stop`); numerical
    stops (non-finite state, step too coarse) also issue a ``RuntimeWarning``.
    """
    bike = _as_bike(bike)
    held = mode == "held"
    if mode not in ("coast", "held"):
        raise ValueError(f"mode {mode!r} unknown; use 'coast' or 'held'")
    if method not in ("rk4", "reference"):
        raise ValueError(f"method {method!r} unknown; use 'rk4' or 'reference'")
    for name, value in (("dt", dt), ("duration", duration), ("fall_limit", fall_limit)):
        if isinstance(value, bool) or not isinstance(value, (int, float, np.floating)):
            raise ValueError(f"{name}={value!r} must be a number")
    if not (math.isfinite(dt) and dt > 0):
        raise ValueError(f"sample time dt={dt!r} must be a positive number of seconds")
    if not (math.isfinite(duration) and duration > 0):
        raise ValueError(f"duration={duration!r} must be a positive number of seconds")
    check_memory(
        duration / dt + 1,
        37,
        f"a {duration:g} s run at dt={dt:g} s",
        "shorten the duration or raise the sample time",
    )  # the arrays below
    nsteps = int(round(duration / dt))
    if nsteps < 1 or abs(nsteps * dt - duration) > 1e-9 * max(1.0, duration):
        raise ValueError(f"duration {duration} s is not a whole number of samples of dt={dt} s")
    if int(substeps) != substeps or substeps < 1:
        raise ValueError(f"substeps={substeps!r} must be a positive integer")
    if not (0 < fall_limit <= math.pi / 2):
        raise ValueError(f"fall_limit={fall_limit!r} rad must lie in (0, pi/2]")
    y = np.array(x0, dtype=float)
    if y.shape != (10,) or not np.all(np.isfinite(y)):
        raise ValueError(
            "x0 must be 10 finite numbers in sim.nonlinear.STATE order; build it with "
            "WhippleBicycle.state(v, phi, delta, ...)"
        )
    if abs(y[3]) > fall_limit:
        raise ValueError(f"initial roll {y[3]} rad is beyond the fall limit {fall_limit} rad")
    n = nsteps + 1
    ol = _input_array(inputs, n)
    if held and np.any(ol[:, 3] != 0.0):
        raise ValueError("open-loop T_R cannot be given in held mode (the drive holds the speed)")
    chain: InputChain = input_chain(effects, dt)
    ev = plant_vector(effects)
    if controller is not None and hasattr(controller, "reset"):
        controller.reset()

    q5g = np.array([bike.pitch(y[3], y[5])])
    info = np.zeros(4)
    t = dt * np.arange(n)
    OUT = np.empty((n, 13))  # MEASURED, q5, xR, yR, xF, yF
    Ym = np.empty((n, 8))
    U = np.zeros((n, 4))
    NC = np.full((n, 2), np.nan)  # normal forces [N_R, N_F] at each sample
    cmd = np.zeros(n)
    X = np.empty((n, 10))
    X[0] = y
    outputs(y, q5g, bike.p, OUT[0])
    E = np.empty(n) if energy else None
    nd = chain.delay_samples
    ring = np.zeros(nd + 1)  # delayed command buffer
    gain, tau = chain.gain, chain.tau
    T_applied = 0.0
    stop: Stop | None = None
    last = n - 1
    rk4 = method == "rk4"
    nsub = int(substeps)
    for k in range(n):
        if E is not None:
            ke, pe = bike.energy(X[k])
            E[k] = ke + pe
        if measure is None:
            ym = OUT[k, :8]
        else:
            ym = np.asarray(measure(OUT[k, :8].copy()), dtype=float)
            if ym.shape != (8,):
                raise ValueError(
                    f"measure hook must return 8 values (MEASURED order), got {ym.shape}"
                )
        Ym[k] = ym
        c = 0.0 if controller is None else float(controller(t[k], ym))
        if not math.isfinite(c):
            stop = Stop(
                "controller_nonfinite",
                t[k],
                f"controller returned a non-finite steer torque {c} at t={t[k]:.4f} s "
                "(a numerical failure of the controller, not a fall)",
            )
            last = k
            break
        cmd[k] = c
        ring[k % (nd + 1)] = c + ol[k, 0]
        Tc = gain * ring[(k + 1) % (nd + 1)] if nd else gain * ring[0]
        if k < nd:
            Tc = 0.0
        if tau <= 0.0:
            T_applied = Tc
        if k == n - 1:
            U[k] = ol[k]
            U[k, 0] = T_applied
            T_R = rhs_contact(X[k].copy(), q5g, bike.p, U[k].copy(), ev, held, np.empty(10),
                              NC[k])  # fmt: skip
            if held:
                U[k, 3] = T_R
            break
        if rk4:
            q5_start = q5g[0]
            status = _rk4_sample(
                k, Tc, T_applied, X, OUT, ol, U, NC, q5g, bike.p, ev, held, tau, dt, nsub,
                fall_limit, STEER_LIMIT, info,
            )  # fmt: skip
        else:
            y = X[k].copy()
            rc = ol[k].copy()
            rc[0] = Tc
            U[k] = ol[k]
            U[k, 0] = T_applied
            status = _reference_interval(
                bike, y, q5g, ev, held, rc, T_applied, tau, dt, fall_limit, STEER_LIMIT, info,
                NC[k], rtol, atol,
            )  # fmt: skip
            U[k, 3] = info[2]
            X[k + 1] = y
            if status == _OK:
                outputs(y, q5g, bike.p, OUT[k + 1])
        if status != _OK:
            t_stop = float(t[k] + info[1])
            stop = _limit_stop(status, t_stop, fall_limit, int(info[3]))
            if rk4:
                rc = ol[k].copy()
                rc[0] = Tc
                coarse = _coarse_step(
                    bike, X[k], q5_start, ev, held, rc, T_applied, tau, dt, nsub,
                    abs(float(OUT[k, 0])), f"stopped on {stop.cause} at t={t_stop:.3f} s",
                )  # fmt: skip
                if coarse is not None:
                    stop = Stop("step_too_coarse", t_stop, coarse)
            if not stop.physical:
                warnings.warn(stop.message, RuntimeWarning, stacklevel=2)
            last = k
            break
        T_applied = _lagged(T_applied, Tc, tau, dt)
    sl = slice(0, last + 1)
    return Trajectory(
        t=t[sl],
        y=OUT[sl, :8],
        measured=Ym[sl],
        theta=OUT[sl, 8] - bike.lam,
        rear=OUT[sl, 9:11],
        front=OUT[sl, 11:13],
        inputs=U[sl],
        normal_forces=NC[sl],
        command=cmd[sl],
        states=X[sl],
        fell_at=stop.time if stop is not None and stop.physical else None,
        stop_reason=None if stop is None else stop.message,
        energy=None if E is None else E[sl],
        meta={
            "mode": mode,
            "dt": dt,
            "substeps": int(substeps),
            "method": method,
            "fall_limit": fall_limit,
            "bicycle": bike.params.name,
            "lateral_force_point": list(bike.lateral_force_point),
        },
        stop=stop,
    )


def _limit_stop(status: int, t_stop: float, fall_limit: float, wheel: int = 0) -> Stop:
    """The stop the integrator's status code stands for, before the step check."""
    if status == _UNLOADED:
        return Stop(
            "wheel_unloaded",
            t_stop,
            f"fell: the {WHEELS[wheel]} wheel's normal contact force reached 0 N at "
            f"t={t_stop:.3f} s (the wheel lifts off; the Whipple model, with both wheels "
            "held on the ground, ends here)",
        )
    if status == _FELL:
        return Stop(
            "roll_limit",
            t_stop,
            f"fell: |roll| exceeded {math.degrees(fall_limit):.1f} deg at t={t_stop:.3f} s",
        )
    if status == _STEER:
        return Stop(
            "steer_limit",
            t_stop,
            f"fell: |steer| exceeded {math.degrees(STEER_LIMIT):.0f} deg at t={t_stop:.3f} s "
            "(front wheel folded)",
        )
    return Stop(
        "nonfinite_state",
        t_stop,
        f"state became non-finite (or pitch had no solution) at t={t_stop:.4f} s; "
        "integration stopped (configuration far from upright or inputs out of range?)",
    )


def _coarse_step(bike, y0, q5_start, ev, held, rc, T0, tau, dt, nsub, speed, what) -> str | None:
    """Message if the RK4 step cannot resolve the dynamics at a stop, else None.

    Two tests (module docstring): lambda h of each decaying mode of the linearized plant
    at ``speed`` against RK4's stability region (:func:`rk4_amplification`), and
    re-integration of the stop's sample interval from ``y0`` with ``nsub`` and ``2 nsub``
    steps, limits off, compared on roll and steer against :data:`STEP_CHECK_TOL`.
    """
    from .linear import eigenvalues

    h = dt / nsub
    lams = eigenvalues(bike.params, speed)
    decaying = lams[lams.real < 0]
    fix = "use a smaller --dt (sample time) or more --substeps"
    unstable = decaying[rk4_amplification(decaying * h) > 1.0]
    if unstable.size:
        lam = unstable[np.argmax(np.abs(unstable))]
        h_ok = h
        while np.any(rk4_amplification(decaying * h_ok) > 1.0):
            h_ok /= 2
        return (
            f"numerical blow-up, not a fall ({what}): the RK4 step h = {h:g} s is too "
            f"coarse at {speed:.3g} m/s (the decaying mode lambda = {lam:.1f} 1/s gives "
            f"|R(lambda h)| = {float(rk4_amplification(lam * h)):.2f} > 1, outside RK4's "
            f"stability region); {fix} so that h <= {h_ok:.3g} s"
        )
    ends = []
    for m in (nsub, 2 * nsub):
        y = np.array(y0, dtype=float)
        info = np.zeros(4)
        _rk4_interval(
            y, np.array([q5_start]), bike.p, ev, held, rc, T0, tau, dt, m, np.inf, np.inf,
            False, info, np.empty(2),
        )  # fmt: skip
        ends.append(y[[3, 5]])
    coarse, fine = ends
    if not np.all(np.isfinite(fine)):
        return None  # non-finite even with half the step: not the step's fault
    diff = float(np.max(np.abs(coarse - fine))) if np.all(np.isfinite(coarse)) else math.inf
    if diff > STEP_CHECK_TOL:
        return (
            f"numerical blow-up, not a fall ({what}): halving the RK4 step h = {h:g} s "
            f"changes roll/steer over the last sample by {diff:.3g} rad (> {STEP_CHECK_TOL} "
            f"rad); {fix}"
        )
    return None


def simulate_reference(bike, x0, duration, **kwargs) -> Trajectory:
    """:func:`simulate` with the adaptive DOP853 reference (rtol = atol = 1e-12).

    Parameters
    ----------
    bike : WhippleBicycle or BicycleParameters
        The plant.
    x0 : (10,) array_like
        Initial state, :data:`sim.nonlinear.STATE` order.
    duration : float
        Simulated time [s].
    **kwargs
        Further :func:`simulate` keywords; ``method`` defaults to ``"reference"``.

    Returns
    -------
    Trajectory

    Raises
    ------
    ValueError
        As :func:`simulate`.
    """
    kwargs.setdefault("method", "reference")
    return simulate(bike, x0, duration, **kwargs)


def _simulate_kwargs(kwargs: Mapping[str, Any]) -> Trajectory:
    kw = dict(kwargs)
    try:
        bike, x0, duration = kw.pop("bike"), kw.pop("x0"), kw.pop("duration")
    except KeyError as exc:
        raise ValueError(f"each run needs 'bike', 'x0' and 'duration'; missing {exc}") from None
    return simulate(bike, x0, duration, **kw)


def simulate_many(runs: Sequence[Mapping[str, Any]], processes: int = 1) -> list[Trajectory]:
    """Simulate several runs, optionally in parallel processes.

    Parameters
    ----------
    runs : sequence of mapping
        Each a dict of :func:`simulate` arguments: ``bike``, ``x0``, ``duration`` and
        keywords.
    processes : int, optional
        Number of worker processes. ``processes`` > 1 uses a process pool
        (controllers and hooks must then be picklable). Default 1 (serial).

    Returns
    -------
    list of Trajectory
        One per run, in the order of ``runs``.

    Raises
    ------
    ValueError
        If a run lacks ``bike``, ``x0`` or ``duration``, or :func:`simulate` refuses
        its arguments.
    """
    runs = list(runs)
    if processes <= 1 or len(runs) <= 1:
        return [_simulate_kwargs(r) for r in runs]
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(max_workers=int(processes)) as pool:
        return list(pool.map(_simulate_kwargs, runs))
