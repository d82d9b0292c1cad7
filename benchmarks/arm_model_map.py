"""Where Moore & Hubbard's arm-model finding holds: a map over posture and arm mass.

The finding (Moore & Hubbard, section 6.2, and Moore's dissertation, "Rider Arms"): the arm
model has an unstable real mode at every speed and a weave that is stable at every speed,
so no stable speed range.  ``experiments.papers.moore_hubbard.arm_model_summary`` decides it
for one set of arms (benchmark bicycle, 72 kg rider, 0.01-10 m/s at 0.01 m/s).  The nominal
posture (shoulders x 0.35, y 0.19, z -1.40 m; grips x 0.75, y 0.25, z -1.00 m, benchmark
axes) is an assumption (``sim.arm_model``), so this maps:

- posture: each of the six coordinates moved alone by -0.10 .. +0.10 m in 0.025 m steps
  (8 offsets x 6 coordinates = 48 postures), nominal arm mass;
- arm mass: every segment mass and inertia scaled by 0.1 .. 2.0 at the nominal posture.

Usage::

    python benchmarks/arm_model_map.py [--vmax 10]

Prints one line per case (holds / fails and which part fails) and a count.  Pure linear
algebra: about 0.2 s per case.
"""

from __future__ import annotations

import argparse
from dataclasses import replace

from bikeid.experiments.papers.moore_hubbard import arm_model_summary
from bikeid.sim.arm_model import ArmParameters
from bikeid.sim.errors import InputError

COORDS = ("shoulder_x", "shoulder_y", "shoulder_z", "grip_x", "grip_y", "grip_z")
OFFSETS = (-0.1, -0.075, -0.05, -0.025, 0.025, 0.05, 0.075, 0.1)
MASS_SCALES = (0.1, 0.2, 0.3, 0.4, 0.45, 0.5, 0.55, 0.6, 0.7, 0.8, 0.9, 1.0, 1.25, 1.5, 2.0)


def verdict(arms: ArmParameters | str, vmax: float) -> str:
    """``holds`` or ``fails: <which part>`` for one set of arms (or why there is none)."""
    if isinstance(arms, str):
        return arms
    try:
        a = arm_model_summary("B", vmax, arms)
    except InputError as exc:
        return f"invalid: {exc}"
    if a["reproduces_dissertation"]:
        return "holds"
    why = []
    if a["stable_ranges"]:
        why.append("stable " + ", ".join(f"{lo:.2f}-{hi:.2f} m/s" for lo, hi in a["stable_ranges"]))
    if not a["real_unstable_everywhere"]:
        why.append("no real mode unstable at every speed")
    if not a["oscillatory_stable_everywhere"]:
        why.append("weave unstable at some speed")
    return "fails: " + "; ".join(why)


def moved(nominal: ArmParameters, coord: str, d: float) -> ArmParameters | str:
    """The nominal arms with one coordinate moved by ``d`` [m], or why that is no posture."""
    try:
        return replace(nominal, **{coord: getattr(nominal, coord) + d})
    except InputError as exc:
        return f"invalid: {exc}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--vmax", type=float, default=10.0, help="highest speed [m/s]")
    args = ap.parse_args()
    nominal = ArmParameters()
    print(f"nominal arms ({nominal.mass:.2f} kg): {verdict(nominal, args.vmax)}")
    fails = invalid = 0
    print("posture (one coordinate moved, nominal mass):")
    for c in COORDS:
        for d in OFFSETS:
            v = verdict(moved(nominal, c, d), args.vmax)
            fails += v.startswith("fails")
            invalid += v.startswith("invalid")
            print(f"  {c} {d:+.3f} m: {v}")
    n = len(COORDS) * len(OFFSETS)
    print(f"posture: fails in {fails} of {n}, out of the arm's reach in {invalid}")
    print("arm mass and inertia scaled (nominal posture):")
    for s in MASS_SCALES:
        arms = nominal.scaled(s)
        print(f"  x{s:g} ({arms.mass:.2f} kg): {verdict(arms, args.vmax)}")


if __name__ == "__main__":
    main()
