"""Exact zero-order-hold closed loop of the *linear* benchmark model (a test helper).

The plant is ``sim.linear.state_matrices`` extended with the yaw angle
psi' = (v delta + c delta') cos(lam) / w, discretized exactly with ``scipy.linalg.expm``
of the augmented matrix [[A, B], [0, 0]] dt, so the only approximation is the ZOH
itself, which is what a sampled controller does.  The controller is called at every
sample t_k = k dt with the measurement vector in ``sim.conventions.MEASURED`` order
built from the linear state (v constant, thetaRdot = -v / rR as in Meijaard 2007).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.linalg import expm

from bikeid.sim.linear import state_matrices
from bikeid.sim.parameters import BicycleParameters

__all__ = ["LoopResult", "closed_loop_matrix", "discretize", "simulate"]


@dataclass
class LoopResult:
    t: np.ndarray  # (N,) sample times [s]
    x: np.ndarray  # (N, 5) [phi, delta, phidot, deltadot, psi] at t
    u: np.ndarray  # (N,) total steer torque applied on [t_k, t_k+1) [N m]
    ref: np.ndarray  # (N,) controller reference at t [rad]
    fell: bool  # |phi| exceeded the fall limit (the run stops there)

    @property
    def phi(self) -> np.ndarray:
        return self.x[:, 0]


def discretize(p: BicycleParameters, v: float, dt: float, force_point=None):
    """(Ad, Bd) of the 5-state model; inputs [T_delta] or [T_delta, F]."""
    A4, B4 = state_matrices(p, v, force_point)
    B4 = B4[:, 1:]  # drop T_phi
    k = math.cos(p.lam) / p.w
    A = np.zeros((5, 5))
    A[:4, :4] = A4
    A[4, 1] = v * k
    A[4, 3] = p.c * k
    B = np.zeros((5, B4.shape[1]))
    B[:4] = B4
    n, m = 5, B.shape[1]
    big = np.zeros((n + m, n + m))
    big[:n, :n] = A
    big[:n, n:] = B
    E = expm(big * dt)
    return E[:n, :n], E[:n, n:]


def simulate(
    p: BicycleParameters,
    v: float,
    controller: Callable[[float, list], float],
    t_end: float,
    dt: float | None = None,
    x0=(0.0, 0.0, 0.0, 0.0),
    dither: Callable[[float], float] | None = None,
    force: Callable[[float], float] | None = None,
    force_point: tuple[float, float] = (0.3, -1.0),
    fall_limit: float = 1.0,
) -> LoopResult:
    """Run the sampled loop from t = 0 to t_end (inclusive of the start sample)."""
    dt = controller.sample_time if dt is None else dt
    n = int(round(t_end / dt)) + 1
    Ad, Bd = discretize(p, v, dt, force_point if force is not None else None)
    Ad_l, Bd_l = Ad.tolist(), Bd.tolist()
    k = math.cos(p.lam) / p.w
    x = [float(x0[0]), float(x0[1]), float(x0[2]), float(x0[3]), 0.0]
    xs = np.empty((n, 5))
    us = np.empty(n)
    refs = np.empty(n)
    ref = getattr(controller, "reference", None)
    thetaRdot = -v / p.rR
    fell = False
    if hasattr(controller, "reset"):
        controller.reset()
    for i in range(n):
        t = i * dt
        phi, delta, phidot, deltadot, psi = x
        y = [v, phi, delta, psi, phidot, deltadot, k * (v * delta + p.c * deltadot), thetaRdot]
        u = controller(t, y)
        if dither is not None:
            u += dither(t)
        xs[i] = x
        us[i] = u
        refs[i] = ref(t) if ref is not None else 0.0
        if abs(phi) > fall_limit:
            fell = True
            n = i + 1
            break
        inp = [u] if force is None else [u, force(t)]
        x = [
            sum(a * b for a, b in zip(row, x, strict=True))
            + sum(b * w for b, w in zip(brow, inp, strict=True))
            for row, brow in zip(Ad_l, Bd_l, strict=True)
        ]
    t = np.arange(n) * dt
    return LoopResult(t=t, x=xs[:n], u=us[:n], ref=refs[:n], fell=fell)


def closed_loop_matrix(p: BicycleParameters, v: float, K: np.ndarray) -> np.ndarray:
    """Continuous A - B K for a static state feedback T = -K [phi, delta, phidot, deltadot]."""
    A, B = state_matrices(p, v)
    return A - B[:, 1:2] @ np.atleast_2d(K)
