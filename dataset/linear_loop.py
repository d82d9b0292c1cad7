"""Exact zero-order-hold closed loop of the *linear* Whipple bicycle: the linear engine.

The one linear closed-loop simulator of bikeid (the nonlinear one is
:mod:`dataset.closed_loop`): a second-method plant next to the nonlinear simulator, and the
plant of the identification tests, where every quantity the identifiers estimate is known
exactly.

Model (``sim.linear.state_matrices``), x = [phi, delta, phidot, deltadot]::

    x' = A(v) x + B(v) [T_phi, T_delta + w, F]

The controller (any :mod:`controllers` controller) runs at its ``sample_time`` dt, which is
also the logging period: every controller sample is logged, so the logged steer torque is
exactly the torque the plant held over [t_k, t_k+1) (the sampling contract of
``ident.signals.check_sampling``).  The disturbance w (unlogged steer torque, "process
noise"), the dither (held ``dither_hold`` whole samples), the roll torque and the lateral
force are held the same way, so the sampled plant x[k+1] = Ad x[k] + Bd u[k] is *exact*
(``sim.sampling.zoh``), not an integration with truncation error.  With per-sample speed
variation the speed is held over each sample as well (exact for that piecewise-constant
speed).

Controllers see the *measured* vector (``sim.conventions.MEASURED`` order, sensor noise
included), so noise circulates through the loop.  Two paths, same loop:

- compiled (numba): for controllers whose law is linear in the measurement
  (:meth:`controllers.base.Controller.linear_law`: PID, pole placement, steer-into-lean
  without saturation)::

      u[k]    = L @ x_meas[k] + l_i xi[k] + l_r r[k] + l_rd r'[k] + dither[k]
      xi[k+1] = xi[k] + dt (r[k] - phi_meas[k])

  with r = ``controller.reference`` at t_k and r' its ``rate`` (a backward difference
  over dt, zero at the first sample, when the reference has no rate);
- Python: any other controller (fuzzy, saturating laws) is called as
  ``controller(t_k, y_meas) + dither[k]`` once per sample.

Both give the same run to round-off for a linear law (``tests/dataset/test_closed_loop.py``).

Exact accelerations ``truth['phiddot'], truth['deltaddot']`` are
q''(t_k+) = A[2:4] x[k] + B[2:4] u_applied[k], the right limit at the sample (the input
changes at t_k): they satisfy M q'' + v C1 q' + (g K0 + v^2 K2) q = T + H F to round-off
with the *applied* torques in ``truth``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import numba
import numpy as np

from bikeid.controllers.base import DEFAULT_SAMPLE_TIME, Controller, LinearLaw
from bikeid.controllers.pid import PID
from bikeid.sim.errors import UntrustworthyResult
from bikeid.sim.linear import lateral_force_vector, state_matrices, yaw_rate
from bikeid.sim.parameters import BicycleParameters
from bikeid.sim.sampling import zoh

from .run import Run

__all__ = ["PATHS", "closed_loop_matrix", "run_loop", "simulate", "sweep"]

#: Loop implementations of :func:`simulate` (``path=``).
PATHS = ("auto", "compiled", "python")


def _describe(obj: Any) -> Any:
    """The description stored in a run's meta of a controller, reference, dither, ..."""
    if obj is None:
        return None
    if hasattr(obj, "describe"):
        return obj.describe()
    return {"name": getattr(obj, "__name__", type(obj).__name__)}


def _law(controller: Controller, v: float) -> LinearLaw | None:
    law = getattr(controller, "linear_law", None)
    return None if law is None else law(v)


