"""Units of a user's data: the one table of conversions to SI and the one parser of units.

:data:`CONVERSIONS` lists, for each SI unit of :data:`bikeid.sim.conventions.UNITS` (and time,
``"s"``), the units a log or an option may be in and the exact factor to SI.  The factors are
the SI/NIST definitions: 1 deg = pi/180 rad, 1 km/h = 1/3.6 m/s, 1 mph = 0.44704 m/s
(international mile 1609.344 m per 3600 s), 1 N cm = 0.01 N m, 1 ms = 0.001 s.

Unit names are matched case-insensitively where that cannot change their meaning
(:func:`resolve_unit`): ``KM/H``, ``Deg`` and ``RAD/S`` are km/h, deg and rad/s.  A spelling
that differs from a unit of the table only in case *and* reads, case-sensitively, as another
SI unit is refused with the candidates listed, since SI symbols are case-sensitive: ``Ms`` is
a megasecond and ``mS`` a millisiemens, not milliseconds; ``S`` is the siemens; ``m/S`` reads
as metre per siemens.  ``M/S`` is accepted as m/s: ``M`` alone (the prefix mega) is no unit,
so it has no other reading.

:func:`parse_quantity` reads a number with an optional unit (``"14.4km/h"``, ``"5 m/s"``,
``"9MPH"``) into SI; ``bikeid``'s ``--speed`` options use it.
"""

from __future__ import annotations

import math
import re

__all__ = [
    "CONVERSIONS",
    "QUANTITIES",
    "parse_quantity",
    "resolve_unit",
    "si_reading",
    "unit_factor",
]

_DEG = math.pi / 180.0

#: For each SI unit (the keys: the units of :data:`bikeid.sim.conventions.UNITS`, and ``"s"``
#: for time), the units a value may be given in and the factor that converts a value in
#: that unit to the SI unit (NIST SP 811 / ISO 80000: exact definitions).
CONVERSIONS: dict[str, dict[str, float]] = {
    "rad": {"rad": 1.0, "deg": _DEG},
    "rad/s": {"rad/s": 1.0, "deg/s": _DEG},
    "m/s": {"m/s": 1.0, "km/h": 1.0 / 3.6, "kph": 1.0 / 3.6, "mph": 0.44704},
    "N m": {"N m": 1.0, "N cm": 0.01},
    "N": {"N": 1.0},
    "m": {"m": 1.0},
    "s": {"s": 1.0, "ms": 1e-3},
}

#: What each SI unit of :data:`CONVERSIONS` measures (for messages).
QUANTITIES = {"rad": "an angle", "rad/s": "an angular rate", "m/s": "a speed",
              "N m": "a torque", "N": "a force", "m": "a length", "s": "a time"}  # fmt: skip

# SI symbols (case-sensitive) and prefixes, with their names: enough to tell whether a
# case variant of a table unit reads as another unit (ISO 80000-1, SI brochure tables 2-5, 8).
_SYMBOLS = {
    "s": "second", "m": "metre", "g": "gram", "A": "ampere", "K": "kelvin", "mol": "mole",
    "cd": "candela", "N": "newton", "J": "joule", "W": "watt", "Pa": "pascal", "Hz": "hertz",
    "C": "coulomb", "V": "volt", "F": "farad", "S": "siemens", "H": "henry", "T": "tesla",
    "Wb": "weber", "rad": "radian", "sr": "steradian", "lm": "lumen", "lx": "lux",
    "Bq": "becquerel", "Gy": "gray", "Sv": "sievert", "kat": "katal", "h": "hour",
    "min": "minute", "d": "day", "L": "litre", "l": "litre", "t": "tonne", "Ohm": "ohm",
}  # fmt: skip
_PREFIXES = {
    "Y": "yotta", "Z": "zetta", "E": "exa", "P": "peta", "T": "tera", "G": "giga", "M": "mega",
    "k": "kilo", "h": "hecto", "da": "deca", "d": "deci", "c": "centi", "m": "milli",
    "u": "micro", "n": "nano", "p": "pico", "f": "femto", "a": "atto", "z": "zepto",
    "y": "yocto",
}  # fmt: skip


def _normalized(text: str) -> str:
    """One spelling of a unit: outer blanks dropped, ``*``/``·`` and blank runs as one blank,
    no blanks around ``/``."""
    text = re.sub(r"\s*[*\u00b7]\s*|\s+", " ", text.strip())
    return re.sub(r"\s*/\s*", "/", text)


def _symbol(token: str) -> str | None:
    """The SI name of one case-sensitive token (``"Ms"`` -> ``"megasecond"``), or None."""
    if token in _SYMBOLS:
        return _SYMBOLS[token]
    for k in (2, 1):
        head, rest = token[:k], token[k:]
        if head in _PREFIXES and rest in _SYMBOLS:
            return _PREFIXES[head] + _SYMBOLS[rest]
    return None


