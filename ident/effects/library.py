"""The identification library: the effects the selection may add, with their fit settings.

Each effect's facts (name, unit, absent value, its one-line doc) are those of the registry
(:mod:`bikeid.sim.effect_registry`); a :class:`Candidate` adds only how the ident layer fits
it: additive or structural, the scale the optimizer works in, the fit bounds and, for a
structural effect, the grid its start value is scanned on.  ``LIBRARY`` holds exactly the
registry's entries with ``in_library`` (tests/ident/effects/test_diagnostics.py), in the order the
selection tries them.  A user's effects (:func:`bikeid.sim.effect_registry.register_effects`,
``--effects-file``) with ``in_library`` join it as they are registered, after the built-in
ones: additive, fitted within their plausible range, in steps of their declared ``scale``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bikeid.sim.effect_registry import Effect, RegistryFacts, on_register, user_effects

__all__ = ["LIBRARY", "Candidate"]


@dataclass(frozen=True)
class Candidate(RegistryFacts):
    """How the identification fits one effect.

    Attributes
    ----------
    name : str
        Registry name (:func:`bikeid.sim.effect_registry.effect`).
    kind : str
        ``"additive"`` (fitted from its absent value) or ``"structural"`` (start scanned on
        ``grid`` first, then refined).
    scale : float
        Typical magnitude [the effect's unit]: the optimizer's unit step.
    lower, upper : float
        Fit bounds [the effect's unit] (infinite: none).
    grid : tuple of float
        Scan grid of a structural effect [the effect's unit].
    bounded : bool
        Fit within the registry's plausible range (``lower``/``upper`` are then taken from
        :mod:`bikeid.sim.effect_registry`, not given here).
    """

    name: str
    kind: str
    scale: float
    lower: float = -np.inf
    upper: float = np.inf
    grid: tuple[float, ...] = ()
    bounded: bool = False

    def __post_init__(self) -> None:
        if self.bounded:  # fit within the registry's plausible range, declared there once
            lo, hi = self.entry.plausible
            object.__setattr__(self, "lower", lo)
            object.__setattr__(self, "upper", hi)

    @property
    def doc(self) -> str:
        """The term the effect adds (registry)."""
        return self.entry.doc


LIBRARY: dict[str, Candidate] = {
    c.name: c
    for c in (
        Candidate("steer_viscous_damping", "additive", 0.3),
        Candidate("steer_coulomb_friction", "additive", 0.1, 0.0),
        Candidate("steer_stiffness", "additive", 1.0),
        Candidate("tire_scrub_torque", "additive", 0.5),
        Candidate("command_gain", "additive", 0.2, 0.05),
        Candidate("steer_torque_bias", "additive", 0.05),
        Candidate("steer_inertia", "additive", 0.02),
        Candidate("trail_correction", "additive", 0.01, bounded=True),
        # front-frame (fork + motor) inertia borrowed from a similar bicycle: x0.2-20
        Candidate("front_inertia_scale", "additive", 0.5, bounded=True),
        # estimated rear/front mass split: -0.5..5 kg to the front frame
        Candidate("front_mass_shift", "additive", 0.5, bounded=True),
        # rear-frame inertia borrowed from a similar bicycle: x0.5-2
        Candidate("rear_inertia_scale", "additive", 0.2, bounded=True),
        Candidate("roll_angle_bias", "additive", 0.01),
        Candidate("steer_angle_bias", "additive", 0.01),
        Candidate("roll_rate_bias", "additive", 0.01),
        Candidate("roll_rate_scale", "additive", 0.05, 0.2),
        Candidate("speed_scale", "additive", 0.05, 0.3),
        Candidate("input_delay", "structural", 0.02, bounded=True,
                  grid=(0.005, 0.01, 0.02, 0.03, 0.045, 0.06)),
        Candidate("actuator_lag", "structural", 0.02, bounded=True,
                  grid=(0.005, 0.01, 0.02, 0.035, 0.05, 0.08)),
        Candidate("tire_relaxation", "structural", 0.1, bounded=True,
                  grid=(0.02, 0.05, 0.1, 0.2, 0.35, 0.5)),
    )  # fmt: skip
}


#: Start grid of a user's effect whose absent value is a bound of its range [its scale].
USER_GRID = (0.25, 0.5, 1.0, 2.0, 4.0, 8.0)


def _user_candidate(e: Effect) -> Candidate:
    """A user's library effect, fitted within its plausible range in steps of its scale.

    Additive from absent when absent lies inside the range.  When absent is a bound (a
    damping in [0, 100]), a least-squares start on the bound does not move (its finite
    differences see no descent), so the start is scanned instead on :data:`USER_GRID` times
    the scale towards the open side (kept inside the range), as a structural effect's."""
    lo, hi = e.plausible
    scale = float(e.scale)
    if lo < e.absent < hi:
        return Candidate(e.name, "additive", scale, bounded=True)
    sign = 1.0 if e.absent == lo else -1.0
    points = (e.absent + sign * g * scale for g in USER_GRID)
    grid = tuple(x for x in points if lo < x < hi)
    return Candidate(e.name, "structural", scale, bounded=True, grid=grid or ((lo + hi) / 2,))


_BUILT_IN = dict(LIBRARY)


def _follow_registry(entries: tuple[Effect, ...], added: bool) -> None:
    """Keep LIBRARY the registry's in_library set as user effects come and go (an adopted
    built-in library entry keeps its built-in fit settings)."""
    for e in entries:
        LIBRARY.pop(e.name, None)
        if not added or not e.user:
            if e.name in _BUILT_IN:
                LIBRARY[e.name] = _BUILT_IN[e.name]
        elif e.in_library:
            LIBRARY[e.name] = _BUILT_IN.get(e.name) or _user_candidate(e)


_follow_registry(user_effects(), True)  # registered before this module was imported
on_register(_follow_registry)
