"""A user's effects file: extra effects declared in the law language, without editing bikeid.

The file (YAML or JSON) lists declarations, either at the top level or under ``effects``::

    effects:
      - name: roll_support_damping        # a new name, or a built-in one (below)
        law: "roll: -c * phidot"          # bikeid.sim.effect_law
        unit: N m s/rad                   # must be the law's unit
        plausible: [0, 100]               # range of values accepted [unit]
        doc: roll torque of the treadmill's support   # optional
        in_library: true                  # optional (default true): a fit candidate
        scale: 2.0                        # optional: the fit's step [unit]
        value: 5.0                        # optional: the value `bikeid simulate` uses

Every declaration is an additive term with absent value 0, and joins the registry
(:func:`bikeid.sim.effect_registry.register_effects`) marked with its file: it is simulated
(constants, states and signs of rates by the nonlinear plant; every law by the linear
experiment model), a candidate of ``bikeid measured fit`` when ``in_library``, and saved with
a fitted model (the model file re-declares it).  A declaration that repeats a built-in
entry's law is refused, naming that entry, unless it takes the entry's own name: then it *is*
that entry, adopted with the file's range, scale and library membership (e.g. the built-in
``roll_viscous_damping``, outside the library, made a candidate).

Every problem (unknown key or term, wrong unit, duplicate law, value out of range) is one
line naming the file's line and the fix (:class:`bikeid.sim.errors.InputError`).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .effect_law import parse_law, same_unit
from .effect_registry import Effect, register_effects, unregister_effects
from .errors import InputError

__all__ = [
    "EffectsFile",
    "declaration",
    "declarations_from",
    "load_effects_file",
    "read_effects_file",
    "register",
]

_KEYS = ("name", "law", "unit", "plausible", "doc", "in_library", "scale", "value")
_REQUIRED = ("name", "law", "unit", "plausible")
_NAME_CHARS = set("abcdefghijklmnopqrstuvwxyz0123456789_")


@dataclass(frozen=True)
class EffectsFile:
    """The declarations of one effects file.

    Attributes
    ----------
    path : str
        The file.
    effects : tuple of Effect
        The declarations, in file order.
    values : dict of str to float
        The ``value`` of the declarations that give one [their units].
    lines : tuple of int
        Line of each declaration in the file (empty when unknown).
    """

    path: str
    effects: tuple[Effect, ...]
    values: dict[str, float]
    lines: tuple[int, ...] = ()

    @property
    def names(self) -> tuple[str, ...]:
        """The declared names, in file order."""
        return tuple(e.name for e in self.effects)


def declaration(e: Effect) -> dict:
    """A user entry as the file (and a model file) writes it.

    Parameters
    ----------
    e : Effect
        A registered entry with a law.

    Returns
    -------
    dict
        ``name``, ``law``, ``unit``, ``plausible``, ``doc``, ``in_library``, ``scale``.
    """
    return {"name": e.name, "law": e.law.text(), "unit": e.unit,
            "plausible": [e.plausible[0], e.plausible[1]], "doc": e.doc,
            "in_library": e.in_library, "scale": e.scale}  # fmt: skip


def _lines(text: str) -> list[dict[str, int]]:
    """Line (1-based) of each declaration's keys, by list position (empty when unknown)."""
    import yaml

    try:
        node = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.YAMLError:
        return []
    if isinstance(node, yaml.MappingNode):
        for k, v in node.value:
            if getattr(k, "value", None) == "effects":
                node = v
                break
    if not isinstance(node, yaml.SequenceNode):
        return []
    out = []
    for item in node.value:
        d = {"": item.start_mark.line + 1}
        if isinstance(item, yaml.MappingNode):
            for k, v in item.value:
                d[str(k.value)] = v.start_mark.line + 1
        out.append(d)
    return out


def _number(x: Any) -> float | None:
    if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
        return None
    return float(x)


