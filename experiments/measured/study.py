"""Moore & Hubbard's study on the real steer-by-wire bicycle: five models, held-out tables.

What ``bikeid measured study`` computes on the TU Delft logs (``tudelft-sbw``, read by
:mod:`bikeid.dataset.sbw_logs`): Moore & Hubbard's model comparison (their Tables 2-5,
Figs. 2-4) with the models bikeid can build from these logs:

- ``direct``: the direct least-squares method (the method table's ``direct`` with
  :data:`DIRECT_SETTINGS`, :func:`bikeid.ident.direct.identify`, their
  free sets; the runs of the fit speeds stacked, which K0dd + K2dd need);
- ``pem``: the canonical PEM at one speed (:func:`bikeid.ident.pem.fit`), one per speed;
- ``greybox``: the grey-box PEM of the same entries over all fit speeds jointly
  (:func:`bikeid.ident.greybox.fit`, entries the data do not determine fixed, conditioning
  reported);
- ``whipple``: the linear Whipple model of the steer-by-wire bicycle;
- ``effects``: the Whipple model with the effects of the effect library (the effect set of
  ``bikeid measured fit`` on the same fit speeds; by default the set that command selects,
  as documented in docs/measured.md, or refitted with ``fit_effects=True``).

Hold-out (the split is stated in every report): speed models (direct, grey-box, Whipple,
effects) are fitted on two eigen speeds and evaluated on the other two (:data:`SPLITS`);
a per-speed PEM model is fitted on the first half of the settled stretch of its run and
evaluated on the second half, so every model of a split is evaluated on the same records:
the second halves of the held-out runs.  The Bode runs (4 m/s only) allow a within-speed
hold-out across runs (PEM fitted on the even-numbered runs, evaluated on the odd ones) and
a 4 m/s validation of the speed models fitted on the eigen runs (4 m/s is in no fit).

Quality measures, per model and held-out run:

- **equation VAF** (Moore & Hubbard eq. 6 on the regression rows, their Tables 2-3):
  1 - ||r|| / ||Y - mean(Y)|| with r = (M q'' + D q' + K q - T) of the row and Y = T minus
  the terms no model frees (roll row: Mpp phi'' + g K0pp phi of the Whipple model; steer
  row: none), q'' from Moore & Hubbard's preprocessing (:func:`bikeid.ident.signals.prepare`);
  D = v C1 and K = g K0 + v^2 K2, or the torque form of the effects model.  Not defined for
  the canonical PEM (its b1, b2 fix one column of M^-1 only, not M);
- **simulation VAF** (eq. 6 on simulated outputs, their Table 4): each model driven open
  loop by the logged total steer command in consecutive :data:`SIM_WINDOW` s windows from
  the measured state at each window start (the models are unstable), per output over the
  record; the table shows the mean over phi, delta, phidot, deltadot;
- **decay NRMSE** (``measured evaluate --drive logged``,
  :func:`bikeid.ident.effects.experiment_model.window_errors`): the free-decay windows of the
  held-out record replayed with the logged command from their measured start state.

The effect translation (:func:`effect_footprints`, :func:`translate_deviations`) reads
identified entries that leave the Whipple values physically: each library effect's change
of the torque-form matrices (finite differences of the experiment model) is projected on
the canonical entries over the fit speeds, and the deviations are fitted as a combination
of effects by generalized least squares with the estimate's covariance.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import control
import numpy as np

from bikeid.dataset.decays import load_decays
from bikeid.dataset.run import Run
from bikeid.dataset.sbw_logs import DT, data_dir, find_logs
from bikeid.ident import greybox
from bikeid.ident.direct import ALL_ENTRIES, parse_entry
from bikeid.ident.effects.before_after import before_after
from bikeid.ident.effects.experiment_model import ExperimentModel, window_errors
from bikeid.ident.effects.library import LIBRARY
from bikeid.ident.effects.pipeline import fit_model
from bikeid.ident.effects.weave import decay_eigenvalue, median_complex, weave_uncertainty
from bikeid.ident.methods import DIRECT_PRESETS, METHODS, Identified
from bikeid.ident.signals import prepare
from bikeid.ident.validate import windowed_simulation_vaf
from bikeid.ident.validation_report import frequency_response_estimate, model_frequency_response
from bikeid.sim.effect_registry import effect
from bikeid.sim.errors import InputError
from bikeid.sim.linear import CanonicalMatrices, canonical_matrices, state_space
from bikeid.sim.parameters import steer_by_wire
from bikeid.sim.sampling import zoh

__all__ = [
    "DOCUMENTED_EFFECTS",
    "SIM_WINDOW",
    "SPLITS",
    "StudyModel",
    "effect_footprints",
    "equation_vaf",
    "decay_errors",
    "decay_runs",
    "effects_before_after",
    "matrix_model",
    "run_study",
    "signal_consistency",
    "simulation_vaf",
    "translate_deviations",
]

#: Fit speeds [m/s] of the two eigen splits; each is evaluated on the other eigen speeds.
SPLITS = ((2.5, 4.5), (1.5, 3.5))
#: Effects ``bikeid measured fit --speeds 2.5,4.5`` / ``1.5,3.5`` select (docs/measured.md,
#: "Results on the real data"; registry units).
DOCUMENTED_EFFECTS = {
    (2.5, 4.5): {"steer_viscous_damping": 0.358, "steer_stiffness": 1.44,
                 "steer_angle_bias": 0.024},
    (1.5, 3.5): {"tire_scrub_torque": 0.619, "steer_stiffness": 1.58, "command_gain": 0.891},
}  # fmt: skip
#: Window of the simulation VAF [s] (Moore & Hubbard simulate over the run; the models here
#: are open-loop unstable, so each window restarts from the measured state).
SIM_WINDOW = 2.0
#: |z| above which an identified entry counts as away from its Whipple value.
Z_SIGNIFICANT = 3.0
OUTPUTS = ("phi", "delta", "phidot", "deltadot")
MODEL_ORDER = ("whipple", "effects", "direct", "greybox", "pem")
#: The direct model's settings (ident.methods): least squares on the logged signals as they
#: are, central differences of the unfiltered rates, means kept; not Moore & Hubbard's
#: published processing (15 Hz, means removed), which the equation VAF's rows use.
DIRECT_SETTINGS = DIRECT_PRESETS["unfiltered"]


@dataclass
class StudyModel:
    """One model of the study: its plant at any speed it is defined at, and its entries.

    Attributes
    ----------
    name : str
        ``"whipple"``, ``"effects"``, ``"direct"``, ``"greybox"`` or ``"pem"``.
    label : str
        Human-readable description (method, fit data).
    ab : callable
        ``ab(v) -> (A, b)``: continuous state matrix (4, 4) and steer-torque column (4,) at
        the treadmill speed v [m/s], states [phi, delta, phidot, deltadot] [rad, rad/s],
        input the logged total steer command [N m, positive to the right].
    torque_form : callable or None
        ``torque_form(v) -> (M, D, K)`` (2x2 each, [kg m^2], [N m s/rad], [N m/rad]) of
        M q'' + D q' + K q = [0, T]; None when the model has none (canonical PEM).
    speeds : tuple of float or None
        The only speeds [m/s] the model is defined at (per-speed PEM), None for any.
    free : dict of str to float
        Identified entries (names of :mod:`bikeid.ident.direct`), matrix units.
    stderr : dict of str to float
        Their standard errors.
    covariance : (P, P) ndarray or None
        Covariance of ``free`` in its order.
    info : dict
        Fit facts (condition numbers, dropped entries, notes).
    """

    name: str
    label: str
    ab: Callable[[float], tuple[np.ndarray, np.ndarray]]
    torque_form: Callable[[float], tuple[np.ndarray, np.ndarray, np.ndarray]] | None
    speeds: tuple[float, ...] | None = None
    free: dict[str, float] = field(default_factory=dict)
    stderr: dict[str, float] = field(default_factory=dict)
    covariance: np.ndarray | None = None
    info: dict = field(default_factory=dict)


def matrix_model(name: str, label: str, cm: CanonicalMatrices, **kw) -> StudyModel:
    """A :class:`StudyModel` from canonical matrices (M, C1, K0, K2), valid at any speed.

    Parameters
    ----------
    name, label : str
        As :class:`StudyModel`.
    cm : CanonicalMatrices
        M [kg m^2], C1 [kg m], K0 [kg m], K2 [kg], g [m/s^2].
    **kw
        Further :class:`StudyModel` fields (free, stderr, covariance, info).

    Returns
    -------
    StudyModel
        With D = v C1 and K = g K0 + v^2 K2.
    """

    def ab(v: float):
        ss = state_space(cm, v, inputs=("T_delta",))
        return np.asarray(ss.A, float), np.asarray(ss.B, float)[:, 0]

    def tf(v: float):
        return cm.M, v * cm.C1, cm.g * cm.K0 + v * v * cm.K2

    return StudyModel(name, label, ab, tf, **kw)


def _effects_model(effects: dict[str, float], label: str) -> StudyModel:
    """The experiment model with ``effects`` as a StudyModel (plant part; 4 states only)."""
    em = ExperimentModel(effects=dict(effects))

    def ab(v: float):
        return _effect_ab(em, v)

    def tf(v: float):
        return _torque_form(em, v)

    return StudyModel("effects", label, ab, tf, info={"effects": dict(effects)})


def _effect_ab(em: ExperimentModel, v: float) -> tuple[np.ndarray, np.ndarray]:
    """(A, b) of the experiment model's plant at treadmill speed v: true speed through
    speed_scale, command through command_gain; refuses effects that add states."""
    A, B = em.continuous(em.e("speed_scale") * v)
    if A.shape != (4, 4):
        raise InputError(
            f"effects {sorted(em.effects)} add plant states (actuator lag or tyre relaxation): "
            "the study's linear comparison needs the 4-state plant; leave those effects out"
        )
    return A, B[:, 0] * em.e("command_gain")


def _torque_form(em: ExperimentModel, v: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(M, D, K) with M q'' + D q' + K q = [0, T] equivalent to the plant's (A, b) at v."""
    A, b = _effect_ab(em, v)
    M = em.canonical().M
    Mb = M @ b[2:]
    # row operation P with P (M b) = [0, 1]: the steer command enters the steer row only
    P = np.array([[1.0, -Mb[0] / Mb[1]], [0.0, 1.0 / Mb[1]]])
    return P @ M, -P @ M @ A[2:, 2:], -P @ M @ A[2:, :2]


