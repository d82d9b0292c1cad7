"""The law language of the effects: one generalized-force term of the roll or steer equation.

A *law* says which term an additive effect adds to the linearized equations of motion
(Meijaard 2007, eq. A.21, roll and steer rows) and what its value means::

    "steer: -c * deltadot"        steer viscous damping      [c: N m s/rad]
    "steer: -c / v * deltadot"    tyre scrub (falls with v)  [c: N m s/rad * m/s]
    "roll: -c * v * phidot"       a damping growing with v   [c: N m s^2/rad/m]
    "steer: -T * sign(deltadot)"  Coulomb friction          [T: N m]
    "steer: -I * deltaddot"       an inertia                 [I: kg m^2]
    "steer: +b"                   a constant torque          [b: N m]

Grammar: ``EQUATION ":" SIGN SYMBOL [("*" | "/") "v" | "*" "v^2"] ["*" SIGNAL]`` where
EQUATION is ``roll`` or ``steer``, SIGN ``+`` or ``-`` (the sign of the term for a positive
value), SYMBOL any name for the value (``c``, ``k``, ...; it is not stored), and SIGNAL one of
:data:`SIGNALS`: a state, an acceleration, the sign of a rate (smoothed as
tanh(rate / smoothing) where a kernel needs it smooth) or the applied steer torque ``T``.
Without a SIGNAL the term is a constant.  Factors may come in any order and the product
``c / v`` may be parenthesized (``-(k / v) * delta``).  The generalized force [N m] the term
adds to its equation, with every sign as in :mod:`bikeid.sim.conventions` (roll, steer and
torques positive to the right), is ``sign * value * v**speed_power * signal``.

A law's identity is its :attr:`Law.key` (equation, signal, speed power): two effects with the
same key are the same term under two names (the registry refuses that), whatever their sign.
:func:`all_laws` enumerates the language, so that a term search can use it as its dictionary.

Kernel codes: :data:`KERNEL_SIGNALS` numbers the signals the compiled kernels evaluate
(:mod:`bikeid.sim.effects`, the experiment model's sampled loop), in the order in which they
sum a row's terms (constants, rates, signs of rates, angles).
"""

from __future__ import annotations

import itertools
import math
import re
from dataclasses import dataclass

__all__ = [
    "EQUATIONS",
    "KERNEL_SIGNALS",
    "SIGNALS",
    "SPEED_POWERS",
    "Law",
    "all_laws",
    "parse_law",
    "same_unit",
    "unit_dimensions",
]

EQUATIONS = ("roll", "steer")
#: Signal name -> its unit.  Order: the kernels' summation order (constants, rates, signs of
#: rates, angles), then the terms the compiled plant does not evaluate (accelerations, torque).
SIGNALS: dict[str, str] = {
    "1": "-",
    "phidot": "rad/s",
    "deltadot": "rad/s",
    "sign(phidot)": "-",
    "sign(deltadot)": "-",
    "phi": "rad",
    "delta": "rad",
    "phiddot": "rad/s^2",
    "deltaddot": "rad/s^2",
    "T": "N m",
}
#: Signals the compiled kernels evaluate, by code (the index).
KERNEL_SIGNALS = ("1", "phidot", "deltadot", "sign(phidot)", "sign(deltadot)", "phi", "delta")
#: Allowed powers of the speed v: 1/v, none, v, v^2.
SPEED_POWERS = (-1, 0, 1, 2)
_ACCELERATIONS = ("phiddot", "deltaddot")
_RATE_OF = {"sign(phidot)": "phidot", "sign(deltadot)": "deltadot"}
_SPEED_TEXT = {-1: " / v", 0: "", 1: " * v", 2: " * v^2"}
_SPEED_UNIT = {-1: " * m/s", 0: "", 1: " * s/m", 2: " * s^2/m^2"}