def declarations_from(items: Any, where: str, lines: list | None = None,
                      origin: str | None = None) -> EffectsFile:  # fmt: skip
    """Build the declarations from parsed data (a list of mappings, or ``{"effects": [...]}``).

    Parameters
    ----------
    items : object
        Parsed YAML/JSON.
    where : str
        The source, for messages (a file name).
    lines : list of dict, optional
        Line of each declaration's keys (:func:`_lines`); messages then name the line.
    origin : str, optional
        The entries' ``origin`` (default ``where``).

    Returns
    -------
    EffectsFile
        The declarations (not registered).

    Raises
    ------
    InputError
        One line naming the problem, its line and the fix.
    """
    lines = lines or []
    if isinstance(items, dict) and set(items) == {"effects"}:
        items = items["effects"]
    if not isinstance(items, list) or not items:
        raise InputError(f"{where}: expected a list of effect declarations (or 'effects:' "
                         "with one); see bikeid.sim.effect_files for the format")  # fmt: skip
    effects, values = [], {}
    for i, item in enumerate(items):
        ln = lines[i] if i < len(lines) else {}

        def fail(msg: str, key: str = "", i=i, ln=ln) -> InputError:
            line = ln.get(key) or ln.get("")
            at = f"{where}:{line}" if line else f"{where}: declaration {i + 1}"
            return InputError(f"{at}: {msg}")

        if not isinstance(item, dict):
            raise fail("a declaration is a mapping with name, law, unit and plausible")
        name = item.get("name")
        label = f"effect {name!r}" if isinstance(name, str) else "effect"
        unknown = [k for k in item if k not in _KEYS]
        if unknown:
            raise fail(f"{label}: unknown key {unknown[0]!r}; use {', '.join(_KEYS)}",
                       str(unknown[0]))  # fmt: skip
        missing = [k for k in _REQUIRED if k not in item]
        if missing:
            raise fail(f"{label}: give its {missing[0]} (required: {', '.join(_REQUIRED)})")
        if not isinstance(name, str) or not name or not set(name) <= _NAME_CHARS:
            raise fail(f"name {name!r}: use lower-case letters, digits and _", "name")
        try:
            law = parse_law(item["law"])
        except ValueError as exc:
            raise fail(f"{label}: {exc}", "law") from None
        if law.kind == "torque":
            raise fail(f"{label}: a term in the steer torque T is the command gain "
                       "(command_gain); declare a term of the states, a rate's sign or a "
                       "constant", "law")  # fmt: skip
        unit = item["unit"]
        try:
            ok = isinstance(unit, str) and same_unit(unit, law.unit)
        except ValueError as exc:
            raise fail(f"{label}: {exc}", "unit") from None
        if not ok:
            raise fail(f"{label}: unit {unit!r} is not that of {law.text()!r}; write "
                       f"unit: {law.unit}", "unit")  # fmt: skip
        pl = item["plausible"]
        lo, hi = (_number(pl[0]), _number(pl[1])) if isinstance(pl, list) and len(pl) == 2 \
            else (None, None)  # fmt: skip
        if lo is None or hi is None or not lo <= 0.0 <= hi or lo == hi:
            raise fail(f"{label}: plausible {pl!r} must be [low, high] numbers with low <= 0 "
                       "<= high (0 is 'absent'), e.g. [0, 100]", "plausible")  # fmt: skip
        doc = item.get("doc", f"{law.equation} torque {law.text().split(': ', 1)[1]}")
        if not isinstance(doc, str):
            raise fail(f"{label}: doc must be one line of text", "doc")
        in_lib = item.get("in_library", True)
        if not isinstance(in_lib, bool):
            raise fail(f"{label}: in_library must be true or false", "in_library")
        scale = item.get("scale", max(abs(lo), abs(hi)) / 20.0)
        if _number(scale) is None or scale <= 0:
            raise fail(f"{label}: scale {scale!r} must be a number > 0 [{unit}]", "scale")
        carried = law.kernel_code is not None
        no_plant = "" if carried else (
            "an acceleration term changes the mass matrix, which the nonlinear plant takes "
            "from the rigid bodies: the linear experiment model carries it"
        )  # fmt: skip
        try:
            e = Effect(name, unit, 0.0, (lo, hi), in_lib, "plant" if carried else "linear",
                       doc.strip().splitlines()[0] if doc.strip() else name, law=law,
                       no_plant=no_plant, origin=origin or where, scale=float(scale))  # fmt: skip
        except ValueError as exc:
            raise fail(str(exc)) from None
        if "value" in item:
            try:
                values[name] = e.check(item["value"])
            except ValueError as exc:
                raise fail(f"{exc}; give a value inside it", "value") from None
        effects.append(e)
    seen: dict[str, int] = {}
    for i, e in enumerate(effects):
        if e.name in seen:
            raise InputError(f"{where}: effect {e.name!r} is declared twice (declarations "
                             f"{seen[e.name] + 1} and {i + 1}); keep one")  # fmt: skip
        seen[e.name] = i
    at = tuple(int(d.get("name") or d.get("", 0)) for d in lines[: len(effects)])
    return EffectsFile(where, tuple(effects), values, at if len(at) == len(effects) else ())


def read_effects_file(path: str | os.PathLike) -> EffectsFile:
    """Read and check a user's effects file (not registered yet).

    Parameters
    ----------
    path : str or path-like
        A ``.yaml``, ``.yml`` or ``.json`` file (module docstring).

    Returns
    -------
    EffectsFile

    Raises
    ------
    InputError
        If the file is missing, unreadable or malformed, or a declaration is invalid (one
        line naming the file's line and the fix).
    """
    from .textformats import loads_json, loads_yaml

    p = Path(path)
    where = str(path)
    if p.suffix.lower() not in (".yaml", ".yml", ".json"):
        raise InputError(f"effects file {where!r}: use a .yaml, .yml or .json file")
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(f"effects file {where!r} not found; check the path") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"effects file {where!r} cannot be read: {exc}") from None
    data = loads_json(text, where) if p.suffix.lower() == ".json" else loads_yaml(text, where)
    return declarations_from(data, where, _lines(text))


def load_effects_file(path: str | os.PathLike) -> EffectsFile:
    """Read a user's effects file and register its effects (the Python API of
    ``--effects-file``).

    Parameters
    ----------
    path : str or path-like
        The file (:func:`read_effects_file`).

    Returns
    -------
    EffectsFile
        The declarations, now in :data:`bikeid.sim.effect_registry.EFFECTS` (and, with
        ``in_library``, in the identification library once it is imported).

    Raises
    ------
    InputError
        For an invalid file or declaration, or a name or law that repeats a registered
        entry's (one line naming the file's line, both names and the fix).
    """
    f = read_effects_file(path)
    register(f)
    return f


def register(f: EffectsFile) -> tuple[str, ...]:
    """Register the declarations of ``f``; InputError naming the declaration's file line.

    Parameters
    ----------
    f : EffectsFile
        Declarations (:func:`read_effects_file`, or a model file's).

    Returns
    -------
    tuple of str
        The newly registered names.

    Raises
    ------
    InputError
        If a declaration repeats a registered entry's name or law (naming both).
    """
    done: list[str] = []
    for i, e in enumerate(f.effects):  # one at a time, so the message names the declaration
        try:
            done += register_effects([e])
        except ValueError as exc:
            unregister_effects(done)  # all or nothing
            at = f"{f.path}:{f.lines[i]}" if f.lines else f"{f.path}: declaration {i + 1}"
            raise InputError(f"{at}: {exc}") from None
    return f.names