# --------------------------------------------------------------------------- measures


def equation_vaf(model: StudyModel, run: Run) -> dict[str, float]:
    """Moore & Hubbard's equation VAF (eq. 6) of the roll and steer rows on one run.

    Parameters
    ----------
    model : StudyModel
        With a torque form (else both rows are NaN).
    run : Run
        A measured run (phi, delta [rad], rates [rad/s], T_delta [N m], v [m/s]) at one
        treadmill speed ``run.speed``.

    Returns
    -------
    dict
        ``roll``, ``steer``: 1 - ||r|| / ||Y - mean(Y)|| (dimensionless), r the row's
        equation error M q'' + D q' + K q - T, Y = T minus the terms every model fixes
        (roll: the Whipple Mpp phi'' + g K0pp phi; steer: none).
    """

    if model.torque_form is None:
        return {"roll": math.nan, "steer": math.nan}
    r = prepare(run)  # 15 Hz low-pass, central differences, means removed (their section 5)
    q = np.vstack([r["phi"], r["delta"]])
    qd = np.vstack([r["phidot"], r["deltadot"]])
    qdd = np.vstack([r["phiddot"], r["deltaddot"]])
    T = np.vstack([np.zeros(r.n), r["T_delta"]])
    M, D, K = model.torque_form(run.speed)
    res = M @ qdd + D @ qd + K @ q - T
    w = canonical_matrices(steer_by_wire())
    fixed = np.vstack([w.M[0, 0] * qdd[0] + w.g * w.K0[0, 0] * q[0], np.zeros(r.n)])
    Y = T - fixed
    out = {}
    for i, row in enumerate(("roll", "steer")):
        den = np.linalg.norm(Y[i] - Y[i].mean())
        out[row] = float(1.0 - np.linalg.norm(res[i]) / den) if den > 0 else math.nan
    return out


