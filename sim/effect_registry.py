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

Laws: every additive equation-of-motion entry (layer ``plant``, and the ``linear`` entries
that add a term, the steer inertia and the constant steer torque) carries its *law* in the
language of :mod:`bikeid.sim.effect_law` (``"steer: -c * deltadot"``): equation, term, sign,
speed factor, and from them the unit of its value and the entry of the linear model it
changes (:func:`linear_entry`).  The loops apply the laws from this table: the nonlinear
plant's compiled forces (:mod:`bikeid.sim.effects`), the experiment model's matrices and
sampled loop and the equation-error regressors (``bikeid.ident.effects``).  The other entries
keep their code and say why: an input entry shapes the command (gain, delay, lag are not
additive terms of the equations), a sensor entry changes what an instrument reports, a
parameter entry changes the bicycle, and the tyre relaxation adds a state.  Two entries with
the same law (the same equation, term and speed factor, whatever the sign) are refused at
import, naming both.

Adding a plant effect: one declaration with its law below, and a test.  The plant, the
experiment model, the diagnostics and, when ``in_library``, the identification (which needs
the fit settings of ``bikeid.ident.effects.library.LIBRARY``) follow from it.  Effects from a
user's file join the table through :func:`register_effects` (:mod:`bikeid.sim.effect_files`
reads the file).

Signs follow :mod:`bikeid.sim.conventions` (roll, steer and steer torque positive to the
right): a damping c gives the torque -c * rate, a stiffness k the torque -k * angle.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, replace

from .effect_law import Law, parse_law, same_unit

