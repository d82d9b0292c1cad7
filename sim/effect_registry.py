"""The effect registry: every effect the Whipple model lacks, declared once.

An *effect* is one named physical or instrument term that a real bicycle experiment may
have and the Carvallo-Whipple model does not (steer friction, an actuator lag, a gyro
bias, ...).  Each is declared here exactly once, as an :class:`Effect`: its name (the
stable JSON key), unit, the value that means "absent", a plausible range for a real
bicycle, whether the identification library may select it, where it acts (its *layer*),
and how the nonlinear plant of :mod:`bikeid.sim.nonlinear` carries it, or why it cannot.

Higher stages attach their *application* of an entry and never re-spell its facts:

* :mod:`bikeid.sim.effects` implements the ``plant`` and ``input`` layers in the
  nonlinear simulator (:meth:`Effect.nonlinear` builds those objects);
* :mod:`bikeid.dataset.sensors` applies the ``sensor`` layer (bias and scale of a channel,
  :meth:`Effect.sensor`);
* the experiment model of the measured data (``bikeid.ident.effects.experiment_model``) applies
  every entry to the linear model, and the effect library (``bikeid.ident``) adds its fit
  settings (scale, bounds, scan grid) to the entries with ``in_library``.

Layers: ``plant`` (a generalized force on the roll or steer equation), ``input`` (shapes
the commanded steer torque: gain, delay, lag), ``sensor`` (what an instrument reports),
``parameter`` (a correction of a bicycle parameter; the plant sees it through the
parameters), ``linear`` (implemented in the linear experiment model only; the reason is
stated in the entry).

Adding an effect: declare it below; implement its application in each layer that carries
it (the experiment model always; the nonlinear plant where possible); add its tests.  The
README's "Adding an effect" section walks through an example.

Signs follow :mod:`bikeid.sim.conventions` (roll, steer and steer torque positive to the
right): a damping c gives the torque -c * rate, a stiffness k the torque -k * angle.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass

__all__ = [
    "EFFECTS",
    "LAYERS",
    "Effect",
    "RegistryFacts",
    "check_values",
    "effect",
    "library_names",
    "nonlinear_effects",
]

LAYERS = ("plant", "input", "sensor", "parameter", "linear")
#: Speed floor [m/s] of the 1/v laws (tyre scrub and twist), so they stay finite at rest.
V_FLOOR = 0.1


@dataclass(frozen=True)
class Effect:
    """One effect's declaration.

    Attributes
    ----------
    name : str
        Stable key (JSON, CLI, reports).
    unit : str
        Unit of the value, SI.
    absent : float
        The value that means "no such effect" (0 for additive terms, 1 for scales).
    plausible : (float, float)
        Closed range a real bicycle experiment can have [unit]; values outside it are refused
        where a user supplies them (model files, trial specifications).
    in_library : bool
        Whether the identification library may select it on measured data.  Effects outside
        it exist to test that the pipeline answers ``unexplained``.
    layer : str
        Where it acts, one of :data:`LAYERS`.
    doc : str
        One line: the term it adds, with its sign.
    plant_term : str or None
        For effects the nonlinear plant carries: the name of the effect whose
        :mod:`bikeid.sim.effects` object implements it (itself, or another entry it folds
        into, like the 1/v tyre scrub into the steer damping at the run's speed).
    per_speed : bool
        The term is ``value / max(v, V_FLOOR)`` at speed v when folded into ``plant_term``.
    sensor_channel, sensor_field : str or None
        For ``sensor`` effects: the :data:`bikeid.sim.conventions.MEASURED` channel and the
        instrument field (``"bias"`` or ``"scale"``) it sets.
    no_plant : str
        Why the nonlinear plant does not carry it (empty when it does).

    Raises
    ------
    ValueError
        On construction, if ``layer`` is not in :data:`LAYERS`, ``absent`` lies outside
        ``plausible``, or not exactly one of ``plant_term`` and ``no_plant`` is given.
    """

    name: str
    unit: str
    absent: float
    plausible: tuple[float, float]
    in_library: bool
    layer: str
    doc: str
    plant_term: str | None = None
    per_speed: bool = False
    sensor_channel: str | None = None
    sensor_field: str | None = None
    no_plant: str = ""

    def __post_init__(self) -> None:
        if self.layer not in LAYERS:
            raise ValueError(f"effect {self.name}: layer {self.layer!r} not in {LAYERS}")
        lo, hi = self.plausible
        if not lo <= self.absent <= hi:
            raise ValueError(f"effect {self.name}: absent value outside its plausible range")
        if (self.plant_term is None) == (not self.no_plant):
            raise ValueError(f"effect {self.name}: give plant_term or the reason in no_plant")

    def check(self, value: object, source: str = "") -> float:
        """``value`` as a float, or ValueError naming the effect, its unit and its range.

        Parameters
        ----------
        value : object
            A number (bool is refused: ``true`` is not a damping).
        source : str, optional
            Where the value came from (a file), for the message.

        Returns
        -------
        float
            The value [``unit``].

        Raises
        ------
        ValueError
            If ``value`` is not an int or float (or is a bool), is not finite, or lies
            outside :attr:`plausible`.
        """
        where = f"{source}: " if source else ""
        lo, hi = self.plausible
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueError(
                f"{where}effect {self.name} must be a number [{self.unit}], got {value!r}"
            )
        x = float(value)
        if not (math.isfinite(x) and lo <= x <= hi):
            raise ValueError(
                f"{where}effect {self.name} = {value!r} {self.unit} is outside its plausible "
                f"range [{lo:g}, {hi:g}] {self.unit}"
            )
        return x


def _e(*args, **kw) -> Effect:
    return Effect(*args, **kw)


_SENSOR = "a sensor term: applied by the instrument model (dataset.sensors), not the plant"
_PARAM = "a parameter correction: the plant sees it through the corrected parameters"

#: Every effect, by name (the order is the order of reports).
EFFECTS: Mapping[str, Effect] = {
    e.name: e
    for e in (
        _e("steer_viscous_damping", "N m s/rad", 0.0, (-1.0, 10.0), True, "plant",
           "steer torque -c * deltadot (bearing, motor)", plant_term="steer_viscous_damping"),
        _e("steer_coulomb_friction", "N m", 0.0, (0.0, 5.0), True, "plant",
           "steer torque -T_c * tanh(deltadot / smoothing)",
           plant_term="steer_coulomb_friction"),
        _e("steer_stiffness", "N m/rad", 0.0, (-10.0, 20.0), True, "plant",
           "steer torque -k * delta (centring: cables, belt, tyre twist)",
           plant_term="steer_stiffness"),
        _e("tire_twist_stiffness", "N m/rad * m/s", 0.0, (-20.0, 50.0), False, "plant",
           "steer torque -(k / v) * delta (contact-patch twist falling with speed)",
           plant_term="steer_stiffness", per_speed=True),
        _e("tire_scrub_torque", "N m s/rad * m/s", 0.0, (-5.0, 20.0), True, "plant",
           "steer torque -(k / v) * deltadot (tyre scrub damping)",
           plant_term="steer_viscous_damping", per_speed=True),
        _e("command_gain", "-", 1.0, (0.05, 5.0), True, "input",
           "applied steer torque = gain * command (motor torque constant)",
           plant_term="command_gain"),
        _e("steer_torque_bias", "N m", 0.0, (-2.0, 2.0), True, "linear",
           "constant steer torque",
           no_plant="the nonlinear simulator has no constant-torque term; the linear "
           "experiment model carries it"),
        _e("input_delay", "s", 0.0, (0.0, 0.1), True, "input",
           "command applied this long later", plant_term="input_delay"),
        _e("actuator_lag", "s", 0.0, (0.0, 0.2), True, "input",
           "first-order lag tau T' = T_cmd - T of the applied torque",
           plant_term="actuator_lag"),
        _e("roll_angle_bias", "rad", 0.0, (-0.2, 0.2), True, "sensor",
           "phi_m = phi + b (IMU roll offset)", sensor_channel="phi", sensor_field="bias",
           no_plant=_SENSOR),
        _e("steer_angle_bias", "rad", 0.0, (-0.2, 0.2), True, "sensor",
           "delta_m = delta + b (encoder zero)", sensor_channel="delta", sensor_field="bias",
           no_plant=_SENSOR),
        _e("roll_rate_bias", "rad/s", 0.0, (-0.5, 0.5), True, "sensor",
           "phidot_m = s phidot + b (gyro bias; the controller sees it)",
           sensor_channel="phidot", sensor_field="bias", no_plant=_SENSOR),
        _e("roll_rate_scale", "-", 1.0, (0.2, 5.0), True, "sensor",
           "s in phidot_m = s phidot + b (gyro scale factor)", sensor_channel="phidot",
           sensor_field="scale", no_plant=_SENSOR),
        _e("speed_scale", "-", 1.0, (0.3, 3.0), True, "parameter",
           "true speed = s * calibrated speed",
           no_plant="a speed calibration: the plant runs at the corrected speed"),
        _e("steer_inertia", "kg m^2", 0.0, (-0.2, 1.0), True, "linear",
           "added to M[delta, delta] (front-frame inertia about the steer axis)",
           no_plant="an entry of M alone has no rigid-body counterpart in the nonlinear "
           "plant; use front_inertia_scale for a physical inertia change"),
        _e("trail_correction", "m", 0.0, (-0.07, 0.2), True, "parameter",
           "trail c -> c + dc (all matrices recomputed)", no_plant=_PARAM),
        _e("front_inertia_scale", "-", 1.0, (0.2, 20.0), True, "parameter",
           "front-frame inertia tensor IH times s", no_plant=_PARAM),
        _e("front_mass_shift", "kg", 0.0, (-0.5, 5.0), True, "parameter",
           "mass moved from the rear to the front frame (total mass and centre kept)",
           no_plant=_PARAM),
        _e("rear_inertia_scale", "-", 1.0, (0.5, 2.0), True, "parameter",
           "rear-frame inertia tensor IB times s", no_plant=_PARAM),
        _e("tire_relaxation", "m", 0.0, (0.0, 0.6), True, "linear",
           "front-tyre lateral relaxation length sigma (heading lag sigma / v)",
           no_plant="the nonlinear plant has knife-edge non-slip wheels; the relaxed front "
           "constraint exists in the linear experiment model only"),
        _e("roll_viscous_damping", "N m s/rad", 0.0, (0.0, 100.0), False, "plant",
           "roll torque -c * phidot (air, support)", plant_term="roll_viscous_damping"),
        _e("roll_stiffness", "N m/rad", 0.0, (0.0, 1000.0), False, "plant",
           "roll torque -k * phi (tether, support frame)", plant_term="roll_stiffness"),
    )  # fmt: skip
}


class RegistryFacts:
    """Mixin for a higher layer's application of an effect: the registry's facts by name.

    A class with a ``name`` attribute (a registry name) gains read-only ``entry``, ``unit``,
    ``absent`` and ``in_library``, so that it never re-spells them.

    Attributes
    ----------
    name : str
        Registry name (set by the subclass, e.g. a dataclass field).
    """

    name: str

    @property
    def entry(self) -> Effect:
        """The registry entry (:func:`effect`)."""
        return effect(self.name)

    @property
    def unit(self) -> str:
        """Unit of the value (registry)."""
        return self.entry.unit

    @property
    def absent(self) -> float:
        """The value that means "no such effect" (registry)."""
        return self.entry.absent

    @property
    def in_library(self) -> bool:
        """Whether the identification library may select it (registry)."""
        return self.entry.in_library


def effect(name: str) -> Effect:
    """The registry entry of an effect.

    Parameters
    ----------
    name : str
        Registry name (a key of :data:`EFFECTS`).

    Returns
    -------
    Effect

    Raises
    ------
    ValueError
        If ``name`` is unknown (the message lists the known names).
    """
    try:
        return EFFECTS[name]
    except (KeyError, TypeError):
        raise ValueError(
            f"unknown effect {name!r}; known effects are {', '.join(EFFECTS)}"
        ) from None


def library_names() -> tuple[str, ...]:
    """Names of the effects the identification library may select.

    Returns
    -------
    tuple of str
        Names with ``in_library`` true, in registry order.
    """
    return tuple(n for n, e in EFFECTS.items() if e.in_library)


def _plant_builders() -> dict[str, Callable[[float], object]]:
    from . import effects as fx

    return {
        "steer_viscous_damping": fx.SteerDamping,
        "steer_coulomb_friction": fx.SteerCoulomb,
        "steer_stiffness": fx.SteerStiffness,
        "command_gain": fx.TorqueGain,
        "input_delay": fx.InputDelay,
        "actuator_lag": fx.ActuatorLag,
        "roll_viscous_damping": fx.RollDamping,
        "roll_stiffness": fx.RollStiffness,
    }


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
        True forward speed [m/s], for the 1/v terms.
    dt : float
        Controller sample time [s]: an input delay is rounded to whole samples.
    coulomb_smoothing : float, optional
        tanh smoothing [rad/s] of the steer Coulomb friction (default that of
        :class:`bikeid.sim.effects.SteerCoulomb`).

    Returns
    -------
    objects : list
        :mod:`bikeid.sim.effects` objects for :func:`bikeid.sim.integrate.simulate`.
    equivalent : dict of str to float
        The carried terms as effect values (1/v terms folded in at ``speed``, the delay
        rounded): the same model expressed in the plant's own terms.

    Raises
    ------
    ValueError
        If a name in ``values`` is not in the registry.

    Notes
    -----
    A folded damping or friction is carried only when positive, a stiffness when non-zero,
    a gain when not 1, a lag when positive and a delay when it rounds to at least one sample.
    """
    folded: dict[str, float] = {}
    for name, value in values.items():
        e = effect(name)
        if e.plant_term is None:
            continue
        x = float(value) / max(speed, V_FLOOR) if e.per_speed else float(value)
        base = folded.get(e.plant_term, EFFECTS[e.plant_term].absent)
        folded[e.plant_term] = base * x if e.plant_term == "command_gain" else base + x
    build = _plant_builders()
    objects: list[object] = []
    eq: dict[str, float] = {}
    for name in EFFECTS:  # registry order, so the result does not depend on dict order
        if name not in folded:
            continue
        x = folded[name]
        if name == "input_delay":
            x = round(x / dt) * dt
            keep = x > 0
        elif name == "command_gain":
            keep = x != 1.0
        elif name == "steer_stiffness":
            keep = x != 0.0
        else:
            keep = x > 0
        if not keep:
            continue
        if name == "steer_coulomb_friction" and coulomb_smoothing is not None:
            objects.append(build[name](x, smoothing=coulomb_smoothing))
        else:
            objects.append(build[name](x))
        eq[name] = x
    return objects, eq


def check_values(values: Mapping[str, object], source: str = "") -> dict[str, float]:
    """Validate a mapping of effect values (names known, numbers in range).

    Parameters
    ----------
    values : mapping
        Effect name -> value, as read from a file.
    source : str, optional
        Where the mapping came from, for messages.

    Returns
    -------
    dict of str to float
        The values as floats, keyed by name, in the order of ``values``.

    Raises
    ------
    ValueError
        If ``values`` is not a mapping, a name is unknown, or a value is not a number in
        its plausible range (:meth:`Effect.check`).
    """
    if not isinstance(values, Mapping):
        raise ValueError(f"{source or 'effects'}: expected a mapping of effect names to numbers")
    out = {}
    for k, v in values.items():
        try:
            entry = effect(k)
        except ValueError as exc:
            raise ValueError(f"{source}: {exc}" if source else str(exc)) from None
        out[str(k)] = entry.check(v, source)
    return out