def _replay(A: np.ndarray, b: np.ndarray, x0: np.ndarray, T: np.ndarray) -> np.ndarray:
    """States (n, 4) of the zero-order-hold model from x0 driven by T (n,)."""
    Ad, Bd = zoh(A, b[:, None], DT)
    x = np.asarray(x0, float).copy()
    Y = np.empty((T.size, 4))
    with np.errstate(over="ignore", invalid="ignore"):
        for k in range(T.size):
            Y[k] = x
            x = Ad @ x + Bd[:, 0] * T[k]
    return Y


def simulation_vaf(model: StudyModel, run: Run, window: float = SIM_WINDOW) -> dict[str, float]:
    """Moore & Hubbard's simulation VAF (eq. 6 on simulated outputs) of one run.

    Parameters
    ----------
    model : StudyModel
        The model (evaluated at ``run.speed``).
    run : Run
        A measured run; its logged ``T_delta`` [N m] drives the model.
    window : float, optional
        Window length [s]: each window starts from the measured state (the models are
        open-loop unstable).

    Returns
    -------
    dict
        Per output (phi, delta, phidot, deltadot): 1 - ||y_sim - y|| / ||y - mean(y)||
        over all windows of the run (:func:`bikeid.ident.validate.windowed_simulation_vaf`,
        -inf where the simulation overflowed); ``mean``: their mean.
    """
    A, b = model.ab(run.speed)
    Ad, Bd = zoh(A, b[:, None], DT)
    Y = np.vstack([run[o] for o in OUTPUTS]).T
    out = windowed_simulation_vaf(Ad, Bd, Y, run["T_delta"], int(round(window / DT)),
                                  initial="measured", names=OUTPUTS)  # fmt: skip
    out = {o: float(v) for o, v in out.items()}
    out["mean"] = float(np.mean([out[o] for o in OUTPUTS]))
    return out


def decay_errors(model: StudyModel, windows: list) -> np.ndarray:
    """Each window's decay error of ``measured evaluate --drive logged``.

    Parameters
    ----------
    model : StudyModel
        The model.
    windows : list of Window
        Free decays with their logged command (:func:`bikeid.dataset.decays.load_decays`).

    Returns
    -------
    ndarray
        Per window, the mean NRMSE of roll rate and steer angle
        (:func:`bikeid.ident.effects.experiment_model.window_errors`; dimensionless; inf or
        NaN where the replay diverged); empty without windows.
    """
    sims = []
    for w in windows:
        A, b = model.ab(w.speed)
        Y = _replay(A, b, w.state0(), w.T_logged)
        sims.append({o: Y[:, j] for j, o in enumerate(OUTPUTS)})
    if not sims:
        return np.zeros(0)
    with np.errstate(over="ignore", invalid="ignore"):
        return window_errors(windows, sims).mean(axis=1)


def decay_nrmse(model: StudyModel, windows: list) -> float:
    """Mean decay error of ``measured evaluate --drive logged`` over ``windows``.

    Parameters
    ----------
    model : StudyModel
        The model.
    windows : list of Window
        Free decays with their logged command (:func:`bikeid.dataset.decays.load_decays`).

    Returns
    -------
    float
        Mean over windows of :func:`decay_errors`; NaN without windows, inf when a replay
        diverged.
    """

    if not windows:
        return math.nan
    e = decay_errors(model, windows)
    return float(np.mean(e)) if np.all(np.isfinite(e)) else math.inf


def effects_before_after(whipple: StudyModel, effects: StudyModel, windows: list) -> dict:
    """The held-out decay error before (Whipple) and after (Whipple + effects), with interval.

    The same statistic, bootstrap and paired test as ``measured evaluate``'s summary
    (:func:`bikeid.ident.effects.before_after.before_after`: per-decay errors resampled
    within each log file, the models held fixed).

    Parameters
    ----------
    whipple, effects : StudyModel
        The models before and after.
    windows : list of Window
        The held-out decays (logged command replayed, :func:`decay_errors`).

    Returns
    -------
    dict
        :func:`bikeid.ident.effects.before_after.before_after`'s result, or
        ``{"undefined": reason}`` without decays or when a replay diverged.
    """
    if not windows:
        return {"undefined": "no held-out decays"}
    e0, e1 = decay_errors(whipple, windows), decay_errors(effects, windows)
    if not (np.all(np.isfinite(e0)) and np.all(np.isfinite(e1))):
        return {"undefined": "a replay diverged: no finite per-decay errors"}
    return before_after(e0, e1, [w.file for w in windows])


