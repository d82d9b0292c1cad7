"""Whether a capped coasting run ends on a periodic orbit: Newton on the Poincare map decides.

A run of length T_max is classified from its Poincare section
(:func:`experiments.papers.limit_cycles.classify`).  Near v_w the weave grows so slowly that
no affordable T_max lets the run settle: at 4.29 m/s it still grows 0.5 % per return after
300 s, inside the 1 % closure tolerance.  So the run's class is not the verdict.
:func:`converge_from_run_end` takes the run's last section point and lets Newton on the
Poincare map (:func:`sim.periodic_orbits.orbit_stability`, at the run's energy) find the
periodic orbit there:

- a ``periodic`` run: Newton from the last section point, the run's period;
- a ``growing`` run: Newton from the last section point scaled by 1, then
  :data:`GROWING_START_SCALES` (angles and steer rate; the speed follows from the energy).
  Near a Hopf orbit the map along the amplitude r is r + a r - b r^3: Newton from below
  r*/sqrt(3) heads to upright (r = 0), from above r* it converges monotonically to r*, so
  larger starts find the orbit that a growing motion approaches.

The orbit is accepted (verdict ``periodic``) only if Newton converges (residual 1e-10), its
section amplitude |(phi, delta, deltadot)| is not below the run end's for a growing run
(a growing motion cannot be heading to a smaller orbit, and upright is not an orbit), and
every multiplier other than the energy one is inside the unit circle (the orbit attracts
the motions of its energy level; otherwise the run cannot be approaching it; the
multipliers come from the last Newton iteration's Jacobian, good to the last step's size,
which is enough for this verdict and saves a third of the cost).  Otherwise
the verdict is ``not converged``, with the reason.  Reported for an accepted orbit: its
period, roll extremes and mean, and mean speed over one period
(:func:`sim.periodic_orbits.orbit_profile`) and its family
(:func:`experiments.papers.limit_cycles.orbit_family`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from bikeid.sim.errors import UntrustworthyResult
from bikeid.sim.parameters import BicycleParameters
from bikeid.sim.periodic_orbits import orbit_profile, orbit_stability

__all__ = ["GROWING_START_SCALES", "OrbitVerdict", "converge_from_run_end", "nontrivial_modulus"]

#: Scales of a growing run's last section point tried after 1 (the amplitude where Newton
#: converges from above: 3 covers an end at a third of the orbit's amplitude, 9 a ninth).
GROWING_START_SCALES = (3.0, 9.0)
#: Newton iterations per start (quadratic convergence from a near start needs 2-3).
MAX_ITER = 8


@dataclass(frozen=True)
class OrbitVerdict:
    """What Newton on the Poincare map says about a run's end (deg, deg/s, m/s, s).

    Attributes
    ----------
    outcome : {"periodic", "not converged"}
        ``periodic``: an attracting orbit found from the run's end; else ``not converged``.
    reason : str
        Why (one line).
    returns_per_period : int or None
        Section returns per period of the orbit.
    period : float or None
        Period of the orbit [s].
    roll_min, roll_max, roll_mean : float or None
        Roll extremes and time-averaged roll over one period [deg].
    speed_mean : float or None
        Time-averaged forward speed over one period [m/s].
    speed_range : (float, float) or None
        Forward speed extremes over one period [m/s].
    family : {"symmetric", "turning"} or None
        :func:`experiments.papers.limit_cycles.orbit_family` of the orbit.
    largest_multiplier : float or None
        Largest modulus of the multipliers other than the energy one [-].
    section_point : tuple of 4 float or None
        Fixed point (phi [deg], delta [deg], deltadot [deg/s], v [m/s]).
    start_scale : float or None
        Scale of the run's last section point Newton converged from [-].
    run_end_amplitude : float
        |(phi, delta, deltadot)| of the run's last section point [deg, deg, deg/s].
    """

    outcome: str
    reason: str
    returns_per_period: int | None = None
    period: float | None = None
    roll_min: float | None = None
    roll_max: float | None = None
    roll_mean: float | None = None
    speed_mean: float | None = None
    speed_range: tuple[float, float] | None = None
    family: str | None = None
    largest_multiplier: float | None = None
    section_point: tuple[float, float, float, float] | None = None
    start_scale: float | None = None
    run_end_amplitude: float = 0.0

    def as_dict(self) -> dict:
        """The verdict as a JSON-able dict.

        Returns
        -------
        dict
            The attributes by name.
        """
        return asdict(self)


#: Benchmark bicycle, 0.1 deg steer start, 300 s runs on a 0.02 m/s grid over 3.2-4.3 m/s:
#: the symmetric cycles have |mean roll| / amplitude <= 0.006 (the half-run mean over a
#: non-integer number of periods) and |max + min| / amplitude < 1e-5; the lopsided ones
#: have both >= 0.12.  0.03 lies between with a margin of 4-5 both ways.
FAMILY_REL = 0.03


def orbit_family(
    roll_min: float, roll_max: float, roll_mean: float, rel: float = FAMILY_REL
) -> str:
    """Family of a periodic coasting orbit from its roll statistics (last half of the run).

    Parameters
    ----------
    roll_min, roll_max : float
        Minimum and maximum roll over the last half [deg].
    roll_mean : float
        Mean roll over the last half [deg].
    rel : float, optional
        Tolerance relative to the amplitude (roll_max - roll_min) / 2 (default
        :data:`FAMILY_REL`).

    Returns
    -------
    str
        ``"symmetric"`` (about upright: |mean| and |max + min| both below ``rel`` times the
        amplitude) or ``"turning"`` (lopsided).

    Raises
    ------
    ValueError
        If ``roll_max < roll_min``.
    """
    if roll_max < roll_min:
        raise ValueError(f"roll_max {roll_max} below roll_min {roll_min}: pass (min, max, mean)")
    amp = 0.5 * (roll_max - roll_min)
    if amp <= 0:
        return "turning"
    sym = abs(roll_mean) < rel * amp and abs(roll_max + roll_min) < rel * 2 * amp
    return "symmetric" if sym else "turning"


def nontrivial_modulus(multipliers) -> float:
    """Largest modulus of a periodic orbit's multipliers other than the energy one.

    Parameters
    ----------
    multipliers : sequence of complex
        Eigenvalues of the Poincare map's Jacobian; the one nearest 1 is the energy
        direction's (exactly 1 in the model).

    Returns
    -------
    float
        max |mu| over the others (0 if there are none) [-].
    """
    mu = sorted((complex(m) for m in multipliers), key=lambda m: abs(m - 1))
    return max((abs(m) for m in mu[1:]), default=0.0)


def converge_from_run_end(
    p: BicycleParameters,
    last_point,
    run_outcome: str,
    returns: int | None,
    energy: float,
) -> OrbitVerdict:
    """Newton on the Poincare map from a capped run's end: is there an orbit, and which.

    Parameters
    ----------
    p : BicycleParameters
        The bicycle.
    last_point : (4,) array_like
        The run's last section point (phi [deg], delta [deg], deltadot [deg/s], v [cm/s]),
        :attr:`experiments.papers.limit_cycles.Periodicity.last_section_point`.
    run_outcome : {"periodic", "growing"}
        The run's class at T_max.
    returns : int or None
        Returns per period of a periodic run (a growing run: 1, the weave).
    energy : float
        The run's total energy [J] (coasting conserves it).

    Returns
    -------
    OrbitVerdict

    Raises
    ------
    ValueError
        If ``run_outcome`` is neither ``periodic`` nor ``growing``.
    """
    if run_outcome not in ("periodic", "growing"):
        raise ValueError(
            f"run outcome {run_outcome!r}: only a periodic or growing run ends near an orbit"
        )
    z_end = np.asarray(last_point, float)
    amp_end = float(np.linalg.norm(z_end[:3]))
    n = int(returns or 1)
    scales = (1.0,) if run_outcome == "periodic" else (1.0, *GROWING_START_SCALES)
    reasons = []
    for s in scales:
        z0 = np.append(s * z_end[:3], z_end[3])
        try:
            o = orbit_stability(p, z0, n, energy=energy, max_iter=MAX_ITER, jacobian_at_end=False)
        except (UntrustworthyResult, ValueError) as exc:  # no convergence, or a step so
            # far that the map cannot be evaluated (the pitch solve fails)
            reasons.append(f"start x{s:g}: {exc}".split(": no periodic orbit")[0])
            continue
        amp = float(np.linalg.norm(o.section_point[:3]))
        if run_outcome == "growing" and amp < amp_end:
            reasons.append(
                f"start x{s:g}: Newton reached amplitude {amp:.3g} below the growing run's "
                f"{amp_end:.3g}"
            )
            continue
        mod = nontrivial_modulus(o.multipliers)
        if mod >= 1.0:
            reasons.append(f"start x{s:g}: the orbit found is unstable (|mu| = {mod:.4f})")
            continue
        prof = orbit_profile(p, o.section_point, o.period)
        fam = orbit_family(prof.roll_min, prof.roll_max, prof.roll_mean)
        return OrbitVerdict(
            outcome="periodic",
            reason=(
                f"Newton converged from the run's end (x{s:g}) to an attracting orbit "
                f"(|mu| <= {mod:.4f})"
            ),
            returns_per_period=n,
            period=o.period,
            roll_min=prof.roll_min,
            roll_max=prof.roll_max,
            roll_mean=prof.roll_mean,
            speed_mean=prof.speed_mean,
            speed_range=prof.speed_range,
            family=fam,
            largest_multiplier=mod,
            section_point=o.section_point,
            start_scale=s,
            run_end_amplitude=amp_end,
        )
    return OrbitVerdict(
        outcome="not converged",
        reason="no attracting orbit from the run's end: " + "; ".join(reasons),
        run_end_amplitude=amp_end,
    )
