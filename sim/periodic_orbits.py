"""Periodic coasting orbits of the nonlinear Whipple bicycle: Poincare map, Newton
refinement of its fixed point and the Floquet multipliers.

Section (as in :mod:`experiments.papers.limit_cycles`): phidot = 0 with phidot decreasing (roll
maxima).  A point on it is z = (phi, delta, deltadot, v) [rad, rad, rad/s, m/s]; the full
state is :meth:`sim.nonlinear.WhippleBicycle.state` (v, phi, delta, 0, deltadot) (heading,
position and wheel angles are cyclic: the dynamics do not depend on them).  The map
P^p(z) integrates the coasting equations (rear wheel free, no inputs) with
``scipy.integrate.solve_ivp`` DOP853 (the integrator of :func:`sim.integrate.simulate_reference`)
at rtol = atol = :data:`RTOL` through p downward crossings of phidot = 0, located by the
integrator's event root finder (dense output, to the tolerance).

A period-p orbit is a fixed point z* = P^p(z*).  Coasting conserves energy, so the orbits
form a one-parameter family (one per energy level) and DP^p - I is singular along the
family: Newton solves P^p(z) = z together with E(z) = E0 (the initial condition's energy)
by least squares, which picks the orbit on that level.  The multipliers are the
eigenvalues of the Jacobian DP^p(z*), by central differences with step :data:`FD_STEP` in
every coordinate; one of them is 1 (the energy direction), a check of the computation.
They are the nontrivial Floquet multipliers of the orbit (the monodromy matrix's
eigenvalues without the trivial one along the flow), independent of the section chosen.
Error budget of the Jacobian: truncation O(h^2 |P'''|) ~ 1e-10, integration error / h
~ 1e-12 / 1e-5 = 1e-7.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from bikeid.sim.errors import UntrustworthyResult
from bikeid.sim.integrate import DEFAULT_FALL_LIMIT
from bikeid.sim.nonlinear import WhippleBicycle
from bikeid.sim.parameters import BicycleParameters

__all__ = [
    "FD_STEP",
    "RTOL",
    "OrbitProfile",
    "OrbitStability",
    "orbit_profile",
    "orbit_stability",
    "poincare_map",
]

RTOL = 1e-12  #: rtol = atol of the DOP853 integration of the Poincare map
FD_STEP = 1e-5  #: central-difference step of the Jacobian [rad, rad/s, m/s]
FALL = DEFAULT_FALL_LIMIT  # the simulator's fall limit, so both call the same motion a fall


def _start(bike: WhippleBicycle, z: np.ndarray) -> np.ndarray:
    return bike.state(float(z[3]), float(z[0]), float(z[1]), 0.0, float(z[2]))


def poincare_map(
    bike: WhippleBicycle, z: np.ndarray, returns: int = 1, rtol: float = RTOL
) -> tuple[np.ndarray, float]:
    """Image of a section point after ``returns`` downward crossings of phidot = 0.

    Parameters
    ----------
    bike : WhippleBicycle
        The plant (coasting, no inputs).
    z : (4,) array_like
        Section point (phi [rad], delta [rad], deltadot [rad/s], v [m/s]).
    returns : int, optional
        Number of crossings p. Default 1.
    rtol : float, optional
        rtol = atol of DOP853. Default :data:`RTOL`.

    Returns
    -------
    z_next : (4,) ndarray
        The section point after p returns, same units.
    time : float
        Time taken by the p returns [s].

    Raises
    ------
    UntrustworthyResult
        If the bicycle falls (|roll| > 60 deg) or no crossing occurs within 60 s per return.
    """
    from scipy.integrate import solve_ivp

    f = bike.ode()

    def cross(_t, y):
        return y[7]

    cross.terminal, cross.direction = True, -1

    def fall(_t, y):
        return abs(y[3]) - FALL

    fall.terminal = True
    y = _start(bike, np.asarray(z, float))
    t = 0.0
    for k in range(returns):
        # leave the section first: at t = 0 phidot = 0 and falling, which the event
        # detector would count as a crossing
        s = solve_ivp(f, (t, t + 0.05), y, method="DOP853", rtol=rtol, atol=rtol)
        t, y = s.t[-1], s.y[:, -1]
        s = solve_ivp(
            f, (t, t + 60.0), y, method="DOP853", rtol=rtol, atol=rtol, events=(cross, fall)
        )
        if s.status != 1 or s.t_events[0].size == 0:
            raise UntrustworthyResult(
                f"no return to the section phidot = 0 (return {k + 1} of {returns}): the "
                "motion fell or left the section; this is not a periodic orbit"
            )
        t, y = float(s.t_events[0][0]), s.y_events[0][0]
    return np.array([y[3], y[5], y[9], -bike.rR * y[8]]), t


@dataclass(frozen=True)
class OrbitStability:
    """Converged periodic orbit and its multipliers (angles deg, rates deg/s, speed m/s).

    ``section_point`` is z* = (phi, delta, deltadot, v); ``residual`` = max |P^p(z*) - z*|
    [rad, rad/s, m/s]; ``multipliers`` the eigenvalues of DP^p, sorted by modulus, largest
    first; ``unit_multiplier_error`` = min |mu - 1|; ``seconds`` the wall time.

    Attributes
    ----------
    returns_per_period : int
        Section returns p per period.
    period : float
        Period of the converged orbit [s].
    section_point : tuple of 4 float
        Fixed point z* of P^p: phi [deg], delta [deg], deltadot [deg/s], v [m/s].
    residual : float
        max |P^p(z*) - z*| [rad, rad/s, m/s mixed].
    newton_iterations : int
        Newton steps taken.
    multipliers : tuple of complex
        Eigenvalues of the Jacobian DP^p [-], by decreasing modulus.
    unit_multiplier_error : float
        min |mu - 1| [-]: the energy direction's multiplier is 1 exactly in the model.
    energy : float
        Total energy of the orbit [J].
    seconds : float
        Wall time of the computation [s].
    """

    returns_per_period: int
    period: float
    section_point: tuple[float, float, float, float]
    residual: float
    newton_iterations: int
    multipliers: tuple[complex, ...]
    unit_multiplier_error: float
    energy: float
    seconds: float


def _jacobian(bike: WhippleBicycle, z: np.ndarray, p: int, h: float) -> np.ndarray:
    J = np.empty((4, 4))
    for j in range(4):
        e = np.zeros(4)
        e[j] = h
        J[:, j] = (poincare_map(bike, z + e, p)[0] - poincare_map(bike, z - e, p)[0]) / (2 * h)
    return J


def _energy(bike: WhippleBicycle, z: np.ndarray) -> float:
    ke, pe = bike.energy(_start(bike, z))
    return ke + pe


def orbit_stability(
    p: BicycleParameters,
    z0_deg: np.ndarray,
    returns: int,
    energy: float | None = None,
    tol: float = 1e-10,
    max_iter: int = 8,
    jacobian_at_end: bool = True,
) -> OrbitStability:
    """Newton-converge a period-``returns`` orbit from a section point and get its multipliers.

    Parameters
    ----------
    p : BicycleParameters
        The bicycle.
    z0_deg : (4,) array_like
        Starting section point (phi [deg], delta [deg], deltadot [deg/s], v [cm/s]), the
        units of :func:`experiments.papers.limit_cycles.section_points`.
    returns : int
        Returns to the section per period (p >= 1).
    energy : float, optional
        Total energy [J] of the wanted orbit (the initial condition's: coasting conserves
        it).  Newton then solves P^p(z) = z together with E(z) = energy, which picks the
        one orbit of the family on that level (so mirrored initial conditions give exactly
        mirrored orbits).  None: the minimum-norm step, the level near the start.
    tol : float, optional
        Stop when max |P^p(z) - z| < tol [rad, rad/s, m/s]. Default 1e-10.
    max_iter : int, optional
        Newton iterations at most. Default 8.
    jacobian_at_end : bool, optional
        True (default): the multipliers from a Jacobian computed at the converged z*.
        False: from the last Newton iteration's Jacobian (at a point one Newton step,
        below 1e-4 here, from z*, so the multipliers move by O(step) ~ 1e-4 or less), which
        saves 2 x 4 map evaluations: for a verdict (inside the unit circle or not), not for
        quoting multipliers to 1e-7.

    Returns
    -------
    OrbitStability

    Raises
    ------
    UntrustworthyResult
        If Newton does not reach ``tol`` within ``max_iter`` iterations (no periodic
        orbit near the start) or the map cannot be evaluated (fall).
    """
    t0 = time.perf_counter()
    bike = WhippleBicycle(p)
    z0 = np.asarray(z0_deg, float)
    z = np.array([math.radians(z0[0]), math.radians(z0[1]), math.radians(z0[2]), z0[3] / 100])
    it = 0
    while True:
        zn, period = poincare_map(bike, z, returns)
        res = float(np.max(np.abs(zn - z)))
        de = 0.0 if energy is None else _energy(bike, z) - energy
        if res < tol and abs(de) < tol * max(1.0, abs(energy or 0.0)):
            break
        if it >= max_iter:
            raise UntrustworthyResult(
                f"Newton on the period-{returns} Poincare map did not converge "
                f"(residual {res:.2e} after {it} iterations): no periodic orbit near "
                f"{z0_deg}; run the coasting motion longer"
            )
        J = _jacobian(bike, z, returns, FD_STEP)
        A, r = J - np.eye(4), -(zn - z)
        if energy is not None:
            g = np.empty(4)
            for j in range(4):
                e = np.zeros(4)
                e[j] = FD_STEP
                g[j] = (_energy(bike, z + e) - _energy(bike, z - e)) / (2 * FD_STEP)
            # energy row scaled to the size of the map rows (E ~ 1e3 J, dE/dz ~ 1e3)
            w = 1.0 / np.linalg.norm(g)
            A, r = np.vstack([A, w * g]), np.append(r, -w * de)
        z = z + np.linalg.lstsq(A, r, rcond=1e-10)[0]
        it += 1
    if jacobian_at_end or it == 0:
        J = _jacobian(bike, z, returns, FD_STEP)
    mu = np.linalg.eigvals(J)
    mu = mu[np.argsort(-np.abs(mu))]
    return OrbitStability(
        returns_per_period=returns,
        period=period,
        section_point=(
            math.degrees(z[0]),
            math.degrees(z[1]),
            math.degrees(z[2]),
            float(z[3]),
        ),
        residual=res,
        newton_iterations=it,
        multipliers=tuple(complex(m) for m in mu),
        unit_multiplier_error=float(np.min(np.abs(mu - 1.0))),
        energy=_energy(bike, z),
        seconds=time.perf_counter() - t0,
    )


@dataclass(frozen=True)
class OrbitProfile:
    """Roll and speed over one period of a converged orbit (angles deg, speed m/s, time s).

    Attributes
    ----------
    roll_min, roll_max : float
        Extreme roll angles over the period [deg], positive to the right.
    roll_mean : float
        Time-averaged roll over the period [deg].
    speed_mean : float
        Time-averaged forward speed over the period [m/s].
    speed_range : (float, float)
        Minimum and maximum forward speed over the period [m/s].
    period : float
        Duration of the period [s].
    """

    roll_min: float
    roll_max: float
    roll_mean: float
    speed_mean: float
    speed_range: tuple[float, float]
    period: float


def orbit_profile(
    p: BicycleParameters, section_point: tuple[float, ...], period: float, samples: int = 4000
) -> OrbitProfile:
    """Roll extremes, mean roll and mean speed over one period of an orbit.

    Integrates the coasting equations from the orbit's section point for one period
    (DOP853, rtol = atol = :data:`RTOL`, dense output) and averages over ``samples``
    uniformly spaced times (trapezoidal rule; the integrand is smooth and periodic, so the
    rule's error is far below the integration tolerance at 4000 samples).

    Parameters
    ----------
    p : BicycleParameters
        The bicycle.
    section_point : tuple of 4 float
        :attr:`OrbitStability.section_point`: phi [deg], delta [deg], deltadot [deg/s],
        v [m/s].
    period : float
        The orbit's period [s] (:attr:`OrbitStability.period`).
    samples : int, optional
        Samples over the period. Default 4000.

    Returns
    -------
    OrbitProfile

    Raises
    ------
    UntrustworthyResult
        If the integration stops before the period ends.
    """
    from scipy.integrate import solve_ivp

    if not period > 0:
        raise ValueError(f"period {period} s: an orbit's period must be positive")
    bike = WhippleBicycle(p)
    phi, delta, deltadot, v = (float(x) for x in section_point)
    y0 = bike.state(v, math.radians(phi), math.radians(delta), 0.0, math.radians(deltadot))
    s = solve_ivp(
        bike.ode(), (0.0, period), y0, method="DOP853", rtol=RTOL,
        atol=RTOL, dense_output=True,
    )  # fmt: skip
    if s.status != 0:
        raise UntrustworthyResult(f"orbit integration stopped before one period: {s.message}")
    t = np.linspace(0.0, period, samples)
    y = s.sol(t)
    roll, speed = np.degrees(y[3]), -bike.rR * y[8]
    return OrbitProfile(
        roll_min=float(roll.min()),
        roll_max=float(roll.max()),
        roll_mean=float(np.trapezoid(roll, t) / period),
        speed_mean=float(np.trapezoid(speed, t) / period),
        speed_range=(float(speed.min()), float(speed.max())),
        period=float(period),
    )
