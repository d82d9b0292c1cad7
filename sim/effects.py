"""Optional physical effects the Whipple model lacks, injected by the simulator.

Each effect is a small frozen dataclass with named parameters in SI units.  There
are two kinds:

* **Plant-side** effects act as extra generalized forces on the dynamic equations
  of (u4, u6, u7) = (roll rate, rear wheel rate, steer rate) of
  :mod:`sim.nonlinear`.  They are compiled into one parameter vector
  (:func:`plant_vector`) that the numba kernel passes to :func:`plant_forces`, so
  they stay on the compiled fast path.
* **Input-side** effects shape the commanded steer torque before it reaches the
  plant: gain, pure delay (a whole number of controller samples), first-order lag.
  Order: command -> delay -> gain -> lag -> plant.

Signs follow :mod:`sim.conventions`: a damping torque opposes the rate, so a steer
damping c gives the generalized force -c * deltadot on the steer equation.

Adding an effect: its facts (name, unit, absent value, plausible range, layer, whether the
identification library may select it) are declared once, as an entry of
:data:`bikeid.sim.effect_registry.EFFECTS`; this module only implements the ``plant`` and
``input`` layers for the nonlinear simulator.  For an effect the plant carries:

1. give it a dataclass below with a ``kind`` of ``"plant"`` or ``"input"``;
2. for a plant effect, append its slots to :data:`PLANT_SLOTS`, fill them in
   :func:`plant_vector` and add its generalized force to :func:`plant_forces`;
   for an input effect, handle it in :func:`input_chain` and in
   ``sim.integrate`` (only there are commands shaped);
3. name it as the entry's ``plant_term`` and add its class to the registry's builders
   (``effect_registry._plant_builders``), so that
   :func:`bikeid.sim.effect_registry.nonlinear_effects` builds it from a value;
4. apply the entry in the linear experiment model (``bikeid.ident.effects.experiment_model``) and,
   if the identification may select it, give it fit settings in
   ``bikeid.ident.effects.library.LIBRARY`` (tests/sim/test_effect_registry.py checks both).

An effect the plant cannot carry states why in the entry's ``no_plant`` instead (sensor
effects are applied by :meth:`bikeid.dataset.sensors.Sensors.with_effects`).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import asdict, dataclass

import numpy as np
from numba import njit

__all__ = [
    "PLANT_SLOTS",
    "ActuatorLag",
    "InputChain",
    "InputDelay",
    "RollDamping",
    "RollStiffness",
    "SteerCoulomb",
    "SteerDamping",
    "SteerStiffness",
    "TorqueGain",
    "describe",
    "input_chain",
    "plant_forces",
    "plant_vector",
]


def _check(name: str, value: float, unit: str, minimum: float = 0.0, strict: bool = False) -> None:
    ok = math.isfinite(value) and (value > minimum if strict else value >= minimum)
    if not ok:
        rel = ">" if strict else ">="
        raise ValueError(f"{name} must be finite and {rel} {minimum} {unit}, got {value!r}")


@dataclass(frozen=True)
class SteerDamping:
    """Viscous steer damping: torque -c * deltadot on the front frame [c: N m s/rad].

    Parameters
    ----------
    c : float
        Damping coefficient [N m s/rad], finite and >= 0.

    Attributes
    ----------
    kind : str
        ``"plant"``.

    Raises
    ------
    ValueError
        If ``c`` is negative or not finite.
    """

    c: float
    kind = "plant"

    def __post_init__(self) -> None:
        _check("SteerDamping.c", self.c, "N m s/rad")


@dataclass(frozen=True)
class SteerCoulomb:
    """Steer Coulomb friction -torque * tanh(deltadot / smoothing).

    torque [N m] is the sliding friction level; smoothing [rad/s] the steer rate
    over which the tanh rises (the smaller, the closer to a sign function and the
    stiffer the equations).

    Parameters
    ----------
    torque : float
        Sliding friction level [N m], finite and >= 0.
    smoothing : float, optional
        Steer rate scale of the tanh [rad/s], finite and > 0 (default 0.01).

    Attributes
    ----------
    kind : str
        ``"plant"``.

    Raises
    ------
    ValueError
        If ``torque`` is negative or ``smoothing`` not positive, or either is not finite.
    """

    torque: float
    smoothing: float = 0.01
    kind = "plant"

    def __post_init__(self) -> None:
        _check("SteerCoulomb.torque", self.torque, "N m")
        _check("SteerCoulomb.smoothing", self.smoothing, "rad/s", strict=True)


@dataclass(frozen=True)
class RollDamping:
    """Viscous roll damping: torque -c * phidot on the rear frame [c: N m s/rad].

    Parameters
    ----------
    c : float
        Damping coefficient [N m s/rad], finite and >= 0.

    Attributes
    ----------
    kind : str
        ``"plant"``.

    Raises
    ------
    ValueError
        If ``c`` is negative or not finite.
    """

    c: float
    kind = "plant"

    def __post_init__(self) -> None:
        _check("RollDamping.c", self.c, "N m s/rad")


@dataclass(frozen=True)
class RollStiffness:
    """Roll spring: torque -k * phi on the rear frame [k: N m/rad].

    A support that pulls the bicycle back upright (a treadmill safety tether or harness,
    or a lumped lateral compliance of a support frame); unlike :class:`RollDamping` it
    acts on the roll *angle*.  It weakens the gravity term g K0[phi, phi] of the
    linear model (Meijaard 2007 eq. A.21).

    Parameters
    ----------
    k : float
        Spring constant [N m/rad], finite and >= 0.

    Attributes
    ----------
    kind : str
        ``"plant"``.

    Raises
    ------
    ValueError
        If ``k`` is negative or not finite.
    """

    k: float
    kind = "plant"

    def __post_init__(self) -> None:
        _check("RollStiffness.k", self.k, "N m/rad")


@dataclass(frozen=True)
class SteerStiffness:
    """Steer centring spring: torque -k * delta on the steer axis [k: N m/rad].

    Lumps what pulls the fork back to centre besides gravity and the tyres' kinematics:
    cable harness and motor belt/gearbox of a steer-by-wire fork, tyre twist torque at
    the contact patch.  It adds to g K0[delta, delta] + v^2 K2[delta, delta] of the linear
    model (Meijaard 2007 eq. A.21).  Either sign is accepted (k < 0 is a destabilizing
    spring).

    Parameters
    ----------
    k : float
        Spring constant [N m/rad], finite (either sign).

    Attributes
    ----------
    kind : str
        ``"plant"``.

    Raises
    ------
    ValueError
        If ``k`` is not finite.
    """

    k: float
    kind = "plant"

    def __post_init__(self) -> None:
        if not math.isfinite(self.k):
            raise ValueError(f"SteerStiffness.k must be finite N m/rad, got {self.k!r}")


@dataclass(frozen=True)
class TorqueGain:
    """Steer torque actually applied = gain * command [-] (actuator calibration error).

    Parameters
    ----------
    gain : float
        Dimensionless gain [-], finite (1 = exact; a negative gain flips the sign).

    Attributes
    ----------
    kind : str
        ``"input"``.

    Raises
    ------
    ValueError
        If ``gain`` is not finite.
    """

    gain: float
    kind = "input"

    def __post_init__(self) -> None:
        if not math.isfinite(self.gain):
            raise ValueError(f"TorqueGain.gain must be finite, got {self.gain!r}")


@dataclass(frozen=True)
class ActuatorLag:
    """First-order steer-torque actuator lag tau T' = T_cmd - T [tau: s].

    Parameters
    ----------
    tau : float
        Time constant [s], finite and >= 0 (0 = no lag).

    Attributes
    ----------
    kind : str
        ``"input"``.

    Raises
    ------
    ValueError
        If ``tau`` is negative or not finite.
    """

    tau: float
    kind = "input"

    def __post_init__(self) -> None:
        _check("ActuatorLag.tau", self.tau, "s")


@dataclass(frozen=True)
class InputDelay:
    """Pure delay of the steer-torque command [s]; a whole number of controller samples.

    Parameters
    ----------
    delay : float
        Delay [s], finite and >= 0; :func:`input_chain` requires a whole multiple of the
        controller sample time.

    Attributes
    ----------
    kind : str
        ``"input"``.

    Raises
    ------
    ValueError
        If ``delay`` is negative or not finite.
    """

    delay: float
    kind = "input"

    def __post_init__(self) -> None:
        _check("InputDelay.delay", self.delay, "s")


#: Slots of the plant-effect vector consumed by :func:`plant_forces`.
PLANT_SLOTS = (
    "steer_damping",
    "steer_coulomb",
    "steer_coulomb_smoothing",
    "roll_damping",
    "roll_stiffness",
    "steer_stiffness",
)
_S = {name: i for i, name in enumerate(PLANT_SLOTS)}


def plant_vector(effects: Iterable[object] | None = None) -> np.ndarray:
    """Compile the plant-side effects into the vector read by :func:`plant_forces`.

    Effects of the same type add up (two dampers in parallel); input-side effects
    are ignored here.

    Parameters
    ----------
    effects : iterable of effect dataclasses, optional
        Plant- and input-side effects of this module; None or empty for none.

    Returns
    -------
    (6,) ndarray
        Values in :data:`PLANT_SLOTS` order: steer damping [N m s/rad], steer Coulomb
        torque [N m], its smoothing rate [rad/s] (1.0 without Coulomb friction), roll
        damping [N m s/rad], roll stiffness [N m/rad], steer stiffness [N m/rad].

    Raises
    ------
    ValueError
        For an object that is not an effect of this module, or a second
        :class:`SteerCoulomb` (after one with a positive torque).
    """
    vec = np.zeros(len(PLANT_SLOTS))
    vec[_S["steer_coulomb_smoothing"]] = 1.0
    for e in effects or ():
        if isinstance(e, SteerDamping):
            vec[_S["steer_damping"]] += e.c
        elif isinstance(e, RollDamping):
            vec[_S["roll_damping"]] += e.c
        elif isinstance(e, RollStiffness):
            vec[_S["roll_stiffness"]] += e.k
        elif isinstance(e, SteerStiffness):
            vec[_S["steer_stiffness"]] += e.k
        elif isinstance(e, SteerCoulomb):
            if vec[_S["steer_coulomb"]] > 0.0:
                raise ValueError("give at most one SteerCoulomb effect")
            vec[_S["steer_coulomb"]] = e.torque
            vec[_S["steer_coulomb_smoothing"]] = e.smoothing
        elif getattr(e, "kind", None) != "input":
            raise ValueError(f"unknown effect {e!r}; use one of the dataclasses in sim.effects")
    return vec


@njit(cache=True)
def plant_forces(ev, q4, q7, u4, u6, u7, out):
    """Extra generalized forces [N m] on the (u4, u6, u7) equations; fills ``out``.

    Compiled with numba (called from the integrator's kernel).

    Parameters
    ----------
    ev : (6,) ndarray
        Plant-effect vector from :func:`plant_vector`.
    q4 : float
        Roll angle phi [rad].
    q7 : float
        Steer angle delta [rad].
    u4 : float
        Roll rate phidot [rad/s].
    u6 : float
        Rear wheel rate [rad/s] (unused: no effect acts on the wheel).
    u7 : float
        Steer rate deltadot [rad/s].
    out : (3,) ndarray
        Output, overwritten: generalized forces [N m] on the roll, rear-wheel and steer
        equations, i.e. -c_phi phidot - k_phi phi, 0 and
        -c_delta deltadot - T_c tanh(deltadot / s) - k_delta delta.

    Returns
    -------
    None
        The result is written into ``out``.
    """
    out[0] = -ev[3] * u4 - ev[4] * q4
    out[1] = 0.0
    out[2] = -ev[0] * u7 - ev[1] * math.tanh(u7 / ev[2]) - ev[5] * q7


@dataclass(frozen=True)
class InputChain:
    """Compiled input-side effects: gain [-], lag tau [s], delay in samples.

    Applied as command -> delay -> gain -> lag -> plant (module docstring).

    Parameters
    ----------
    gain : float, optional
        Product of the :class:`TorqueGain` gains [-] (default 1).
    tau : float, optional
        Lag time constant [s] (default 0, none).
    delay_samples : int, optional
        Delay in controller samples (default 0).
    """

    gain: float = 1.0
    tau: float = 0.0
    delay_samples: int = 0


def input_chain(effects: Iterable[object] | None, dt: float) -> InputChain:
    """Compile input-side effects for controller sample time ``dt`` [s].

    Gains multiply, delays add; the time constants of several :class:`ActuatorLag`
    effects are added into one first-order lag.

    Parameters
    ----------
    effects : iterable of effect dataclasses or None
        Plant- and input-side effects of this module (plant-side ones are ignored).
    dt : float
        Controller sample time [s], positive.

    Returns
    -------
    InputChain
        The combined gain [-], lag [s] and delay [samples].

    Raises
    ------
    ValueError
        For an object that is not an effect of this module, or an :class:`InputDelay`
        that is not a whole number of samples ``dt``.
    """
    gain, tau, delay = 1.0, 0.0, 0
    for e in effects or ():
        if isinstance(e, TorqueGain):
            gain *= e.gain
        elif isinstance(e, ActuatorLag):
            tau += e.tau
        elif isinstance(e, InputDelay):
            n = e.delay / dt
            if abs(n - round(n)) > 1e-9 * max(1.0, n):
                raise ValueError(
                    f"InputDelay.delay={e.delay} s is not a multiple of the controller sample "
                    f"time {dt} s; use a whole number of samples"
                )
            delay += int(round(n))
        elif getattr(e, "kind", None) != "plant":
            raise ValueError(f"unknown effect {e!r}; use one of the dataclasses in sim.effects")
    return InputChain(gain=gain, tau=tau, delay_samples=delay)


def describe(effects: Iterable[object] | None) -> list[dict]:
    """JSON-friendly description of effects for run metadata.

    Parameters
    ----------
    effects : iterable of effect dataclasses or None
        The effects; None or empty for none.

    Returns
    -------
    list of dict
        One dict per effect: ``type`` (class name) and its fields in SI units.
    """
    return [{"type": type(e).__name__, **asdict(e)} for e in effects or ()]