# --------------------------------------------------------------------------- models


def _halves(run: Run) -> tuple[Run, Run]:
    """First and second half of a run's time span."""
    mid = 0.5 * (run.t[0] + run.t[-1])
    return run.window(run.t[0], mid), run.window(mid, run.t[-1] + DT)


def _pem_model(runs: list[Run], label: str) -> StudyModel:
    """Canonical PEM at the runs' (single) speed as a StudyModel (the method table's pem)."""
    fitted = METHODS["pem"].fit(runs, informativity="report")
    (m,) = fitted.models

    def ab(v: float):
        ss = m.state_space()
        return np.asarray(ss.A, float), np.asarray(ss.B, float)[:, 0]

    eig = m.eigenvalues()
    return StudyModel("pem", label, ab, None, speeds=(float(m.speed),),
                      info={"speed": float(m.speed), "eigenvalues": [complex(x) for x in eig],
                            "notes": list(m.notes),
                            **_informativity(fitted)})  # fmt: skip


def _direct_model(runs: list[Run], label: str) -> StudyModel:
    """The method table's direct with the settings :data:`DIRECT_SETTINGS` names."""
    fitted = METHODS["direct"].fit(runs, DIRECT_SETTINGS, reference=steer_by_wire(),
                                   informativity="report")  # fmt: skip
    (d,) = fitted.models
    names = list(d.free)
    cov = np.zeros((len(names), len(names)))
    for nm, C in d.covariance.values():
        idx = [names.index(x) for x in nm]
        cov[np.ix_(idx, idx)] = C
    return matrix_model("direct", label, d.canonical(), free=dict(d.free), stderr=dict(d.stderr),
                        covariance=cov, info={"settings": DIRECT_SETTINGS.describe(),
                                              "condition": dict(d.condition),
                                              "vaf_in_sample": dict(d.vaf_moore),
                                              "notes": list(d.notes),
                                              **_informativity(fitted)})  # fmt: skip


def _informativity(fitted: Identified) -> dict:
    """Whether the logs can determine the fitted model, as the fit assessed it
    (``informativity="report"``, :func:`bikeid.ident.methods.check_informativity`):
    ``informativity`` always, ``undetermined`` (the cause) when they cannot, so the rows
    say so instead of reporting numbers."""
    record = fitted.informativity or {}
    per = record.get("per_speed") or record.get("per_run")
    infos = list(per.values()) if per else [record]
    out: dict = {"informativity": infos[0] if len(infos) == 1 else record}
    causes = [i["cause"] for i in infos if i.get("cause")]
    if causes:
        out["undetermined"] = f"the logs cannot determine this model: {causes[0]}"
    return out


def _greybox_model(runs: list[Run], label: str, max_nfev: int = 100) -> StudyModel:
    g = greybox.fit(runs, reference=steer_by_wire(), drop_unidentifiable=True, max_nfev=max_nfev,
                    informativity="report")  # what the logs cannot determine: in its notes
    info = {"condition": float(g.condition), "dropped": list(g.dropped),
            "inflation": dict(g.inflation), "notes": list(g.notes)}  # fmt: skip
    return matrix_model("greybox", label, g.canonical(), free=dict(g.free), stderr=dict(g.stderr),
                        covariance=np.asarray(g.covariance), info=info)  # fmt: skip


def _effects_for(split: tuple[float, ...], decays: list, fit_effects: bool) -> tuple[dict, str]:
    """The effect set of the split: refitted (``measured fit``) or the documented one."""
    if fit_effects:
        fit_ws = [w for w in decays if any(abs(w.speed - s) < 0.25 for s in split)]
        obj = fit_model(fit_ws)
        return dict(obj["effects"]), "bikeid measured fit (refitted here)"
    key = tuple(sorted(split))
    if key not in DOCUMENTED_EFFECTS:
        raise InputError(
            f"no documented effect set for fit speeds {list(key)}; pass fit_effects=True "
            "(bikeid measured study --fit-effects)"
        )
    return dict(DOCUMENTED_EFFECTS[key]), "documented in docs/measured.md (measured fit)"


# --------------------------------------------------------------------------- translation