@dataclass(frozen=True)
class Law:
    """One additive generalized-force term: ``sign * value * v**speed_power * signal``.

    Parameters
    ----------
    equation : {"roll", "steer"}
        The equation of motion the term acts on.
    signal : str
        A key of :data:`SIGNALS` (``"1"``: a constant).
    speed_power : int, optional
        Power of the forward speed v [m/s], one of :data:`SPEED_POWERS` (default 0);
        accelerations and the torque take none.  1/v is evaluated as 1/max(v, v_floor) by
        the kernels (``bikeid.sim.effect_registry.V_FLOOR``).
    sign : int, optional
        +1 or -1 (default -1: a damping or stiffness for a positive value).

    Raises
    ------
    ValueError
        For an unknown equation or signal, a speed power not in :data:`SPEED_POWERS`, a speed
        factor on an acceleration or the torque, or a sign other than +1/-1.
    """

    equation: str
    signal: str
    speed_power: int = 0
    sign: int = -1

    def __post_init__(self) -> None:
        if self.equation not in EQUATIONS:
            raise ValueError(f"equation {self.equation!r}: use one of {', '.join(EQUATIONS)}")
        if self.signal not in SIGNALS:
            raise ValueError(
                f"unknown term {self.signal!r}; use one of {', '.join(SIGNALS)} (or none for "
                "a constant)"
            )
        if self.speed_power not in SPEED_POWERS:
            raise ValueError(f"speed power {self.speed_power!r}: use / v, * v or * v^2")
        if self.speed_power and self.signal in (*_ACCELERATIONS, "T"):
            raise ValueError(f"{self.signal} takes no speed factor; drop the v")
        if self.sign not in (-1, 1):
            raise ValueError(f"sign {self.sign!r}: use + or -")

    @property
    def key(self) -> tuple[str, str, int]:
        """(equation, signal, speed_power): the term itself, whatever its sign."""
        return (self.equation, self.signal, self.speed_power)

    @property
    def index(self) -> int:
        """0 for the roll equation, 1 for the steer equation."""
        return EQUATIONS.index(self.equation)

    @property
    def term(self) -> str:
        """The term in bikeid's signal names, without the value: ``v*deltadot``,
        ``deltadot/v``, ``sign(deltadot)``, ``1``."""
        s = self.signal
        if self.speed_power == 0:
            return s
        if self.speed_power == -1:
            return "1/v" if s == "1" else f"{s}/v"
        vp = "v" if self.speed_power == 1 else "v^2"
        return vp if s == "1" else f"{vp}*{s}"

    @property
    def kernel_code(self) -> int | None:
        """Index in :data:`KERNEL_SIGNALS`, or None for a term the kernels do not evaluate."""
        return KERNEL_SIGNALS.index(self.signal) if self.signal in KERNEL_SIGNALS else None

    @property
    def kind(self) -> str:
        """``"constant"``, ``"rate"``, ``"sign"``, ``"angle"``, ``"acceleration"`` or
        ``"torque"``."""
        s = self.signal
        if s == "1":
            return "constant"
        if s in _RATE_OF:
            return "sign"
        if s in _ACCELERATIONS:
            return "acceleration"
        if s == "T":
            return "torque"
        return "rate" if s.endswith("dot") else "angle"

    @property
    def unit(self) -> str:
        """SI unit of the value: N m over the signal's unit, times (m/s)^-speed_power."""
        su = SIGNALS[self.signal]
        base = {"-": "N m", "rad": "N m/rad", "rad/s": "N m s/rad", "rad/s^2": "kg m^2",
                "N m": "-"}[su]  # fmt: skip
        return base + _SPEED_UNIT[self.speed_power]

    def text(self, symbol: str = "c") -> str:
        """The law as written in the language.

        Parameters
        ----------
        symbol : str, optional
            The coefficient's symbol (default ``"c"``).

        Returns
        -------
        str
            E.g. ``"steer: -c / v * deltadot"``.
        """
        sig = "+" if self.sign > 0 else "-"
        tail = "" if self.signal == "1" else f" * {self.signal}"
        return f"{self.equation}: {sig}{symbol}{_SPEED_TEXT[self.speed_power]}{tail}"

    def coefficient(self, value: float, v: float, v_floor: float) -> float:
        """The signed coefficient of the signal at speed v: sign * value * v**speed_power.

        Parameters
        ----------
        value : float
            The effect's value [:attr:`unit`].
        v : float
            Forward speed [m/s].
        v_floor : float
            Speed floor [m/s] of 1/v (so the term stays finite at rest).

        Returns
        -------
        float
            Generalized force [N m] per unit of the signal.
        """
        p = self.speed_power
        x = value / max(v, v_floor) if p == -1 else value * v**p if p else value
        return x if self.sign > 0 else -x

    def force(self, value: float, v: float, signals: dict, v_floor: float,
              smoothing: float = 0.0) -> float:  # fmt: skip
        """The generalized force [N m] on :attr:`equation` (reference evaluation, no numba).

        Parameters
        ----------
        value : float
            The effect's value [:attr:`unit`].
        v : float
            Forward speed [m/s].
        signals : dict
            Signal values by name (SI); a sign term reads its rate.
        v_floor : float
            Speed floor [m/s] of 1/v.
        smoothing : float, optional
            tanh smoothing [rad/s] of a sign term; 0 for the exact sign.

        Returns
        -------
        float
            sign * value * v**speed_power * signal [N m].
        """
        s = self.signal
        if s == "1":
            x = 1.0
        elif s in _RATE_OF:
            r = signals[_RATE_OF[s]]
            x = math.tanh(r / smoothing) if smoothing > 0 else float(math.copysign(1.0, r))
        else:
            x = signals[s]
        return self.coefficient(value, v, v_floor) * x


