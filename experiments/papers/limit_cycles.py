"""Chen & Dao (2010) Figs. 4-5: uncontrolled coasting motions at 3.5 m/s, and whether they are
periodic.

Set-up (Chen & Dao §III.C): benchmark bicycle, nonlinear Whipple plant, rear wheel free
(``mode="coast"``, speed is a state, total energy conserved), no steer torque, initial speed
3.5 m/s, initial conditions of the paper's Figs. 4 and 5.  The extracted text of the paper
lost the minus signs, so the Fig. 4 roll rates (55.236, 27.291 deg/s with steer 10, 5 deg) are
run in both readings: same sign as the steer angle (``+``) and opposite sign (``-``).  Mirror
symmetry (phi, delta, phidot) -> -(phi, delta, phidot) makes the overall sign irrelevant.

Classification (a Poincare section).  The section is phidot = 0 with phidot decreasing
(every local maximum of roll); each crossing is located by linear interpolation between
samples and gives the section point x_n = (phi, delta, deltadot, v).  :func:`classify`
calls a run ``falls`` (the integrator stopped it: |roll| > 60 deg), ``decays`` (the
amplitude |(phi, delta, deltadot)| of the section points shrinks geometrically towards
zero, at a rate distinguishable from zero), ``growing`` (the amplitude grows at a rate
distinguishable from zero, by more than :data:`CLOSURE_REL` over the last half: a motion
still growing 0.5 % per return closes to 0.5 % and is not periodic), ``periodic`` with
period n (the smallest p in 1..4 with max |x_{n+p} - x_n| below :data:`CLOSURE_REL` of the
points' amplitude, per component, on the last half of the returns) or ``irregular`` (none
of these).  Tolerances are relative to the motion's amplitude, so a motion dying out or
still growing is not called periodic.

That is the class of a run capped at T_max.  The speed scan then lets Newton on the
Poincare map decide from the run's end whether a periodic orbit exists
(:mod:`experiments.papers.orbit_convergence`): a growing or periodic run is ``periodic``
only if Newton finds an attracting orbit there, else ``not converged``.

Stability of a periodic orbit: :mod:`sim.periodic_orbits` converges the orbit by Newton
on the Poincare map's fixed point (DOP853 at rtol = atol = 1e-12) and takes the
multipliers of the map (its Jacobian by central differences); one multiplier is 1, the
energy direction, which checks the computation.

On the word "limit cycle".  The system conserves energy but is nonholonomic: it is not
Hamiltonian, phase volume is not conserved, and asymptotically stable motions exist (the
benchmark's self-stable weave above v_w is one).  So energy conservation alone does not
rule out an attracting periodic orbit *within one energy level*; what it does imply is that
there is no single isolated cycle in the full state space: each energy level carries its
own orbit, so the orbits form a one-parameter family indexed by energy.  The report states
what the measurement shows for each initial condition.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import asdict, dataclass

import numpy as np

from bikeid.experiments.papers.orbit_convergence import (  # noqa: F401 (re-exported)
    FAMILY_REL,
    converge_from_run_end,
    orbit_family,
)
from bikeid.experiments.parallel import map_jobs
from bikeid.experiments.plots import plt, save
from bikeid.sim.integrate import DEFAULT_SUBSTEPS, simulate
from bikeid.sim.nonlinear import WhippleBicycle
from bikeid.sim.parameters import BicycleParameters
from bikeid.sim.periodic_orbits import orbit_stability

__all__ = [
    "FIG4_CONDITIONS",
    "FIG5_CONDITIONS",
    "FAMILIES",
    "FAMILY_REL",
    "Classification",
    "InitialCondition",
    "Periodicity",
    "classify",
    "coast",
    "periodicity",
    "mirrored",
    "orbit_family",
    "plot_energy_speed",
    "scan_windows",
    "plot_phase_portraits",
    "section_points",
    "speed_scan",
    "stop_info",
    "summary_entry",
]

SPEED = 3.5  # m/s, Chen & Dao Figs. 4-5


@dataclass(frozen=True)
class InitialCondition:
    """Initial roll, steer [deg] and their rates [deg/s]; ``label`` names it in figures.

    Attributes
    ----------
    label : str
        Name of the condition in figures and tables.
    phi, delta : float
        Initial roll and steer angles [deg], positive to the right (Meijaard 2007).
    phidot, deltadot : float
        Initial roll and steer rates [deg/s].
    """

    label: str
    phi: float = 0.0
    delta: float = 0.0
    phidot: float = 0.0
    deltadot: float = 0.0

    def radians(self) -> dict[str, float]:
        """The condition in SI units.

        Returns
        -------
        dict of str to float
            ``phi``, ``delta`` [rad], ``phidot``, ``deltadot`` [rad/s].
        """
        return {k: math.radians(getattr(self, k)) for k in ("phi", "delta", "phidot", "deltadot")}


#: Fig. 4 (steer 10, 5, 0.1 deg; roll rates 55.236, 27.291, 0 deg/s), both sign readings.
FIG4_CONDITIONS = (
    InitialCondition("delta0=10, phidot0=+55.236", delta=10.0, phidot=55.236),
    InitialCondition("delta0=10, phidot0=-55.236", delta=10.0, phidot=-55.236),
    InitialCondition("delta0=5, phidot0=+27.291", delta=5.0, phidot=27.291),
    InitialCondition("delta0=5, phidot0=-27.291", delta=5.0, phidot=-27.291),
    InitialCondition("delta0=0.1, phidot0=0", delta=0.1),
)
#: Fig. 5 (roll 0.1, 15, 25 deg, steer 0).
FIG5_CONDITIONS = (
    InitialCondition("phi0=0.1", phi=0.1),
    InitialCondition("phi0=15", phi=15.0),
    InitialCondition("phi0=25", phi=25.0),
)


def coast(
    p: BicycleParameters,
    ic: InitialCondition,
    duration: float,
    speed: float = SPEED,
    dt: float = 0.01,
    substeps: int | None = None,
):
    """Uncontrolled coasting run (no inputs, speed free) with total energy recorded.

    Returns a :class:`sim.integrate.Trajectory`; it ends early at a fall (|roll| > 60 deg).

    Parameters
    ----------
    p : BicycleParameters
        The bicycle.
    ic : InitialCondition
        Initial roll, steer and rates (upright otherwise).
    duration : float
        Length of the run [s].
    speed : float, optional
        Initial forward speed [m/s] (3.5, Chen & Dao Figs. 4-5).
    dt : float, optional
        Output sample period [s].
    substeps : int, optional
        RK4 steps per sample (default ``sim.integrate.DEFAULT_SUBSTEPS``).

    Returns
    -------
    Trajectory
        The run (``mode="coast"``: rear wheel free, speed a state) with total energy
        ``energy`` [J] per sample.
    """

    bike = WhippleBicycle(p)
    x0 = bike.state(speed, **ic.radians())
    n = DEFAULT_SUBSTEPS if substeps is None else int(substeps)
    return simulate(bike, x0, duration, dt=dt, substeps=n, mode="coast", energy=True)


def section_points(t, phi, phidot, delta, deltadot, v) -> tuple[np.ndarray, np.ndarray]:
    """Crossings of phidot = 0 downward (roll maxima): times [s] and points
    (phi [deg], delta [deg], deltadot [deg/s], v [cm/s]), linearly interpolated.

    Parameters
    ----------
    t : (N,) array_like
        Sample times [s].
    phi, phidot : (N,) array_like
        Roll angle [rad] and rate [rad/s].
    delta, deltadot : (N,) array_like
        Steer angle [rad] and rate [rad/s].
    v : (N,) array_like
        Forward speed [m/s].

    Returns
    -------
    times : (n,) ndarray
        Crossing times [s].
    points : (n, 4) ndarray
        Section points (phi [deg], delta [deg], deltadot [deg/s], v [cm/s]).
    """
    t, phi, phidot, delta, deltadot, v = (
        np.asarray(a, float) for a in (t, phi, phidot, delta, deltadot, v)
    )
    k = np.where((phidot[:-1] > 0) & (phidot[1:] <= 0))[0]
    f = phidot[k] / (phidot[k] - phidot[k + 1])

    def at(x):
        return x[k] + f * (x[k + 1] - x[k])

    pts = np.column_stack(
        [np.degrees(at(phi)), np.degrees(at(delta)), np.degrees(at(deltadot)), 100.0 * at(v)]
    )
    return at(t), pts


#: closure |x_{n+p} - x_n| below this fraction of the amplitude: periodic.  The section points
#: of a 10 ms run are linearly interpolated; on the converged 3.5 m/s orbits (Newton residual
#: 1e-10, multipliers |mu| < 0.2) that leaves closures of 5e-5 .. 1.4e-3, hence 1e-2.
CLOSURE_REL = 1e-2
OUTCOMES = ("decays", "growing", "periodic", "irregular", "falls")


@dataclass(frozen=True)
class Classification:
    """Class of a coasting run from its Poincare section points.

    ``outcome`` is one of :data:`OUTCOMES`; ``period_n`` the returns per period (periodic
    only); ``closure_rel`` = max over the last half of the returns and the components j of
    |x_{n+p,j} - x_{n,j}| / s_j, s_j = max |x_{n,j}| on that half (for the smallest p <= 4,
    or the best p when none closes); ``decay_rate`` = slope of log amplitude per return
    over the last half (amplitude = |(phi, delta, deltadot)| of the section point) and
    ``decay_rate_se`` its standard error.

    Attributes
    ----------
    outcome : str
        ``decays``, ``growing``, ``periodic``, ``irregular`` or ``falls``.
    period_n : int or None
        Returns per period (periodic only).
    closure_rel : float or None
        Relative closure [-] as defined above.
    decay_rate : float or None
        Slope of the log amplitude per return [-].
    decay_rate_se : float or None
        Its standard error [-].
    """

    outcome: str
    period_n: int | None
    closure_rel: float | None
    decay_rate: float | None
    decay_rate_se: float | None


def _slope(y: np.ndarray) -> tuple[float, float]:
    n = np.arange(y.size, dtype=float)
    (b, a), res, *_ = np.polyfit(n, y, 1, full=True)
    r = y - (a + b * n)
    se = math.sqrt(float(r @ r) / max(y.size - 2, 1) / float(((n - n.mean()) ** 2).sum()))
    return float(b), se


def classify(
    pts: np.ndarray,
    fell: bool,
    closure_rel: float = CLOSURE_REL,
    final_rel: float | None = None,
) -> Classification:
    """Classify a coasting run as ``decays``, ``growing``, ``periodic``, ``irregular``, ``falls``.

    Rules (on the last half of the section points, at least 8 returns there):
    ``falls`` if the run fell; ``decays`` if the log amplitude shrinks at a rate
    distinguishable from zero (slope + 3 standard errors < 0), by more than ``closure_rel``
    over the tail, and geometrically (the slope over the second half of the tail is at
    least half the slope over the first half: the amplitude heads to zero, not to a
    nonzero orbit); ``growing`` if the log amplitude grows at a rate distinguishable from
    zero (slope - 3 standard errors > 0) by more than ``closure_rel`` over the tail (so a
    growth below ``closure_rel`` per return is not taken for closure); ``periodic`` (period
    n = smallest p in 1..4) if the relative closure is below ``closure_rel``; otherwise
    ``irregular``.

    Parameters
    ----------
    pts : (N, 4) ndarray
        Section points (phi [deg], delta [deg], deltadot [deg/s], v [cm/s]).
    fell : bool
        Whether the run ended in a fall (or another integrator stop).
    closure_rel : float, optional
        Relative closure tolerance. Default :data:`CLOSURE_REL`.
    final_rel : float, optional
        |(phi, delta, phidot, deltadot)| at the end of the run divided by its maximum over
        the run.  When the section has fewer than 8 returns on its last half (a decay
        whose last phase is the non-oscillatory capsize mode stops returning) and
        ``final_rel`` < ``closure_rel``, the run ``decays``.

    Returns
    -------
    Classification

    Raises
    ------
    ValueError
        If ``pts`` is not an (N, 4) array.
    """
    pts = np.asarray(pts, float)
    if pts.ndim != 2 or pts.shape[1] != 4:
        raise ValueError(f"section points must be an (N, 4) array, got shape {pts.shape}")
    if fell:
        return Classification("falls", None, None, None, None)
    tail = pts[pts.shape[0] // 2 :]
    if tail.shape[0] < 8:
        if final_rel is not None and final_rel < closure_rel:
            b = se = None
            if pts.shape[0] >= 3 and np.all(np.linalg.norm(pts[:, :3], axis=1) > 0):
                b, se = _slope(np.log(np.linalg.norm(pts[:, :3], axis=1)))
            return Classification("decays", None, None, b, se)
        return Classification("irregular", None, None, None, None)
    amp = np.linalg.norm(tail[:, :3], axis=1)
    b = se = None
    if np.all(amp > 0):
        la = np.log(amp)
        b, se = _slope(la)
        h = la.size // 2
        b1, _ = _slope(la[:h])
        b2, _ = _slope(la[h:])
        if b + 3 * se < 0 and -b * la.size > closure_rel and b2 < 0.5 * b1 < 0:
            return Classification("decays", None, None, b, se)
        if b - 3 * se > 0 and b * la.size > closure_rel:
            return Classification("growing", None, None, b, se)
    s = np.max(np.abs(tail), axis=0)
    s[s == 0] = 1.0
    best = None
    for p in range(1, 5):
        c = float(np.max(np.abs(tail[p:] - tail[:-p]) / s))
        if best is None or c < best[1]:
            best = (p, c)
        if c < closure_rel:
            return Classification("periodic", p, c, b, se)
    return Classification("irregular", None, best[1], b, se)


@dataclass(frozen=True)
class Periodicity:
    """Outcome of one coasting run (angles deg, rates deg/s, speed m/s, energy J).

    ``verdict`` is the :func:`classify` outcome (``decays``, ``growing``, ``periodic``,
    ``irregular``, ``falls``); ``returns_per_period`` its period n; ``period`` the mean
    time of n returns over the last half [s]; ``closure`` the relative closure of
    :class:`Classification`; ``decay_rate`` the log-amplitude slope per return;
    ``fall_cause`` the integrator's stop reason; ``energy_drift`` = (max - min) / |mean|
    of the total energy.

    Attributes
    ----------
    label : str
        The initial condition's label.
    verdict : {"decays", "growing", "periodic", "irregular", "falls"}
        Outcome of :func:`classify`.
    fell_at : float or None
        Time the run ended early [s] (None if it ran to the end).
    fall_cause : str or None
        Why it ended (the integrator's stop reason), None if it ran to the end.
    duration : float
        Simulated time [s].
    n_returns : int
        Number of section crossings.
    returns_per_period : int or None
        Period n in returns (periodic runs), else None.
    period : float or None
        Mean time of n returns over the last half [s].
    closure : float or None
        Relative closure max |x_{n+p} - x_n| / amplitude over the last half [-].
    closure_tol : float
        Relative closure tolerance used [-].
    decay_rate : float or None
        Slope of the log section amplitude per return [-] (negative: shrinking).
    last_section_point : tuple of 4 float or None
        Last section point (phi [deg], delta [deg], deltadot [deg/s], v [cm/s]).
    roll_range : (float, float)
        Minimum and maximum roll [deg].
    roll_mean : float
        Mean roll over the second half [deg].
    speed_range : (float, float)
        Minimum and maximum forward speed [m/s].
    speed_mean : float
        Mean forward speed over the second half [m/s].
    yaw_rate_mean : float
        Mean yaw rate over the second half [rad/s].
    turn_radius : float or None
        |speed / yaw rate| over the second half [m] (None without a mean turn).
    energy : float
        Initial total energy [J].
    energy_drift : float
        (max - min) / |mean| of the total energy (dimensionless; NaN without energy).
    roll_range_last_half : (float, float)
        Minimum and maximum roll over the second half [deg].
    family : {"symmetric", "turning"} or None
        Orbit family of a periodic run (:func:`orbit_family`), None otherwise.
    """

    label: str
    verdict: str
    fell_at: float | None
    fall_cause: str | None
    duration: float
    n_returns: int
    returns_per_period: int | None
    period: float | None
    closure: float | None
    closure_tol: float
    decay_rate: float | None
    last_section_point: tuple[float, float, float, float] | None
    roll_range: tuple[float, float]
    roll_mean: float
    speed_range: tuple[float, float]
    speed_mean: float
    yaw_rate_mean: float
    turn_radius: float | None
    energy: float
    energy_drift: float
    roll_range_last_half: tuple[float, float] = (0.0, 0.0)
    family: str | None = None

    def as_dict(self) -> dict:
        """The outcome as a JSON-able dict.

        Returns
        -------
        dict
            The attributes by name (tuples as tuples).
        """
        return asdict(self)


def stop_info(traj) -> tuple[float | None, str | None]:
    """Fall time [s] and cause of a run that ended early, else (None, None).

    The one place that reads the integrator's stop record (``Trajectory.stop``: the cause
    is its code in ``sim.integrate.STOP_CAUSES``, e.g. ``roll_limit``, ``steer_limit``).
    A numerical stop (step too coarse, non-finite state) is refused, not called a fall.

    Parameters
    ----------
    traj : sim.integrate.Trajectory
        A finished run.

    Returns
    -------
    time : float or None
        When the run ended early [s].
    cause : str or None
        Why (the integrator's stop reason).
    """
    stop = getattr(traj, "stop", None)
    if stop is not None:
        if not stop.physical:  # a numerical failure is not a fall: never classify it
            raise ValueError(
                f"coasting run stopped for a numerical reason, not a fall: {stop.message}"
            )
        return float(stop.time), stop.cause
    if traj.fell_at is None and traj.stop_reason is None:
        return None, None
    t = traj.fell_at if traj.fell_at is not None else float(traj.t[-1])
    return float(t), traj.stop_reason


def periodicity(traj, label: str = "", closure_rel: float = CLOSURE_REL) -> Periodicity:
    """Poincare-section analysis and :func:`classify` verdict of a coasting trajectory.

    Parameters
    ----------
    traj : sim.integrate.Trajectory
        A coasting run (``energy=True`` for the energy statistics).
    label : str, optional
        Name of the run.
    closure_rel : float, optional
        Relative closure tolerance of :func:`classify`.

    Returns
    -------
    Periodicity
        The verdict and the run's statistics.
    """
    t = traj.t
    phi, phidot = traj.signal("phi"), traj.signal("phidot")
    delta, deltadot, v = traj.signal("delta"), traj.signal("deltadot"), traj.signal("v")
    psidot = traj.signal("psidot")
    E = traj.energy if traj.energy is not None else np.full(t.size, np.nan)
    half = slice(t.size // 2, None)  # statistics of the settled second half
    fell_at, cause = stop_info(traj)
    tc, pts = section_points(t, phi, phidot, delta, deltadot, v)
    n = len(tc)
    size = np.sqrt(phi**2 + delta**2 + phidot**2 + deltadot**2)
    final_rel = float(size[-1] / size.max()) if size.max() > 0 else 0.0
    cl = classify(pts, fell_at is not None, closure_rel, final_rel)
    period = None
    if cl.period_n is not None:
        k, p = n // 2, cl.period_n
        period = float(np.mean(tc[k + p :] - tc[k : n - p]))
    r = float(np.mean(v[half]) / psidot[half].mean()) if abs(psidot[half].mean()) > 1e-6 else None
    ph = np.degrees(phi[half])
    roll_mean = float(ph.mean())
    fam = orbit_family(float(ph.min()), float(ph.max()), roll_mean) if cl.period_n else None
    return Periodicity(
        label=label,
        verdict=cl.outcome,
        fell_at=fell_at,
        fall_cause=cause,
        duration=float(t[-1]),
        n_returns=n,
        returns_per_period=cl.period_n,
        period=period,
        closure=cl.closure_rel,
        closure_tol=closure_rel,
        decay_rate=cl.decay_rate,
        last_section_point=tuple(float(x) for x in pts[-1]) if n else None,
        roll_range=(float(np.degrees(phi.min())), float(np.degrees(phi.max()))),
        roll_mean=roll_mean,
        speed_range=(float(v.min()), float(v.max())),
        speed_mean=float(v[half].mean()),
        yaw_rate_mean=float(psidot[half].mean()),
        turn_radius=None if r is None else abs(r),
        energy=float(E[0]),
        energy_drift=float(np.ptp(E) / abs(np.mean(E))),
        roll_range_last_half=(float(ph.min()), float(ph.max())),
        family=fam,
    )


def mirrored(ic: InitialCondition) -> InitialCondition:
    """Mirror image of an initial condition: every angle and rate negated.

    Parameters
    ----------
    ic : InitialCondition

    Returns
    -------
    InitialCondition
        Label suffixed with ``" (mirrored)"``.
    """
    return InitialCondition(ic.label + " (mirrored)", -ic.phi, -ic.delta, -ic.phidot, -ic.deltadot)


def summary_entry(p: BicycleParameters, ic: InitialCondition, res: Periodicity) -> dict:
    """One ``limit_cycles`` entry of summary.json: class, period and Floquet multipliers.

    For a periodic run the orbit is Newton-converged from the run's last section point and
    its multipliers computed (:func:`sim.periodic_orbits.orbit_stability`).

    Parameters
    ----------
    p : BicycleParameters
        The bicycle.
    ic : InitialCondition
        The run's initial condition.
    res : Periodicity
        The run's analysis.

    Returns
    -------
    dict
        ``phi0_deg``, ``delta0_deg``, ``phidot0_deg_s``, ``outcome``, ``period_n``,
        ``family`` (:func:`orbit_family`, null unless periodic), ``roll_mean_last_half_deg``,
        ``fall_time_s``, ``fall_cause``, ``period_s``, ``floquet_multipliers`` ([re, im]
        pairs), ``unit_multiplier_error``, ``orbit_energy_J``, ``orbit_section_point``
        (deg, deg, deg/s, m/s), ``closure_rel``, ``decay_rate_per_return``,
        ``floquet_seconds`` [s]; null where not applicable.
    """

    e = {
        "label": ic.label,
        "phi0_deg": ic.phi,
        "delta0_deg": ic.delta,
        "phidot0_deg_s": ic.phidot,
        "outcome": res.verdict,
        "period_n": res.returns_per_period,
        "family": res.family,
        "roll_mean_last_half_deg": res.roll_mean,
        "fall_time_s": res.fell_at,
        "fall_cause": res.fall_cause,
        "period_s": None,
        "floquet_multipliers": None,
        "unit_multiplier_error": None,
        "orbit_energy_J": None,
        "orbit_section_point": None,
        "closure_rel": res.closure,
        "decay_rate_per_return": res.decay_rate,
        "floquet_seconds": None,
    }
    if res.verdict == "periodic":
        o = orbit_stability(
            p, np.asarray(res.last_section_point), res.returns_per_period, energy=res.energy
        )
        e.update(
            period_s=o.period,
            floquet_multipliers=[[m.real, m.imag] for m in o.multipliers],
            unit_multiplier_error=o.unit_multiplier_error,
            orbit_energy_J=o.energy,
            orbit_section_point=list(o.section_point),
            floquet_seconds=o.seconds,
        )
    return e


#: Initial condition of the speed scan: Fig. 4's smallest start (0.1 deg steer, at rest).
SCAN_CONDITION = InitialCondition("delta0=0.1, phidot0=0", delta=0.1)


#: Orbit families (Chen & Dao's turning orbits of Figs. 4-5; orbits symmetric about upright,
#: the weave cycles born at v_w among them, but not only: the period-3 orbit at 3.36 m/s is
#: symmetric too, see ``report.window_label``).  A periodic run is ``symmetric`` when over
#: its last half the mean roll and the sum of the roll extrema are both within
#: :data:`FAMILY_REL` of the roll amplitude (max - min) / 2, else ``turning`` (lopsided: a
#: mean lean, a mean turn).
FAMILIES = ("symmetric", "turning")
def _scan_point(args: tuple) -> dict:
    """Class of one coasting run at initial speed v (picklable worker: parameters, initial
    condition, speed [m/s], duration [s]); a numerical stop is rerun at a 4x finer RK4 step
    before it is reported as ``numerical``."""

    p, ic, v, duration = args
    msg = ""
    for substeps in (None, 8):
        with warnings.catch_warnings():  # a numerical stop is handled here, not warned about
            warnings.simplefilter("ignore", RuntimeWarning)
            tr = coast(p, ic, duration, speed=v, substeps=substeps)
        try:
            r = periodicity(tr, ic.label)
        except ValueError as exc:  # numerical stop (stop_info refuses it)
            msg = str(exc)
            continue
        e = {
            "v0": float(v),
            "outcome": r.verdict,
            "run_outcome": r.verdict,
            "period_n": r.returns_per_period,
            "family": r.family,
            "period_s": r.period,
            "fall_time_s": r.fell_at,
            "fall_cause": r.fall_cause,
            "roll_range_last_half_deg": r.roll_range_last_half,
            "roll_mean_last_half_deg": r.roll_mean,
            "speed_range": r.speed_range,
            "speed_mean_last_half": r.speed_mean,
            "growth_per_return": r.decay_rate,
            "rk4_substeps": substeps,
            "orbit": None,
        }
        if r.verdict in ("periodic", "growing"):
            o = converge_from_run_end(
                p, r.last_section_point, r.verdict, r.returns_per_period, r.energy
            )
            e.update(
                outcome=o.outcome,
                period_n=o.returns_per_period,
                family=o.family,
                period_s=o.period,
                orbit=o.as_dict(),
            )
        return e
    return {"v0": float(v), "outcome": "numerical", "period_n": None, "family": None,
            "message": msg}  # fmt: skip


def scan_windows(points) -> dict[str, list]:
    """Windows of a speed scan: runs of neighbouring initial speeds with the same class.

    A pure function of the scan's entries.  Entries are sorted by ``v0``; consecutive
    entries with the same ``outcome`` and ``family`` form one window.  A window's ends are
    the first and last grid speeds in it (the true edge lies within one grid step outside).

    Parameters
    ----------
    points : sequence of dict
        Scan entries with at least ``v0`` [m/s], ``outcome`` (``decays``, ``periodic``,
        ``irregular``, ``falls``, ``numerical``), ``period_n`` (int or None) and
        ``family`` (``"symmetric"``, ``"turning"`` or None).

    Returns
    -------
    dict
        ``periodic``: list of [low, high, family] [m/s] for the periodic windows (the
        ``chen_dao.periodic_windows`` of summary.json); ``all``: every window as a dict
        (``low``, ``high`` [m/s], ``outcome``, ``family``, ``period_n``: sorted distinct
        period numbers in it, ``n``: number of grid speeds; for entries with a converged
        ``orbit`` (:mod:`experiments.papers.orbit_convergence`) also [min, max] over the
        window of ``roll_amplitude_deg`` (half the roll range [deg]), ``orbit_period_s``
        [s], ``orbit_speed_mean`` (mean speed over the orbit [m/s]) and ``speed_gain``
        (that minus the initial speed [m/s])).

    Raises
    ------
    ValueError
        If an entry lacks ``v0`` or ``outcome``, or two entries share a speed.
    """
    pts = sorted(points, key=lambda q: q["v0"])
    for q in pts:
        if "v0" not in q or "outcome" not in q:
            raise ValueError(f"scan entry {q} needs 'v0' and 'outcome'")
    vs = [q["v0"] for q in pts]
    if len(set(vs)) != len(vs):
        raise ValueError("two scan entries share an initial speed: one entry per speed")
    runs: list[dict] = []
    for q in pts:
        key = (q["outcome"], q.get("family"))
        if runs and (runs[-1]["outcome"], runs[-1]["family"]) == key:
            w = runs[-1]
            w["high"] = q["v0"]
            w["n"] += 1
        else:
            w = {"low": q["v0"], "high": q["v0"], "outcome": key[0], "family": key[1],
                 "period_n": [], "n": 1}  # fmt: skip
            runs.append(w)
        if q.get("period_n") is not None and q["period_n"] not in w["period_n"]:
            w["period_n"] = sorted(w["period_n"] + [q["period_n"]])
        o = q.get("orbit") or {}
        if o.get("outcome") == "periodic":
            for key, val in (
                ("roll_amplitude_deg", 0.5 * (o["roll_max"] - o["roll_min"])),
                ("orbit_period_s", o["period"]),
                ("orbit_speed_mean", o["speed_mean"]),
                ("speed_gain", o["speed_mean"] - q["v0"]),
            ):
                lo_hi = w.get(key)
                w[key] = [val, val] if lo_hi is None else [min(lo_hi[0], val), max(lo_hi[1], val)]
    per = [[w["low"], w["high"], w["family"]] for w in runs if w["outcome"] == "periodic"]
    return {"periodic": per, "all": runs}


def speed_scan(
    p: BicycleParameters,
    speeds,
    duration: float,
    ic: InitialCondition = SCAN_CONDITION,
    workers: int = 1,
    dask: str | None = None,
) -> dict:
    """Class of coasting from ``ic`` at every initial speed of a grid (Chen & Dao's v_l .. v_w).

    Every speed is run (:func:`coast`, :func:`periodicity`; the runs in parallel through
    :func:`bikeid.experiments.parallel.map_jobs`, the reproduction's pool), classified
    (``decays``, ``periodic`` with its period number and orbit family
    (:func:`orbit_family`), ``irregular``, ``falls`` with time and cause) and the grid is
    cut into windows of one class (:func:`scan_windows`).  No bisection: a class can change
    more than once between two grid speeds, so the windows are as fine as the grid and no
    finer.  Runs that stop for a numerical reason are rerun at a 4x finer step; if that
    also fails they are ``numerical``.

    Parameters
    ----------
    p : BicycleParameters
        The bicycle.
    speeds : sequence of float
        Initial speeds [m/s].
    duration : float
        T_max, the length of each run [s]; a run still ``growing`` or ``periodic`` at the
        end is decided by Newton from its end (``periodic`` or ``not converged``).
    ic : InitialCondition, optional
        Initial roll, steer and rates (default :data:`SCAN_CONDITION`).
    workers : int, optional
        Worker processes (1: in this process).
    dask : str or None, optional
        ``"local"`` or a Dask scheduler address (:mod:`bikeid.experiments.parallel`); the
        classes do not depend on it.

    Returns
    -------
    dict
        ``condition`` (label), ``duration`` [s], ``step`` (smallest grid step [m/s]),
        ``points`` (one entry per speed, sorted: ``v0`` [m/s], ``outcome``, ``period_n``,
        ``family``, ``period_s`` [s], fall time [s] and cause, roll range and mean over the
        last half [deg], speed range [m/s]), ``windows`` (every window of
        :func:`scan_windows`) and ``periodic_windows`` (list of [low, high, family] [m/s]).
    """
    grid = sorted({float(v) for v in speeds})
    if not grid:
        raise ValueError("speed scan needs at least one initial speed")

    pts = map_jobs(_scan_point, [(p, ic, v, duration) for v in grid], workers, dask)
    w = scan_windows(pts)
    return {
        "condition": ic.label,
        "duration": duration,
        "step": float(np.min(np.diff(grid))) if len(grid) > 1 else None,
        "points": pts,
        "windows": w["all"],
        "periodic_windows": w["periodic"],
    }


# -- figures ---------------------------------------------------------------------------------
def plot_phase_portraits(trajs, labels, path, title: str):
    """Roll angle vs roll rate and steer angle vs steer rate [deg, deg/s], one colour per run.

    Parameters
    ----------
    trajs : sequence of Trajectory
        The runs; a run that falls is drawn until |roll| first exceeds 45 deg.
    labels : sequence of str
        Legend label per run.
    path : str or Path
        PNG file to write (atomically, :func:`experiments.plots.save`).
    title : str
        Figure title.

    Returns
    -------
    pathlib.Path
        ``path``.
    """

    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.6))
    for tr, lab in zip(trajs, labels, strict=True):
        n = tr.t.size
        fell = ""
        if tr.fell_at is not None or tr.stop_reason is not None:
            # the last phase of a fall is fast and not what the figure is about: draw the
            # run until |roll| first exceeds 45 deg
            big = np.nonzero(np.abs(tr.signal("phi")) > math.radians(45.0))[0]
            n = int(big[0]) + 1 if big.size else n
            stop = getattr(tr, "stop", None)
            if stop is not None and not stop.physical:
                fell = f" (numerical failure, {stop.cause}, at {stop.time:.1f} s)"
            else:
                fell = f" (falls at {tr.fell_at or tr.t[-1]:.1f} s; leaves the axes)"
        kw = dict(lw=0.6, label=lab + fell)
        a1.plot(np.degrees(tr.signal("phi")[:n]), np.degrees(tr.signal("phidot")[:n]), **kw)
        a2.plot(np.degrees(tr.signal("delta")[:n]), np.degrees(tr.signal("deltadot")[:n]), **kw)
    kept = [tr for tr in trajs if tr.fell_at is None and tr.stop_reason is None]
    for ax, (xn, yn) in ((a1, ("phi", "phidot")), (a2, ("delta", "deltadot"))):
        if kept:  # axes fitted to the runs that stay up; falls leave the frame
            x = np.degrees(np.concatenate([tr.signal(xn) for tr in kept]))
            y = np.degrees(np.concatenate([tr.signal(yn) for tr in kept]))
            ax.set_xlim(1.4 * x.min() - 2, 1.4 * x.max() + 2)
            ax.set_ylim(1.4 * y.min() - 5, 1.4 * y.max() + 5)
    a1.set_xlabel("roll angle phi [deg]")
    a1.set_ylabel("roll rate [deg/s]")
    a2.set_xlabel("steer angle delta [deg]")
    a2.set_ylabel("steer rate [deg/s]")
    for a in (a1, a2):
        a.grid(alpha=0.3)
    fig.legend(
        *a1.get_legend_handles_labels(),
        fontsize=7,
        loc="lower center",
        ncol=3,
        bbox_to_anchor=(0.5, -0.08),
    )
    fig.suptitle(title)
    return save(fig, path)


def plot_energy_speed(trajs, labels, path, title: str):
    """Relative energy change |E(t) - E(0)| / |E(0)| (log axis) and forward speed [m/s]
    against time, each run drawn only up to its stop (fall) time, which is marked.

    Parameters
    ----------
    trajs : sequence of Trajectory
        The runs, with energy recorded (:func:`coast`).
    labels : sequence of str
        Legend label per run.
    path : str or Path
        PNG file to write (atomically).
    title : str
        Figure title.

    Returns
    -------
    pathlib.Path
        ``path``.
    """

    fig, (a1, a2) = plt.subplots(2, 1, figsize=(9, 6.5), sharex=True)
    for tr, lab in zip(trajs, labels, strict=True):
        try:
            t_stop, cause = stop_info(tr)
        except ValueError:  # numerical stop: drawn to its end, named in the label
            t_stop, cause = float(tr.t[-1]), "numerical stop"
        n = tr.t.size if t_stop is None else int(np.searchsorted(tr.t, t_stop, side="right"))
        n = max(n, 1)
        t = tr.t[:n]
        rel = np.abs(tr.energy[:n] - tr.energy[0]) / abs(tr.energy[0])
        rel = np.maximum(rel, 1e-16)  # exact zeros (t = 0) on the log axis
        name = lab + ("" if t_stop is None else f" (stops at {t_stop:.2f} s: {cause})")
        (line,) = a1.semilogy(t, rel, lw=0.7, label=name)
        a2.plot(t, tr.signal("v")[:n], lw=0.7, color=line.get_color())
        if t_stop is not None:
            a1.semilogy(t[-1], rel[-1], "x", color=line.get_color(), ms=6)
            a2.plot(t[-1], tr.signal("v")[n - 1], "x", color=line.get_color(), ms=6)
    a1.set_ylabel("|E(t) - E(0)| / |E(0)|")
    a1.set_ylim(1e-16, 1.0)
    a2.set_ylabel("forward speed v [m/s]")
    a2.set_xlabel("time [s]   (x: the run stops, a fall)")
    for a in (a1, a2):
        a.grid(alpha=0.3, which="both")
    a1.legend(fontsize=7, loc="upper right")
    a1.set_title(
        title + "\n(runs that stay up conserve energy to the RK4 error; falls end at the x)",
        fontsize=9,
    )
    return save(fig, path)
