"""Moore & Hubbard (direct identification) on the testbed: Tables 2-5, Figs. 2-4 analogues.

Analogue of the paper's data set (stated in the report):

- "riders" = three riders on one bicycle, as the paper (:data:`RIDERS`,
  :func:`rider_parameters`): the benchmark bicycle's rear body (85 kg, frame and rider) is
  taken as a 13 kg rear frame plus a 72 kg nominal rider at the rear body's mass centre whose
  share of the rear body's inertia equals its mass share; a light and a heavy rider scale the
  rider's mass and inertia by 0.8 and 1.2 (57.6 and 86.4 kg, same shape and position), the
  bicycle unchanged.  Each rider has its own Whipple model (an assumption of the analogue:
  the benchmark does not split frame and rider);
- "environments" = :data:`ENVIRONMENTS`: ``N`` nominal Whipple plant, ``S`` the plant plus
  steer damping 0.3 N m s/rad and steer Coulomb friction 0.1 N m (an effect the Whipple
  model lacks, like tyre scrub);
- "manoeuvre": PID roll control (steer into the lean) following a 3 deg roll chirp, with
  half-sine lateral pushes of 50 N (0.2 s, irregular intervals, at the rear-body mass
  centre) as Moore & Hubbard's manual perturbations; default sensor noise, 100 Hz.

Identification (paper eqs. 4-5): two-stage least squares, roll row free {Mpd, C1pd, K0pd},
then steer row free {Mdd, C1dp, C1dd, K0dd, K2dd, HdF} with Mdp := Mpd, K0dp := K0pd.  The
fixed entries of each run come from that run's own rider (Whipple values; HpF from the push
point), as Moore & Hubbard used each rider's measured parameters, so runs of different riders
stack in one regression.  For a single rider this is :func:`ident.direct.identify` (the tests
check the two agree).  Accelerations: Moore & Hubbard's own processing, central differences
of the 15 Hz low-passed rates (:func:`ident.signals.prepare`, ``derivative="central"``,
:data:`DERIVATIVE`; forward differences, exact for zero-order-hold torques, are the
accuracy table's comparison, :mod:`bikeid.experiments.testbed.accuracy`).

VAF (Tables 2-3): Moore's eq. 6, 1 - ||Gamma Theta - Y|| / ||Y - mean(Y)||, with Y the torque
minus the entries fixed in every model; in the steer row Mdp and K0dp count as model terms.
Simulation VAF (Table 4): each model (with the run's rider's fixed entries, at the run's mean
speed) is simulated on the measured T_delta and F in consecutive windows of
:data:`SIM_WINDOW` seconds, the initial state of each window fitted by least squares (the
models are unstable, so a whole-run simulation diverges); eq.-6 VAF per output over the run,
median over runs.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import control
import numpy as np

from bikeid.controllers.excitation import ChirpReference, LateralForcePulses
from bikeid.controllers.registry import make
from bikeid.dataset.closed_loop import simulate_run
from bikeid.dataset.sensors import Sensors
from bikeid.experiments.parallel import map_jobs
from bikeid.experiments.plots import phase_deg, plt, save
from bikeid.ident.direct import ALL_ENTRIES, parse_entry, regressors, vaf_moore
from bikeid.ident.effects.experiment_model import ExperimentModel
from bikeid.ident.methods import DIRECT_PRESETS
from bikeid.ident.signals import prepare
from bikeid.ident.validate import windowed_simulation_vaf
from bikeid.sim.arm_model import ArmParameters, arm_model_matrices, stability_summary
from bikeid.sim.effects import SteerCoulomb, SteerDamping
from bikeid.sim.linear import (
    CanonicalMatrices,
    canonical_matrices,
    eigenvalues_vs_speed,
    lateral_force_vector,
    match_eigenvalues,
    state_matrices,
    state_space,
)
from bikeid.sim.parameters import benchmark
from bikeid.sim.sampling import zoh

__all__ = [
    "ENVIRONMENTS",
    "RIDERS",
    "SUBSETS",
    "fit_subset",
    "make_runs",
    "ARM",
    "arm_model_summary",
    "reproduce",
    "rider_parameters",
    "row_vaf",
    "table4_vaf",
]

RIDERS = {
    "B": "benchmark rider (72 kg)",
    "L": "light rider (57.6 kg)",
    "H": "heavy rider (86.4 kg)",
}
#: Rider mass and inertia scale factors on the nominal rider (:func:`rider_parameters`).
RIDER_SCALES = {"B": 1.0, "L": 0.8, "H": 1.2}
#: The nominal rider's mass [kg] within the benchmark's 85 kg rear body.
RIDER_MASS = 72.0


def rider_parameters(rider: str):
    """The benchmark bicycle with rider ``rider`` (module docstring: the rider's mass and
    inertia scaled, the bicycle and the rider's position fixed).

    Parameters
    ----------
    rider : str
        A key of :data:`RIDERS`.

    Returns
    -------
    BicycleParameters
        Rear body mass mB = 85 - 72 + 72 s [kg] and inertia (IBxx, IByy, IBzz, IBxz) times
        (13 + 72 s) / 85 [kg m^2], s = :data:`RIDER_SCALES` [rider]; all else the benchmark's.

    Raises
    ------
    KeyError
        If ``rider`` is not a key of :data:`RIDERS`.
    """

    s = RIDER_SCALES[rider]
    p = benchmark()
    f = (p.mB - RIDER_MASS + RIDER_MASS * s) / p.mB
    return p.replace(
        mB=p.mB * f, IBxx=p.IBxx * f, IByy=p.IByy * f, IBzz=p.IBzz * f, IBxz=p.IBxz * f
    )


ENVIRONMENTS = {"N": "nominal Whipple plant", "S": "steer damping 0.3 N m s/rad + Coulomb 0.1 N m"}
ROLL_FREE = ("Mpd", "C1pd", "K0pd")
STEER_FREE = ("Mdd", "C1dp", "C1dd", "K0dd", "K2dd", "HdF")
SYMMETRIC = (("Mdp", "Mpd"), ("K0dp", "K0pd"))
SIM_WINDOW = 2.0  # s
#: Moore & Hubbard's data processing (paper §4): 2nd-order Butterworth low-pass at 15 Hz,
#: accelerations by central differences of the filtered rates: the direct method's
#: "moore-hubbard" settings of the method table (ident.methods.DIRECT_PRESETS).
MH_SETTINGS = DIRECT_PRESETS["moore-hubbard"]
CUTOFF_HZ = MH_SETTINGS.cutoff
DERIVATIVE = MH_SETTINGS.derivative
BODE_SPEEDS = (2.0, 4.0, 6.0, 9.0)


def _subsets() -> dict[str, tuple[tuple[str, ...], tuple[str, ...]]]:
    out = {}
    for r in (*RIDERS, "A"):
        for e in (*ENVIRONMENTS, "A"):
            out[f"{r}-{e}"] = (
                tuple(RIDERS) if r == "A" else (r,),
                tuple(ENVIRONMENTS) if e == "A" else (e,),
            )
    return out


#: 12 subsets as in the paper: rider-environment, rider-all, all-environment, all-all.
SUBSETS = _subsets()


def _effects(env: str) -> list:
    return [] if env == "N" else [SteerDamping(0.3), SteerCoulomb(0.1, smoothing=0.05)]


def _one_run(args: tuple) -> Any:
    rider, env, speed, duration, seed = args
    p = rider_parameters(rider)
    ctrl = make("pid", p, sample_time=0.01)
    run = simulate_run(
        p,
        ctrl,
        speed,
        duration=duration,
        reference=ChirpReference(math.radians(3.0), 0.05, 0.5, duration),
        lateral_force=LateralForcePulses(50.0, 0.2, 2.0, 0.8, seed=seed + 7, first=0.5),
        sensors=Sensors.default(100.0),
        effects=_effects(env),
        seed=seed,
    )
    # the load cell: F is logged exactly, like the steer torque
    run.signals["F"] = run.true("F").copy()
    run = prepare(run, cutoff=CUTOFF_HZ, derivative=DERIVATIVE)
    run.meta.update({"rider": rider, "environment": env})
    return run


def make_runs(
    speeds: Sequence[float], duration: float, workers: int = 1, dask: str | None = None
) -> list:
    """One run per rider x environment x speed (seeded by their position).

    Parameters
    ----------
    speeds : sequence of float
        Forward speeds [m/s].
    duration : float
        Length of each run [s].
    workers : int, optional
        Worker processes (1: in this process).
    dask : str or None, optional
        ``"local"`` or a Dask scheduler address (:mod:`bikeid.experiments.parallel`); the
        runs do not depend on where they are computed.

    Returns
    -------
    list of Run
        Prepared runs (15 Hz low-pass, central-difference accelerations ``phiddot``,
        ``deltaddot`` [rad/s^2]; lateral force ``F`` [N] logged exactly), in the order
        rider, environment, speed; ``meta["rider"]`` and ``meta["environment"]`` name
        the cell.
    """
    jobs = []
    for i, r in enumerate(RIDERS):
        for j, e in enumerate(ENVIRONMENTS):
            for k, v in enumerate(speeds):
                jobs.append((r, e, float(v), duration, 100 * i + 10 * j + k))
    return map_jobs(_one_run, jobs, workers, dask)


# -- regression ------------------------------------------------------------------------------
@functools.cache
def _whipple_values(rider: str) -> dict[str, float]:
    """All entries (M.., C1.., K0.., K2.., HpF, HdF) of a rider's Whipple model."""

    p = rider_parameters(rider)
    cm = canonical_matrices(p)
    H = lateral_force_vector(p, p.xB, p.zB)  # the push acts at the rear-body mass centre
    vals = {}
    for n in ALL_ENTRIES:
        m, r, c = parse_entry(n)
        vals[n] = float(H[r]) if m == "H" else float(getattr(cm, m)[r, c])
    vals["g"] = cm.g
    return vals


def _columns(run) -> dict[str, np.ndarray]:
    d = {
        k: np.asarray(run[k], float)
        for k in ("phi", "delta", "phidot", "deltadot", "v", "T_phi", "T_delta", "F")
    }
    d["phiddot"], d["deltaddot"] = run.signals["phiddot"], run.signals["deltaddot"]
    return regressors(d, 9.81)


def _row_parts(run, free_names: Sequence[str], row: int, model: dict[str, float] | None):
    """(Gamma, Y) of one run's row; entries outside ``free_names`` (and outside the symmetric
    pair) take the rider's Whipple values; ``model`` supplies Mdp/K0dp for the steer row."""

    cols = _columns(run)
    wv = dict(_whipple_values(run.meta["rider"]))
    names = [n for n in ALL_ENTRIES if parse_entry(n)[1] == row]
    sym = {a for a, _ in SYMMETRIC} if row == 1 else set()
    Y = np.asarray(run["T_phi" if row == 0 else "T_delta"], float).copy()
    model_terms = np.zeros_like(Y)
    for n in names:
        if n in free_names:
            continue
        if n in sym:
            val = wv[dict(SYMMETRIC)[n]] if model is None else model[dict(SYMMETRIC)[n]]
            model_terms += val * cols[n]
        else:
            Y -= wv[n] * cols[n]
    G = np.column_stack([cols[n] for n in free_names])
    return G, Y, model_terms


def fit_subset(runs: Sequence) -> dict[str, float]:
    """Two-stage least squares over ``runs`` (see the module docstring); free entry -> value.

    Parameters
    ----------
    runs : sequence of Run
        Runs of :func:`make_runs` (their ``meta["rider"]`` selects the fixed entries).

    Returns
    -------
    dict of str to float
        Roll {Mpd, C1pd, K0pd} then steer {Mdd, C1dp, C1dd, K0dd, K2dd, HdF} estimates, in
        their matrix units (M kg m^2, C1 kg m, K0 kg m, K2 kg, H m).
    """
    est: dict[str, float] = {}
    parts = [_row_parts(r, ROLL_FREE, 0, None) for r in runs]
    G = np.vstack([p[0] for p in parts])
    Y = np.concatenate([p[1] for p in parts])
    est.update(zip(ROLL_FREE, np.linalg.lstsq(G, Y, rcond=None)[0], strict=True))
    parts = [_row_parts(r, STEER_FREE, 1, est) for r in runs]
    G = np.vstack([p[0] for p in parts])
    Y = np.concatenate([p[1] - p[2] for p in parts])
    est.update(zip(STEER_FREE, np.linalg.lstsq(G, Y, rcond=None)[0], strict=True))
    return {k: float(v) for k, v in est.items()}


def _whipple_free(rider: str) -> dict[str, float]:
    wv = _whipple_values(rider)
    return {n: wv[n] for n in (*ROLL_FREE, *STEER_FREE)}


def row_vaf(runs: Sequence, model: dict[str, float] | None) -> dict[str, float]:
    """Eq.-6 VAF of the roll and steer rows on ``runs`` for ``model`` (free entries; None =
    each run's own Whipple model).

    Parameters
    ----------
    runs : sequence of Run
        Runs of :func:`make_runs`.
    model : dict of str to float or None
        Free-entry values (:func:`fit_subset`), or None for each run's Whipple values.

    Returns
    -------
    dict of str to float
        ``"roll"`` and ``"steer"``: Moore's eq. 6 (:func:`bikeid.ident.direct.vaf_moore`)
        of the row's torque [N m] over all runs stacked (dimensionless).
    """

    out = {}
    for row, free in ((0, ROLL_FREE), (1, STEER_FREE)):
        ys, ps = [], []
        for r in runs:
            m = _whipple_free(r.meta["rider"]) if model is None else model
            G, Y, terms = _row_parts(r, free, row, m)
            ys.append(Y)
            ps.append(G @ np.array([m[n] for n in free]) + terms)
        out["roll" if row == 0 else "steer"] = vaf_moore(np.concatenate(ys), np.concatenate(ps))
    return out


#: Table 4's name of the arm model (:mod:`bikeid.sim.arm_model`) among the models.
ARM = "Arm"


@functools.cache
def _arm_matrices(rider: str) -> CanonicalMatrices:
    """The rider's arm model: the default arms (72 kg rider, ``sim.arm_model``) with mass and
    inertia scaled like the rider's (:data:`RIDER_SCALES`), taken out of the rear body and
    added back as moving segments."""

    arms = ArmParameters().scaled(RIDER_SCALES[rider])
    return arm_model_matrices(rider_parameters(rider), arms)


def _model_matrices(rider: str, model: dict[str, float] | str | None):
    """CanonicalMatrices and H of ``model``'s free entries over the rider's Whipple values
    (``model`` = :data:`ARM`: the rider's arm model, with the Whipple model's H: the push acts
    on the rear frame, whose kinematics the arms do not change)."""

    if isinstance(model, str):
        if model != ARM:
            raise ValueError(f"unknown model {model!r}: a dict of free entries, None or {ARM!r}")
        return _arm_matrices(rider), _model_matrices(rider, None)[1]

    vals = dict(_whipple_values(rider))
    if model is not None:
        vals.update(model)
        for a, b in SYMMETRIC:
            vals[a] = model[b]
    mats = {
        m: np.array([[vals[f"{m}{r}{c}"] for c in "pd"] for r in "pd"])
        for m in ("M", "C1", "K0", "K2")
    }
    return CanonicalMatrices(g=vals["g"], **mats), np.array([vals["HpF"], vals["HdF"]])


def table4_vaf(run, model: dict[str, float] | str | None, window: float = SIM_WINDOW):
    """Table 4's entries: eq.-6 VAF of phi, delta, phidot, deltadot for a windowed
    simulation driven by T_delta and F (module doc).

    Parameters
    ----------
    run : Run
        A run of :func:`make_runs`.
    model : dict of str to float, str or None
        Free-entry values, None for the run's rider's Whipple model, or :data:`ARM` for the
        rider's arm model.
    window : float, optional
        Window length [s]; the initial state of each window is fitted by least squares.

    Returns
    -------
    dict of str to float
        Moore's eq. 6 fit per state ``phi``, ``delta``, ``phidot``, ``deltadot``
        (dimensionless; :func:`bikeid.ident.validate.windowed_simulation_vaf`).
    """

    cm, H = _model_matrices(run.meta["rider"], model)
    v = float(np.mean(run["v"]))
    A, B = state_matrices(cm, v)
    Bf = np.vstack([np.zeros((2, 1)), (np.linalg.inv(cm.M) @ H)[:, None]])
    Bu = np.hstack([B[:, 1:2], Bf])  # inputs T_delta, F
    dt = run.dt
    Ad, Bd = zoh(A, Bu, dt)
    names = ("phi", "delta", "phidot", "deltadot")
    y = np.column_stack([run[n] for n in names])
    u = np.column_stack([run["T_delta"], run["F"]])
    n = max(2, int(round(window / dt)))
    return windowed_simulation_vaf(Ad, Bd, y, u, n, initial="estimate", names=names)


# -- the whole reproduction -------------------------------------------------------------------
def reproduce(
    out: Path,
    speeds: Sequence[float],
    duration: float,
    workers: int = 1,
    log: Callable[[str], None] = lambda s: None,
    dask: str | None = None,
) -> dict[str, Any]:
    """Runs, 12 identified models, Tables 2-5 and Figs. 2-4 analogues.

    Parameters
    ----------
    out : Path
        Existing output folder for the three figures (PNG).
    speeds : sequence of float
        Forward speeds [m/s] of the runs.
    duration : float
        Length of each run [s].
    workers : int, optional
        Worker processes of the simulation.
    log : callable, optional
        Receives progress lines.
    dask : str or None, optional
        ``"local"`` or a Dask scheduler address for the simulation.

    Returns
    -------
    dict
        ``riders``, ``environments``, ``speeds`` [m/s], ``duration`` [s], ``n_runs``,
        ``fell`` (runs whose bicycle fell), ``models`` (subset -> free entries),
        ``table2_roll_vaf`` and ``table3_steer_vaf`` (data subset -> model -> eq.-6 VAF),
        ``table4_simulation_vaf`` (model -> median VAF per state and their mean),
        ``table5`` (M, C1, K0, K2, H of B-N, B-S, A-A, the benchmark Whipple model and the
        benchmark rider's arm model), ``figures`` (file names), ``sim_window`` [s] and
        ``arm_model`` (:func:`arm_model_summary`).  Table 4 has a row :data:`ARM`.
    """
    runs = make_runs(speeds, duration, workers, dask)
    fell = [
        f"{r.meta['rider']}-{r.meta['environment']} at {r.speed} m/s"
        for r in runs
        if r.meta.get("fell_at") is not None
    ]
    log(f"  {len(runs)} runs simulated ({len(fell)} fell)")

    def members(name):
        rs, es = SUBSETS[name]
        return [r for r in runs if r.meta["rider"] in rs and r.meta["environment"] in es]

    models = {name: fit_subset(members(name)) for name in SUBSETS}
    cols = [*SUBSETS, "Whipple"]
    table2, table3 = {}, {}
    for data_name in SUBSETS:
        rs = members(data_name)
        table2[data_name], table3[data_name] = {}, {}
        for mname in cols:
            vaf = row_vaf(rs, None if mname == "Whipple" else models[mname])
            table2[data_name][mname] = vaf["roll"]
            table3[data_name][mname] = vaf["steer"]
    log("  Tables 2-3 (equation VAF) done")
    table4 = {}
    for mname in (*cols, ARM):
        spec = {"Whipple": None, ARM: ARM}[mname] if mname in ("Whipple", ARM) else models[mname]
        per = [table4_vaf(r, spec) for r in runs]
        med = {k: float(np.median([p[k] for p in per])) for k in per[0]}
        med["mean"] = float(np.mean(list(med.values())))
        table4[mname] = med
    log("  Table 4 (simulation VAF) done")
    table5 = {}
    for mname in ("B-N", "B-S", "A-A"):
        cm, H = _model_matrices("B", models[mname])
        table5[mname] = {"M": cm.M, "C1": cm.C1, "K0": cm.K0, "K2": cm.K2, "H": H}
    cmw, Hw = _model_matrices("B", None)
    table5["Whipple (benchmark)"] = {"M": cmw.M, "C1": cmw.C1, "K0": cmw.K0, "K2": cmw.K2, "H": Hw}
    cma, Ha = _model_matrices("B", ARM)
    table5["Arm model (benchmark)"] = {"M": cma.M, "C1": cma.C1, "K0": cma.K0, "K2": cma.K2,
                                       "H": Ha}  # fmt: skip
    figs = _figures(out, {k: _model_matrices("B", models[k])[0] for k in ("B-N", "B-S")})
    return {
        "riders": RIDERS,
        "environments": ENVIRONMENTS,
        "speeds": list(speeds),
        "duration": duration,
        "n_runs": len(runs),
        "fell": fell,
        "models": models,
        "table2_roll_vaf": table2,
        "table3_steer_vaf": table3,
        "table4_simulation_vaf": table4,
        "table5": table5,
        "figures": figs,
        "sim_window": SIM_WINDOW,
        "arm_model": arm_model_summary(),
    }


def arm_model_summary(
    rider: str = "B", vmax: float = 10.0, arms: ArmParameters | None = None
) -> dict[str, Any]:
    """Stability of the rider's arm model and Whipple model from 0.01 to ``vmax`` m/s.

    Parameters
    ----------
    rider : str, optional
        A key of :data:`RIDERS`. Default the benchmark rider.
    vmax : float, optional
        Highest speed [m/s] (the paper's figures reach 10 m/s).
    arms : ArmParameters, optional
        The arms (posture, segment masses); default the nominal arms scaled like the rider
        (:data:`RIDER_SCALES`).  ``benchmarks/arm_model_map.py`` varies them to map where
        the finding holds.

    Returns
    -------
    dict
        ``stable_ranges`` and ``whipple_stable_ranges``: lists of [low, high] [m/s] where
        every eigenvalue has a negative real part; ``real_unstable_everywhere``,
        ``oscillatory_stable_everywhere`` (:func:`bikeid.sim.arm_model.stability_summary`);
        ``reproduces_dissertation``: True if the arm model has no stable speed range, a real
        mode unstable at every speed and a stable oscillatory mode (Moore's dissertation);
        ``arms_mass`` [kg]; ``vmax`` [m/s].
    """
    if arms is None:
        arms = ArmParameters().scaled(RIDER_SCALES[rider])
    arm = stability_summary(arm_model_matrices(rider_parameters(rider), arms), vmax=vmax)
    whipple = stability_summary(_model_matrices(rider, None)[0], vmax=vmax)
    return {
        "stable_ranges": arm["stable_ranges"],
        "real_unstable_everywhere": arm["real_unstable_everywhere"],
        "oscillatory_stable_everywhere": arm["oscillatory_stable_everywhere"],
        "whipple_stable_ranges": whipple["stable_ranges"],
        "reproduces_dissertation": bool(
            not arm["stable_ranges"]
            and arm["real_unstable_everywhere"]
            and arm["oscillatory_stable_everywhere"]
        ),
        "arms_mass": arms.mass,
        "vmax": vmax,
    }


def _truth_eigenvalues(env: str, speeds: np.ndarray) -> np.ndarray:
    """Eigenvalues [1/s] of the benchmark rider's true linear plant in environment ``env``
    at each speed, tracked continuously across speeds: the Whipple model for N; for S plus
    the steer damping (``ident.effects.experiment_model``; the Coulomb friction has no linear term).
    """

    fx = {} if env == "N" else {"steer_viscous_damping": 0.3}
    m = ExperimentModel(p=benchmark(), effects=fx)
    out = np.empty((len(speeds), 4), complex)
    for k, v in enumerate(speeds):
        ev = np.linalg.eigvals(m.continuous(float(v))[0])
        out[k] = ev if k == 0 else match_eigenvalues(ev, out[k - 1])
    return out


def _truth_tf(env: str, v: float):
    """python-control T_delta -> phi transfer function of the true plant in ``env``."""

    fx = {} if env == "N" else {"steer_viscous_damping": 0.3}
    A, B = ExperimentModel(p=benchmark(), effects=fx).continuous(v)
    C = np.zeros((1, A.shape[0]))
    C[0, 0] = 1.0
    return control.ss(A, B[:, 1:2], C, 0)  # input w: torque straight on the steer


def _figures(out: Path, models: dict[str, Any]) -> list[str]:
    speeds = np.linspace(0.5, 10.0, 200)
    styles = {"B-N": ("tab:blue", "--"), "B-S": ("tab:red", "--")}
    truth = {
        "truth N (Whipple, benchmark)": ("tab:blue", "-", _truth_eigenvalues("N", speeds)),
        "truth S (Whipple + steer damping)": ("tab:red", "-", _truth_eigenvalues("S", speeds)),
    }
    ident = {name: eigenvalues_vs_speed(cm, speeds).values for name, cm in models.items()}
    curves = {**{k: v for k, v in truth.items()}}
    for name, ev in ident.items():
        c, ls = styles[name]
        curves[f"identified {name}"] = (c, ls, ev)
    arm_ev = eigenvalues_vs_speed(_arm_matrices("B"), speeds).values
    curves["arm model (benchmark rider)"] = ("tab:green", "-.", arm_ev)
    # Fig. 2: root locus
    fig, ax = plt.subplots(figsize=(7.5, 6))
    for name, (c, ls, ev) in curves.items():
        lw = 1.6 if name.startswith("truth") else 1.0
        for j in range(4):
            ax.plot(ev[:, j].real, ev[:, j].imag, color=c, ls=ls, lw=lw,
                    alpha=0.45 if name.startswith("truth") else 1.0,
                    label=name if j == 0 else None)  # fmt: skip
        for v in (2.0, 4.0, 6.0, 9.0):
            e = ev[np.argmin(np.abs(speeds - v))]
            ax.plot(e.real, e.imag, "o", color=c, ms=3)
    ax.set_xlim(-20, 10)
    ax.axvline(0, color="0.5", lw=0.6)
    ax.set_xlabel("real part [1/s]")
    ax.set_ylabel("imaginary part [rad/s]")
    ax.set_title(
        "Moore & Hubbard Fig. 2 analogue: root locus 0.5-10 m/s, benchmark rider\n"
        "(solid: truth of each environment, dashed: identified, dash-dot: arm model; "
        "dots at 2, 4, 6, 9 m/s)",
        fontsize=9,
    )
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    save(fig, out / "mh_fig2_root_locus.png")
    # Fig. 3: real and imaginary parts vs speed
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(8, 6.5), sharex=True)
    for name, (c, ls, ev) in curves.items():
        lw = 1.6 if name.startswith("truth") else 1.0
        al = 0.45 if name.startswith("truth") else 1.0
        for j in range(4):
            a1.plot(speeds, ev[:, j].real, color=c, ls=ls, lw=lw, alpha=al,
                    label=name if j == 0 else None)  # fmt: skip
            a2.plot(speeds, np.abs(ev[:, j].imag), color=c, ls=ls, lw=lw, alpha=al)
    a1.set_ylim(-20, 10)
    a1.axhline(0, color="0.5", lw=0.6)
    a1.set_ylabel("real part [1/s]")
    a2.set_ylabel("|imag part| [rad/s]")
    a2.set_xlabel("speed v [m/s]")
    a1.legend(fontsize=7)
    a1.set_title(
        "Moore & Hubbard Fig. 3 analogue: eigenvalues vs speed, identified vs each "
        "environment's truth",
        fontsize=9,
    )
    for a in (a1, a2):
        a.grid(alpha=0.3)
    save(fig, out / "mh_fig3_eigenvalues.png")
    # Fig. 4: Bode of T_delta -> phi
    # phases unwrapped from 1e-5 rad/s, where every curve is at the phase of its static gain
    # (0 or -180 deg: phase_deg's branch), and drawn from 0.1 rad/s
    w = np.logspace(-5, 2, 700)
    shown = w >= 0.1
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(8, 7), sharex=True)
    colors = dict(zip(BODE_SPEEDS, ("tab:blue", "tab:orange", "tab:green", "tab:red"), strict=True))
    for name, ls in (("truth N", "-"), ("truth S", ":"), ("B-S", "--"), ("arm model", "-.")):
        for v in BODE_SPEEDS:
            if name == "B-S":
                sys = state_space(models["B-S"], v, inputs=("T_delta",))[0, 0]
            elif name == "arm model":
                sys = state_space(_arm_matrices("B"), v, inputs=("T_delta",))[0, 0]
            else:
                sys = _truth_tf(name[-1], v)
            resp = control.frequency_response(sys, w).complex.ravel()
            a1.semilogx(w[shown], 20 * np.log10(np.abs(resp[shown])), color=colors[v], ls=ls,
                        lw=1.0, label=f"{name}, {v:g} m/s")  # fmt: skip
            a2.semilogx(w[shown], phase_deg(resp)[shown], color=colors[v], ls=ls, lw=1.0)
    a1.set_ylabel("|phi / T_delta| [dB re 1 rad/(N m)]")
    a2.set_ylabel("phase [deg] (0 or -180 at w -> 0)")
    a2.set_xlabel("frequency [rad/s]")
    a1.legend(fontsize=6, ncol=3)
    a1.set_title(
        "Moore & Hubbard Fig. 4 analogue: steer torque to roll angle\n(solid: truth N = "
        "Whipple, dotted: truth S, dashed: identified B-S, dash-dot: arm model)",
        fontsize=9,
    )
    for a in (a1, a2):
        a.grid(alpha=0.3, which="both")
    save(fig, out / "mh_fig4_bode.png")
    return ["mh_fig2_root_locus.png", "mh_fig3_eigenvalues.png", "mh_fig4_bode.png"]