_FACTOR = re.compile(r"\s*([*/])?\s*([A-Za-z_][A-Za-z0-9_]*(?:\([A-Za-z]+\))?|1)(\s*\^\s*2)?")


def parse_law(text: str) -> Law:
    """Parse a law of the language (module docstring).

    Parameters
    ----------
    text : str
        E.g. ``"steer: -c * deltadot"``, ``"roll: -c * v * phidot"``, ``"steer: +b"``.

    Returns
    -------
    Law

    Raises
    ------
    ValueError
        One line naming what is wrong and how to write it.
    """
    hint = 'write it as "steer: -c * deltadot" (equation: sign, value, [v factor], [term])'
    if not isinstance(text, str) or ":" not in text:
        raise ValueError(f"law {text!r} has no equation; {hint}")
    eq, _, rhs = text.partition(":")
    eq = eq.strip()
    if eq not in EQUATIONS:
        raise ValueError(f"law {text!r}: unknown equation {eq!r}; use roll or steer")
    body = rhs.replace("(", " ").replace(")", " ").strip()
    # sign(...) lost its parentheses above: put them back around the rate
    body = re.sub(r"\bsign\s+(phidot|deltadot)\b", r"sign(\1)", body)
    body = body.replace("**", "^")
    if not body or body[0] not in "+-":
        raise ValueError(f"law {text!r}: start the term with its sign, + or -; {hint}")
    sign = 1 if body[0] == "+" else -1
    rest = body[1:].strip()
    symbol, signal, power = None, None, 0
    pos = 0
    first = True
    while pos < len(rest):
        m = _FACTOR.match(rest, pos)
        if m is None or m.end() == pos:
            raise ValueError(f"law {text!r}: cannot read {rest[pos:]!r}; {hint}")
        op, name, sq = m.group(1), m.group(2), m.group(3)
        pos = m.end()
        if first != (op is None):
            raise ValueError(f"law {text!r}: join the factors with * or /; {hint}")
        first = False
        if name == "v":
            p = (2 if sq else 1) * (-1 if op == "/" else 1)
            if power or p not in SPEED_POWERS:
                raise ValueError(f"law {text!r}: one speed factor, / v, * v or * v^2")
            power = p
        elif sq:
            raise ValueError(f"law {text!r}: only v may be squared")
        elif name in SIGNALS and name != "1":
            if signal is not None or op == "/":
                raise ValueError(f"law {text!r}: one term, multiplied (not divided); {hint}")
            signal = name
        elif name == "1" or name.startswith("sign("):
            raise ValueError(
                f"law {text!r}: unknown term {name!r}; use one of "
                f"{', '.join(s for s in SIGNALS if s != '1')} (or none for a constant)"
            )
        elif symbol is None and op != "/":
            symbol = name
        else:
            raise ValueError(
                f"law {text!r}: unknown term {name!r}; use one of "
                f"{', '.join(s for s in SIGNALS if s != '1')} (or none for a constant)"
            )
    if symbol is None:
        raise ValueError(f"law {text!r}: name the value (e.g. c); {hint}")
    try:
        return Law(eq, signal or "1", power, sign)
    except ValueError as exc:
        raise ValueError(f"law {text!r}: {exc}") from None


