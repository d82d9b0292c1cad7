"""Roll-angle controllers, references, dither and lateral-force pulses.

Every controller is a zero-order-hold callable ``controller(t, y) -> T_delta`` [N m]
on the measured vector ``y`` (``sim.conventions.MEASURED`` order), with
``sample_time`` (default :data:`DEFAULT_SAMPLE_TIME`, the default logging period),
``saturation``, ``reset()``, ``reference(t)`` and ``describe()``;
see :mod:`controllers.base`.  Heavy modules (scikit-fuzzy, python-control) load
lazily through the attributes below.

Sign convention (Meijaard et al. 2007): roll phi, steer delta and steer torque T_delta
positive to the right; stabilizing roll feedback steers into the lean.  Units SI (rad,
rad/s, m/s, N m, s).

Modules:

- :mod:`~bikeid.controllers.base`: the interface (:class:`Controller`,
  :class:`ControllerLike`), gain schedules and the :class:`LinearLaw` form of laws that
  are linear in the measurement.
- :mod:`~bikeid.controllers.pid`: roll-angle PID with anti-windup.
- :mod:`~bikeid.controllers.pole_placement`: state feedback with integral action by pole
  placement (Chen & Dao 2010, eqs. 7-17), speed scheduled.
- :mod:`~bikeid.controllers.fuzzy`: speed-adaptive Mamdani fuzzy-PD controller (a
  reconstruction of Chen & Dao's).
- :mod:`~bikeid.controllers.steer_into_lean`: the TU Delft steer-by-wire bicycle's
  balance law T = K (V - v) phidot.
- :mod:`~bikeid.controllers.excitation`: roll references, steer-torque dither and
  lateral-force pulses.
- :mod:`~bikeid.controllers.registry`: controller names and :func:`make`.
"""

from __future__ import annotations

import importlib
from typing import Any

from .base import DEFAULT_SAMPLE_TIME, Controller, ControllerLike, GainSchedule, LinearLaw
from .excitation import (
    ChirpReference,
    LateralForcePulses,
    StepReference,
    UniformDither,
    ZeroReference,
)
from .registry import ALIASES, CONTROLLER_NAMES, STUDY_CONTROLLERS, canonical_name, make

__all__ = [
    "ALIASES",
    "CONTROLLER_NAMES",
    "DEFAULT_SAMPLE_TIME",
    "PID",
    "ChirpReference",
    "Controller",
    "ControllerLike",
    "FuzzyController",
    "GainSchedule",
    "LateralForcePulses",
    "LinearLaw",
    "PolePlacement",
    "StepReference",
    "STUDY_CONTROLLERS",
    "SteerIntoLean",
    "UniformDither",
    "ZeroReference",
    "canonical_name",
    "make",
]

_LAZY = {
    "PID": "pid",
    "PolePlacement": "pole_placement",
    "FuzzyController": "fuzzy",
    "SteerIntoLean": "steer_into_lean",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