def effect_footprints(
    speeds: Sequence[float], names: Sequence[str] | None = None
) -> tuple[dict[str, dict[str, float]], dict[str, str]]:
    """Each library effect's change of the canonical entries per unit of the effect.

    For effect e the torque form (M, D(v), K(v)) of ``ExperimentModel(effects={e: absent +
    scale})`` minus the nominal's, divided by the library scale (a finite difference), is
    projected on the canonical form over ``speeds``: dM directly, dC1 = sum v dD / sum v^2,
    and (dK0, dK2) the least-squares fit of dK(v) = g dK0 + v^2 dK2 (with one speed, all
    of dK is put in dK0).

    Parameters
    ----------
    speeds : sequence of float
        Treadmill speeds [m/s] the footprint is taken over (those of the fit).
    names : sequence of str, optional
        Effects (default: the whole library).

    Returns
    -------
    footprints : dict of str to dict of str to float
        Per effect: d entry / d effect for every entry of :data:`bikeid.ident.direct.ALL_ENTRIES`
        except H ([entry unit] per [effect unit]).
    skipped : dict of str to str
        Effects without a footprint and why (no change of the plant matrices: sensor,
        bias and input-path effects; or extra plant states).
    """

    names = list(LIBRARY) if names is None else list(names)
    speeds = np.asarray(sorted(set(float(s) for s in speeds)), float)
    base = ExperimentModel()
    g = base.canonical().g
    out, skipped = {}, {}
    for n in names:
        c = LIBRARY[n]
        em = ExperimentModel(effects={n: c.absent + c.scale})
        try:
            pairs = [(_torque_form(em, v), _torque_form(base, v)) for v in speeds]
        except InputError:
            skipped[n] = "adds a plant state (not a canonical-form change)"
            continue
        dM = (pairs[0][0][0] - pairs[0][1][0]) / c.scale
        dD = np.array([(a[1] - b[1]) / c.scale for a, b in pairs])
        dK = np.array([(a[2] - b[2]) / c.scale for a, b in pairs])
        dC1 = np.tensordot(speeds, dD, axes=1) / float(speeds @ speeds)
        if speeds.size >= 2:
            X = np.column_stack([np.full(speeds.size, g), speeds**2])
            coef = np.linalg.lstsq(X, dK.reshape(speeds.size, -1), rcond=None)[0]
            dK0, dK2 = coef[0].reshape(2, 2), coef[1].reshape(2, 2)
        else:
            dK0, dK2 = dK[0] / g, np.zeros((2, 2))
        mats = {"M": dM, "C1": dC1, "K0": dK0, "K2": dK2}
        fp = {}
        for e in ALL_ENTRIES:
            m, i, j = parse_entry(e)
            if j is not None:
                fp[e] = float(mats[m][i, j])
        if max(abs(x) for x in fp.values()) < 1e-12:
            skipped[n] = "does not change the plant matrices (sensor, bias or input path)"
            continue
        out[n] = fp
    return out, skipped


def translate_deviations(
    free: dict[str, float],
    covariance: np.ndarray,
    speeds: Sequence[float],
    reference: CanonicalMatrices | None = None,
    names: Sequence[str] | None = None,
    max_effects: int = 3,
) -> dict:
    """Explain identified entries' deviations from the Whipple values by library effects.

    Deviations d = free - Whipple; with the covariance S of ``free`` and the footprints J
    (:func:`effect_footprints`, over ``speeds``), effects are added greedily: each step adds
    the effect whose generalized-least-squares fit of d (weight S^-1) lowers the chi-square
    most, if that drop exceeds Z_SIGNIFICANT^2 (9: a 3-sigma effect) and the effect's own
    |value / stderr| exceeds Z_SIGNIFICANT; at most ``max_effects``.  When no entry has
    |z| > Z_SIGNIFICANT, no effect is fitted.

    Parameters
    ----------
    free : dict of str to float
        Identified entries (:mod:`bikeid.ident.direct` names), matrix units.
    covariance : (P, P) ndarray
        Their covariance, in the order of ``free``.
    speeds : sequence of float
        Fit speeds [m/s] of the estimate.
    reference : CanonicalMatrices, optional
        The Whipple values (default: the steer-by-wire bicycle's).
    names : sequence of str, optional
        Candidate effects (default: the library).
    max_effects : int, optional
        Largest number of effects combined.

    Returns
    -------
    dict
        ``deviations`` (entry -> value, whipple, deviation, stderr, z), ``significant``
        (entries with |z| > 3), ``effects`` (name -> value, stderr, in registry units; the
        registry's plausible range and whether the value lies in it),
        ``chi2_before``/``chi2_after``, ``unexplained`` (entries whose residual |z| > 3
        after the fit), ``single`` (each effect fitted alone: value, stderr, chi2) and
        ``skipped`` (effects without a footprint, with the reason).
    """
    ref = reference or canonical_matrices(steer_by_wire())
    keys = list(free)
    whip = np.array([_entry(ref, k) for k in keys])
    d = np.array([free[k] for k in keys]) - whip
    S = np.asarray(covariance, float)
    se = np.sqrt(np.diag(S))
    z = d / se
    W = np.linalg.pinv(S)
    fps, skipped = effect_footprints(speeds, names)
    J = {n: np.array([fp[k] for k in keys]) for n, fp in fps.items()}
    dev = {k: {"value": float(free[k]), "whipple": float(whip[i]), "deviation": float(d[i]),
               "stderr": float(se[i]), "z": float(z[i])} for i, k in enumerate(keys)}  # fmt: skip
    sig = [k for i, k in enumerate(keys) if abs(z[i]) > Z_SIGNIFICANT]
    chi0 = float(d @ W @ d)

    def gls(cols):
        X = np.column_stack([J[c] for c in cols])
        F = X.T @ W @ X
        if np.linalg.cond(F) > 1e12:
            return None
        Fi = np.linalg.inv(F)
        c = Fi @ X.T @ W @ d
        r = d - X @ c
        return c, np.sqrt(np.diag(Fi)), float(r @ W @ r), r

    single = {}
    for n in J:
        s = gls([n])
        if s is not None:
            single[n] = {"value": float(s[0][0]), "stderr": float(s[1][0]), "chi2": s[2]}
    chosen: list[str] = []
    best = (None, None, chi0, d)
    if sig:
        while len(chosen) < max_effects:
            trial = None
            for n in J:
                if n in chosen:
                    continue
                s = gls([*chosen, n])
                if s is None or abs(s[0][-1] / s[1][-1]) <= Z_SIGNIFICANT:
                    continue
                if trial is None or s[2] < trial[1][2]:
                    trial = (n, s)
            if trial is None or best[2] - trial[1][2] <= Z_SIGNIFICANT**2:
                break
            chosen.append(trial[0])
            best = trial[1]

    effects = {}
    for i, n in enumerate(chosen):
        lo, hi = effect(n).plausible
        val = float(best[0][i])
        effects[n] = {"value": val, "stderr": float(best[1][i]), "plausible": [lo, hi],
                      "in_range": bool(lo <= val <= hi)}  # fmt: skip
    aliases = {}
    for n in chosen:  # effects the matrices cannot tell from a chosen one (parallel footprints)
        u = J[n] / np.linalg.norm(J[n])
        aliases[n] = [m for m in J if m != n and abs(u @ J[m]) > 0.999 * np.linalg.norm(J[m])]
    resid = best[3]
    unexplained = [k for i, k in enumerate(keys) if abs(resid[i] / se[i]) > Z_SIGNIFICANT]
    return {
        "deviations": dev, "significant": sig, "effects": effects, "chi2_before": chi0,
        "chi2_after": float(best[2]), "unexplained": unexplained if sig else [],
        "single": single, "skipped": skipped, "aliases": aliases,
        "speeds": [float(s) for s in speeds],
    }  # fmt: skip