def closed_loop_matrix(
    p: BicycleParameters, v: float, controller: Controller, dt: float
) -> np.ndarray:
    """The sampled closed-loop matrix of [x, xi] for a linear law (noise-free measurement).

    Parameters
    ----------
    p : BicycleParameters
        The bicycle.
    v : float
        Forward speed [m/s] of the plant and of the controller's gains.
    controller : Controller
        A controller with a :meth:`~controllers.base.Controller.linear_law` at ``v``.
    dt : float
        Controller (= sample) period [s].

    Returns
    -------
    (5, 5) ndarray
        z[k+1] = Acl z[k] with z = [phi, delta, phidot, deltadot, xi] (reference zero).

    Raises
    ------
    ValueError
        If the controller has no linear law at ``v``.
    """
    law = _law(controller, v)
    if law is None:
        raise ValueError(
            f"controller {type(controller).__name__} has no linear law (nonlinear or "
            "saturating): no closed-loop matrix"
        )
    A, B = state_matrices(p, v)
    Ad, Bd = zoh(A, B[:, 1:2], dt)
    Acl = np.zeros((5, 5))
    Acl[:4, :4] = Ad + Bd @ np.asarray(law.L, dtype=float)[None, :]
    Acl[:4, 4] = Bd[:, 0] * law.l_i
    Acl[4, 0] = -dt
    Acl[4, 4] = 1.0
    return Acl


@numba.njit(cache=True)
def _loop(Ad, Bd, Ac, Bc, x0, L, li, lr, lrd, dt, ref, rdot, dither, w, tphi, force, nmeas):
    n = ref.shape[0]
    X = np.empty((n, 4))
    U = np.empty(n)
    Qdd = np.empty((n, 2))
    x = x0.copy()
    xi = 0.0
    for k in range(n):
        ka = k if Ad.shape[0] > 1 else 0
        X[k] = x
        y = x + nmeas[k]
        u = li * xi + lr * ref[k] + lrd * rdot[k] + dither[k]
        for j in range(4):
            u += L[j] * y[j]
        U[k] = u
        inp = np.array([tphi[k], u + w[k], force[k]])
        for j in range(2):
            acc = 0.0
            for i in range(4):
                acc += Ac[ka, 2 + j, i] * x[i]
            for i in range(3):
                acc += Bc[ka, 2 + j, i] * inp[i]
            Qdd[k, j] = acc
        xn = np.zeros(4)
        for r in range(4):
            acc = 0.0
            for i in range(4):
                acc += Ad[ka, r, i] * x[i]
            for i in range(3):
                acc += Bd[ka, r, i] * inp[i]
            xn[r] = acc
        xi += dt * (ref[k] - y[0])
        x = xn
    return X, U, Qdd


def _python_loop(p, Ad, Bd, Ac, Bc, x0, controller, t, v, dither, w, tphi, force, nmeas,
                 psi_noise, yaw_noise, limit):  # fmt: skip
    """The same loop, calling ``controller(t_k, y_meas)``; stops early past ``limit`` rad."""
    n = t.size
    X = np.full((n, 4), np.nan)
    U = np.full(n, np.nan)
    Qdd = np.full((n, 2), np.nan)
    x = np.array(x0, dtype=float)
    k_yaw = math.cos(p.lam) / p.w
    psi = 0.0
    psidot_prev = 0.0
    dt = float(t[1] - t[0])
    for k in range(n):
        ka = k if Ad.shape[0] > 1 else 0
        X[k] = x
        if not (np.all(np.isfinite(x)) and abs(x[0]) <= limit and abs(x[1]) <= limit):
            break
        psidot = (v[k] * x[1] + p.c * x[3]) * k_yaw
        if k:
            psi = psi + 0.5 * (psidot_prev + psidot) * dt
        psidot_prev = psidot
        ym = x + nmeas[k]
        y = [float(v[k]), ym[0], ym[1], psi + psi_noise[k], ym[2], ym[3],
             psidot + yaw_noise[k], -float(v[k]) / p.rR]  # fmt: skip
        u = float(controller(float(t[k]), y)) + dither[k]
        U[k] = u
        inp = np.array([tphi[k], u + w[k], force[k]])
        Qdd[k] = Ac[ka, 2:4] @ x + Bc[ka, 2:4] @ inp
        x = Ad[ka] @ x + Bd[ka] @ inp
    return X, U, Qdd


