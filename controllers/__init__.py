"""Roll-angle controllers, references, dither and lateral-force pulses.

Every controller is a zero-order-hold callable ``controller(t, y) -> T_delta`` [N m]
on the measured vector ``y`` (``sim.conventions.MEASURED`` order), with
``sample_time`` (default :data:`DEFAULT_SAMPLE_TIME`, the default logging period),
``saturation``, ``reset()``, ``reference(t)`` and ``describe()``;
see :mod:`controllers.base`.  Heavy modules (scikit-fuzzy, python-control) load
lazily through the attributes below.
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