def _entry(cm: CanonicalMatrices, name: str) -> float:
    m, i, j = parse_entry(name)
    return float(getattr(cm, m)[i, j])


def decay_runs(windows: list) -> list[Run]:
    """The free-decay windows as runs (no push inside): signals, logged command, speed.

    Parameters
    ----------
    windows : list of Window
        Free decays with ``T_logged`` (:func:`bikeid.dataset.decays.load_decays`).

    Returns
    -------
    list of Run
        One run per window: phi, delta [rad], rates [rad/s], ``v`` the treadmill speed
        [m/s], ``T_delta`` the logged total steer command [N m]; ``meta['speed']`` rounded
        to 0.5 m/s like :func:`bikeid.dataset.sbw_logs.settled`.
    """
    out = []
    for w in windows:
        n = w.n
        sig = {"phi": w.phi, "delta": w.delta, "phidot": w.phidot, "deltadot": w.deltadot,
               "v": np.full(n, w.speed), "T_delta": w.T_logged}  # fmt: skip
        out.append(Run(t=np.arange(n) * DT, signals=sig,
                       meta={"speed": round(w.speed * 2) / 2, "file": w.file}))  # fmt: skip
    return out


def signal_consistency(run: Run, max_lag: int = 30) -> dict[str, dict[str, float]]:
    """Timing and scale of each measured angle against its measured rate.

    The central difference of the angle (phi: the IMU's Kalman estimate; delta: the encoder)
    is compared with the rate (gyro; fork rate): the shift [samples] that maximizes their
    cross-correlation (positive: the differentiated angle lags the rate) and the
    least-squares gain d(angle)/dt ~ gain x rate.  Consistent sensors give 0 and 1.

    Parameters
    ----------
    run : Run
        A measured run (0.01 s samples).
    max_lag : int, optional
        Largest shift tried [samples].

    Returns
    -------
    dict
        ``roll`` and ``steer``: ``lag`` [samples] and ``gain`` (dimensionless).
    """
    out = {}
    for row, (ang, rate) in (("roll", ("phi", "phidot")), ("steer", ("delta", "deltadot"))):
        a = np.gradient(run[ang], run.dt)
        b = run[rate]
        a, b = a - a.mean(), b - b.mean()
        m = max_lag
        n = a.size
        lag = max(range(-m, m + 1), key=lambda k: float(a[m + k : n - m + k] @ b[m : n - m]))
        out[row] = {"lag": int(lag), "gain": float(a @ b / (b @ b))}
    return out


# --------------------------------------------------------------------------- the study


def _load(root: Path, kind: str) -> list[Run]:
    """The settled part of each ``kind`` log, through the one loader (every check)."""
    from bikeid.dataset.logs import LogOptions, load_runs

    return load_runs(find_logs(root, kind), LogOptions(format="sbw", bicycle="steer-by-wire"))


def _near(v: float, speeds) -> bool:
    return any(abs(v - s) < 0.25 for s in speeds)


def _second_half_windows(decays: list, run: Run) -> list:
    """Decay windows of ``run``'s file starting in the second half of its settled stretch."""
    mid = 0.5 * (run.t[0] + run.t[-1])
    return [w for w in decays if w.file == run.meta["file"] and w.start * DT >= mid]


def _evaluate(models: dict[str, StudyModel], run: Run, windows: list) -> dict:
    out = {}
    for name, m in models.items():
        if m is None:
            continue
        if m.speeds is not None and not any(abs(run.speed - s) < 1e-6 for s in m.speeds):
            continue
        if m.info.get("undetermined"):  # no numbers for a model the logs cannot determine
            out[name] = {"undetermined": m.info["undetermined"]}
            continue
        out[name] = {
            "equation_vaf": equation_vaf(m, run),
            "simulation_vaf": simulation_vaf(m, run),
            "decay_nrmse": decay_nrmse(m, windows),
            "decay_windows": len(windows),
        }
    return out


