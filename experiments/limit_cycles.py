"""Chen & Dao (2010) Figs. 4-5: uncontrolled coasting motions at 3.5 m/s, and whether they are
periodic.

Set-up (Chen & Dao §III.C): benchmark bicycle, nonlinear Whipple plant, rear wheel free
(``mode="coast"``, speed is a state, total energy conserved), no steer torque, initial speed
3.5 m/s, initial conditions of the paper's Figs. 4 and 5.  The extracted text of the paper
lost the minus signs, so the Fig. 4 roll rates (55.236, 27.291 deg/s with steer 10, 5 deg) are
run in both readings: same sign as the steer angle (``+``) and opposite sign (``-``).  Mirror
symmetry (phi, delta, phidot) -> -(phi, delta, phidot) makes the overall sign irrelevant.

Periodicity check (a Poincare section).  The section is phidot = 0 with phidot decreasing
(every local maximum of roll); each crossing is located by linear interpolation between
samples and gives the section point x_n = (phi, delta, deltadot, v).  On the last half of
the returns we look for the smallest p in 1..4 with max_n |x_{n+p} - x_n| (angles in deg,
speed in cm/s) below ``closure_tol``: the orbit then closes after p returns (period = the
time of p returns).  The distance d_n = |x_{n+p} - x_n| over all returns measures how the
motion approaches that orbit; a straight-line fit of log d_n against n gives the
contraction factor per p returns (< 1: nearby motions on the same energy level are
attracted; = 1: a neutral family).  Falls (|roll| > 60 deg) end the run and are reported.

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
from dataclasses import asdict, dataclass

import numpy as np

from bikeid.sim.parameters import BicycleParameters

__all__ = [
    "FIG4_CONDITIONS",
    "FIG5_CONDITIONS",
    "InitialCondition",
    "Periodicity",
    "coast",
    "periodicity",
    "plot_energy_speed",
    "plot_phase_portraits",
    "section_points",
]

SPEED = 3.5  # m/s, Chen & Dao Figs. 4-5
CLOSURE_TOL = 0.05  # deg (and cm/s): section points closer than this count as the same


@dataclass(frozen=True)
class InitialCondition:
    """Initial roll, steer [deg] and their rates [deg/s]; ``label`` names it in figures."""

    label: str
    phi: float = 0.0
    delta: float = 0.0
    phidot: float = 0.0
    deltadot: float = 0.0

    def radians(self) -> dict[str, float]:
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
):
    """Uncontrolled coasting run (no inputs, speed free) with total energy recorded.

    Returns a :class:`sim.integrate.Trajectory`; it ends early at a fall (|roll| > 60 deg).
    """
    from bikeid.sim.integrate import simulate
    from bikeid.sim.nonlinear import WhippleBicycle

    bike = WhippleBicycle(p)
    x0 = bike.state(speed, **ic.radians())
    return simulate(bike, x0, duration, dt=dt, mode="coast", energy=True)


def section_points(t, phi, phidot, delta, deltadot, v) -> tuple[np.ndarray, np.ndarray]:
    """Crossings of phidot = 0 downward (roll maxima): times [s] and points
    (phi [deg], delta [deg], deltadot [deg/s], v [cm/s]), linearly interpolated."""
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


@dataclass(frozen=True)
class Periodicity:
    """Outcome of one coasting run (angles deg, rates deg/s, speed m/s, energy J).

    ``verdict`` is one of ``fell`` (a physical stop), ``numerical failure`` (the run
    ended for a numerical reason, not a fall), ``periodic`` (closes after
    ``returns_per_period`` returns to the section within ``closure_tol``), ``not closed``
    (bounded but no period found); ``stop_cause`` is the run's stop cause
    (``sim.integrate.STOP_CAUSES``) or None; ``closure`` = max |x_{n+p} - x_n| over the
    last half of the returns;
    ``contraction`` = factor by which d_n shrinks per period (NaN when not measurable);
    ``energy_drift`` = (max - min) / |mean| of the total energy.
    """

    label: str
    verdict: str
    fell_at: float | None
    duration: float
    n_returns: int
    returns_per_period: int | None
    period: float | None
    closure: float | None
    closure_tol: float
    contraction: float | None
    roll_range: tuple[float, float]
    roll_mean: float
    speed_range: tuple[float, float]
    speed_mean: float
    yaw_rate_mean: float
    turn_radius: float | None
    energy: float
    energy_drift: float
    stop_cause: str | None = None

    def as_dict(self) -> dict:
        return asdict(self)


def periodicity(traj, label: str = "", closure_tol: float = CLOSURE_TOL) -> Periodicity:
    """Poincare-section analysis of a coasting trajectory (see the module docstring)."""
    t = traj.t
    phi, phidot = traj.signal("phi"), traj.signal("phidot")
    delta, deltadot, v = traj.signal("delta"), traj.signal("deltadot"), traj.signal("v")
    psidot = traj.signal("psidot")
    E = traj.energy if traj.energy is not None else np.full(t.size, np.nan)
    half = slice(t.size // 2, None)  # statistics of the settled second half
    common = dict(
        label=label,
        fell_at=traj.fell_at,
        duration=float(t[-1]),
        closure_tol=closure_tol,
        roll_range=(float(np.degrees(phi.min())), float(np.degrees(phi.max()))),
        roll_mean=float(np.degrees(phi[half].mean())),
        speed_range=(float(v.min()), float(v.max())),
        speed_mean=float(v[half].mean()),
        yaw_rate_mean=float(psidot[half].mean()),
        energy=float(E[0]),
        energy_drift=float(np.ptp(E) / abs(np.mean(E))),
    )
    r = float(np.mean(v[half]) / psidot[half].mean()) if abs(psidot[half].mean()) > 1e-6 else None
    common["turn_radius"] = None if r is None else abs(r)
    tc, pts = section_points(t, phi, phidot, delta, deltadot, v)
    n = len(tc)
    common["n_returns"] = n
    no_period = dict(returns_per_period=None, period=None, closure=None, contraction=None)
    stop = getattr(traj, "stop", None)
    if traj.fell_at is not None or traj.stop_reason is not None:
        numerical = stop is not None and not stop.physical
        verdict = "numerical failure" if numerical else "fell"
        cause = stop.cause if stop is not None else None
        return Periodicity(verdict=verdict, **no_period, **common, stop_cause=cause)
    best = None
    tail0 = n // 2
    for p in range(1, 5):
        if n - tail0 - p < 4:
            break
        d = np.max(np.abs(pts[tail0 + p :] - pts[tail0 : n - p]))
        if best is None or d < best[1] - 1e-12:
            best = (p, d)
        if d < closure_tol:
            best = (p, d)
            break
    if best is None:
        return Periodicity(verdict="not closed", **no_period, **common)
    p, closure = best
    period = float(np.mean(tc[tail0 + p :] - tc[tail0 : n - p]))
    dn = np.linalg.norm(pts[p:] - pts[:-p], axis=1)
    contraction = _contraction(dn, p)
    verdict = "periodic" if closure < closure_tol else "not closed"
    return Periodicity(
        verdict=verdict,
        returns_per_period=p,
        period=period,
        closure=float(closure),
        contraction=contraction,
        **common,
    )


def _contraction(dn: np.ndarray, p: int) -> float | None:
    """Factor per period by which d_n decays (fit of log d_n while above round-off)."""
    ok = dn > 1e-6
    idx = np.arange(dn.size)[ok]
    if idx.size < 4 or idx[-1] - idx[0] < 3:
        return None
    # fit only the decaying part: from the first return to the point d_n stops shrinking
    stop = idx.size
    floor = np.median(dn[-max(3, dn.size // 10) :])
    above = np.where(dn[idx] > 3 * floor)[0] if floor > 0 else np.arange(idx.size)
    if above.size >= 4:
        stop = above[-1] + 1
    sel = idx[:stop]
    if sel.size < 4:
        return None
    slope = np.polyfit(sel, np.log(dn[sel]), 1)[0]
    return float(math.exp(slope * p))


# -- figures ---------------------------------------------------------------------------------
def plot_phase_portraits(trajs, labels, path, title: str):
    """Roll angle vs roll rate and steer angle vs steer rate [deg, deg/s], one colour per run."""
    from .plots import plt, save

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
    """Total energy minus its initial value [J] and forward speed [m/s] against time."""
    from .plots import plt, save

    fig, (a1, a2) = plt.subplots(2, 1, figsize=(9, 5.5), sharex=True)
    for tr, lab in zip(trajs, labels, strict=True):
        a1.plot(tr.t, tr.energy - tr.energy[0], lw=0.7, label=lab)
        a2.plot(tr.t, tr.signal("v"), lw=0.7, label=lab)
    a1.set_ylabel("E(t) - E(0) [J]")
    a2.set_ylabel("forward speed v [m/s]")
    a2.set_xlabel("time [s]")
    for a in (a1, a2):
        a.grid(alpha=0.3)
    a2.legend(fontsize=7, loc="upper right", ncol=2)
    a1.set_title(title)
    return save(fig, path)
