"""Optional physical effects the Whipple model lacks, injected by the simulator.

Each effect is a small frozen dataclass with named parameters in SI units.  There
are two kinds:

* **Plant-side** effects act as extra generalized forces on the dynamic equations
  of (u4, u6, u7) = (roll rate, rear wheel rate, steer rate) of
  :mod:`sim.nonlinear`.  Each is the law of its registry entry
  (:mod:`bikeid.sim.effect_law`: ``sign * value * v^p * signal`` on the roll or steer
  equation); :func:`plant_vector` compiles them into a table of rows that the numba kernel
  :func:`plant_forces` sums in a loop, so they stay on the compiled fast path.
  :class:`PlantLaw` carries any law; the named classes below (:class:`SteerDamping`, ...)
  are the built-in entries under their historical names.
* **Input-side** effects shape the commanded steer torque before it reaches the
  plant: gain, pure delay (a whole number of controller samples), first-order lag.
  Order: command -> delay -> gain -> lag -> plant.

Signs follow :mod:`sim.conventions`: a damping torque opposes the rate, so a steer
damping c gives the generalized force -c * deltadot on the steer equation.

Adding a plant effect: declare it, with its law, in
:data:`bikeid.sim.effect_registry.EFFECTS`; nothing here changes (the registry builds a
:class:`PlantLaw` for it).  A law the compiled plant does not evaluate (an acceleration: the
plant's mass matrix is the rigid bodies') states why in the entry's ``no_plant``.  An input
effect needs a dataclass here (with ``effect``, the registry name), its handling in
:func:`input_chain` and in ``sim.integrate`` (only there are commands shaped).  Sensor effects
are applied by :meth:`bikeid.dataset.sensors.Sensors.with_effects`.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import asdict, dataclass
from typing import ClassVar

import numpy as np
from numba import njit

from .effect_law import KERNEL_SIGNALS, Law, parse_law
from .effect_registry import EFFECTS, V_FLOOR, effect

__all__ = [
    "PLANT_COLUMNS",
    "PLANT_SLOTS",
    "nonlinear_effects",
    "ActuatorLag",
    "InputChain",
    "InputDelay",
    "PlantLaw",
    "RollDamping",
    "RollStiffness",
    "SteerCoulomb",
    "SteerDamping",
    "SteerStiffness",
    "TorqueGain",
    "describe",
    "input_chain",
    "named_class",
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
    effect: ClassVar[str] = "steer_viscous_damping"
    nonnegative: ClassVar[bool] = True

    @property
    def value(self) -> float:
        """The registry value [the entry's unit]."""
        return self.c

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
    effect: ClassVar[str] = "steer_coulomb_friction"
    nonnegative: ClassVar[bool] = True

    @property
    def value(self) -> float:
        """The registry value [the entry's unit]."""
        return self.torque

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
    effect: ClassVar[str] = "roll_viscous_damping"
    nonnegative: ClassVar[bool] = True

    @property
    def value(self) -> float:
        """The registry value [the entry's unit]."""
        return self.c

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
    effect: ClassVar[str] = "roll_stiffness"
    nonnegative: ClassVar[bool] = True

    @property
    def value(self) -> float:
        """The registry value [the entry's unit]."""
        return self.k

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
    effect: ClassVar[str] = "steer_stiffness"
    nonnegative: ClassVar[bool] = False

    @property
    def value(self) -> float:
        """The registry value [the entry's unit]."""
        return self.k

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
    effect: ClassVar[str] = "command_gain"
    nonnegative: ClassVar[bool] = False

    @property
    def value(self) -> float:
        """The registry value [the entry's unit]."""
        return self.gain

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
    effect: ClassVar[str] = "actuator_lag"
    nonnegative: ClassVar[bool] = True

    @property
    def value(self) -> float:
        """The registry value [the entry's unit]."""
        return self.tau

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
    effect: ClassVar[str] = "input_delay"
    nonnegative: ClassVar[bool] = False

    @property
    def value(self) -> float:
        """The registry value [the entry's unit]."""
        return self.delay

    def __post_init__(self) -> None:
        _check("InputDelay.delay", self.delay, "s")


@dataclass(frozen=True)
class PlantLaw:
    """Any additive term of the language of :mod:`bikeid.sim.effect_law` on the plant.

    The generalized force ``sign * value * v**speed_power * signal`` of ``law`` at the run's
    speed ``speed`` (held fixed: the speed factor is evaluated once, as the registry folds
    1/v terms), a sign term smoothed as tanh(rate / smoothing).  The registry builds one for
    an entry without a named class (:func:`nonlinear_effects`).

    Parameters
    ----------
    law : Law or str
        The term (a string is parsed); a constant, a state or the sign of a rate (the
        plant's mass matrix and torque input are the rigid bodies': accelerations and the
        torque are refused).
    value : float
        The effect's value [the law's unit], finite.
    speed : float, optional
        Forward speed [m/s] of the speed factor (default 0: none allowed with a factor v).
    smoothing : float, optional
        tanh smoothing [rad/s] of a sign term, > 0 (default 0.01, as :class:`SteerCoulomb`).

    Attributes
    ----------
    kind : str
        ``"plant"``.

    Raises
    ------
    ValueError
        For a term the plant does not evaluate, a value that is not finite, a speed that is
        negative or not finite, or a smoothing that is not positive.
    """

    law: Law | str
    value: float
    speed: float = 0.0
    smoothing: float = 0.01
    kind = "plant"

    def __post_init__(self) -> None:
        if isinstance(self.law, str):
            object.__setattr__(self, "law", parse_law(self.law))
        if self.law.kernel_code is None:
            raise ValueError(
                f"PlantLaw {self.law.text()!r}: the nonlinear plant carries constants, states "
                "and signs of rates, not accelerations or the torque (its mass matrix and "
                "torque input are the rigid bodies'); use the linear experiment model"
            )
        if not math.isfinite(self.value):
            raise ValueError(f"PlantLaw.value must be finite {self.law.unit}, got {self.value!r}")
        _check("PlantLaw.speed", self.speed, "m/s")
        _check("PlantLaw.smoothing", self.smoothing, "rad/s", strict=True)

    def row(self) -> tuple[int, int, float, float]:
        """The plant-table row of this term.

        Returns
        -------
        tuple
            (output index, kernel code, coefficient [N m per unit of signal], smoothing).
        """
        coef = self.law.coefficient(self.value, self.speed, V_FLOOR)
        return 2 * self.law.index, self.law.kernel_code, coef, self.smoothing


def named_class(name: str) -> type | None:
    """The class of this module implementing registry entry ``name`` (None: none, the entry
    is carried as a :class:`PlantLaw`).

    Parameters
    ----------
    name : str
        Registry name.

    Returns
    -------
    type or None
    """
    return _NAMED.get(name)


def _row(e: object) -> tuple[int, int, float, float] | None:
    """The plant-table row of an effect object, or None for an input-side one."""
    if isinstance(e, PlantLaw):
        return e.row()
    name = getattr(type(e), "effect", None)
    if getattr(e, "kind", None) == "plant" and name in _NAMED:
        law = effect(name).law
        smooth = getattr(e, "smoothing", 1.0)
        return 2 * law.index, law.kernel_code, law.coefficient(e.value, 0.0, 1.0), smooth
    if getattr(e, "kind", None) == "input":
        return None
    raise ValueError(f"unknown effect {e!r}; use one of the dataclasses in sim.effects")


#: Columns of a plant-table row: output index (0 roll, 2 steer), kernel code
#: (:data:`bikeid.sim.effect_law.KERNEL_SIGNALS`), coefficient, tanh smoothing [rad/s].
PLANT_COLUMNS = ("output", "signal", "coefficient", "smoothing")


def plant_vector(effects: Iterable[object] | None = None) -> np.ndarray:
    """Compile the plant-side effects into the table read by :func:`plant_forces`.

    One row per term (:data:`PLANT_COLUMNS`): terms with the same equation, signal and
    smoothing add up (two dampers in parallel); rows are sorted by equation and then in the
    kernels' summation order (:data:`bikeid.sim.effect_law.KERNEL_SIGNALS`).  Input-side
    effects are ignored here.

    Parameters
    ----------
    effects : iterable of effect dataclasses, optional
        Plant- and input-side effects of this module; None or empty for none.

    Returns
    -------
    (n, 4) ndarray
        The rows: output index, signal code, coefficient [N m per unit of the signal, with
        the law's sign and speed factor], smoothing [rad/s] (that of a sign term, else 1).

    Raises
    ------
    ValueError
        For an object that is not an effect of this module, or a second sign term of the
        same rate on the same equation (e.g. a second :class:`SteerCoulomb`).
    """
    rows: dict[tuple[int, int, float], float] = {}
    for e in effects or ():
        r = _row(e)
        if r is None:
            continue
        out, code, coef, smooth = r
        if KERNEL_SIGNALS[code].startswith("sign"):
            if any(k[:2] == (out, code) for k in rows):
                raise ValueError("give at most one SteerCoulomb effect (one sign term per "
                                 "rate and equation)")  # fmt: skip
        else:
            smooth = 1.0
        key = (out, code, smooth)
        rows[key] = rows[key] + coef if key in rows else coef
    table = np.zeros((len(rows), 4))
    for i, key in enumerate(sorted(rows, key=lambda k: (k[0], k[1]))):
        table[i] = (key[0], key[1], rows[key], key[2])
    return table


@njit(cache=True)
def plant_forces(ev, q4, q7, u4, u6, u7, out):
    """Extra generalized forces [N m] on the (u4, u6, u7) equations; fills ``out``.

    Compiled with numba (called from the integrator's kernel).  Each row of the table adds
    ``coefficient * signal`` to its equation, the signals as
    :data:`bikeid.sim.effect_law.KERNEL_SIGNALS` (a sign as tanh(rate / smoothing)).

    Parameters
    ----------
    ev : (n, 4) ndarray
        Plant table from :func:`plant_vector`.
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
        equations (the wheel's is 0).

    Returns
    -------
    None
        The result is written into ``out``.
    """
    out[0] = 0.0
    out[1] = 0.0
    out[2] = 0.0
    for i in range(ev.shape[0]):
        code = int(ev[i, 1])
        if code == 0:
            x = 1.0
        elif code == 1:
            x = u4
        elif code == 2:
            x = u7
        elif code == 3:
            x = math.tanh(u4 / ev[i, 3])
        elif code == 4:
            x = math.tanh(u7 / ev[i, 3])
        elif code == 5:
            x = q4
        else:
            x = q7
        out[int(ev[i, 0])] += ev[i, 2] * x


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


_CLASSES = (SteerDamping, SteerCoulomb, RollDamping, RollStiffness, SteerStiffness, TorqueGain,
            ActuatorLag, InputDelay)  # fmt: skip
_NAMED: dict[str, type] = {c.effect: c for c in _CLASSES}


def _plant_slots() -> tuple[str, ...]:
    return tuple(n for n, e in EFFECTS.items() if e.layer == "plant" and e.plant_term == n)


#: The built-in plant entries the table carries, one row each, generated from the registry's
#: declarations (those folded into another, like the 1/v tyre terms, share its row).
PLANT_SLOTS = _plant_slots()


def nonlinear_effects(
    values: Mapping[str, float],
    speed: float,
    dt: float,
    coulomb_smoothing: float | None = None,
) -> tuple[list[object], dict[str, float]]:
    """The nonlinear-plant objects carrying the effects ``values`` at one speed.

    Parameters
    ----------
    values : mapping of str to float
        Effect values by registry name; names the plant cannot carry are skipped (their
        entry's ``no_plant`` says why).
    speed : float
        True forward speed [m/s], for the speed factors of the laws.
    dt : float
        Controller sample time [s]: an input delay is rounded to whole samples.
    coulomb_smoothing : float, optional
        tanh smoothing [rad/s] of the sign terms (default that of
        :class:`bikeid.sim.effects.SteerCoulomb`).

    Returns
    -------
    objects : list
        :mod:`bikeid.sim.effects` objects for :func:`bikeid.sim.integrate.simulate`: the
        entry's named class where :mod:`bikeid.sim.effects` has one, else a
        :class:`bikeid.sim.effects.PlantLaw` (an entry with a law needs nothing more).
    equivalent : dict of str to float
        The carried terms as effect values (1/v terms folded in at ``speed``, the delay
        rounded): the same model expressed in the plant's own terms.

    Raises
    ------
    ValueError
        If a name in ``values`` is not in the registry.

    Notes
    -----
    An entry folds into its ``plant_term`` as the value giving the same generalized force at
    ``speed``.  A term is carried when its value is not absent, except that a damping,
    friction or stiffness whose named class requires a value >= 0 is carried only when
    positive; a gain when not 1, a lag when positive and a delay when it rounds to at least
    one sample.
    """
    folded: dict[str, float] = {}
    for name, value in values.items():
        e = effect(name)
        if e.plant_term is None:
            continue
        target = EFFECTS[e.plant_term]
        if e.plant_term == name:
            x = float(value)
        elif e.law is not None:  # the value of the target's law giving the same force
            per_unit = target.law.coefficient(1.0, speed, V_FLOOR)
            x = e.law.coefficient(float(value), speed, V_FLOOR) / per_unit
        else:
            x = float(value)
        base = folded.get(e.plant_term, target.absent)
        folded[e.plant_term] = base * x if e.plant_term == "command_gain" else base + x
    objects: list[object] = []
    eq: dict[str, float] = {}
    for name in EFFECTS:  # registry order, so the result does not depend on dict order
        if name not in folded:
            continue
        x = folded[name]
        e = EFFECTS[name]
        cls = named_class(name)
        if name == "input_delay":
            x = round(x / dt) * dt
            keep = x > 0
        elif getattr(cls, "nonnegative", False):
            keep = x > 0
        else:
            keep = x != e.absent
        if not keep:
            continue
        smooth = {} if coulomb_smoothing is None else {"smoothing": coulomb_smoothing}
        if cls is None:
            objects.append(PlantLaw(e.law, x, speed, **smooth))
        elif e.law is not None and e.law.kind == "sign":
            objects.append(cls(x, **smooth))
        else:
            objects.append(cls(x))
        eq[name] = x
    return objects, eq