def all_laws(
    equations: tuple[str, ...] = EQUATIONS,
    signals: tuple[str, ...] | None = None,
    speed_powers: tuple[int, ...] = SPEED_POWERS,
) -> list[Law]:
    """Every term of the language (sign -1), e.g. a term search's dictionary.

    Parameters
    ----------
    equations : tuple of str, optional
        Equations (default both).
    signals : tuple of str, optional
        Signals (default all of :data:`SIGNALS`).
    speed_powers : tuple of int, optional
        Speed powers (default all); accelerations and the torque get power 0 only.

    Returns
    -------
    list of Law
        In the order equation, signal, speed power; keys unique.
    """
    out = []
    for eq, s, p in itertools.product(equations, signals or tuple(SIGNALS), speed_powers):
        if p and s in (*_ACCELERATIONS, "T"):
            continue
        out.append(Law(eq, s, p))
    return out


# -- units ------------------------------------------------------------------------------
_BASE = {"kg": (1, 0, 0, 0), "m": (0, 1, 0, 0), "s": (0, 0, 1, 0), "N": (1, 1, -2, 0),
         "rad": (0, 0, 0, 1), "-": (0, 0, 0, 0), "1": (0, 0, 0, 0)}  # fmt: skip
_UNIT_TOKEN = re.compile(r"\s*([*/])?\s*([A-Za-z]+|-|1)(?:\^(-?\d+))?")


def unit_dimensions(unit: str) -> tuple[int, int, int, int]:
    """(kg, m, s, rad) exponents of a unit written as the registry writes them.

    Tokens are separated by spaces or ``*``; ``/`` divides by the next token only
    (``"N m s/rad * m/s"`` = N m s rad^-1 m s^-1); ``^n`` raises a token.  The radian is
    counted (dimensionless in SI, but a stiffness per radian and a torque are not
    interchangeable in a declaration); an inertia is written kg m^2 (:attr:`Law.unit`).

    Parameters
    ----------
    unit : str
        E.g. ``"N m s/rad"``, ``"kg m^2"``, ``"-"``.

    Returns
    -------
    tuple of int
        Exponents of kg, m, s and rad.

    Raises
    ------
    ValueError
        For a token other than kg, m, s, N, rad, - or 1.
    """
    dims = [0, 0, 0, 0]
    pos, u = 0, str(unit).strip()
    while pos < len(u):
        m = _UNIT_TOKEN.match(u, pos)
        if m is None or m.end() == pos:
            raise ValueError(f"unit {unit!r}: cannot read {u[pos:]!r}; write e.g. 'N m s/rad'")
        op, tok, exp = m.groups()
        pos = m.end()
        if tok not in _BASE:
            raise ValueError(f"unit {unit!r}: unknown unit {tok!r}; use kg, m, s, N, rad or -")
        k = (int(exp) if exp else 1) * (-1 if op == "/" else 1)
        for i in range(4):
            dims[i] += k * _BASE[tok][i]
    return tuple(dims)


def same_unit(a: str, b: str) -> bool:
    """Whether two unit strings have the same dimensions (kg, m, s and rad).

    Parameters
    ----------
    a, b : str
        Units (:func:`unit_dimensions`).

    Returns
    -------
    bool
    """
    return unit_dimensions(a) == unit_dimensions(b)
