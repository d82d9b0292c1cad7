"""The names of the checks a caller may skip, and the signals each range check bounds.

One vocabulary for ``skip=`` in Python and ``--skip-check`` on the command line, kept in a
module of its own so that the run type (:mod:`bikeid.dataset.run`) and the checks of the
loader (:mod:`bikeid.dataset.plausibility`, :mod:`bikeid.dataset.signs`) share it without
importing each other.
"""

from __future__ import annotations

__all__ = ["BOUND_CHECKS", "SKIPPABLE_CHECKS"]

#: The range checks of :func:`bikeid.dataset.run.check_plausible` by name (the vocabulary of
#: ``skip`` and of ``bikeid identify --skip-check``), each with the SI unit of the signals it
#: bounds: every name of :data:`~bikeid.sim.conventions.PLAUSIBLE` falls under the check of
#: its unit (``speed-bounds`` also bounds the nominal speed from above, NOMINAL_SPEED).
BOUND_CHECKS = {
    "angle-bounds": "rad",
    "rate-bounds": "rad/s",
    "speed-bounds": "m/s",
    "torque-bounds": "N m",
    "force-bounds": "N",
}

#: Every check a caller may skip by name: the range checks above, the import's plausibility
#: checks (:mod:`bikeid.dataset.plausibility`), the sign check against a nominal bicycle
#: (:mod:`bikeid.dataset.signs`) and the fit's informativity check
#: (:mod:`bikeid.ident.informativity`).  ``skip`` and ``--skip-check`` take these names.
SKIPPABLE_CHECKS = (*BOUND_CHECKS, "sample-period", "rate-derivative", "signs", "informativity")
