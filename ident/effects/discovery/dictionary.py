"""The term dictionary of the discovery: every term of the roll and steer equations that the
effect laws' language (:mod:`bikeid.sim.effect_law`) can write, generated from it.

For each equation (roll, steer) the dictionary holds, classified by :attr:`Law.kind`:

- each state (phi, delta, phidot, deltadot) and the steer torque T, alone and (states only:
  the language gives T no speed factor) times v, v^2 and 1/v;
- the two accelerations (phiddot, deltaddot);
- the sign of each rate (sign(phidot), sign(deltadot));
- a constant (``1``).

That is 22 terms per equation, 44 in all.  A term's coefficient is the generalized torque
[N m] it adds to its equation per unit of the term (:attr:`Term.unit`, SI), positive adding
torque in bikeid's sign convention (roll, steer and torques positive to the right,
:mod:`bikeid.sim.conventions`): the torque is ``coefficient * term``.

Each term is carried by a registry entry (:mod:`bikeid.sim.effect_registry`): the entry
already declaring its law (built in, e.g. ``roll_viscous_damping``, or from a user's file),
else one declared for it through the effects-file mechanism
(:func:`bikeid.sim.effect_files.declarations_from`, :func:`declarations`).  The steer
equation's T is the command gain (``command_gain``: coefficient = gain - 1); the roll
equation's T has no entry (the experiment model applies the steer torque to the steer
equation only) and is listed with the reason (:attr:`Term.no_closure`).

:func:`injection_file` writes any terms with values as an effects file, so the project's own
generator (:func:`bikeid.ident.effects.synthetic_decays.synthetic_windows` on an
:class:`~bikeid.ident.effects.experiment_model.ExperimentModel` with the file's values) draws
decays whose answer a test knows.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path

from bikeid.sim.effect_law import EQUATIONS, SIGNALS, SPEED_POWERS, Law, all_laws, parse_law
from bikeid.sim.effect_registry import EFFECTS, register_effects, unregister_effects

__all__ = [
    "ORIGIN",
    "Term",
    "declarations",
    "dictionary",
    "injection_file",
    "registered",
    "term_by_name",
]

#: ``origin`` of the registry entries declared for dictionary terms.
ORIGIN = "discovery dictionary"
#: Kinds of signal that take the speed factors (the states and, where the language allows
#: one, the torque: :func:`~bikeid.sim.effect_law.all_laws` drops T's).
_WITH_SPEED = ("angle", "rate", "torque")
#: The registry entry of the steer torque term (the language refuses T in a declaration).
_TORQUE_ENTRY = {"steer": "command_gain"}
_COORD = {"phi": "roll", "delta": "steer"}
_KIND_NAME = {"rate": "viscous damping", "angle": "stiffness", "sign": "Coulomb friction",
              "acceleration": "inertia"}  # fmt: skip
_SPEED_READING = {1: " growing with v", 2: " growing with v^2", -1: " falling as 1/v", 0: ""}


def _coordinate(signal: str) -> str:
    """The coordinate a signal belongs to (roll or steer; empty for the constant and T)."""
    s = signal.removeprefix("sign(").removesuffix(")")
    for c in ("phi", "delta"):
        if s.startswith(c):
            return _COORD[c]
    return ""


def _reading(law: Law) -> str:
    """A physical name of the term, generated from its equation, signal and speed power."""
    kind, eq = law.kind, law.equation
    if kind == "constant":
        return f"constant {eq} torque (or an offset of a {eq}-equation signal)"
    if kind == "torque":
        return ("steer command gain - 1 (motor torque constant)" if eq == "steer"
                else "steer torque acting on the roll equation")  # fmt: skip
    coord = _coordinate(law.signal)
    base = _KIND_NAME[kind]
    signal = {"rate": "rate", "angle": "angle", "sign": "rate's sign",
              "acceleration": "acceleration"}[kind]  # fmt: skip
    what = f"{eq} {base}" if coord == eq else f"{eq} torque from the {coord} {signal}"
    return what + _SPEED_READING[law.speed_power]


def _slug(law: Law) -> str:
    """A registry name for a term without an entry: ``roll_v_phidot``, ``steer_delta_per_v``."""
    s = law.signal.replace("sign(", "sign_").replace(")", "")
    s = "constant" if s == "1" else s
    p = law.speed_power
    return f"{law.equation}_" + {0: s, 1: f"v_{s}", 2: f"v2_{s}", -1: f"{s}_per_v"}[p]


@dataclass(frozen=True)
class Term:
    """One term of the dictionary.

    Attributes
    ----------
    law : Law
        The term in the law language (the registry entry's law; sign -1 for a generated one).
    entry : str
        The registry name that carries it: an existing entry with its law, ``command_gain``
        for the steer torque, else :attr:`generated_name` (declared by :func:`registered`).
    no_closure : str
        Why the closure cannot fit the term (empty when it can).
    """

    law: Law
    entry: str
    no_closure: str = ""

    @property
    def equation(self) -> str:
        """``"roll"`` or ``"steer"``."""
        return self.law.equation

    @property
    def term(self) -> str:
        """The term in bikeid's signal names (``phidot``, ``v*deltadot``, ``1``)."""
        return self.law.term

    @property
    def label(self) -> str:
        """``equation: term``, e.g. ``roll: phidot``."""
        return f"{self.equation}: {self.term}"

    @property
    def unit(self) -> str:
        """SI unit of the coefficient: generalized torque per unit of the term."""
        return self.law.unit

    @property
    def reading(self) -> str:
        """A physical name (e.g. ``"roll viscous damping"``)."""
        return _reading(self.law)

    @property
    def generated_name(self) -> str:
        """The name a declaration for this term takes when no entry carries its law."""
        return _slug(self.law)

    @property
    def absent(self) -> float:
        """The entry's value meaning "no such term" (0; 1 for the command gain)."""
        return EFFECTS[self.entry].absent if self.entry in EFFECTS else 0.0

    def coefficient(self, value: float) -> float:
        """The term's coefficient [:attr:`unit`] for an entry value [the entry's unit].

        Parameters
        ----------
        value : float
            The registry entry's value.

        Returns
        -------
        float
            ``sign * (value - absent)``: positive adds torque (the law's sign; +1 for T).
        """
        sign = 1 if self.law.kind == "torque" else self.law.sign
        return sign * (float(value) - self.absent)

    def value(self, coefficient: float) -> float:
        """The entry value [the entry's unit] of a coefficient (inverse of :meth:`coefficient`).

        Parameters
        ----------
        coefficient : float
            Generalized torque per unit of the term [:attr:`unit`].

        Returns
        -------
        float
        """
        sign = 1 if self.law.kind == "torque" else self.law.sign
        return self.absent + sign * float(coefficient)


def dictionary(equations: tuple[str, ...] = EQUATIONS) -> list[Term]:
    """The dictionary, generated from the law language (module docstring).

    Parameters
    ----------
    equations : tuple of str, optional
        Equations (default both, roll then steer).

    Returns
    -------
    list of Term
        22 terms per equation, in the language's order (equation, signal, speed power); each
        term's entry is the registered one with its law where there is one.
    """
    by_key = {e.law.key: e for e in EFFECTS.values() if e.law is not None}
    speed = tuple(s for s in SIGNALS if Law("roll", s).kind in _WITH_SPEED)
    plain = tuple(s for s in SIGNALS if s not in speed)
    laws = {law.key: law for law in all_laws(equations, speed, SPEED_POWERS)}
    laws.update({law.key: law for law in all_laws(equations, plain, (0,))})
    order = {s: i for i, s in enumerate(SIGNALS)}
    out = []
    for key in sorted(laws, key=lambda k: (EQUATIONS.index(k[0]), order[k[1]], k[2] % 5)):
        law = laws[key]
        if law.kind == "torque":
            entry = _TORQUE_ENTRY.get(law.equation)
            why = "" if entry else ("the experiment model applies the steer torque to the "
                                    "steer equation only; no entry carries it on the roll "
                                    "equation")  # fmt: skip
            out.append(Term(law, entry or "", why))
            continue
        e = by_key.get(key)
        out.append(Term(e.law, e.name) if e is not None else Term(law, _slug(law)))
    return out


def term_by_name(text: str, terms: list[Term] | None = None) -> Term:
    """The dictionary term written ``"equation: term"`` (``"roll: v*phidot"``) or as a law.

    Parameters
    ----------
    text : str
        ``"roll: phidot"``, ``"steer: deltadot/v"``, or a law (``"roll: -c * phidot"``).
    terms : list of Term, optional
        The dictionary (default :func:`dictionary`).

    Returns
    -------
    Term

    Raises
    ------
    ValueError
        Naming the text and how to write a term.
    """
    terms = terms if terms is not None else dictionary()
    for t in terms:
        if t.label.replace(" ", "") == str(text).replace(" ", ""):
            return t
    try:
        key = parse_law(text).key
    except ValueError:
        key = None
    for t in terms:
        if t.law.key == key:
            return t
    raise ValueError(f"{text!r} is no term of the dictionary; write it as 'roll: v*phidot' "
                     f"(equation: term), e.g. {', '.join(t.label for t in terms[:3])}")  # fmt: skip


def declarations(terms: list[Term], values: Mapping[str, float] | None = None,
                 in_library: bool = False, span: float = 10.0) -> list[dict]:  # fmt: skip
    """Effects-file declarations of terms (:mod:`bikeid.sim.effect_files`).

    Parameters
    ----------
    terms : list of Term
        Terms carried by a law (not T: the language refuses it in a declaration).
    values : mapping of str to float, optional
        Coefficients by :attr:`Term.label` [the term's unit]; a term with one gets
        ``value`` (what the generator simulates) and a plausible range ``span`` times it.
    in_library : bool, optional
        The declarations' ``in_library`` (True: candidates of ``measured fit``).
    span : float, optional
        Plausible range [-span |value|, span |value|] (at least 1 unit either side) of a
        term with a value; [-1e6, 1e6] without one.

    Returns
    -------
    list of dict
        ``name``, ``law``, ``unit``, ``plausible``, ``doc``, ``in_library`` (and ``value``).

    Raises
    ------
    ValueError
        For a term in T (no law can declare it).
    """
    values = dict(values or {})
    out = []
    for t in terms:
        if t.law.kind == "torque":
            raise ValueError(f"{t.label}: a term in the steer torque is the command gain "
                             "(command_gain), which no effects file declares")  # fmt: skip
        d = {"name": t.entry, "law": t.law.text(), "unit": t.unit, "doc": t.reading,
             "in_library": in_library}  # fmt: skip
        if t.label in values:
            v = t.value(values[t.label])
            half = max(span * abs(v), 1.0)
            d["plausible"] = [-half, half]
            d["value"] = v
        else:
            d["plausible"] = [-1e6, 1e6]
        out.append(d)
    return out


def injection_file(path: str | Path, values: Mapping[str, float]) -> Path:
    """Write an effects file that makes the generator add dictionary terms.

    Parameters
    ----------
    path : str or Path
        A ``.yaml`` or ``.json`` file to write.
    values : mapping of str to float
        Coefficient by term (``{"roll: phidot": -3.0}``: a roll torque of -3 N m s/rad times
        phidot, a damping) [the term's unit].

    Returns
    -------
    Path
        The file: load it with :func:`bikeid.sim.effect_files.load_effects_file` and give
        its ``values`` to the experiment model.

    Raises
    ------
    ValueError
        For an unknown term, T, or a coefficient that is not a finite number.
    """
    import json

    terms = dictionary()
    chosen = {}
    for text, c in values.items():
        if not math.isfinite(float(c)):
            raise ValueError(f"{text}: coefficient {c!r} must be a finite number")
        chosen[term_by_name(text, terms).label] = float(c)
    decl = declarations([term_by_name(k, terms) for k in chosen], chosen)
    import yaml

    from bikeid.dataset.files import atomic_write_text

    p = Path(path)
    text = (json.dumps({"effects": decl}, indent=1) if p.suffix.lower() == ".json"
            else yaml.safe_dump({"effects": decl}, sort_keys=False))  # fmt: skip
    atomic_write_text(p, text)
    return p


@contextlib.contextmanager
def registered(terms: list[Term]) -> Iterator[list[Term]]:
    """The terms' generated entries registered for the duration (removed after).

    Parameters
    ----------
    terms : list of Term
        Terms; those whose entry is not registered are declared (effects-file mechanism,
        origin :data:`ORIGIN`, outside the library).

    Yields
    ------
    list of Term
        The terms the closure can fit (no :attr:`Term.no_closure`).
    """
    from bikeid.sim.effect_files import declarations_from

    new = [t for t in terms if not t.no_closure and t.entry not in EFFECTS]
    added: tuple[str, ...] = ()
    if new:
        f = declarations_from(declarations(new), ORIGIN)
        added = register_effects(f.effects)
    try:
        yield [t for t in terms if not t.no_closure]
    finally:
        unregister_effects(added)