def _plant(
    p: BicycleParameters, v: np.ndarray | float, dt: float, Hcol: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Continuous (Ac, Bc) and ZOH-sampled (Ad, Bd) plant with inputs [T_phi, T_delta, F],
    stacked over the speeds ``v`` (an array: one per sample) or of one speed (a float)."""
    if np.ndim(v):
        AB = [state_matrices(p, vk) for vk in v]
        Ac = np.array([a for a, _ in AB])
        Bc = np.array([np.hstack([b, (b[:, :2] @ Hcol)[:, None]]) for _, b in AB])
    else:
        A, B = state_matrices(p, float(v))
        Ac, Bc = A[None], np.hstack([B, (B[:, :2] @ Hcol)[:, None]])[None]
    Ad, Bd = zoh(Ac, Bc, dt)
    return Ac, Bc, Ad, Bd


def run_loop(
    p: BicycleParameters,
    controller: Callable[[float, Sequence[float]], float],
    speed: float,
    n: int,
    dt: float,
    x0: Sequence[float],
    force: np.ndarray | None = None,
    lateral_force_point: tuple[float, float] | None = None,
    limit: float = 1.0,
) -> dict[str, np.ndarray]:
    """The exact ZOH linear plant under any controller callable, one call per sample.

    The loop of :func:`simulate`'s Python path with nothing added by the engine: the
    controller receives the *true* measurement vector (``sim.conventions.MEASURED`` order)
    and returns the steer torque the plant holds over [t_k, t_k+1), so sensors and dither
    are the controller callable's business (``dataset.closed_loop.simulate_run(...,
    plant="linear")`` passes its sampled loop, the one the nonlinear plant runs under).

    Parameters
    ----------
    p : BicycleParameters
        The bicycle.
    controller : callable
        ``controller(t [s], y_true)`` -> applied steer torque [N m] (positive to the right).
    speed : float
        Forward speed [m/s], held.
    n : int
        Samples t_k = k dt, k = 0 .. n-1 (>= 2).
    dt : float
        Sample (= controller) period [s].
    x0 : sequence of 4 floats
        Initial [phi, delta, phidot, deltadot] [rad, rad/s].
    force : (n,) ndarray, optional
        Lateral force F [N] held over each sample (positive right); None for none.
    lateral_force_point : (float, float), optional
        (x_F, z_F) [m] where F acts on the rear frame (benchmark axes); default the rear
        body's mass centre (xB, zB), as the nonlinear plant (``sim.nonlinear``).
    limit : float, optional
        The loop stops (the rest NaN) once |phi| or |delta| exceeds it [rad].

    Returns
    -------
    dict of str to (n,) ndarray
        ``t`` [s], the states ``phi``, ``delta`` [rad], ``phidot``, ``deltadot`` [rad/s],
        ``phiddot``, ``deltaddot`` (the exact right-limit accelerations [rad/s^2]),
        ``psi`` [rad], ``psidot`` [rad/s] (linearized yaw), ``T_delta`` (applied [N m])
        and ``F`` [N]; NaN after a stop.

    Raises
    ------
    ValueError
        If ``n`` < 2, ``dt`` or ``speed`` is not positive and finite, ``x0`` is not 4
        values or ``force`` has another length.
    """
    n = int(n)
    if n < 2 or not (math.isfinite(dt) and dt > 0) or not (math.isfinite(speed) and speed > 0):
        raise ValueError(f"need n >= 2, dt > 0 and speed > 0; got n={n}, dt={dt}, speed={speed}")
    x_init = np.asarray(x0, dtype=float)
    if x_init.shape != (4,):
        raise ValueError(f"x0 has shape {x_init.shape}; need [phi, delta, phidot, deltadot]")
    force = np.zeros(n) if force is None else np.asarray(force, dtype=float)
    if force.shape != (n,):
        raise ValueError(f"force has shape {force.shape}, expected ({n},)")
    point = (p.xB, p.zB) if lateral_force_point is None else lateral_force_point
    Ac, Bc, Ad, Bd = _plant(p, speed, dt, lateral_force_vector(p, *point))
    t = np.arange(n) * dt
    v = np.full(n, float(speed))
    zero = np.zeros(n)
    X, U, Qdd = _python_loop(
        p, Ad, Bd, Ac, Bc, x_init, controller, t, v, zero, zero, zero, force,
        np.zeros((n, 4)), zero, zero, limit,
    )  # fmt: skip
    psidot = yaw_rate(p, v, X[:, 1], X[:, 3])
    psi = np.concatenate([[0.0], np.cumsum(0.5 * (psidot[1:] + psidot[:-1]) * dt)])
    return {
        "t": t, "phi": X[:, 0], "delta": X[:, 1], "phidot": X[:, 2], "deltadot": X[:, 3],
        "phiddot": Qdd[:, 0], "deltaddot": Qdd[:, 1], "psi": psi, "psidot": psidot,
        "T_delta": U, "F": force,
    }  # fmt: skip


def _held(rng: np.random.Generator, n: int, amplitude: float, hold: int) -> np.ndarray:
    """Uniform pseudo-random in [-amplitude, amplitude], each value held ``hold`` samples."""
    if amplitude == 0.0:
        return np.zeros(n)
    m = -(-n // hold)
    return np.repeat(rng.uniform(-amplitude, amplitude, m), hold)[:n]


class _SampledReference:
    """A reference given as one value per sample, held over the sample (ZOH)."""

    def __init__(self, values: np.ndarray, dt: float):
        self.values = values
        self.dt = dt

    def __call__(self, t: float) -> float:
        k = min(max(int(round(t / self.dt)), 0), self.values.size - 1)
        return float(self.values[k])

    def describe(self) -> dict[str, Any]:
        return {"name": "sampled", "samples": int(self.values.size)}


def _resolve(controller, dt):
    if controller is None:
        dt = DEFAULT_SAMPLE_TIME if dt is None else float(dt)
        if not (math.isfinite(dt) and dt > 0):
            raise ValueError(f"dt={dt}: need a sample period > 0 s")
        return PID(sample_time=dt), dt
    ts = float(controller.sample_time)
    if dt is None:
        return controller, ts
    dt = float(dt)
    if not math.isclose(dt, ts, rel_tol=1e-9):
        raise ValueError(
            f"dt={dt} s differs from the controller's sample_time={ts} s: the linear engine "
            "logs every controller sample (logging period = controller period); build the "
            f"controller with sample_time={dt} or leave dt unset"
        )
    return controller, ts


def simulate(
    p: BicycleParameters,
    speed: float,
    duration: float = 50.0,
    dt: float | None = None,
    controller: Controller | None = None,
    *,
    seed: int = 0,
    dither: float = 1.0,
    dither_hold: int = 1,
    disturbance: float = 0.0,
    roll_torque: float = 0.0,
    lateral_force: float = 0.0,
    lateral_force_point: tuple[float, float] = (0.5, -1.0),
    angle_noise: float = 0.0,
    rate_noise: float = 0.0,
    torque_noise: float = 0.0,
    speed_variation: float = 0.0,
    speed_period: float = 10.0,
    reference: Callable[[float], float] | Sequence[float] | np.ndarray | None = None,
    x0: Sequence[float] | None = None,
    path: str = "auto",
) -> Run:
    """One closed-loop run of the linear bicycle, exact ZOH, as a :class:`dataset.run.Run`.

    Every random signal is white and drawn from ``seed`` (same order as the former
    ``sim.linear_sim``: dither, disturbance, roll torque, lateral force, angle and rate
    noise, logged-torque noise, yaw-rate noise, yaw-angle noise).

    Parameters
    ----------
    p : BicycleParameters
        The bicycle.
    speed : float
        Nominal forward speed v [m/s], >= 0.
    duration : float
        Run length [s]; N = round(duration / dt) samples at t_k = k dt.
    dt : float, optional
        Sample period [s] = controller period = logging period.  Default: the
        controller's ``sample_time``, or :data:`controllers.base.DEFAULT_SAMPLE_TIME`
        (0.01 s) without a controller.  A value different from the controller's
        ``sample_time`` raises ValueError.
    controller : Controller, optional
        Any :mod:`controllers` controller; default ``controllers.PID(sample_time=dt)`` with
        the default gains (-200, -500, -80), which stabilize the linear benchmark from 1
        to 15 m/s.  It is ``reset()`` before the run.
    seed : int
        Seed of every random signal.
    dither : float
        Amplitude [N m] of the uniform steer-torque dither (logged, part of T_delta).
    dither_hold : int
        Samples each dither value is held (>= 1; the dither hold is dither_hold * dt).
    disturbance : float
        Standard deviation [N m] of a white steer torque added to the plant input but
        *not* logged (unmeasured disturbance, process noise).
    roll_torque : float
        Amplitude [N m] of a uniform roll torque T_phi (logged).
    lateral_force : float
        Amplitude [N] of a uniform lateral force F (positive right, logged).
    lateral_force_point : (float, float)
        (x_F, z_F) [m] of the force on the rear frame in benchmark axes (x forward from
        the rear contact, z down, so the default acts 1 m above the ground;
        ``sim.linear.lateral_force_vector``).
    angle_noise, rate_noise : float
        Standard deviations of white measurement noise on phi, delta, psi [rad] and
        phidot, deltadot, psidot [rad/s]; the controller sees it.
    torque_noise : float
        Standard deviation [N m] of white noise on the *logged* T_delta only (the plant
        receives the true torque).
    speed_variation, speed_period : float
        v(t) = speed + speed_variation sin(2 pi t / speed_period) [m/s, s], held per
        sample (per-sample speed for the direct method).  A controller scheduled on the
        measured speed then runs on the Python path.
    reference : callable or (N,) array, optional
        Roll reference r [rad]: installed as ``controller.reference`` (an array is held
        over each sample); None keeps the controller's own (default zero).
    x0 : sequence of 4 floats, optional
        Initial state [phi, delta, phidot, deltadot] [rad, rad/s]; default (0.01, 0, 0, 0).
    path : {"auto", "compiled", "python"}
        "auto" uses the compiled loop when the controller has a linear law (and is not
        scheduled on a varying speed), else the Python loop; "python" forces the
        per-sample Python loop; "compiled" refuses controllers without a linear law.

    Returns
    -------
    Run
        ``signals`` (measured, MEASURED channels plus T_delta, T_phi, F), ``truth``
        (noise-free, the *applied* T_delta = command + disturbance, and the exact
        accelerations phiddot, deltaddot), ``dither`` [N m], ``reference`` [rad] and
        ``meta`` (with ``meta["sampling"]``: controller period, logging period and dither
        hold [s], all equal to or whole multiples of dt).

    Raises
    ------
    ValueError
        On bad arguments; when the sampled closed loop of a linear law is unstable at the
        nominal speed (spectral radius >= 1); when the run leaves the small-angle range
        (|phi| or |delta| > 1 rad).
    """
    if not (math.isfinite(speed) and speed >= 0):
        raise ValueError(f"speed {speed}: need a finite speed >= 0 m/s")
    if path not in PATHS:
        raise ValueError(f"path={path!r}: choose one of {PATHS}")
    controller, dt = _resolve(controller, dt)
    if not (dt > 0 and math.isfinite(duration) and duration >= 2 * dt):
        raise ValueError(
            f"need dt > 0 and a finite duration >= 2 dt, got dt={dt}, duration={duration}"
        )
    if not (math.isfinite(speed_period) and speed_period > 0):
        raise ValueError(f"speed_period={speed_period}: need a finite period > 0 s")
    if int(dither_hold) != dither_hold or dither_hold < 1:
        raise ValueError(f"dither_hold={dither_hold}: need a whole number of samples >= 1")
    dither_hold = int(dither_hold)
    for name, val in (
        ("dither", dither), ("disturbance", disturbance), ("roll_torque", roll_torque),
        ("lateral_force", lateral_force), ("angle_noise", angle_noise),
        ("rate_noise", rate_noise), ("torque_noise", torque_noise),
        ("speed_variation", speed_variation),
    ):  # fmt: skip
        if not (math.isfinite(val) and val >= 0):
            raise ValueError(f"{name}={val}: need a finite value >= 0")
    if speed_variation >= speed > 0:
        raise ValueError(
            f"speed_variation={speed_variation} m/s reaches the speed {speed} m/s: the bicycle "
            "would stop or reverse; use an amplitude below the speed"
        )
    n = int(round(duration / dt))
    t = np.arange(n) * dt
    if reference is not None:
        if callable(reference):
            controller.reference = reference
        else:
            arr = np.asarray(reference, dtype=float)
            if arr.shape != (n,):
                raise ValueError(f"reference has shape {arr.shape}, expected ({n},)")
            controller.reference = _SampledReference(arr, dt)
    controller.reset()
    ref_fn = controller.reference
    ref = np.array([float(ref_fn(tk)) for tk in t])

    law = _law(controller, speed)
    if path == "compiled" and law is None:
        raise ValueError(
            f"path='compiled' needs a controller with a linear law; {type(controller).__name__}"
            " has none (nonlinear or saturating): use path='python' or 'auto'"
        )
    varying = speed_variation > 0 and bool(getattr(controller, "speed_scheduled", True))
    if path == "compiled" and varying:
        raise ValueError(
            "path='compiled' holds the gains at the nominal speed, but this controller is "
            "scheduled on the measured speed, which varies: use path='python' or 'auto'"
        )
    compiled = law is not None and not varying and path != "python"
    if law is not None:
        Acl = closed_loop_matrix(p, speed, controller, dt)
        if law.l_i == 0.0:  # the integrator state does not feed back
            Acl = Acl[:4, :4]
        rho = np.max(np.abs(np.linalg.eigvals(Acl)))
        if rho >= 1.0:
            raise ValueError(
                f"the controller {_describe(controller)} does not stabilize the sampled loop "
                f"at v={speed} m/s (spectral radius {rho:.4f}); choose other gains or speed"
            )

    rng = np.random.default_rng(seed)
    d = _held(rng, n, dither, dither_hold)
    w = rng.normal(0.0, disturbance, n) if disturbance else np.zeros(n)
    tphi = _held(rng, n, roll_torque, 1)
    force = _held(rng, n, lateral_force, 1)
    nmeas = np.zeros((n, 4))
    if angle_noise:
        nmeas[:, :2] = rng.normal(0.0, angle_noise, (n, 2))
    if rate_noise:
        nmeas[:, 2:] = rng.normal(0.0, rate_noise, (n, 2))
    log_noise = rng.normal(0.0, torque_noise, n) if torque_noise else np.zeros(n)
    yaw_noise = rng.normal(0.0, rate_noise, n) if rate_noise else np.zeros(n)
    psi_noise = rng.normal(0.0, angle_noise, n) if angle_noise else np.zeros(n)

    v = speed + speed_variation * np.sin(2 * np.pi * t / speed_period)
    Hcol = lateral_force_vector(p, *lateral_force_point)
    Ac, Bc, Ad, Bd = _plant(p, v if speed_variation else speed, dt, Hcol)
    x_init = np.array([0.01, 0.0, 0.0, 0.0] if x0 is None else x0, dtype=float)
    if x_init.shape != (4,):
        raise ValueError(f"x0 has shape {x_init.shape}; need [phi, delta, phidot, deltadot]")
    if compiled:
        rdot = np.zeros(n)
        if law.l_rd != 0.0:
            rate = getattr(ref_fn, "rate", None)
            if rate is not None:
                rdot = np.array([float(rate(tk)) for tk in t])
            else:
                rdot[1:] = np.diff(ref) / dt
        X, U, Qdd = _loop(
            Ad, Bd, Ac, Bc, x_init, np.asarray(law.L, dtype=float), float(law.l_i),
            float(law.l_r), float(law.l_rd), dt, ref, rdot, d, w, tphi, force, nmeas,
        )  # fmt: skip
    else:
        X, U, Qdd = _python_loop(
            p, Ad, Bd, Ac, Bc, x_init, controller, t, v, d, w, tphi, force, nmeas,
            psi_noise, yaw_noise, 1.0,
        )  # fmt: skip
    if not np.all(np.isfinite(X)) or np.abs(X[:, :2]).max() > 1.0:
        raise UntrustworthyResult(
            f"the linear loop left the small-angle range (max |angle| "
            f"{np.nanmax(np.abs(X[:, :2])):.3g} rad) at v={speed} m/s; reduce dither, noise or "
            "speed variation, or check that the controller stabilizes this bicycle"
        )
    psidot = yaw_rate(p, v, X[:, 1], X[:, 3])
    psi = np.concatenate([[0.0], np.cumsum(0.5 * (psidot[1:] + psidot[:-1]) * dt)])
    truth = {
        "phi": X[:, 0], "delta": X[:, 1], "phidot": X[:, 2], "deltadot": X[:, 3],
        "phiddot": Qdd[:, 0], "deltaddot": Qdd[:, 1], "v": v, "psi": psi, "psidot": psidot,
        "thetaRdot": -v / p.rR, "T_delta": U + w, "T_phi": tphi, "F": force,
    }  # fmt: skip
    meas = {
        "phi": X[:, 0] + nmeas[:, 0], "delta": X[:, 1] + nmeas[:, 1],
        "phidot": X[:, 2] + nmeas[:, 2], "deltadot": X[:, 3] + nmeas[:, 3],
        "v": v, "psi": psi + psi_noise, "psidot": psidot + yaw_noise, "thetaRdot": -v / p.rR,
        "T_delta": U + log_noise, "T_phi": tphi, "F": force,
    }  # fmt: skip
    meta = {
        "source": "simulated",
        "simulator": "bikeid.dataset.linear_loop (exact ZOH, linear)",
        "engine": "compiled" if compiled else "python",
        "parameters": p.as_dict(),
        "bicycle": p.name,
        "speed": float(speed),
        "dt": dt,
        "seed": int(seed),
        "controller": {"sample_time": dt, **_describe(controller)},
        "reference": _describe(ref_fn),
        "sampling": {
            "controller_period": dt,
            "logging_period": dt,
            "dither_hold": dither_hold * dt,
        },
        "dither": {"amplitude": dither, "hold": dither_hold},
        "noise": {
            "disturbance": disturbance, "angle": angle_noise, "rate": rate_noise,
            "torque_log": torque_noise,
        },
        "roll_torque": roll_torque,
        "lateral_force": lateral_force,
        "lateral_force_point": list(lateral_force_point),
        "speed_variation": {"amplitude": speed_variation, "period": speed_period},
        "x0": [float(s) for s in x_init],
    }  # fmt: skip
    return Run(t=t, signals=meas, truth=truth, dither=d, reference=ref, meta=meta)


def sweep(p: BicycleParameters, speeds: Sequence[float], seed: int = 0, **kwargs: Any) -> list[Run]:
    """One :func:`simulate` run per speed; run i uses seed ``seed + i``.

    Parameters
    ----------
    p : BicycleParameters
        The bicycle.
    speeds : sequence of float
        Nominal speeds [m/s].
    seed : int
        Seed of the first run.
    **kwargs
        Passed to :func:`simulate` (a ``controller`` object is shared and reset per run).

    Returns
    -------
    list of Run
        One run per speed, in the order of ``speeds``.

    Raises
    ------
    ValueError
        As :func:`simulate`, for the first run that fails.
    """
    return [simulate(p, float(v), seed=seed + i, **kwargs) for i, v in enumerate(speeds)]
