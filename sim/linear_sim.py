"""Exact zero-order-hold simulation of the linear Whipple bicycle in closed loop.

A second-method plant next to the nonlinear simulator, and the plant of the
identification property tests: every quantity the identifiers estimate is known
exactly here.

Model (``sim.linear.state_matrices``), x = [phi, delta, phidot, deltadot]::

    x' = A(v) x + B(v) [T_phi, T_delta + w, F]

The controller runs at the sample period ``dt`` and its output is held over
[t_k, t_k+1) (zero-order hold).  The disturbance w (unlogged steer torque,
"process noise") and the dither are held the same way, so the sampled plant
x[k+1] = Ad x[k] + Bd u[k] is *exact* (matrix exponential of the augmented
[[A, B], [0, 0]] dt), not an integration with truncation error.  With per-sample
speed variation the speed is held over each sample as well (exact for that
piecewise-constant speed).

Control law (discrete, from the *measured* signals, so sensor noise circulates)::

    u[k]  = L @ x_meas[k] + l_i * xi[k] + l_r * r[k] + dither[k]
    xi[k+1] = xi[k] + dt * (r[k] - phi_meas[k])

:class:`RollPID` (T = kp e + ki int(e) - kd phidot, e = r - phi) and
:class:`StateFeedback` (u = -K x + kI xi) provide L, l_i, l_r.  Stabilizing roll
gains are negative in the Meijaard sign convention (steer into the lean).

Exact accelerations ``truth['phiddot'], truth['deltaddot']`` are
q''(t_k+) = A[2:4] x[k] + B[2:4] u_applied[k], the right limit at the sample (the
input changes at t_k): they satisfy M q'' + v C1 q' + (g K0 + v^2 K2) q = T + H F
to round-off with the *applied* torques in ``truth``.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Protocol

import numba
import numpy as np
from scipy.linalg import expm

from bikeid.dataset.run import Run

from .linear import lateral_force_vector, state_matrices, yaw_rate
from .parameters import BicycleParameters

__all__ = ["ControlLaw", "RollPID", "StateFeedback", "closed_loop_matrix", "simulate", "sweep"]


class ControlLaw(Protocol):
    """Anything with ``law(v) -> (L (4,), l_i, l_r)`` and ``as_dict()``."""

    def law(self, v: float) -> tuple[np.ndarray, float, float]: ...

    def as_dict(self) -> dict: ...


@dataclass(frozen=True)
class RollPID:
    """Roll PID on the steer torque: T = kp (r - phi) + ki int(r - phi) dt - kd phidot [N m].

    Default gains (-200, -500, -80) stabilize the linear benchmark bicycle from 1 to
    15 m/s (controllers reference, summary item 9).
    """

    kp: float = -200.0
    ki: float = -500.0
    kd: float = -80.0

    def law(self, v: float) -> tuple[np.ndarray, float, float]:
        return np.array([-self.kp, 0.0, -self.kd, 0.0]), self.ki, self.kp

    def as_dict(self) -> dict:
        return {"type": "RollPID", **asdict(self)}


@dataclass(frozen=True)
class StateFeedback:
    """u = -K x + kI xi with x = [phi, delta, phidot, deltadot]; K may depend on speed.

    ``K`` is a length-4 sequence, or a callable ``K(v) -> (K (4,), kI)``.
    """

    K: tuple[float, float, float, float] | object
    kI: float = 0.0

    def law(self, v: float) -> tuple[np.ndarray, float, float]:
        if callable(self.K):
            K, kI = self.K(v)
            return -np.asarray(K, dtype=float).reshape(4), float(kI), 0.0
        return -np.asarray(self.K, dtype=float).reshape(4), float(self.kI), 0.0

    def as_dict(self) -> dict:
        K = "callable" if callable(self.K) else [float(k) for k in self.K]
        return {"type": "StateFeedback", "K": K, "kI": self.kI}


def _discretize(A: np.ndarray, B: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact ZOH: expm([[A, B], [0, 0]] dt); A may be batched (..., n, n)."""
    n, m = A.shape[-1], B.shape[-1]
    Z = np.zeros(A.shape[:-2] + (n + m, n + m))
    Z[..., :n, :n] = A * dt
    Z[..., :n, n:] = B * dt
    E = expm(Z)
    return E[..., :n, :n], E[..., :n, n:]


