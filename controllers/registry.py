"""Controller names for the CLI: ``make(name, parameters, **options)`` builds the default.

Names: ``pid``, ``pole-placement``, ``fuzzy``, ``steer-into-lean`` (underscores are
accepted too).  ``parameters`` (a :class:`sim.parameters.BicycleParameters`) is used by
the model-based design (pole placement); the others ignore it.  ``options`` go to the
controller's constructor (e.g. ``reference=``, ``saturation=``, ``design_speed=``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from bikeid.sim.parameters import BicycleParameters

from .base import Controller

__all__ = ["CONTROLLER_NAMES", "make"]


def _pid(parameters: BicycleParameters | None, **kw: Any) -> Controller:
    from .pid import PID

    return PID(**kw)


def _pole_placement(parameters: BicycleParameters | None, **kw: Any) -> Controller:
    from .pole_placement import PolePlacement

    return PolePlacement(parameters=parameters, **kw)


def _fuzzy(parameters: BicycleParameters | None, **kw: Any) -> Controller:
    from .fuzzy import FuzzyController

    return FuzzyController(**kw)


def _steer_into_lean(parameters: BicycleParameters | None, **kw: Any) -> Controller:
    from .steer_into_lean import SteerIntoLean

    return SteerIntoLean(**kw)


_FACTORIES: dict[str, Callable[..., Controller]] = {
    "pid": _pid,
    "pole-placement": _pole_placement,
    "fuzzy": _fuzzy,
    "steer-into-lean": _steer_into_lean,
}

#: The names ``make`` accepts.
CONTROLLER_NAMES = tuple(_FACTORIES)


def make(name: str, parameters: BicycleParameters | None = None, **options: Any) -> Controller:
    """A controller with default gains by name; unknown names or options raise ``ValueError``."""
    key = str(name).strip().lower().replace("_", "-")
    if key not in _FACTORIES:
        raise ValueError(f"unknown controller {name!r}; choose from {', '.join(CONTROLLER_NAMES)}")
    try:
        return _FACTORIES[key](parameters, **options)
    except TypeError as exc:
        raise ValueError(f"bad option for controller {key!r}: {exc}") from None