def run_study(
    data: str | Path | None,
    *,
    splits: Sequence[tuple[float, ...]] = SPLITS,
    fit_effects: bool = False,
    bode: bool = True,
    quick: bool = False,
    progress: Callable[[str], None] | None = None,
) -> dict:
    """Moore & Hubbard's comparison on the steer-by-wire logs (module docstring).

    Parameters
    ----------
    data : str or Path or None
        Folder holding ``tudelft-sbw/`` (or the folder itself; None: ``$BIKEID_DATA``).
    splits : sequence of tuple of float, optional
        Fit speeds [m/s] of each split; the other eigen speeds are held out.
    fit_effects : bool, optional
        Refit the effect set with ``measured fit`` per split (about 25 s each) instead of
        the documented one.
    bode : bool, optional
        Also the Bode runs (4 m/s): within-speed PEM hold-out and the speed models'
        validation.
    quick : bool, optional
        Grey-box with fewer iterations (max_nfev 20) and no Bode part: a smoke run.
    progress : callable, optional
        ``progress(text)`` before each fit.

    Returns
    -------
    dict
        ``splits``: per split the fit speeds, held-out speeds, effect-set source, models
        (entries, stderr, conditioning) and ``runs`` (held-out run -> model -> measures);
        ``bode``: the 4 m/s table and FRF; ``translation`` per split and model;
        ``direct_decays`` per split (the direct method on the free-decay windows only, no
        push inside); ``before_after`` per split (the held-out decay error of the Whipple
        model and of Whipple + effects with its 95 % interval, :func:`effects_before_after`);
        ``weave``: the measured weave per speed; ``signal_consistency`` per
        eigen run (:func:`signal_consistency`); ``definitions``.

    Raises
    ------
    bikeid.sim.errors.InputError
        If the data has no eigen logs, or a split's speeds are not in the data.
    """

    say = progress or (lambda s: None)
    root = data_dir(data)
    eig = _load(root, "eigen")
    if not eig:
        raise InputError(f"{root}: no eigen*.log[.gz] logs; fetch them with bikeid data fetch")
    have = sorted({r.speed for r in eig})
    decays = load_decays(root)
    whipple = matrix_model("whipple", "linear Whipple model of the steer-by-wire bicycle",
                           canonical_matrices(steer_by_wire()))  # fmt: skip
    # per-speed PEM: first half of each settled run (shared by both splits)
    pem_models = {}
    for r in eig:
        say(f"pem {r.speed} m/s")
        first, _ = _halves(r)
        pem_models[r.speed] = _pem_model([first], f"canonical PEM at {r.speed} m/s, first half")
    out = {"data": str(root), "speeds": have, "splits": [], "definitions": DEFINITIONS}
    split_models = []
    for split in splits:
        fit_s = tuple(sorted(split))
        if not all(_near(s, have) for s in fit_s):
            raise InputError(f"split {list(fit_s)} m/s: the data has eigen runs at {have} m/s")
        held = [r for r in eig if not _near(r.speed, fit_s)]
        fit_runs = [r for r in eig if _near(r.speed, fit_s)]
        tag = "+".join(f"{s:g}" for s in fit_s)
        say(f"direct {tag}")
        direct = _direct_model(fit_runs, f"direct LS on {tag} m/s (stacked)")
        say(f"grey-box {tag}")
        grey = _greybox_model(fit_runs, f"grey-box PEM on {tag} m/s", 20 if quick else 100)
        say(f"effects {tag}")
        eff, source = _effects_for(fit_s, decays, fit_effects)
        effm = _effects_model(eff, f"Whipple + effects ({source})")
        models = {"whipple": whipple, "effects": effm, "direct": direct, "greybox": grey}
        rows = {}
        held_ws = []
        for r in held:
            _, second = _halves(r)
            ws = _second_half_windows(decays, r)
            held_ws += ws
            ms = {**models, "pem": pem_models[r.speed]}
            rows[r.meta["file"]] = {"speed": r.speed, **_evaluate(ms, second, ws)}
        say(f"direct on the decay windows {tag}")
        dd = _direct_model(decay_runs([w for w in decays if _near(w.speed, fit_s)]),
                           f"direct LS on the free decays of {tag} m/s")  # fmt: skip
        trans = {}
        for name in ("direct", "greybox"):
            m = models[name]
            trans[name] = translate_deviations(m.free, m.covariance, fit_s)
        out["splits"].append({
            "fit_speeds": list(fit_s), "held_out_speeds": sorted(r.speed for r in held),
            "effects_source": source,
            "models": {k: _model_json(m) for k, m in models.items()},
            "runs": rows, "translation": trans, "direct_decays": _model_json(dd),
            "before_after": effects_before_after(whipple, effm, held_ws),
        })  # fmt: skip
        split_models.append(models)
    out["pem"] = {f"{v:g}": _model_json(m) for v, m in pem_models.items()}
    out["weave"] = _measured_weave(decays)
    out["signal_consistency"] = {r.meta["file"]: signal_consistency(r) for r in eig}
    out["_models"] = {"splits": split_models, "pem": pem_models}
    if bode and not quick:
        out["bode"] = _bode_part(root, split_models, say)
    return out


def _model_json(m: StudyModel) -> dict:
    return {"label": m.label, "free": m.free, "stderr": m.stderr, "info": m.info}


