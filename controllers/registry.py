"""Controller names, the one list in bikeid; ``make(name, parameters, **options)`` builds one.

Names: ``pid``, ``pole-placement``, ``fuzzy``, ``steer-into-lean`` (underscores are
accepted too), and the alias ``pole`` for ``pole-placement``: the short name the sweeps,
``bikeid accuracy`` and ``bikeid reproduce`` use on their command lines, in the sweep
specification stored in their HDF5 files and as keys of their JSON summaries (so those
keep their meaning).  ``parameters`` (a :class:`sim.parameters.BicycleParameters`) is
used by the model-based design (pole placement); the others ignore it.  ``options`` go to
the controller's constructor (e.g. ``reference=``, ``saturation=``, ``design_speed=``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from bikeid.sim.parameters import BicycleParameters

from .base import Controller

__all__ = ["ALIASES", "CONTROLLER_NAMES", "STUDY_CONTROLLERS", "canonical_name", "make"]


def _pid(p: BicycleParameters | None, **kw: Any) -> Controller:
    from .pid import PID

    return PID(**kw)


def _pole_placement(p: BicycleParameters | None, **kw: Any) -> Controller:
    from .pole_placement import PolePlacement

    return PolePlacement(p=p, **kw)


def _fuzzy(p: BicycleParameters | None, **kw: Any) -> Controller:
    from .fuzzy import FuzzyController

    return FuzzyController(**kw)


def _steer_into_lean(p: BicycleParameters | None, **kw: Any) -> Controller:
    from .steer_into_lean import SteerIntoLean

    return SteerIntoLean(**kw)


_FACTORIES: dict[str, Callable[..., Controller]] = {
    "pid": _pid,
    "pole-placement": _pole_placement,
    "fuzzy": _fuzzy,
    "steer-into-lean": _steer_into_lean,
}

#: The canonical controller names.
CONTROLLER_NAMES = tuple(_FACTORIES)

#: Other accepted names -> canonical name.
ALIASES: dict[str, str] = {"pole": "pole-placement"}

#: The closed-loop identification designs that the sweeps, ``bikeid accuracy`` and
#: ``bikeid reproduce`` run, by the names they store (``pole`` = ``pole-placement``).
STUDY_CONTROLLERS: tuple[str, ...] = ("fuzzy", "pid", "pole")


def canonical_name(name: str) -> str:
    """The canonical controller name of ``name`` (case, ``_``/``-`` and aliases resolved).

    Parameters
    ----------
    name : str
        A name of :data:`CONTROLLER_NAMES` or :data:`ALIASES`.

    Returns
    -------
    str
        The :data:`CONTROLLER_NAMES` entry.

    Raises
    ------
    ValueError
        For an unknown name.
    """
    key = str(name).strip().lower().replace("_", "-")
    key = ALIASES.get(key, key)
    if key not in _FACTORIES:
        raise ValueError(f"unknown controller {name!r}; choose from {', '.join(CONTROLLER_NAMES)}")
    return key


def make(name: str, p: BicycleParameters | None = None, **options: Any) -> Controller:
    """A controller with default gains by name; unknown names or options raise ``ValueError``.

    Parameters
    ----------
    name : str
        A controller name (:func:`canonical_name`).
    p : BicycleParameters, optional
        The bicycle (Meijaard 2007 notation), for the model-based pole placement.
    **options
        Keywords of the controller's constructor.

    Returns
    -------
    Controller
        The controller.

    Raises
    ------
    ValueError
        For an unknown name (:func:`canonical_name`) or an option the controller's
        constructor does not accept (the message names the controller).
    """
    key = canonical_name(name)
    try:
        return _FACTORIES[key](p, **options)
    except TypeError as exc:
        raise ValueError(f"bad option for controller {key!r}: {exc}") from None
