"""Small helpers shared by the command modules: ranges, JSON output, argument types.

``atomic_write_text`` is :func:`dataset.files.atomic_write_text` (re-exported for the
command modules).  The argument types (:func:`number`, :func:`integer`, :func:`quantity`,
:func:`speed_value`, :func:`positive_speed`, :func:`duration_value`) are argparse ``type=``
functions: a bad value is a usage error (exit status 2) naming the option, the value and the
allowed range.  A speed takes a unit of the one unit table (``--speed 14.4km/h``, ``9mph``;
:func:`bikeid.dataset.units.parse_quantity`)."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable

import numpy as np

from bikeid.dataset.files import atomic_write_text
from bikeid.dataset.logs import IMPORT_FORMATS, import_check_notes
from bikeid.dataset.plausibility import CHECKS
from bikeid.dataset.units import parse_quantity
from bikeid.sim.conventions import MAX_SPEED
from bikeid.sim.errors import InputError
from bikeid.sim.textformats import dump_json, to_jsonable

__all__ = [
    "IMPORT_FORMATS",
    "import_check_notes",
    "mapping_arg",
    "MAX_POINTS",
    "MAX_SPEED",
    "MAX_WORKERS",
    "atomic_write_text",
    "duration_value",
    "dump_json",
    "integer",
    "number",
    "parse_range",
    "positive_speed",
    "quantity",
    "range_text",
    "skipped_checks",
    "speed_value",
    "to_jsonable",
]

#: Largest number of values a range may expand to.
MAX_POINTS = 1_000_000
#: Most worker processes any command accepts.
MAX_WORKERS = 1024


def number(
    lo: float | None = None,
    hi: float | None = None,
    *,
    lo_open: bool = False,
    hi_open: bool = False,
    unit: str = "",
) -> Callable[[str], float]:
    """An argparse ``type=``: a finite float in ``[lo, hi]`` (``(lo, hi]`` with lo_open).

    Parameters
    ----------
    lo, hi : float, optional
        Bounds (None: unbounded), in ``unit``.
    lo_open : bool, optional
        Exclude ``lo`` itself (e.g. a duration must be > 0).
    hi_open : bool, optional
        Exclude ``hi`` itself (e.g. a fractional gain must be < 1).
    unit : str, optional
        Unit named in the message (e.g. ``"m/s"``).

    Returns
    -------
    callable
        ``parse(text) -> float`` raising :class:`argparse.ArgumentTypeError` with the
        value and the allowed range.
    """
    u = f" {unit}" if unit else ""
    low = "" if lo is None else (f"> {lo:g}{u}" if lo_open else f">= {lo:g}{u}")
    high = "" if hi is None else (f"< {hi:g}{u}" if hi_open else f"<= {hi:g}{u}")
    need = " and ".join(x for x in (low, high) if x) or "a finite number"

    def parse(text: str) -> float:
        try:
            x = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number; need {need}") from None
        if not math.isfinite(x):
            raise argparse.ArgumentTypeError(f"{text!r} is not finite; need {need}")
        if (lo is not None and (x < lo or (lo_open and x == lo))) or (
            hi is not None and (x > hi or (hi_open and x == hi))
        ):
            raise argparse.ArgumentTypeError(f"{text}{u} is out of range; need {need}")
        return x

    parse.__name__ = "number"
    return parse


def integer(lo: int | None = None, hi: int | None = None) -> Callable[[str], int]:
    """An argparse ``type=``: a whole number in ``[lo, hi]``.

    Parameters
    ----------
    lo, hi : int, optional
        Bounds (None: unbounded).

    Returns
    -------
    callable
        ``parse(text) -> int`` raising :class:`argparse.ArgumentTypeError` with the value
        and the allowed range.
    """
    need = (
        " and ".join(
            x for x in ("" if lo is None else f">= {lo}", "" if hi is None else f"<= {hi}") if x
        )
        or "a whole number"
    )

    def parse(text: str) -> int:
        try:
            k = int(text.strip(), 10) if len(text) <= 40 else None
        except ValueError:
            k = None
        if k is None:
            raise argparse.ArgumentTypeError(f"{text[:40]!r} is not a whole number; need {need}")
        if (lo is not None and k < lo) or (hi is not None and k > hi):
            raise argparse.ArgumentTypeError(f"{text} is out of range; need {need}")
        return k

    parse.__name__ = "integer"
    return parse


def quantity(
    si: str,
    lo: float | None = None,
    hi: float | None = None,
    *,
    lo_open: bool = False,
    hi_open: bool = False,
) -> Callable[[str], float]:
    """An argparse ``type=``: a number with an optional unit, in SI, in ``[lo, hi]``.

    Parameters
    ----------
    si : str
        The SI unit of the quantity (a key of :data:`bikeid.dataset.units.CONVERSIONS`, e.g.
        ``"m/s"``); a bare number is in it.
    lo, hi : float, optional
        Bounds in ``si`` (None: unbounded).
    lo_open, hi_open : bool, optional
        Exclude the bound itself.

    Returns
    -------
    callable
        ``parse(text) -> float`` [si] raising :class:`argparse.ArgumentTypeError` with the
        value, the unit table's allowed units (case as in
        :func:`bikeid.dataset.units.resolve_unit`) or the allowed range.
    """
    check = number(lo, hi, lo_open=lo_open, hi_open=hi_open, unit=si)

    def parse(text: str) -> float:
        try:
            float(text)
        except (TypeError, ValueError):
            pass
        else:  # a bare number (nan and inf included): the messages of number()
            return check(text)
        try:
            x = parse_quantity(text, si, "the value")
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None
        try:
            return check(repr(x))
        except argparse.ArgumentTypeError as exc:
            raise argparse.ArgumentTypeError(f"{text[:40]!r} = {exc}") from None

    parse.__name__ = "quantity"
    return parse


#: ``--speed`` [m/s]: finite, 0 <= v <= MAX_SPEED, with an optional unit (14.4km/h).
speed_value = quantity("m/s", 0.0, MAX_SPEED)
#: ``--speed`` of a log [m/s]: finite, 0 < v <= MAX_SPEED, with an optional unit.
positive_speed = quantity("m/s", 0.0, MAX_SPEED, lo_open=True)
#: ``--duration`` [s]: finite, > 0 (a run too long for memory is refused by
#: :func:`bikeid.sim.errors.check_memory` before anything is allocated or written).
duration_value = number(0.0, lo_open=True, unit="s")


def parse_range(
    text: str,
    name: str = "range",
    minimum: float | None = None,
    maximum: float | None = MAX_SPEED,
) -> np.ndarray:
    """Parse ``start:stop:step`` (stop included, MATLAB style), ``a,b,c`` or one value.

    Parameters
    ----------
    text : str
        The option's value.
    name : str, optional
        The option, named in messages (e.g. ``"--speeds"``).
    minimum, maximum : float, optional
        Allowed bounds of every value (default maximum :data:`MAX_SPEED`, the ranges are
        speeds [m/s]; None: unbounded).

    Returns
    -------
    ndarray
        The values, rounded to 12 decimals.

    Raises
    ------
    bikeid.sim.errors.InputError
        If the text does not parse, expands to more than :data:`MAX_POINTS` values, holds
        a non-finite value or one outside the bounds.
    """
    text = text.strip()
    try:
        parts = [float(x) for x in text.split(":")] if ":" in text else None
        values = None if parts else np.array([float(x) for x in text.split(",") if x.strip()])
    except ValueError:
        raise InputError(
            f"{name} {text!r} is not start:stop:step, a comma list or a number"
        ) from None
    if parts is not None:
        if len(parts) != 3 or not all(map(math.isfinite, parts)):
            raise InputError(f"{name} {text!r}: use start:stop:step with three finite numbers")
        start, stop, step = parts
        if step <= 0 or stop < start:
            raise InputError(f"{name} {text!r}: need start <= stop and step > 0")
        ratio = (stop - start) / step
        count = math.floor(ratio + 1e-9) + 1 if math.isfinite(ratio) else math.inf
        if count > MAX_POINTS:
            raise InputError(
                f"{name} {text!r} has {count:.3g} values (step too small for the span); at most "
                f"{MAX_POINTS:,} "
                "(use a larger step)"
            )
        values = start + step * np.arange(int(count))
    if values.size == 0 or not np.all(np.isfinite(values)):
        raise InputError(f"{name} {text!r} holds no finite values")
    if minimum is not None and values.min() < minimum:
        raise InputError(f"{name} {text!r}: values must be >= {minimum}")
    if maximum is not None and values.max() > maximum:
        raise InputError(f"{name} {text!r}: values must be <= {maximum:g}")
    return np.round(values, 12)


def range_text(
    name: str, minimum: float | None = None, maximum: float | None = MAX_SPEED
) -> Callable[[str], str]:
    """An argparse ``type=`` that checks a range with :func:`parse_range` and keeps the text.

    Parameters
    ----------
    name : str
        The option (e.g. ``"--speeds"``).
    minimum, maximum : float, optional
        Bounds passed to :func:`parse_range`.

    Returns
    -------
    callable
        ``check(text) -> text`` raising :class:`argparse.ArgumentTypeError` with
        :func:`parse_range`'s message (a usage error, exit status 2); the handler parses
        the returned text again.
    """

    def check(text: str) -> str:
        try:
            parse_range(text, name, minimum, maximum)
        except InputError as exc:
            raise argparse.ArgumentTypeError(str(exc).removeprefix(f"{name} ")) from None
        return text

    check.__name__ = "range"
    return check


def check_figure_path(path: str | None, option: str = "--plot") -> None:
    """Refuse, before any work, a figure file whose suffix names no format bikeid writes.

    Every command's figure option calls it first; the figure is then written in the format
    its suffix names (:func:`bikeid.experiments.plots.figure_format`, the one rule).

    Parameters
    ----------
    path : str or None
        The figure file given, or None (no figure asked for: nothing checked).
    option : str, optional
        The option that named it, for the message.

    Raises
    ------
    InputError
        If the suffix is not one of :data:`bikeid.experiments.plots.FIGURE_FORMATS`
        (exit status 3; the message lists the supported suffixes).
    """
    if path is None:
        return
    from bikeid.experiments.plots import figure_format  # matplotlib: only when plotting

    figure_format(path, option)


def mapping_arg(option: str) -> Callable[[str], dict[str, str]]:
    """argparse type for ``NAME=VALUE,NAME=VALUE`` (e.g. ``--columns phi=roll,v=speed``).

    Parameters
    ----------
    option : str
        The option's name, for messages.

    Returns
    -------
    callable
        Parses the text into a dict; refuses an empty text, a pair without ``=``, an empty
        name or value, and a repeated name (argparse shows the message as a usage error).
    """

    def parse(text: str) -> dict[str, str]:
        out: dict[str, str] = {}
        pairs = [p for p in text.split(",") if p.strip()]
        if not pairs:
            raise argparse.ArgumentTypeError(f"{option}: give NAME=VALUE pairs separated by commas")
        for pair in pairs:
            name, sep, value = pair.partition("=")
            name, value = name.strip(), value.strip()
            if not sep or not name or not value:
                raise argparse.ArgumentTypeError(f"{option}: {pair!r} is not NAME=VALUE")
            if name in out:
                raise argparse.ArgumentTypeError(f"{option}: {name!r} given twice")
            out[name] = value
        return out

    parse.__name__ = "mapping"
    return parse




def skipped_checks(args: argparse.Namespace) -> list[str]:
    """The checks ``--skip-check NAME,...``/``--no-checks`` turn off.

    Parameters
    ----------
    args : argparse.Namespace
        Parsed options (``skip_check``, ``no_checks``; absent ones count as not given).

    Returns
    -------
    list of str
        Names of :data:`bikeid.dataset.plausibility.CHECKS`, each once (all of them with
        ``--no-checks``).

    Raises
    ------
    bikeid.sim.errors.InputError
        On an unknown name, listing the known ones.
    """
    if getattr(args, "no_checks", False):
        return list(CHECKS)
    names = [n.strip() for n in (getattr(args, "skip_check", "") or "").split(",") if n.strip()]
    bad = [n for n in names if n not in CHECKS]
    if bad:
        raise InputError(f"--skip-check {','.join(bad)}: unknown check; choose from "
                         f"{', '.join(CHECKS)}")  # fmt: skip
    return list(dict.fromkeys(names))