def closed_loop_matrix(
    p: BicycleParameters, v: float, controller: ControlLaw, dt: float
) -> np.ndarray:
    """The 5x5 sampled closed-loop matrix of [x, xi] (noise-free measurement)."""
    A, B = state_matrices(p, v)
    Ad, Bd = _discretize(A, B[:, 1:2], dt)
    L, li, _ = controller.law(v)
    Acl = np.zeros((5, 5))
    Acl[:4, :4] = Ad + Bd @ L[None, :]
    Acl[:4, 4] = Bd[:, 0] * li
    Acl[4, 0] = -dt
    Acl[4, 4] = 1.0
    return Acl


@numba.njit(cache=True)
def _loop(Ad, Bd, Ac, Bc, x0, L, li, lr, dt, ref, dither, w, tphi, force, nmeas):
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
        u = li * xi + lr * ref[k] + dither[k]
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


def _held(rng: np.random.Generator, n: int, amplitude: float, hold: int) -> np.ndarray:
    """Uniform pseudo-random in [-amplitude, amplitude], each value held ``hold`` samples."""
    if amplitude == 0.0:
        return np.zeros(n)
    m = -(-n // hold)
    return np.repeat(rng.uniform(-amplitude, amplitude, m), hold)[:n]


def simulate(
    p: BicycleParameters,
    speed: float,
    duration: float = 50.0,
    dt: float = 0.01,
    controller: ControlLaw | None = None,
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
    reference: np.ndarray | None = None,
    x0: tuple[float, float, float, float] | None = None,
) -> Run:
    """One closed-loop run of the linear bicycle, exact ZOH, as a :class:`dataset.run.Run`.

    Parameters (SI units; every random signal is white, drawn from ``seed``):
    speed : nominal forward speed v [m/s].
    duration, dt : run length and sample period [s]; N = round(duration / dt).
    controller : control law; default :class:`RollPID` with the default gains.
    dither : amplitude [N m] of the uniform steer-torque dither (logged, part of T_delta),
        each value held ``dither_hold`` samples.
    disturbance : standard deviation [N m] of a white steer torque added to the plant
        input but *not* logged (unmeasured disturbance, process noise).
    roll_torque : amplitude [N m] of a uniform roll torque T_phi (logged).
    lateral_force : amplitude [N] of a uniform lateral force F at ``lateral_force_point``
        = (x_F, z_F) [m] (logged; H from ``sim.linear.lateral_force_vector``).
    angle_noise, rate_noise : standard deviation of white measurement noise on
        phi, delta [rad] and phidot, deltadot, psidot [rad/s]; the controller sees it.
    torque_noise : standard deviation [N m] of white noise on the *logged* T_delta
        only (the plant receives the true torque).
    speed_variation : amplitude [m/s] of v(t) = speed + a sin(2 pi t / speed_period),
        held per sample (per-sample speed for the direct method).
    reference : (N,) roll reference r [rad]; default zero.
    x0 : initial state [phi, delta, phidot, deltadot]; default (0.01, 0, 0, 0).

    Raises ValueError when the sampled closed loop is unstable at the nominal speed.
    """
    if not (math.isfinite(speed) and speed >= 0):
        raise ValueError(f"speed {speed}: need a finite speed >= 0 m/s")
    if not (dt > 0 and duration >= 2 * dt):
        raise ValueError(f"need dt > 0 and duration >= 2 dt, got dt={dt}, duration={duration}")
    if dither_hold < 1:
        raise ValueError(f"dither_hold={dither_hold}: need a whole number of samples >= 1")
    for name, val in (
        ("dither", dither), ("disturbance", disturbance), ("roll_torque", roll_torque),
        ("lateral_force", lateral_force), ("angle_noise", angle_noise),
        ("rate_noise", rate_noise), ("torque_noise", torque_noise),
        ("speed_variation", speed_variation),
    ):  # fmt: skip
        if not (math.isfinite(val) and val >= 0):
            raise ValueError(f"{name}={val}: need a finite value >= 0")
    controller = controller or RollPID()
    n = int(round(duration / dt))
    t = np.arange(n) * dt
    rng = np.random.default_rng(seed)
    Acl = closed_loop_matrix(p, speed, controller, dt)
    if controller.law(speed)[1] == 0.0:  # the integrator state does not feed back
        Acl = Acl[:4, :4]
    rho = np.max(np.abs(np.linalg.eigvals(Acl)))
    if rho >= 1.0:
        raise ValueError(
            f"the controller {controller.as_dict()} does not stabilize the sampled loop at "
            f"v={speed} m/s (spectral radius {rho:.4f}); choose other gains or speed"
        )
    ref = np.zeros(n) if reference is None else np.asarray(reference, dtype=float)
    if ref.shape != (n,):
        raise ValueError(f"reference has shape {ref.shape}, expected ({n},)")
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

    v = speed + speed_variation * np.sin(2 * np.pi * t / speed_period)
    Hcol = lateral_force_vector(p, *lateral_force_point)
    if speed_variation:
        AB = [state_matrices(p, vk) for vk in v]
        Ac = np.array([a for a, _ in AB])
        Bc = np.array([np.hstack([b, (b[:, :2] @ Hcol)[:, None]]) for _, b in AB])
    else:
        A, B = state_matrices(p, speed)
        Ac, Bc = A[None], np.hstack([B, (B[:, :2] @ Hcol)[:, None]])[None]
    Ad, Bd = _discretize(Ac, Bc, dt)
    L, li, lr = controller.law(speed)
    x_init = np.array([0.01, 0.0, 0.0, 0.0] if x0 is None else x0, dtype=float)
    X, U, Qdd = _loop(Ad, Bd, Ac, Bc, x_init, L, li, lr, dt, ref, d, w, tphi, force, nmeas)
    if not np.all(np.isfinite(X)) or np.abs(X[:, :2]).max() > 1.0:
        raise ValueError(
            f"the linear loop left the small-angle range (max |angle| "
            f"{np.nanmax(np.abs(X[:, :2])):.3g} rad) at v={speed} m/s; reduce dither, noise or "
            "speed variation"
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
        "v": v, "psi": psi + (rng.normal(0, angle_noise, n) if angle_noise else 0.0),
        "psidot": psidot + yaw_noise, "thetaRdot": -v / p.rR,
        "T_delta": U + log_noise, "T_phi": tphi, "F": force,
    }  # fmt: skip
    meta = {
        "source": "simulated",
        "simulator": "bikeid.sim.linear_sim (exact ZOH, linear)",
        "parameters": p.as_dict(),
        "bicycle": p.name,
        "speed": float(speed),
        "dt": dt,
        "seed": int(seed),
        "controller": controller.as_dict(),
        "dither": {"amplitude": dither, "hold": dither_hold},
        "noise": {
            "disturbance": disturbance, "angle": angle_noise, "rate": rate_noise,
            "torque_log": torque_noise,
        },
        "roll_torque": roll_torque,
        "lateral_force": lateral_force,
        "lateral_force_point": list(lateral_force_point),
        "speed_variation": {"amplitude": speed_variation, "period": speed_period},
    }  # fmt: skip
    return Run(t=t, signals=meas, truth=truth, dither=d, reference=ref, meta=meta)


def sweep(p: BicycleParameters, speeds, seed: int = 0, **kwargs) -> list[Run]:
    """One :func:`simulate` run per speed; run i uses seed ``seed + i``."""
    return [simulate(p, float(v), seed=seed + i, **kwargs) for i, v in enumerate(speeds)]
