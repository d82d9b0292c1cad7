"""The controller interface shared by every roll-angle controller.

A controller is a zero-order-hold callable ``controller(t, y) -> T_delta`` [N m].
``y`` is the *measured* signal vector in :data:`sim.conventions.MEASURED` order
``(v, phi, delta, psi, phidot, deltadot, psidot, thetaRdot)``: controllers never see
the true state.  The simulator calls it once per sample (``sample_time`` [s]); a
repeated call at the same ``t`` returns the held output without touching the
internal state, so an integrator that evaluates the input several times per step
cannot double-count the integral.

Sign convention (Meijaard 2007): phi > 0 leans right, delta > 0 steers right,
T_delta > 0 is a steer torque to the right.  Stabilizing roll feedback steers
*into* the lean, so roll-angle and roll-rate gains are negative in
``T = Kp e + Ki int(e) - Kd phidot`` with ``e = phi_ref - phi``.

Every controller carries its roll reference ``reference(t)`` [rad] (default zero,
see :mod:`controllers.excitation`) and clips its output to ``+-saturation`` [N m].

Speed scheduling: ``design_speed=None`` schedules the gains on the *measured* speed
``y[0]`` at every call; a number fixes the gains at that design speed [m/s].

Sample time: every controller defaults to :data:`DEFAULT_SAMPLE_TIME` = 0.01 s, the
logging period of the default instruments (``dataset.sensors.Sensors``, 100 Hz).  A run
logs the steer torque once per logging period; identification (``ident``) assumes that
the logged value was held by the plant over the whole logging interval, which holds only
when the controller runs at the logging period (or a whole multiple of it).  A faster
controller is allowed when asked for explicitly, but the estimators refuse its runs
(``ident.signals.check_sampling``).

Linear laws: controllers whose output is linear in the measurement (PID, pole placement,
steer-into-lean, without saturation) describe it by :meth:`Controller.linear_law` as a
:class:`LinearLaw`, which the exact linear closed-loop engine
(``dataset.linear_loop``) runs in compiled code; the others return None and run through
the engine's per-sample Python loop.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple, Protocol, runtime_checkable

import numpy as np

from bikeid.sim.conventions import IDX, MEASURED

__all__ = [
    "DEFAULT_SAMPLE_TIME",
    "Controller",
    "ControllerLike",
    "GainSchedule",
    "LinearLaw",
    "Reference",
    "check_measurement",
]

#: Default controller period [s]: the logging period of the default sensors (100 Hz).
DEFAULT_SAMPLE_TIME = 0.01

I_V, I_PHI, I_DELTA, I_PHIDOT, I_DELTADOT = (
    IDX["v"], IDX["phi"], IDX["delta"], IDX["phidot"], IDX["deltadot"]
)  # fmt: skip


@runtime_checkable
class ControllerLike(Protocol):
    """What a simulator needs from a controller.

    Any object with these members can drive ``dataset.closed_loop.simulate_run``;
    :class:`Controller` is the implementation every bikeid controller derives from.

    Attributes
    ----------
    sample_time : float
        Controller period [s]; the simulator calls the controller once per period and
        holds the returned steer torque (zero-order hold) in between.

    Notes
    -----
    ``controller(t, y)`` returns the steer torque T_delta [N m] (positive to the right,
    Meijaard 2007) for time ``t`` [s] and the measurement ``y``, an (8,) sequence in
    :data:`sim.conventions.MEASURED` order ``(v, phi, delta, psi, phidot, deltadot,
    psidot, thetaRdot)`` [m/s, rad, rad, rad, rad/s, rad/s, rad/s, rad/s].
    """

    sample_time: float

    def reset(self) -> None:
        """Forget all internal state before a new run (integrators, held output)."""
        ...

    def __call__(self, t: float, y: Sequence[float]) -> float: ...


class Reference(Protocol):
    """A roll reference: ``ref(t)`` [rad] and optionally ``ref.rate(t)`` [rad/s].

    Any callable of time qualifies; :mod:`controllers.excitation` has the standard ones.
    A reference without ``rate`` gets its rate from a backward difference over the
    controller period (:class:`Controller`).

    Parameters
    ----------
    t : float
        Time [s] (argument of the call).

    Notes
    -----
    The call returns the roll-angle reference phi_ref [rad], positive leaning right.
    """

    def __call__(self, t: float) -> float: ...


def _zero(t: float) -> float:
    return 0.0


def check_measurement(y: Sequence[float]) -> None:
    """Raise ``ValueError`` unless ``y`` is a finite vector in ``MEASURED`` order.

    Parameters
    ----------
    y : sequence of float, length 8
        Measurement in :data:`sim.conventions.MEASURED` order ``(v, phi, delta, psi,
        phidot, deltadot, psidot, thetaRdot)`` [m/s, rad, rad, rad, rad/s, rad/s, rad/s,
        rad/s].

    Raises
    ------
    ValueError
        If ``y`` does not have 8 entries (the message gives the expected order), or if
        an entry is not finite (the message names the channels).
    """
    if len(y) != len(MEASURED):
        raise ValueError(
            f"measurement has {len(y)} entries; expected {len(MEASURED)} in the order {MEASURED}"
        )
    bad = [MEASURED[i] for i, val in enumerate(y) if not math.isfinite(float(val))]
    if bad:
        raise ValueError(f"measurement has non-finite entries {bad}; check the sensor model")


def _positive(name: str, value: float, allow_inf: bool = False) -> float:
    value = float(value)
    if math.isnan(value) or value <= 0 or (math.isinf(value) and not allow_inf):
        rule = "positive (inf for none)" if allow_inf else "positive and finite"
        raise ValueError(f"{name} must be {rule}, got {value}")
    return value


class GainSchedule:
    """Gains interpolated linearly in speed, held constant beyond the grid ends.

    ``speeds`` [m/s] strictly increasing; ``gains[k]`` is the gain tuple at
    ``speeds[k]``.  Evaluation is pure Python (bisection), a few hundred ns.
    Calling the schedule, ``schedule(v)`` with the speed v [m/s], returns the gain
    tuple at v (same length and units as a row of ``gains``).

    Parameters
    ----------
    speeds : sequence of float, length n
        Grid speeds [m/s], finite and strictly increasing.
    gains : sequence of sequence of float, shape (n, m)
        ``gains[k]`` is the gain tuple at ``speeds[k]``, all rows of the same length m;
        units are those of the controller using the schedule.

    Attributes
    ----------
    speeds : list of float
        The grid speeds [m/s].
    gains : list of tuple of float
        The gain rows, one per speed.

    Raises
    ------
    ValueError
        If ``speeds`` is empty or has a different length from ``gains``, is not strictly
        increasing, the rows differ in length, or a speed or gain is not finite.
    """

    def __init__(self, speeds: Sequence[float], gains: Sequence[Sequence[float]]):
        sp = [float(s) for s in speeds]
        gs = [tuple(float(g) for g in row) for row in gains]
        if len(sp) == 0 or len(sp) != len(gs):
            raise ValueError(
                f"gain schedule needs one gain row per speed, got {len(sp)} speeds, {len(gs)} rows"
            )
        if any(b <= a for a, b in zip(sp, sp[1:], strict=False)):
            raise ValueError("gain schedule speeds must be strictly increasing")
        if len({len(r) for r in gs}) != 1:
            raise ValueError("every gain row must have the same length")
        if not all(math.isfinite(x) for r in gs for x in r + (sp[0], sp[-1])):
            raise ValueError("gain schedule speeds and gains must be finite")
        self.speeds = sp
        self.gains = gs
        self._n = len(sp)

    def __call__(self, v: float) -> tuple[float, ...]:
        sp = self.speeds
        if v <= sp[0]:
            return self.gains[0]
        if v >= sp[-1]:
            return self.gains[-1]
        lo, hi = 0, self._n - 1
        while hi - lo > 1:
            mid = (lo + hi) // 2
            if sp[mid] <= v:
                lo = mid
            else:
                hi = mid
        w = (v - sp[lo]) / (sp[hi] - sp[lo])
        a, b = self.gains[lo], self.gains[hi]
        return tuple(x + w * (z - x) for x, z in zip(a, b, strict=True))

    def as_dict(self) -> dict[str, Any]:
        """The schedule as a JSON-serializable dictionary.

        Returns
        -------
        dict
            ``{"speeds": [...], "gains": [[...], ...]}``, speeds in m/s, one gain list
            per speed.
        """
        return {"speeds": list(self.speeds), "gains": [list(g) for g in self.gains]}


class LinearLaw(NamedTuple):
    """A controller law that is linear in the measurement, at one speed.

    With the measured state y_x = [phi, delta, phidot, deltadot] (rad, rad/s), the
    reference r [rad] and its rate r' [rad/s] at sample t_k, and the integral
    xi[k] = sum_{j<k} dt (r[j] - phi_meas[j]) [rad s] (forward Euler, xi[0] = 0)::

        T_delta[k] = L @ y_x[k] + l_i xi[k] + l_r r[k] + l_rd r'[k]   [N m]

    Signs as in the benchmark convention (module docstring): stabilizing roll gains
    are negative in ``-L``, i.e. ``L[0]`` > 0 for a controller that steers into the lean.

    Attributes
    ----------
    L : (4,) ndarray
        Gains on y_x = [phi, delta, phidot, deltadot] (bikeid state order)
        [N m/rad, N m/rad, N m s/rad, N m s/rad].
    l_i : float
        Gain on the roll-error integral xi [N m/(rad s)].
    l_r : float
        Gain on the roll reference r [N m/rad].
    l_rd : float
        Gain on the roll-reference rate r' [N m s/rad].
    """

    L: np.ndarray  #: (4,) [N m/rad, N m/rad, N m s/rad, N m s/rad]
    l_i: float  #: integral gain [N m/(rad s)]
    l_r: float  #: reference gain [N m/rad]
    l_rd: float  #: reference-rate gain [N m s/rad]


class Controller(ABC):
    """Base class: sample time, saturation, reference, ZOH hold and ``describe()``.

    Subclasses implement :meth:`_control` (the unsaturated law, may update state)
    and :meth:`_reset_state`, and set ``name``.

    Calling the controller, ``controller(t, y)`` with time ``t`` [s] and the
    measurement ``y`` ((8,) in :data:`sim.conventions.MEASURED` order), returns the
    steer torque T_delta [N m] (positive to the right), clipped to ``+-saturation``.
    A repeated call at the same ``t`` returns the held output; a call at an earlier
    ``t`` than the previous one raises ``ValueError`` (call :meth:`reset` first).

    Parameters
    ----------
    sample_time : float, optional
        Controller period [s], positive and finite (default
        :data:`DEFAULT_SAMPLE_TIME` = 0.01 s).
    saturation : float, optional
        Steer-torque limit [N m], positive; ``inf`` (default) for none.
    reference : callable, optional
        Roll reference ``reference(t)`` [rad] of time [s] (see :class:`Reference`);
        None (default) for zero.
    design_speed : float or None, optional
        Speed [m/s] at which the gains are fixed; None (default) schedules them on the
        measured speed ``y[0]`` at every call.

    Attributes
    ----------
    name : str
        Controller name recorded in run metadata.
    sample_time : float
        Controller period [s].
    saturation : float
        Steer-torque limit [N m] (``inf`` for none).
    design_speed : float or None
        Fixed design speed [m/s], or None when scheduled on the measured speed.
    reference : callable
        Roll reference [rad] as a function of time [s].

    Raises
    ------
    ValueError
        If ``sample_time``, ``saturation`` or ``design_speed`` is not positive (or
        ``sample_time``/``design_speed`` is infinite).
    """

    name = "controller"

    def __init__(
        self,
        sample_time: float = DEFAULT_SAMPLE_TIME,
        saturation: float = math.inf,
        reference: Callable[[float], float] | None = None,
        design_speed: float | None = None,
    ):
        self.sample_time = _positive("sample_time", sample_time)
        self.saturation = _positive("saturation", saturation, allow_inf=True)
        self.design_speed = (
            None if design_speed is None else _positive("design_speed", design_speed)
        )
        self.reference = reference if reference is not None else _zero
        self.reset()

    # -- public -------------------------------------------------------------------------
    def reset(self) -> None:
        """Forget all internal state (integrators, held output, previous sample)."""
        self._t_last: float | None = None
        self._u_last = 0.0
        self._reset_state()

    def __call__(self, t: float, y: Sequence[float]) -> float:
        """Steer torque [N m] for the measurement ``y`` (``MEASURED`` order) at time ``t`` [s]."""
        t_last = self._t_last
        if t_last is not None:
            if t == t_last:
                return self._u_last
            if t < t_last:
                raise ValueError(
                    f"controller called at t={t} after t={t_last}; call reset() before a new run"
                )
            dt = t - t_last
        else:
            dt = self.sample_time
        u = self._control(t, y, dt)
        if not math.isfinite(u):  # NaN or +-inf: never hand a non-finite torque to a plant
            check_measurement(y)
            raise ValueError(
                f"{self.name} produced a non-finite steer torque ({u}) at t={t} s; check its "
                "gains (overflow) and the measurement"
            )
        s = self.saturation
        if u > s:
            u = s
        elif u < -s:
            u = -s
        self._t_last = t
        self._u_last = u
        return u

    def linear_law(self, v: float) -> LinearLaw | None:
        """The law as a :class:`LinearLaw` with the gains at speed ``v`` [m/s], or None.

        None (the default) means the law is not linear in the measurement (or saturates),
        so a simulator must call the controller itself.  Subclasses whose law is linear
        override this; the law must equal :meth:`__call__` to round-off on every sample.

        Parameters
        ----------
        v : float
            Forward speed [m/s] at which the gains are evaluated.

        Returns
        -------
        LinearLaw or None
            The linear law at ``v``, or None if the law is not linear.
        """
        return None

    @property
    def speed_scheduled(self) -> bool:
        """True if the gains follow the *measured* speed (so they change when it does)."""
        return False

    def speed(self, y: Sequence[float]) -> float:
        """The speed the gains are scheduled on: ``design_speed`` or the measured ``y[0]``.

        Parameters
        ----------
        y : sequence of float, length 8
            Measurement in :data:`sim.conventions.MEASURED` order (``y[0]`` is the
            measured speed v [m/s]).

        Returns
        -------
        float
            Scheduling speed [m/s].
        """
        return self.design_speed if self.design_speed is not None else float(y[I_V])

    def describe(self) -> dict[str, Any]:
        """JSON-serializable summary for run metadata.

        Returns
        -------
        dict
            Keys ``name``, ``sample_time`` [s], ``saturation`` [N m] (None if
            unlimited), ``design_speed`` [m/s] (None if scheduled), ``speed_source``
            (``"design"`` or ``"measured"``), ``reference`` (the reference's own
            ``describe()`` or its name) and ``gains`` (subclass-specific).
        """
        ref = self.reference
        ref_desc = (
            ref.describe()
            if hasattr(ref, "describe")
            else {"name": getattr(ref, "__name__", type(ref).__name__)}
        )
        sat = self.saturation
        return {
            "name": self.name,
            "sample_time": self.sample_time,
            "saturation": None if math.isinf(sat) else sat,
            "design_speed": self.design_speed,
            "speed_source": "design" if self.design_speed is not None else "measured",
            "reference": ref_desc if ref is not _zero else {"name": "zero"},
            "gains": self._gains_description(),
        }

    # -- for subclasses -----------------------------------------------------------------
    def _reference_and_rate(self, t: float, dt: float) -> tuple[float, float]:
        """Reference [rad] and its rate [rad/s]: exact if the reference has ``rate``,
        else a backward difference over ``dt`` (zero at the first sample)."""
        ref = self.reference
        r = float(ref(t))
        rate = getattr(ref, "rate", None)
        if rate is not None:
            rd = float(rate(t))
        elif self._t_last is None:
            rd = 0.0
        else:
            rd = (r - self._r_last) / dt
        self._r_last = r
        return r, rd

    @abstractmethod
    def _control(self, t: float, y: Sequence[float], dt: float) -> float: ...

    def _reset_state(self) -> None:
        self._r_last = 0.0

    def _gains_description(self) -> dict[str, Any]:
        return {}
