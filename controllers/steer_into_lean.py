"""Steer-into-lean balance law of the TU Delft steer-by-wire bicycle (measured data).

    T_delta = K (V - v) phidot   for v < V,   0 for v >= V,

with the measured speed v = y[0] [m/s] and roll rate phidot = y[4] [rad/s];
K = 2 N s^2/rad, V = 6.5 m/s (``/work/shared/data/tudelft-sbw/README.md``).

Sign: in the logs ``sil_command`` equals +2 (6.5 - speed) lean_rate to 5e-7 relative
(least-squares slope 1.0000 on the 1.5 and 4.5 m/s ``eigen`` runs), and lean and fork
angles are positively correlated (+0.74, +0.78): a positive lean rate gives a positive
torque, i.e. the front wheel is steered *into* the lean.  In the benchmark convention
(Meijaard 2007, roll and steer positive to the right) that is the stabilizing sign:
it is roll-rate feedback ``T = -Kd phidot`` with Kd = -K (V - v) < 0 (controllers.md
§4.3), so the law is used here with the same positive sign.

The law ignores the roll reference (it only balances); ``reference`` is kept for the
interface and metadata.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from .base import DEFAULT_SAMPLE_TIME, I_PHIDOT, I_V, Controller, LinearLaw

__all__ = ["SteerIntoLean"]


class SteerIntoLean(Controller):
    """T = K (V - v) phidot below V, zero above; gains scheduled on the measured speed
    (or on ``design_speed`` if given).

    Parameters
    ----------
    gain : float, optional
        K [N s^2/rad] (default 2.0), so that K (V - v) phidot is in N m; finite.
    max_speed : float, optional
        V [m/s] (default 6.5) above which the torque is zero; positive and finite.
    sample_time, saturation, reference, design_speed
        As in :class:`~controllers.base.Controller` ([s], [N m], [rad] of t [s], [m/s]);
        the reference is not used by the law.

    Attributes
    ----------
    gain : float
        K [N s^2/rad].
    max_speed : float
        V [m/s].

    Raises
    ------
    ValueError
        If ``gain`` is not finite or ``max_speed`` is not positive and finite.
    """

    name = "steer_into_lean"

    def __init__(
        self,
        gain: float = 2.0,
        max_speed: float = 6.5,
        *,
        sample_time: float = DEFAULT_SAMPLE_TIME,
        saturation: float = math.inf,
        reference: Callable[[float], float] | None = None,
        design_speed: float | None = None,
    ):
        if not (math.isfinite(gain) and math.isfinite(max_speed) and max_speed > 0):
            raise ValueError(
                f"gain must be finite and max_speed positive, got gain={gain}, "
                f"max_speed={max_speed}"
            )
        self.gain = float(gain)
        self.max_speed = float(max_speed)
        super().__init__(sample_time, saturation, reference, design_speed)

    def _control(self, t: float, y: Sequence[float], dt: float) -> float:
        v = self.design_speed if self.design_speed is not None else y[I_V]
        dv = self.max_speed - v
        if dv <= 0.0:
            return 0.0
        return self.gain * dv * y[I_PHIDOT]

    @property
    def speed_scheduled(self) -> bool:
        """True unless a ``design_speed`` fixes the gain."""
        return self.design_speed is None

    def linear_law(self, v: float) -> LinearLaw | None:
        """T = K (V - v) phidot below V, 0 above: L = [0, 0, K max(V - v, 0), 0].

        Parameters
        ----------
        v : float
            Speed [m/s] the gain is scheduled on (``design_speed`` wins if set).

        Returns
        -------
        LinearLaw or None
            No integral or reference terms; None with a finite ``saturation``.
        """
        if math.isfinite(self.saturation):
            return None
        vs = self.design_speed if self.design_speed is not None else v
        dv = self.max_speed - vs
        k = self.gain * dv if dv > 0.0 else 0.0
        return LinearLaw(np.array([0.0, 0.0, k, 0.0]), 0.0, 0.0, 0.0)

    def roll_rate_gain(self, v: float) -> float:
        """The equivalent Kd(v) in T = -Kd phidot [N m s/rad] (negative below V).

        Parameters
        ----------
        v : float
            Forward speed [m/s] (``design_speed`` is not applied here).

        Returns
        -------
        float
            Kd(v) = -K max(V - v, 0) [N m s/rad].
        """
        return -self.gain * max(self.max_speed - v, 0.0)

    def _gains_description(self) -> dict[str, Any]:
        return {"law": "T = K (V - v) phidot for v < V", "K": self.gain, "V": self.max_speed}
