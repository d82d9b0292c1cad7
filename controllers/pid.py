"""PID roll-angle tracker.

The law::

    T = Kp e + Ki I + D,   e = phi_ref - phi,   I = int e dt,
    D = -Kd phidot              (derivative="measurement", default)
    D =  Kd (phi_ref' - phidot) (derivative="error"; phi_ref' is the reference's exact
                                 rate when it has one, else a backward difference)

with the measured roll phi = y[1] and roll rate phidot = y[4] (no numerical
differentiation: the roll rate is a measured channel).  Gains follow the benchmark
sign convention: stabilizing gains are *negative* (torque steers into the lean).

Integration is forward Euler over the actual time between calls.  Anti-windup:

- ``"clamp"`` (default, conditional integration): the integral is frozen on any
  sample where the output saturates and the error would drive it further into
  saturation;
- ``"backcalc"``: I' = e + (T_sat - T) / (Ki Tt), tracking time ``tracking_time`` Tt [s].

Default gains (Kp, Ki, Kd) = (-200, -500, -80) at every speed: in the linear
benchmark model this one set stabilizes 1-15 m/s (reference controllers.md §4.3;
``tests/controllers/test_controllers.py`` checks it on a speed grid).  Speed scheduling: pass a
:class:`~controllers.base.GainSchedule` of (Kp, Ki, Kd) rows; it is evaluated at the
measured speed, or at ``design_speed`` if one is given.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from .base import DEFAULT_SAMPLE_TIME, I_PHI, I_PHIDOT, Controller, GainSchedule, LinearLaw

__all__ = ["DEFAULT_PID_GAINS", "PID"]

#: (Kp [N m/rad], Ki [N m/(rad s)], Kd [N m s/rad]); stabilizes 1-15 m/s (linear benchmark).
DEFAULT_PID_GAINS = (-200.0, -500.0, -80.0)


class PID(Controller):
    """Roll-angle PID; see the module docstring for the law, signs and anti-windup.

    Parameters
    ----------
    kp : float, optional
        Proportional gain Kp on e = phi_ref - phi [N m/rad] (default -200).
    ki : float, optional
        Integral gain Ki on int e dt [N m/(rad s)] (default -500).
    kd : float, optional
        Derivative gain Kd on the roll rate (or on de/dt) [N m s/rad] (default -80).
    schedule : GainSchedule or None, optional
        Rows (Kp, Ki, Kd) over speed [m/s]; when given it replaces ``kp``, ``ki``,
        ``kd`` and is evaluated at the measured speed (or at ``design_speed``).
    derivative : {"measurement", "error"}, optional
        ``"measurement"`` (default): D = -Kd phidot; ``"error"``: D = Kd (phi_ref' - phidot).
    anti_windup : {"clamp", "backcalc"}, optional
        Conditional integration (default) or back-calculation.
    tracking_time : float, optional
        Back-calculation tracking time Tt [s] (default 0.1), positive; used only with
        ``anti_windup="backcalc"``.
    sample_time, saturation, reference, design_speed
        As in :class:`~controllers.base.Controller` ([s], [N m], [rad] of t [s], [m/s]).

    Attributes
    ----------
    gains : tuple of float
        The fixed (Kp, Ki, Kd) [N m/rad, N m/(rad s), N m s/rad].
    schedule : GainSchedule or None
        The gain schedule, if any.
    integral : float
        The roll-error integral I [rad s] (reset to 0 by ``reset()``).

    Raises
    ------
    ValueError
        If ``derivative`` or ``anti_windup`` is not one of the allowed names, a gain is
        not finite, a schedule row is not (Kp, Ki, Kd), or ``tracking_time`` is not
        positive and finite.
    """

    name = "pid"

    def __init__(
        self,
        kp: float = DEFAULT_PID_GAINS[0],
        ki: float = DEFAULT_PID_GAINS[1],
        kd: float = DEFAULT_PID_GAINS[2],
        *,
        schedule: GainSchedule | None = None,
        derivative: str = "measurement",
        anti_windup: str = "clamp",
        tracking_time: float = 0.1,
        sample_time: float = DEFAULT_SAMPLE_TIME,
        saturation: float = math.inf,
        reference: Callable[[float], float] | None = None,
        design_speed: float | None = None,
    ):
        if derivative not in ("measurement", "error"):
            raise ValueError(f"derivative must be 'measurement' or 'error', got {derivative!r}")
        if anti_windup not in ("clamp", "backcalc"):
            raise ValueError(f"anti_windup must be 'clamp' or 'backcalc', got {anti_windup!r}")
        gains = (float(kp), float(ki), float(kd))
        if not all(math.isfinite(g) for g in gains):
            raise ValueError(f"PID gains must be finite, got {gains}")
        if schedule is not None and len(schedule.gains[0]) != 3:
            raise ValueError("a PID gain schedule needs rows (Kp, Ki, Kd)")
        tracking_time = float(tracking_time)
        if not (tracking_time > 0 and math.isfinite(tracking_time)):
            raise ValueError(f"tracking_time must be positive, got {tracking_time}")
        self.gains = gains
        self.schedule = schedule
        self.derivative = derivative
        self.anti_windup = anti_windup
        self.tracking_time = tracking_time
        super().__init__(sample_time, saturation, reference, design_speed)

    def _reset_state(self) -> None:
        super()._reset_state()
        self.integral = 0.0

    def current_gains(self, v: float) -> tuple[float, float, float]:
        """(Kp, Ki, Kd) at speed v [m/s].

        Parameters
        ----------
        v : float
            Forward speed [m/s] at which the schedule is evaluated (ignored without a
            schedule).

        Returns
        -------
        tuple of float
            (Kp [N m/rad], Ki [N m/(rad s)], Kd [N m s/rad]).
        """
        return self.gains if self.schedule is None else self.schedule(v)  # type: ignore[return-value]

    @property
    def speed_scheduled(self) -> bool:
        """True if a gain schedule is evaluated at the measured speed (no ``design_speed``)."""
        return self.schedule is not None and self.design_speed is None

    def linear_law(self, v: float) -> LinearLaw | None:
        """T = Kp (r - phi) + Ki xi - Kd phidot (+ Kd r' with ``derivative="error"``).

        Parameters
        ----------
        v : float
            Speed [m/s] the gains are scheduled on (``design_speed`` wins if set).

        Returns
        -------
        LinearLaw or None
            L = [-Kp, 0, -Kd, 0], l_i = Ki, l_r = Kp, l_rd = Kd (error derivative) or 0;
            None with a finite ``saturation`` (clipping and anti-windup are not linear).
        """
        if math.isfinite(self.saturation):
            return None
        kp, ki, kd = self.current_gains(self.design_speed if self.design_speed is not None else v)
        lrd = kd if self.derivative == "error" else 0.0
        return LinearLaw(np.array([-kp, 0.0, -kd, 0.0]), float(ki), float(kp), float(lrd))

    def _control(self, t: float, y: Sequence[float], dt: float) -> float:
        if self.schedule is None:
            kp, ki, kd = self.gains
        else:
            kp, ki, kd = self.schedule(self.speed(y))
        r, rd = self._reference_and_rate(t, dt)
        e = r - y[I_PHI]
        if self.derivative == "measurement":
            d = -kd * y[I_PHIDOT]
        else:
            d = kd * (rd - y[I_PHIDOT])
        u = kp * e + ki * self.integral + d
        s = self.saturation
        if self.anti_windup == "clamp":
            if not ((u > s and ki * e > 0) or (u < -s and ki * e < 0)):
                self.integral += e * dt
        else:
            usat = s if u > s else (-s if u < -s else u)
            corr = (usat - u) / (ki * self.tracking_time) if ki != 0.0 else 0.0
            self.integral += (e + corr) * dt
        return u

    def _gains_description(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "kp": self.gains[0], "ki": self.gains[1], "kd": self.gains[2],
            "law": "T = Kp e + Ki int(e) - Kd phidot" if self.derivative == "measurement"
            else "T = Kp e + Ki int(e) + Kd de/dt",
            "derivative": self.derivative, "anti_windup": self.anti_windup,
        }  # fmt: skip
        if self.anti_windup == "backcalc":
            out["tracking_time"] = self.tracking_time
        if self.schedule is not None:
            out["schedule"] = self.schedule.as_dict()
            del out["kp"], out["ki"], out["kd"]
        return out