__all__ = [
    "EFFECTS",
    "LAYERS",
    "Effect",
    "RegistryFacts",
    "check_values",
    "effect",
    "law_entries",
    "library_names",
    "linear_entry",
    "no_law_reason",
    "on_register",
    "register_effects",
    "unregister_effects",
    "user_effects",
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
    law : Law or str or None
        The generalized-force term it adds (:mod:`bikeid.sim.effect_law`; a string is
        parsed); required for the ``plant`` layer, None for the input, sensor and parameter
        layers.  ``unit`` must be the law's unit.
    plant_term : str or None
        For effects the nonlinear plant carries: the name of the effect whose
        :mod:`bikeid.sim.effects` row implements it (itself, the default of a ``plant``
        entry, or another entry it folds into, like the 1/v tyre scrub into the steer
        damping at the run's speed).
    sensor_channel, sensor_field : str or None
        For ``sensor`` effects: the :data:`bikeid.sim.conventions.MEASURED` channel and the
        instrument field (``"bias"`` or ``"scale"``) it sets.
    no_plant : str
        Why the nonlinear plant does not carry it (empty when it does).
    origin : str
        ``"built-in"``, or the file a user's declaration came from.
    scale : float or None
        A user effect's typical magnitude [unit], the fit's unit step (None: built in, the
        library's setting).

    Raises
    ------
    ValueError
        On construction, if ``layer`` is not in :data:`LAYERS`, ``absent`` lies outside
        ``plausible``, not exactly one of ``plant_term`` and ``no_plant`` is given, a
        ``plant`` entry has no law, a law is given to an input, sensor or parameter entry,
        or ``unit`` is not the law's unit.
    """

    name: str
    unit: str
    absent: float
    plausible: tuple[float, float]
    in_library: bool
    layer: str
    doc: str
    law: Law | str | None = None
    plant_term: str | None = None
    sensor_channel: str | None = None
    sensor_field: str | None = None
    no_plant: str = ""
    origin: str = "built-in"
    scale: float | None = None

    def __post_init__(self) -> None:
        if self.layer not in LAYERS:
            raise ValueError(f"effect {self.name}: layer {self.layer!r} not in {LAYERS}")
        lo, hi = self.plausible
        if not lo <= self.absent <= hi:
            raise ValueError(f"effect {self.name}: absent value outside its plausible range")
        if isinstance(self.law, str):
            object.__setattr__(self, "law", parse_law(self.law))
        if self.law is None and self.layer == "plant":
            raise ValueError(f"effect {self.name}: a plant entry needs its law")
        if self.law is not None:
            if self.law.kind == "torque":
                raise ValueError(
                    f"effect {self.name}: a term in the steer torque T is the command gain "
                    "(command_gain); declare a term of the states, a rate's sign or a constant"
                )
            if self.layer not in ("plant", "linear"):
                raise ValueError(f"effect {self.name}: a {self.layer} entry has no law")
            if not same_unit(self.unit, self.law.unit):
                raise ValueError(
                    f"effect {self.name}: unit {self.unit!r} is not that of its law "
                    f"{self.law.text()!r}, {self.law.unit}"
                )
            if self.layer == "plant" and self.plant_term is None and not self.no_plant:
                object.__setattr__(self, "plant_term", self.name)
        if (self.plant_term is None) == (not self.no_plant):
            raise ValueError(f"effect {self.name}: give plant_term or the reason in no_plant")

    @property
    def per_speed(self) -> bool:
        """The law divides by the speed (a 1/v term, folded at the run's speed)."""
        return self.law is not None and self.law.speed_power == -1

    @property
    def user(self) -> bool:
        """Declared in a user's file (not built in)."""
        return self.origin != "built-in"

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
_BUILT_IN = (
        _e("steer_viscous_damping", "N m s/rad", 0.0, (-1.0, 10.0), True, "plant",
           "steer torque -c * deltadot (bearing, motor)", law="steer: -c * deltadot"),
        _e("steer_coulomb_friction", "N m", 0.0, (0.0, 5.0), True, "plant",
           "steer torque -T_c * tanh(deltadot / smoothing)",
           law="steer: -T_c * sign(deltadot)"),
        _e("steer_stiffness", "N m/rad", 0.0, (-10.0, 20.0), True, "plant",
           "steer torque -k * delta (centring: cables, belt, tyre twist)",
           law="steer: -k * delta"),
        _e("tire_twist_stiffness", "N m/rad * m/s", 0.0, (-20.0, 50.0), False, "plant",
           "steer torque -(k / v) * delta (contact-patch twist falling with speed)",
           law="steer: -k / v * delta", plant_term="steer_stiffness"),
        _e("tire_scrub_torque", "N m s/rad * m/s", 0.0, (-5.0, 20.0), True, "plant",
           "steer torque -(k / v) * deltadot (tyre scrub damping)",
           law="steer: -k / v * deltadot", plant_term="steer_viscous_damping"),
        _e("command_gain", "-", 1.0, (0.05, 5.0), True, "input",
           "applied steer torque = gain * command (motor torque constant)",
           plant_term="command_gain"),
        _e("steer_torque_bias", "N m", 0.0, (-2.0, 2.0), True, "linear",
           "constant steer torque", law="steer: +b",
           no_plant="carried by the linear experiment model only: the documented fits take "
           "the nonlinear defect correction without it"),
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
           law="steer: -I * deltaddot",
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
           "roll torque -c * phidot (air, support)", law="roll: -c * phidot"),
        _e("roll_stiffness", "N m/rad", 0.0, (0.0, 1000.0), False, "plant",
           "roll torque -k * phi (tether, support frame)", law="roll: -k * phi"),
    )  # fmt: skip


def _refuse_duplicates(entries: Iterable[Effect], table: Mapping[str, Effect]) -> None:
    """ValueError naming both entries if a name or a law repeats one of ``table``'s or
    another of ``entries``' (the law's sign does not matter: -c and +c are one term)."""
    names = dict(table)
    laws = {e.law.key: e for e in table.values() if e.law is not None}
    for e in entries:
        if e.name in names:
            raise ValueError(f"effect {e.name!r} is declared twice ({names[e.name].origin} "
                             f"and {e.origin}); give the new one another name")  # fmt: skip
        names[e.name] = e
        if e.law is None:
            continue
        other = laws.get(e.law.key)
        if other is not None:
            raise ValueError(
                f"effect {e.name!r} has the same law {e.law.text()!r} as {other.name!r} "
                f"({other.origin}); one term needs one effect: use {other.name!r}"
            )
        laws[e.law.key] = e


def _table(entries: Iterable[Effect]) -> dict[str, Effect]:
    out: dict[str, Effect] = {}
    entries = list(entries)
    _refuse_duplicates(entries, out)
    for e in entries:
        out[e.name] = e
    return out


#: Every effect, by name (the order is the order of reports): the built-in entries, then
#: those of :func:`register_effects` (a user's file).
EFFECTS: dict[str, Effect] = _table(_BUILT_IN)
_LISTENERS: list[Callable[[tuple[Effect, ...], bool], None]] = []
_SHADOWED: dict[str, Effect] = {}  # built-in entries a user's declaration adopted

#: Why an entry without a law has none, by layer (or by name).
_NO_LAW = {
    "input": "shapes the commanded steer torque (gain, delay, lag): not an additive term of "
    "the equations; sim.effects.input_chain and the experiment model apply it",
    "sensor": "changes what an instrument reports, not the equations of motion",
    "parameter": "changes the bicycle's parameters: every matrix is recomputed",
    "tire_relaxation": "adds a state (the kinematic steer of the relaxed front contact), not "
    "a term of the two equations",
}


def no_law_reason(name: str) -> str:
    """Why an entry has no law (empty if it has one).

    Parameters
    ----------
    name : str
        Registry name.

    Returns
    -------
    str
        One line.
    """
    e = effect(name)
    if e.law is not None:
        return ""
    return _NO_LAW.get(name) or _NO_LAW[e.layer]


def law_entries() -> tuple[Effect, ...]:
    """The entries with a law (built in and registered), in registry order.

    Returns
    -------
    tuple of Effect
    """
    return tuple(e for e in EFFECTS.values() if e.law is not None)


def linear_entry(e: Effect) -> str:
    """The entry of the linear model (M q'' + C q' + K q = f, Meijaard 2007 eq. A.21) that a
    law changes, e.g. ``"C[steer, deltadot] += c"``.

    Parameters
    ----------
    e : Effect
        An entry with a law.

    Returns
    -------
    str
        One line: the matrix (M, C, K), the forcing f, or the torque input b_T.
    """
    law = e.law
    if law is None:
        return ""
    row = law.equation
    vf = {-1: " / v", 0: "", 1: " * v", 2: " * v^2"}[law.speed_power]
    val = f"{'-' if law.sign > 0 else ''}value{vf}"
    kind = law.kind
    if kind in ("constant", "sign"):
        fval = f"{'+' if law.sign > 0 else '-'}value{vf}"
        what = "" if kind == "constant" else f" * {law.signal}"
        return f"f[{row}] += {fval}{what}"
    if kind == "torque":
        return f"b_T[{row}] {'+' if law.sign > 0 else '-'}= value"
    mat = {"rate": "C", "angle": "K", "acceleration": "M"}[kind]
    col = {"phi": "phi", "delta": "delta", "phidot": "phi", "deltadot": "delta",
           "phiddot": "phi", "deltaddot": "delta"}[law.signal]  # fmt: skip
    return f"{mat}[{row}, {col}] += {val}"


def _adopted(builtin: Effect, e: Effect) -> Effect:
    """A built-in entry adopted by a user's declaration of its name and law: the built-in
    facts (layer, plant term, doc, unit) with the declaration's range, library membership,
    scale and origin."""
    return replace(builtin, plausible=e.plausible, in_library=e.in_library, scale=e.scale,
                   origin=e.origin)  # fmt: skip


def register_effects(entries: Iterable[Effect]) -> tuple[str, ...]:
    """Add effects (a user's declarations) to :data:`EFFECTS`, after the built-in ones.

    An entry identical to a registered one is accepted again (a model file re-declares
    the effects it was fitted with).  An entry with a built-in name and the same law adopts
    that entry: its built-in facts with the declaration's plausible range, library
    membership, scale and origin (so an entry outside the library becomes a candidate);
    :func:`unregister_effects` restores it.

    Parameters
    ----------
    entries : iterable of Effect
        The declarations (``origin`` names their file).

    Returns
    -------
    tuple of str
        The names of the newly registered (or adopted) entries.

    Raises
    ------
    ValueError
        If a name is already registered with another declaration, or a law repeats a
        registered entry's (naming both).
    """
    new: list[Effect] = []
    adopt: list[Effect] = []
    for e in entries:
        old = EFFECTS.get(e.name)
        builtin = _SHADOWED.get(e.name, old)
        if (
            old is not None
            and builtin is not None
            and not builtin.user
            and (builtin.law is not None and builtin.law == e.law)
        ):
            if replace(old, origin=e.origin) != _adopted(builtin, e):
                if old.user:
                    raise ValueError(f"effect {e.name!r} is already adopted from "
                                     f"{old.origin}; declare it once")  # fmt: skip
                adopt.append(_adopted(builtin, e))
            continue
        if old is not None and old.user and replace(old, origin=e.origin) == e:
            continue  # declared again (a model file re-declares its effects)
        new.append(e)
    _refuse_duplicates(new, EFFECTS)
    for e in adopt:
        _SHADOWED[e.name] = EFFECTS[e.name]
        EFFECTS[e.name] = e
    for e in new:
        EFFECTS[e.name] = e
    for listener in _LISTENERS:
        listener((*adopt, *new), True)
    return tuple(e.name for e in (*adopt, *new))


def unregister_effects(names: Iterable[str]) -> None:
    """Remove registered user effects from :data:`EFFECTS` (an adopted built-in entry is
    restored; built-in names are refused).

    Parameters
    ----------
    names : iterable of str
        Names returned by :func:`register_effects`.

    Raises
    ------
    ValueError
        For a built-in name that no user adopted.
    """
    gone = []
    for n in names:
        e = EFFECTS.get(n)
        if e is None:
            continue
        if not e.user:
            raise ValueError(f"effect {n!r} is built in; only a user's effects can be removed")
        gone.append(e)
        if n in _SHADOWED:
            EFFECTS[n] = _SHADOWED.pop(n)
        else:
            del EFFECTS[n]
    for listener in _LISTENERS:
        listener(tuple(gone), False)


def on_register(listener: Callable[[tuple[Effect, ...], bool], None]) -> None:
    """Call ``listener(entries, added)`` whenever user effects are added or removed (the
    identification library adds its candidates so).

    Parameters
    ----------
    listener : callable
        ``listener(entries, added)``; ``added`` False on removal.
    """
    _LISTENERS.append(listener)


def user_effects() -> tuple[Effect, ...]:
    """The registered user effects, in registration order.

    Returns
    -------
    tuple of Effect
    """
    return tuple(e for e in EFFECTS.values() if e.user)


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