def si_reading(unit: str) -> str | None:
    """How a unit reads as SI symbols, case-sensitively, or None if it is not SI.

    Parameters
    ----------
    unit : str
        A unit as written (``"Ms"``, ``"km/H"``, ``"KM/H"``).

    Returns
    -------
    str or None
        The reading in words (``"megasecond"``, ``"kilometre per henry"``); None when a
        part is no SI symbol with an optional prefix (``"KM/H"``: ``KM`` is none).
    """
    text = _normalized(unit)
    if not text:
        return None
    parts = text.split("/")
    words = []
    for part in parts:
        names = [_symbol(tok) for tok in part.split(" ")]
        if not part or any(n is None for n in names):
            return None
        words.append(" ".join(names))  # type: ignore[arg-type]
    return " per ".join(words)


def _describe(si: str) -> str:
    return f"{QUANTITIES.get(si, si)}; allowed: {list(CONVERSIONS[si])}"


def resolve_unit(unit: str, si: str, what: str = "the value") -> str:
    """The unit of :data:`CONVERSIONS` a user's spelling names, for a quantity in ``si``.

    An exact spelling (blanks around ``/`` and between words aside) is taken as is; a
    spelling that differs only in case is taken when it has no other SI reading
    (:func:`si_reading`), refused when it has one.

    Parameters
    ----------
    unit : str
        The unit as the user wrote it (``"km/h"``, ``"KM/H"``, ``"Deg"``).
    si : str
        The SI unit of the quantity (a key of :data:`CONVERSIONS`, e.g. ``"m/s"``).
    what : str, optional
        What the unit is of, for messages (``"v"``, ``"--speed"``).

    Returns
    -------
    str
        The table's spelling (``"km/h"``).

    Raises
    ------
    ValueError
        For an unknown unit (naming the allowed ones, and the quantity a unit of another
        quantity measures), or a case variant that reads as another SI unit (naming that
        reading and the candidates).
    """
    if si not in CONVERSIONS:
        raise ValueError(f"no unit table for {si!r}; known: {', '.join(CONVERSIONS)}")
    allowed = CONVERSIONS[si]
    if not isinstance(unit, str) or not _normalized(unit):
        raise ValueError(f"unit {unit!r} for {what} is empty; give one of {', '.join(allowed)}")
    text = _normalized(unit)
    if text in allowed:
        return text
    same = [u for u in allowed if u.lower() == text.lower()]
    if same:
        reading = si_reading(text)
        if reading is None:
            return same[0]
        raise ValueError(
            f"unit {unit!r} for {what} is ambiguous: SI symbols are case-sensitive and "
            f"{text!r} reads as {reading}, not {same[0]!r}; write {same[0]!r} (units of "
            f"{_describe(si)})"
        )
    other = [(s, u) for s, units in CONVERSIONS.items() if s != si
             for u in units if u.lower() == text.lower()]  # fmt: skip
    if other:
        s, u = other[0]
        kind = (f"is a unit of {QUANTITIES[s]}" if u == text
                else f"is not a unit of {QUANTITIES[si]} ({u!r} is a unit of {QUANTITIES[s]})")
        raise ValueError(f"unit {unit!r} for {what} {kind}; {what} is {_describe(si)}")
    raise ValueError(f"unit {unit!r} for {what} is not supported; {what} is {_describe(si)}")


def unit_factor(unit: str, si: str, what: str = "the value") -> tuple[str, float]:
    """The table's spelling of a unit and its factor to SI (:func:`resolve_unit`).

    Parameters
    ----------
    unit : str
        The unit as written.
    si : str
        The SI unit of the quantity (a key of :data:`CONVERSIONS`).
    what : str, optional
        What the unit is of, for messages.

    Returns
    -------
    unit : str
        The table's spelling.
    factor : float
        Value in SI = value in ``unit`` x factor.

    Raises
    ------
    ValueError
        As :func:`resolve_unit`.
    """
    name = resolve_unit(unit, si, what)
    return name, CONVERSIONS[si][name]


_QUANTITY = re.compile(r"\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*(.*?)\s*")


def parse_quantity(text: str, si: str, what: str = "the value") -> float:
    """A number with an optional unit (``"14.4km/h"``, ``"5 m/s"``, ``"5"``), in SI.

    Parameters
    ----------
    text : str
        The number, then optionally a unit of :data:`CONVERSIONS` for ``si`` (case as in
        :func:`resolve_unit`); a bare number is in ``si``.
    si : str
        The SI unit of the quantity (e.g. ``"m/s"``).
    what : str, optional
        What the value is (an option's name), for messages.

    Returns
    -------
    float
        The value in ``si`` (may be negative, zero or huge: the caller checks its range).

    Raises
    ------
    ValueError
        If the text is not a decimal number followed by a known unit.
    """
    m = _QUANTITY.fullmatch(text) if isinstance(text, str) else None
    if m is None:
        raise ValueError(
            f"{what} {text!r} is not a number with an optional unit (e.g. 5, "
            f"5{next(iter(CONVERSIONS.get(si, {si: 1})))}); {what} is "
            f"{_describe(si) if si in CONVERSIONS else si}"
        )
    value = float(m.group(1))
    if not m.group(2):
        return value
    return value * unit_factor(m.group(2), si, what)[1]