def _measured_weave(decays: list) -> dict:
    """Per speed: median decay eigenvalue of the free decays and its bootstrap uncertainty."""

    by: dict[float, list[complex]] = {}
    for w in decays:
        try:
            by.setdefault(round(w.speed, 1), []).append(decay_eigenvalue(w))
        except (ValueError, RuntimeError):
            continue
    out = {}
    for v, lams in sorted(by.items()):
        med = median_complex(lams)
        out[f"{v:g}"] = {"speed": v, "eigenvalue": med, "n": len(lams),
                         "rel_uncertainty": weave_uncertainty(lams),
                         "all": lams}  # fmt: skip
    return out


def _bode_part(root: Path, split_models: list, say) -> dict:
    """The 4 m/s runs: PEM and grey-box (entries one speed cannot separate dropped) on the
    even runs, every model on the odd runs; measured FRF."""
    bode = _load(root, "bode")
    if not bode:
        return {"note": "no Bode logs in the data"}
    bode.sort(key=_bode_frequency)
    fit, held = bode[0::2], bode[1::2]
    say("pem 4 m/s (even Bode runs)")
    pem4 = _pem_model(fit, f"canonical PEM on {len(fit)} Bode runs (even) at 4 m/s")
    say("grey-box 4 m/s (even Bode runs)")
    grey4 = _greybox_model(fit, f"grey-box PEM on {len(fit)} Bode runs (even) at 4 m/s")
    grey4.speeds = (float(fit[0].speed),)
    models = {"whipple": split_models[0]["whipple"], "pem": pem4, "greybox[4]": grey4}
    for k, ms in enumerate(split_models):
        for n in ("effects", "direct", "greybox"):
            models[f"{n}[{k}]"] = ms[n]
    rows = {}
    for r in held:
        rows[r.meta["file"]] = {"speed": r.speed, **_evaluate(models, r, [])}
    return {"fit_files": [r.meta["file"] for r in fit], "runs": rows,
            "greybox_4mps": _model_json(grey4),
            "models": list(models), "frf": _frf(bode, models)}  # fmt: skip


def _bode_frequency(run: Run) -> float:
    """Excitation frequency [Hz] of a Bode log from its name (``..._<f>Hz.log[.gz]``)."""

    m = re.search(r"_([0-9.]+)Hz", run.meta["file"])
    return float(m.group(1)) if m else math.nan


def _frf(runs: list[Run], models: dict) -> dict:
    """Measured frequency response T_delta -> phi, delta at 4 m/s (T_ext as the reference
    signal of the joint input-output estimate, one point per run at its excitation
    frequency, kept where the coherence passes) beside each model's sampled response, with
    each model's median relative complex error |H_model - H| / |H| over those points."""

    ex = [Run(t=r.t, signals=r.signals, dither=r["T_ext"], meta=r.meta) for r in runs]
    v = float(np.median([r.speed for r in runs]))

    def ss(m):
        A, b = m.ab(v)
        C = np.eye(4)[:2]
        return control.ss(
            A, b[:, None], C, np.zeros((2, 1)), inputs=["T_delta"], outputs=["phi", "delta"]
        )

    # one estimate per run (each excites one frequency): the bin nearest its frequency
    out = {"speed": v, "outputs": {}}
    nom = ss(models["whipple"])
    for r in ex:
        f0 = _bode_frequency(r)
        nps = int(min(1024, 2 ** np.floor(np.log2(r.n / 4))))  # >= 4 segments, <= 0.1 Hz bins
        for e in frequency_response_estimate([r], nom, nperseg=nps, input="T_delta"):
            k = int(np.argmin(np.abs(e.f - f0)))
            d = out["outputs"].setdefault(e.output, {"f": [], "H": [], "coherence": [],
                                                     "rel_error": [], "file": []})  # fmt: skip
            if e.valid[k]:
                vals = (e.f[k], e.H[k], e.coherence[k], e.rel_error[k], r.meta["file"])
                for key, val in zip(
                    ("f", "H", "coherence", "rel_error", "file"), vals, strict=True
                ):
                    d[key].append(val)

    fgrid = np.geomspace(0.3, 10.0, 200)
    out["models"] = {}
    for n, m in models.items():
        resp = model_frequency_response(ss(m), fgrid, DT)
        out["models"][n] = {"f": fgrid, **{k: val for k, val in resp.items()}}
        err = {}
        for o, d in out["outputs"].items():
            if d["f"]:
                Hm = model_frequency_response(ss(m), np.asarray(d["f"]), DT)[o]
                H = np.asarray(d["H"])
                err[o] = float(np.median(np.abs(Hm - H) / np.abs(H)))
        out["models"][n]["median_rel_error"] = err
    return out


DEFINITIONS = {
    "equation_vaf": "Moore & Hubbard eq. 6 on a regression row: 1 - ||r|| / ||Y - mean(Y)||, "
    "r = M q'' + D q' + K q - T of the row, Y = T minus the terms every model fixes (roll row: "
    "Whipple Mpp phi'' + g K0pp phi; steer row: none); q'' from 15 Hz low-passed central "
    "differences (ident.signals.prepare). n/a for the canonical PEM (no torque form).",
    "simulation_vaf": "eq. 6 on simulated outputs: the model driven open loop by the logged "
    "total steer command in consecutive 2 s windows, each from the measured state; per output "
    "over the record; 'mean' = mean over phi, delta, phidot, deltadot.",
    "decay_nrmse": "measured evaluate --drive logged: free-decay windows replayed with the "
    "logged command from their measured start; mean over windows of the mean NRMSE of roll "
    "rate and steer angle (lower is better).",
    "hold_out": "speed models fitted on the split's fit speeds, evaluated on the second half "
    "of the held-out speeds' runs; the per-speed PEM fitted on the first half of the same run.",
}
