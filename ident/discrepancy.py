"""Residual -> named physical effect -> augmented model -> error before/after.

Workflow (identification.md section 5, approaches A/B/E):

1. **Residuals.**  Output residuals of the experiment model (:mod:`ident.experiment_model`)
   on free-decay windows (roll rate, steer angle), and equation-error residuals of the
   roll and steer rows in Moore & Hubbard's form ``M q'' + v C1 q' + (g K0 + v^2 K2) q
   = [0, T]`` (accelerations from zero-phase-filtered central differences).
   Diagnostics: whiteness (fraction of autocorrelations outside the 99 % band,
   lags 1..25), cross-correlation with the steer command, Welch spectra.
2. **Ranking.**  Additive candidates are ranked by the orthogonal error-reduction ratio
   (ERR, forward orthogonal least squares) on the steer- and roll-row equation errors.
   Every candidate (additive or structural: delay, lag, ...) is then fitted by
   output error on the decays; the structural ones by a scan of their parameter
   followed by a local refinement.  Candidates are ordered by the fraction of the
   output-error cost they remove.
3. **Acceptance.**  An effect is accepted only if |value - absent| / std > 3
   (standard errors clustered by window, :func:`_effect_std`) *and* it lowers the error
   on held-out windows (every other window is held out while selecting); among those,
   a round takes the smallest product of held-out cost ratio and held-out weave-error
   ratio.  Accepted effects are refitted jointly on all fit windows, and effects with
   t <= 3 there are pruned.
4. **"unexplained".**  The measurement-noise floor of each window is estimated from
   second differences (sigma^2 = mean((y[k+1] - 2 y[k] + y[k-1])^2) / 6).  If the
   accepted effects remove less than ``EXPLAINED_MIN`` = 90 % of the nominal cost
   above that floor, the verdict is ``unexplained`` (listed first), with the
   accepted effects reported as partial.

Effect names (stable snake_case keys) are those of ``LIBRARY``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
from scipy import signal
from scipy.optimize import least_squares

from bikeid.ident.experiment_model import (
    EFFECT_DEFAULTS,
    EFFECT_UNITS,
    ExperimentModel,
    Window,
    window_errors,
)

__all__ = [
    "EXPLAINED_MIN",
    "LIBRARY",
    "Candidate",
    "EffectEstimate",
    "Identification",
    "cross_correlation",
    "decay_eigenvalue",
    "equation_error",
    "err_ranking",
    "evaluate",
    "fit_effects",
    "identify",
    "joint_fit",
    "noise_floor",
    "weave_error",
    "weave_targets",
    "weave_uncertainty",
    "WeaveTerm",
    "output_residuals",
    "push_asymmetry",
    "selection_frequencies",
    "spectrum",
    "synthetic_windows",
    "whiteness",
]

EXPLAINED_MIN = 0.9
T_MIN = 3.0
WEAVE_EPS = 0.02  # floor of the weave error in the selection score (fit scatter, ~2 %)


@dataclass(frozen=True)
class Candidate:
    """A library effect: name, unit, additive or structural, scan grid, scale."""

    name: str
    kind: str  # "additive" or "structural"
    scale: float  # typical magnitude, for the optimizer and the scan
    lower: float = -np.inf
    upper: float = np.inf
    grid: tuple[float, ...] = ()
    doc: str = ""

    @property
    def unit(self) -> str:
        return EFFECT_UNITS[self.name]

    @property
    def absent(self) -> float:
        return EFFECT_DEFAULTS[self.name]


LIBRARY: dict[str, Candidate] = {
    c.name: c
    for c in (
        Candidate("steer_viscous_damping", "additive", 0.3, doc="bearing/motor viscous damping"),
        Candidate("steer_coulomb_friction", "additive", 0.1, 0.0, doc="tanh-smoothed friction"),
        Candidate(
            "steer_stiffness", "additive", 1.0, doc="centring spring: cables, belt, tyre twist"
        ),
        Candidate("tire_scrub_torque", "additive", 0.5, doc="tyre scrub damping ~ 1/v"),
        Candidate("command_gain", "additive", 0.2, 0.05, doc="motor torque constant error"),
        Candidate("steer_torque_bias", "additive", 0.05, doc="constant steer torque"),
        Candidate("steer_inertia", "additive", 0.02, doc="front-frame inertia about steer axis"),
        Candidate("trail_correction", "additive", 0.01, -0.07, 0.2, doc="trail error"),
        Candidate(
            "front_inertia_scale",
            "additive",
            0.5,
            0.2,
            20.0,
            doc="front-frame (fork + motor) inertia borrowed from a similar bicycle: x0.2-20",
        ),
        Candidate(
            "front_mass_shift",
            "additive",
            0.5,
            -0.5,
            5.0,
            doc="estimated rear/front mass split: -0.5..5 kg to the front frame",
        ),
        Candidate(
            "rear_inertia_scale",
            "additive",
            0.2,
            0.5,
            2.0,
            doc="rear-frame inertia borrowed from a similar bicycle: x0.5-2",
        ),
        Candidate("roll_angle_bias", "additive", 0.01, doc="IMU roll bias"),
        Candidate("steer_angle_bias", "additive", 0.01, doc="encoder zero offset"),
        Candidate("roll_rate_bias", "additive", 0.01, doc="gyro bias"),
        Candidate("roll_rate_scale", "additive", 0.05, 0.2, doc="gyro scale factor"),
        Candidate("speed_scale", "additive", 0.05, 0.3, doc="speed calibration error"),
        Candidate(
            "input_delay",
            "structural",
            0.02,
            0.0,
            0.1,
            grid=(0.005, 0.01, 0.02, 0.03, 0.045, 0.06),
            doc="command transport delay",
        ),
        Candidate(
            "actuator_lag",
            "structural",
            0.02,
            0.0,
            0.2,
            grid=(0.005, 0.01, 0.02, 0.035, 0.05, 0.08),
            doc="motor current/torque lag",
        ),
        Candidate(
            "tire_relaxation",
            "structural",
            0.1,
            0.0,
            0.6,
            grid=(0.02, 0.05, 0.1, 0.2, 0.35, 0.5),
            doc="front-tyre lateral relaxation length sigma (lag sigma / v of the path heading)",
        ),
    )  # fmt: skip
}


# -- output residuals ----------------------------------------------------------------------
def _norms(windows, channels=("phidot", "delta")):
    return [
        [max(np.linalg.norm(getattr(w, c) - getattr(w, c).mean()), 1e-12) for c in channels]
        for w in windows
    ]


def output_residuals(model: ExperimentModel, windows: list[Window], norms=None) -> np.ndarray:
    """Stacked residuals (sim - measured) of roll rate and steer angle, each window and
    channel divided by ||y - mean y|| so the sum of squares is a sum of NRMSE^2."""
    norms = norms or _norms(windows)
    sims = model.simulate(windows)
    parts = []
    for w, s, nr in zip(windows, sims, norms, strict=True):
        parts.append((s["phidot"] - w.phidot) / nr[0])
        parts.append((s["delta"] - w.delta) / nr[1])
    return np.concatenate(parts)


def noise_floor(windows: list[Window]) -> float:
    """Expected normalized cost of a perfect model: sum n sigma^2 / ||y - ybar||^2."""
    tot = 0.0
    for w, nr in zip(windows, _norms(windows), strict=True):
        for y, ni in ((w.phidot, nr[0]), (w.delta, nr[1])):
            s2 = np.mean(np.diff(y, 2) ** 2) / 6.0
            tot += y.size * s2 / ni**2
    return float(tot)


@dataclass
class EffectEstimate:
    name: str
    value: float
    std: float
    unit: str
    t: float
    explained: float = 0.0  # fraction of the nominal cost removed when added
    accepted: bool = False

    def as_dict(self) -> dict:
        return {
            "name": self.name, "value": self.value, "std": self.std, "unit": self.unit,
            "t": self.t, "explained": self.explained, "accepted": self.accepted,
        }  # fmt: skip


@dataclass
class FitResult:
    model: ExperimentModel
    values: dict[str, float]
    std: dict[str, float]
    cost: float


@dataclass(frozen=True)
class WeaveTerm:
    """The measured weave eigenvalues as extra data of an output-error fit.

    ``targets``: per speed (speed key, mean sensor speed [m/s], measured weave [1/s], its
    standard error [1/s]) from :func:`weave_targets`; ``weight``: the factor on the
    residuals (lambda_model + offset - lambda_data) / standard error (real and imaginary
    parts), lambda_model the loop root nearest to the data (:meth:`ExperimentModel.weave`).
    ``offsets`` (see :meth:`at`) carry the difference between the estimator used on the data
    (damped-oscillation fit of nonlinear decays) and the linear loop root.
    """

    weight: float
    targets: tuple[tuple[float, float, complex, float], ...]
    offsets: tuple[complex, ...] = ()

    def residuals(self, model: ExperimentModel) -> np.ndarray:
        off = self.offsets or (0j,) * len(self.targets)
        d = [(model.weave(vs, lam) + o - lam) / unc
             for (_k, vs, lam, unc), o in zip(self.targets, off, strict=True)]  # fmt: skip
        return self.weight * np.concatenate([np.real(d), np.imag(d)])

    def at(self, model: ExperimentModel, windows: list[Window]) -> WeaveTerm:
        """Offsets at ``model``: per speed, the median decay fit of the model's simulated
        decays (windows corrected at ``model`` when the plant is nonlinear) minus the loop
        root, so that the term compares like with like at ``model`` and to first order near
        it (the defect correction of the signals, applied to the eigenvalue estimator)."""
        sims = model.simulate(windows)
        off = []
        for key, vs, lam, _unc in self.targets:
            idx = [i for i, w in enumerate(windows) if w.kind == "decay" and _key(w) == key]
            fitted = _simulated_weave([windows[i] for i in idx], [sims[i] for i in idx])
            off.append(fitted - model.weave(vs, lam))
        return replace(self, offsets=tuple(off))


def _key(w: Window) -> float:
    return round(w.speed, 1)


def weave_targets(
    windows: list[Window], lams: list[complex] | None = None
) -> tuple[tuple[float, float, complex, float], ...]:
    """(speed key, mean sensor speed, measured weave, standard error) of each speed with
    >= 3 decays: the median of :func:`decay_eigenvalue` over the decays and
    :func:`weave_uncertainty`.  ``lams``: the windows' decay fits if already computed."""
    if lams is None:
        lams = [decay_eigenvalue(w) if w.kind == "decay" else 0j for w in windows]
    groups: dict[float, list[int]] = {}
    for i, w in enumerate(windows):
        if w.kind == "decay":
            groups.setdefault(_key(w), []).append(i)
    out = []
    for key, idx in groups.items():
        if len(idx) >= 3:
            g = [lams[i] for i in idx]
            lam = _median_complex(g)
            vs = float(np.mean([np.mean(windows[i].v_sensor) for i in idx]))
            out.append((key, vs, lam, weave_uncertainty(g) * abs(lam)))
    return tuple(out)


def fit_effects(
    model: ExperimentModel,
    windows: list[Window],
    names: list[str],
    start: dict | None = None,
    weave: WeaveTerm | None = None,
) -> FitResult:
    """Output-error least squares of the named effects (others kept as in ``model``);
    with ``weave``, the weave-eigenvalue residuals are appended (one more cluster for the
    standard errors) and ``cost`` includes them."""
    extra = weave is not None and weave.weight > 0 and bool(weave.targets)
    if not names:
        r = output_residuals(model, windows)
        if extra:
            r = np.concatenate([r, weave.residuals(model)])
        return FitResult(model, {}, {}, float(r @ r))
    norms = _norms(windows)
    cands = [LIBRARY[n] if n in LIBRARY else Candidate(n, "additive", 0.1) for n in names]
    start = start or {}
    x0 = np.array([(start.get(c.name, model.e(c.name)) - c.absent) / c.scale for c in cands])
    lo = np.array([(c.lower - c.absent) / c.scale if c.lower > -np.inf else -np.inf for c in cands])
    hi = np.array([(c.upper - c.absent) / c.scale if c.upper < np.inf else np.inf for c in cands])
    lo = np.where(np.isfinite(lo), lo, -np.inf)
    x0 = np.clip(x0, lo + 1e-9, hi - 1e-9)

    def mk(x):
        return model.with_effects(
            **{c.name: c.absent + c.scale * xi for c, xi in zip(cands, x, strict=True)}
        )

    def fun(x):
        m = mk(x)
        r = output_residuals(m, windows, norms)  # ~O(1) per sample (normalized)
        if extra:
            try:
                r = np.concatenate([r, weave.residuals(m)])
            except ValueError:  # a trial value the loop roots cannot take
                r = np.concatenate([r, np.full(2 * len(weave.targets), 1e3)])
        # a trial value that makes the loop diverge must not overflow the Jacobian
        return np.where(np.isfinite(r), np.clip(r, -1e3, 1e3), 1e3)

    sol = least_squares(fun, x0, bounds=(lo, hi), x_scale=1.0, diff_step=1e-3, max_nfev=60)
    r = sol.fun
    sizes = [2 * w.n for w in windows] + ([2 * len(weave.targets)] if extra else [])
    std = _effect_std(sol.jac, r, sizes)
    vals = {c.name: c.absent + c.scale * xi for c, xi in zip(cands, sol.x, strict=True)}
    stds = {c.name: c.scale * si for c, si in zip(cands, std, strict=True)}
    return FitResult(mk(sol.x), vals, stds, float(r @ r))


def joint_fit(
    model: ExperimentModel,
    windows: list[Window],
    names: list[str],
    start: dict | None = None,
    nonlinear: bool = False,
    weave: WeaveTerm | None = None,
) -> FitResult:
    """Fit the named effects jointly on all windows (and ``weave``, see
    :func:`fit_effects`); with ``nonlinear`` the defect
    correction is attached at the nominal first and re-attached at the fitted model twice
    (each re-attachment moves the linearization point of the correction to the fit).
    Leaves the windows corrected at the returned model."""
    if nonlinear and all(w.correction is None for w in windows):
        _attach(windows, model, True)
    res = fit_effects(model, windows, names, start, weave)
    for _ in range(2 if nonlinear and names else 0):
        _attach(windows, res.model, True)
        res = fit_effects(model, windows, names, res.values, weave)
    return res


def _effect_std(J: np.ndarray, r: np.ndarray, sizes: list[int]) -> np.ndarray:
    """Standard errors of output-error estimates, clustered by window.

    The residual of one decay is smooth and mostly model error, so its samples are far
    from independent, while separate pushes are: the covariance is the cluster-robust
    sandwich (J^T J)^-1 (sum_g J_g^T r_g r_g^T J_g) (J^T J)^-1 G / (G - 1) over the G
    windows (Liang & Zeger 1986).  With fewer than p + 2 windows it falls back to
    s^2 (J^T J)^-1 with the sample count reduced for the lag-1 autocorrelation r1,
    N_eff = N (1 - r1) / (1 + r1).
    """
    n, p = J.shape
    try:
        bread = np.linalg.pinv(J.T @ J)
    except np.linalg.LinAlgError:
        return np.full(p, np.inf)
    g = len(sizes)
    if g >= p + 2 and sum(sizes) == n:
        meat = np.zeros((p, p))
        i = 0
        for m in sizes:
            u = J[i : i + m].T @ r[i : i + m]
            meat += np.outer(u, u)
            i += m
        cov = bread @ meat @ bread * g / (g - 1)
    else:
        r1 = float(np.clip(np.corrcoef(r[:-1], r[1:])[0, 1], 0.0, 0.99)) if n > 3 else 0.0
        neff = max(n * (1 - r1) / (1 + r1), p + 1)
        cov = float(r @ r) / (neff - p) * bread
    return np.sqrt(np.maximum(np.diag(cov), 0.0))


def _scan_start(model, windows, cand: Candidate, base: list[str], start: dict) -> float:
    best, arg = np.inf, cand.grid[0]
    for g in cand.grid:
        m = model.with_effects(**start, **{cand.name: g})
        r = output_residuals(m, windows)
        if r @ r < best:
            best, arg = float(r @ r), g
    return arg


@dataclass
class Identification:
    """Outcome of :func:`identify`."""

    model: ExperimentModel
    effects: list[EffectEstimate]
    ranking: list[EffectEstimate]
    verdict: list[str]
    cost_nominal: float
    cost_final: float
    cost_floor: float
    explained: float
    eq_ranking: list[dict] = field(default_factory=list)
    rounds: list[dict] = field(default_factory=list)  # forward-selection log, per round
    weave_weight: float = 0.0  # weight of the weave-eigenvalue term in the fits

    def as_dict(self) -> dict:
        return {
            "selection_rounds": self.rounds,
            "verdict": self.verdict,
            "effects": [e.as_dict() for e in self.effects],
            "ranking": [e.as_dict() for e in self.ranking],
            "equation_error_ranking": self.eq_ranking,
            "cost_nominal": self.cost_nominal,
            "cost_final": self.cost_final,
            "cost_noise_floor": self.cost_floor,
            "explained_fraction": self.explained,
            "weave_weight": self.weave_weight,
        }


def _attach(windows, model, nonlinear: bool) -> None:
    if nonlinear:
        from bikeid.ident.experiment_model import attach_nonlinear_correction

        attach_nonlinear_correction(windows, model)


def identify(
    model: ExperimentModel,
    windows: list[Window],
    candidates: list[str] | None = None,
    max_effects: int = 3,
    min_gain: float = 0.02,
    nonlinear: bool = False,
    weave_weight: float | str = "auto",
) -> Identification:
    """Greedy forward selection of library effects by output error (module docstring).

    ``weave_weight``: every fit also matches the measured weave eigenvalue of each speed
    with >= 3 decays (:class:`WeaveTerm`, targets from the windows being fitted, offsets
    for the estimator bias re-taken at the current model with the defect correction).
    "auto" (default) weighs it so that, at the nominal model, it carries as much cost as
    the decay signals (w^2 chi2_weave = output-error cost); 0 fits the decay signals only.

    ``nonlinear``: the model is the nonlinear plant through the per-window defect
    correction (:func:`ident.experiment_model.attach_nonlinear_correction`), re-attached
    at the current model after each accepted effect, at each of the three leading
    candidates of a round before they are re-ranked (first-order corrections favoured a
    fractional input delay over a true actuator lag), and twice in the final joint fit; the
    windows are left corrected at the returned model.  After the joint fit, effects with
    t <= 3 are dropped (backward pruning) and the rest are listed by their contribution
    (increase of the cost when the effect alone is set back to absent).
    """
    names = list(candidates or LIBRARY)
    bad = [n for n in names if n not in LIBRARY]
    if bad:
        raise ValueError(f"unknown candidate effects {bad}; the library has {sorted(LIBRARY)}")
    if len(windows) < 2:
        raise ValueError("identification needs at least 2 windows (one is held out)")
    fit_w, val_w = windows[0::2], windows[1::2]
    _attach(windows, model, nonlinear)
    cost0 = fit_effects(model, windows, []).cost  # decay signals only (for "explained")
    floor = noise_floor(windows)
    lam_all = [decay_eigenvalue(w) for w in windows]  # measured weave of each decay
    lam_val = lam_all[1::2]
    unit = WeaveTerm(1.0, weave_targets(windows, lam_all))
    if weave_weight == "auto":
        unit = unit.at(model, windows) if unit.targets else unit
        chi0 = float(np.sum(unit.residuals(model) ** 2)) if unit.targets else 0.0
        weave_weight = math.sqrt(cost0 / chi0) if chi0 > 0 else 0.0  # no weave data: off
    weave_weight = float(weave_weight)
    if not (weave_weight >= 0 and math.isfinite(weave_weight)):
        raise ValueError(f"weave_weight must be 'auto' or a finite number >= 0, got {weave_weight}")
    wv_fit = wv_all = None
    if weave_weight > 0:
        wv_fit = WeaveTerm(weave_weight, weave_targets(fit_w, lam_all[0::2])).at(model, fit_w)
        wv_all = replace(unit, weight=weave_weight)  # offsets taken at the final model below
    accepted: list[str] = []
    cur = model
    cur_val = fit_effects(cur, val_w, []).cost
    cur_wv = weave_error(val_w, cur.simulate(val_w), lam_val)
    ranking: list[EffectEstimate] = []
    rounds: list[dict] = []
    for _round in range(max_effects):
        trials = []
        base_cost = fit_effects(cur, fit_w, [], weave=wv_fit).cost
        for n in names:
            if n in accepted:
                continue
            cand = LIBRARY[n]
            start = {}
            if cand.kind == "structural":
                start[n] = _scan_start(cur, fit_w, cand, accepted, {})
            res = fit_effects(cur, fit_w, accepted + [n], start, wv_fit)
            v, sd = res.values[n], res.std[n]
            t = abs(v - cand.absent) / sd if sd > 0 else np.inf
            gain = (base_cost - res.cost) / max(base_cost, 1e-300)
            trials.append((gain, n, res, EffectEstimate(n, v, sd, cand.unit, t, gain)))
        trials.sort(key=lambda z: -z[0])
        if nonlinear:  # re-rank the leaders with the correction re-attached at each of them
            top = []
            for _gain, n, res, _est in trials[:3]:
                _attach(windows, res.model, True)
                wv_n = wv_fit.at(res.model, fit_w) if wv_fit else None
                res = fit_effects(cur, fit_w, accepted + [n], res.values, wv_n)
                v, sd = res.values[n], res.std[n]
                t = abs(v - LIBRARY[n].absent) / sd if sd > 0 else np.inf
                gain = (base_cost - res.cost) / max(base_cost, 1e-300)
                top.append((gain, n, res, EffectEstimate(n, v, sd, LIBRARY[n].unit, t, gain)))
            trials = sorted(top, key=lambda z: -z[0]) + trials[3:]
        if _round == 0:
            ranking = [z[3] for z in trials]
        passing = []  # (score, name, result, validation cost, validation weave error)
        log = []
        for gain, n, res, est in trials:
            row = {"name": n, "value": est.value, "t": est.t, "fit_gain": gain}
            log.append(row)
            if est.t <= T_MIN or gain < min_gain:
                continue
            _attach(val_w, res.model, nonlinear)  # only the held-out half is simulated here
            sims = res.model.simulate(val_w)
            val = float(np.sum(window_errors(val_w, sims) ** 2))
            row["heldout_cost_ratio"] = val / cur_val
            if val >= cur_val * (1 - min_gain):
                continue
            wv = weave_error(val_w, sims, lam_val)
            score = val / cur_val * (wv + WEAVE_EPS) / (cur_wv + WEAVE_EPS)
            row.update(heldout_weave_error=wv, heldout_weave_before=cur_wv, score=score)
            passing.append((score, n, res, val, wv))
        if passing:
            _score, n, res, cur_val, cur_wv = min(passing, key=lambda z: z[0])
            accepted.append(n)
            cur = res.model
        rounds.append({"accepted": n if passing else None, "candidates": log})
        _attach(windows, cur, nonlinear)
        if not passing:
            break
        if wv_fit:  # the estimator offsets follow the current model, like the correction
            wv_fit = wv_fit.at(cur, fit_w)
    if wv_all:
        wv_all = wv_all.at(cur, windows)
    final = joint_fit(model, windows, accepted, {n: cur.e(n) for n in accepted}, nonlinear, wv_all)

    def tval(n):
        sd = final.std[n]
        return abs(final.values[n] - LIBRARY[n].absent) / sd if sd > 0 else np.inf

    while accepted and min(tval(n) for n in accepted) <= T_MIN:  # backward pruning
        accepted.remove(min(accepted, key=tval))
        final = fit_effects(model, windows, accepted, final.values, wv_all)
        _attach(windows, final.model, nonlinear and bool(accepted))
        if nonlinear and not accepted:
            _attach(windows, model, True)
    contrib = {}  # increase of the fitted cost (signals + weave term) without the effect
    for n in accepted:
        without = final.model.with_effects(**{n: LIBRARY[n].absent})
        contrib[n] = fit_effects(without, windows, [], weave=wv_all).cost - final.cost
    accepted.sort(key=lambda n: -contrib[n])
    r_sig = output_residuals(final.model, windows)
    cost_sig = float(r_sig @ r_sig)  # decay signals only, as cost0 and the floor
    effects = []
    for n in accepted:
        cand = LIBRARY[n]
        v, sd = final.values[n], final.std[n]
        effects.append(EffectEstimate(n, v, sd, cand.unit, tval(n), accepted=True))
    explained = (cost0 - cost_sig) / max(cost0 - floor, 1e-12 * cost0)
    verdict = [e.name for e in effects]
    if explained < EXPLAINED_MIN or not effects:
        verdict = ["unexplained"] + verdict
    for e in effects:
        e.explained = float(explained)
    return Identification(
        model=final.model, effects=effects, ranking=ranking, verdict=verdict,
        cost_nominal=cost0, cost_final=cost_sig, cost_floor=floor, explained=float(explained),
        eq_ranking=err_ranking(model, windows), rounds=rounds, weave_weight=weave_weight,
    )  # fmt: skip


def selection_frequencies(
    model: ExperimentModel,
    windows: list[Window],
    resamples: int = 20,
    fraction: float = 0.75,
    seed: int = 0,
    **identify_kw,
) -> dict[str, float]:
    """How stable is the verdict?  Fraction of subsamples in which each name is selected.

    Stability selection (Meinshausen & Buehlmann 2010) over decays: each of ``resamples``
    runs of :func:`identify` sees a random ``fraction`` of the windows of every file (drawn
    without replacement, at least 2 per file, so every speed stays in), and each name of its
    verdict (``"unexplained"`` included) is counted.  A name near 1 is what the data say
    whichever decays are used; names well below 1 depend on which pushes were logged.
    ``identify_kw`` go to :func:`identify` (e.g. ``nonlinear=True``, ``max_effects``).
    """
    if int(resamples) != resamples or resamples < 1:
        raise ValueError(f"resamples must be a positive integer, got {resamples!r}")
    if not 0.0 < fraction <= 1.0:
        raise ValueError(f"fraction must be in (0, 1], got {fraction!r}")
    rng = np.random.default_rng(seed)
    groups: dict[str, list[int]] = {}
    for i, w in enumerate(windows):
        groups.setdefault(w.file, []).append(i)
    counts: dict[str, int] = {}
    for _ in range(int(resamples)):
        pick = []
        for idx in groups.values():
            k = min(len(idx), max(2, round(fraction * len(idx))))
            pick.extend(sorted(rng.choice(idx, size=k, replace=False)))
        sub = [replace(windows[i], correction=None) for i in sorted(pick)]  # own copies
        for name in identify(model, sub, **identify_kw).verdict:
            counts[name] = counts.get(name, 0) + 1
    return dict(sorted(((k, v / resamples) for k, v in counts.items()), key=lambda z: -z[1]))


# -- equation error -------------------------------------------------------------------------
def _deriv(y: np.ndarray, dt: float = 0.01, fc: float = 15.0) -> np.ndarray:
    b, a = signal.butter(2, fc / (0.5 / dt))
    pad = min(3 * max(len(a), len(b)), y.size - 1)
    return np.gradient(signal.filtfilt(b, a, y, padlen=pad), dt)


def equation_error(model: ExperimentModel, windows: list[Window]) -> dict[str, np.ndarray]:
    """Roll- and steer-row equation errors and additive candidate regressors.

    r = [0, T] - (M q'' + v C1 q' + (g K0 + v^2 K2) q), with q'' from filtered central
    differences of the measured rates (2nd-order 15 Hz Butterworth, zero phase) and T the
    logged command.  Regressors (per unit of effect) for the steer row:
    steer_viscous_damping -deltadot, steer_coulomb_friction -tanh(deltadot/0.1),
    tire_scrub_torque -deltadot/v, command_gain T, steer_torque_bias 1,
    steer_inertia -deltaddot, steer_stiffness -delta; for the roll row: roll_viscous_damping -phidot
    (outside the library, used only to show the residual pattern).
    """
    cm = model.canonical()
    rows = {k: [] for k in ("roll", "steer", "T", "v")}
    reg = {k: [] for k in ("steer_viscous_damping", "steer_coulomb_friction",
                           "tire_scrub_torque", "command_gain", "steer_torque_bias",
                           "steer_inertia", "steer_stiffness",
                           "roll_viscous_damping")}  # fmt: skip
    sims = model.simulate(windows)
    for w, s in zip(windows, sims, strict=True):
        v = model.true_speed(float(np.mean(w.v_sensor)))
        q = np.vstack([w.phi, w.delta])
        qd = np.vstack([w.phidot, w.deltadot])
        qdd = np.vstack([_deriv(w.phidot), _deriv(w.deltadot)])
        T = s["T"]  # the applied command the model reconstructs (= logged law)
        lhs = cm.M @ qdd + v * cm.C1 @ qd + cm.stiffness(v) @ q
        rows["roll"].append(-lhs[0])
        rows["steer"].append(T - lhs[1])
        rows["T"].append(T)
        rows["v"].append(np.full(w.n, v))
        reg["steer_viscous_damping"].append(-w.deltadot)
        reg["steer_coulomb_friction"].append(-np.tanh(w.deltadot / 0.1))
        reg["tire_scrub_torque"].append(-w.deltadot / v)
        reg["command_gain"].append(T)
        reg["steer_torque_bias"].append(np.ones(w.n))
        reg["steer_inertia"].append(-qdd[1])
        reg["steer_stiffness"].append(-w.delta)
        reg["roll_viscous_damping"].append(-w.phidot)
    out = {k: np.concatenate(v) for k, v in rows.items()}
    out.update({f"reg:{k}": np.concatenate(v) for k, v in reg.items()})
    return out


def err_ranking(model: ExperimentModel, windows: list[Window], steps: int = 4) -> list[dict]:
    """Forward orthogonal least squares (FROLS) on the steer-row equation error.

    ERR_i = (w_i . r)^2 / ((w_i . w_i)(r . r)) with w_i the candidate orthogonalised
    against those already chosen.  Also reports, for comparison, the share of the
    roll-row residual a roll damping term would explain (an effect outside the library:
    a large value there points to "unexplained").
    """
    ee = equation_error(model, windows)
    r = ee["steer"]
    names = [k[4:] for k in ee if k.startswith("reg:") and k != "reg:roll_viscous_damping"]
    P = {n: ee[f"reg:{n}"].astype(float) for n in names}
    chosen, basis, out = [], [], []
    rr = float(r @ r)
    for _ in range(min(steps, len(names))):
        best = None
        for n in names:
            if n in chosen:
                continue
            wv = P[n].copy()
            for b in basis:
                wv -= (b @ wv) / (b @ b) * b
            den = float(wv @ wv)
            if den < 1e-12 * max(float(P[n] @ P[n]), 1e-300):
                continue
            err = float((wv @ r) ** 2 / (den * rr))
            if best is None or err > best[0]:
                best = (err, n, wv)
        if best is None:
            break
        chosen.append(best[1])
        basis.append(best[2])
        out.append({"name": best[1], "err": best[0], "row": "steer"})
    rl = ee["roll"]
    wv = ee["reg:roll_viscous_damping"]
    out.append(
        {"name": "roll_row:roll_damping_pattern", "row": "roll",
         "err": float((wv @ rl) ** 2 / ((wv @ wv) * (rl @ rl)))}
    )  # fmt: skip
    return out


# -- residual diagnostics ----------------------------------------------------------------
def whiteness(e: np.ndarray, maxlag: int = 25) -> dict:
    """Fraction of normalized autocorrelations r(1..maxlag) outside +-2.58/sqrt(N)."""
    e = np.asarray(e, float) - np.mean(e)
    n = e.size
    r0 = float(e @ e)
    r = np.array([float(e[:-k] @ e[k:]) / r0 for k in range(1, maxlag + 1)])
    band = 2.58 / math.sqrt(n)
    return {"acf": r, "band": band, "fraction_outside": float(np.mean(np.abs(r) > band))}


def cross_correlation(e: np.ndarray, u: np.ndarray, maxlag: int = 25) -> dict:
    """Normalized cross-correlation r_eu(tau), tau = -maxlag..maxlag, and the 99 % band."""
    e = np.asarray(e, float) - np.mean(e)
    u = np.asarray(u, float) - np.mean(u)
    n = e.size
    den = math.sqrt(float(e @ e) * float(u @ u))
    lags = np.arange(-maxlag, maxlag + 1)
    r = np.array(
        [float(e[k:] @ u[: n - k]) if k >= 0 else float(e[: n + k] @ u[-k:]) for k in lags]
    ) / max(den, 1e-300)
    band = 2.58 / math.sqrt(n)
    return {
        "lags": lags,
        "ccf": r,
        "band": band,
        "fraction_outside": float(np.mean(np.abs(r) > band)),
    }


def spectrum(e: np.ndarray, dt: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """Welch power spectral density (Hz, unit^2/Hz)."""
    return signal.welch(np.asarray(e, float), fs=1 / dt, nperseg=min(256, len(e)))


def push_asymmetry(windows: list[Window], errors) -> dict:
    """Does the error depend on the direction of the push?

    The Whipple model and the steer-into-lean loop are mirror-symmetric: a push to the left
    is the mirror image of one to the right.  A term that breaks the symmetry (a sensor
    zero offset, a constant torque, a lateral mass offset) makes the errors of the two
    directions differ, while symmetric errors (damping, stiffness, inertia, gains, delay)
    do not.  ``errors``: one number per window (e.g. the mean NRMSE of
    :func:`window_errors`).  Windows are split by the sign of the measured initial roll rate;
    returns the counts, the mean error of each side, their ratio (right / left) and the
    two-sided Mann-Whitney p-value of "same distribution" (nan with fewer than 2 per side).
    """
    from scipy.stats import mannwhitneyu

    e = np.asarray(errors, float)
    if e.shape != (len(windows),):
        raise ValueError(f"need one error per window ({len(windows)}), got shape {e.shape}")
    right = np.array([w.state0()[2] > 0 for w in windows])
    a, b = e[right], e[~right]
    p = float(mannwhitneyu(a, b).pvalue) if min(a.size, b.size) >= 2 else float("nan")
    ea = float(a.mean()) if a.size else float("nan")
    eb = float(b.mean()) if b.size else float("nan")
    return {"n_right": int(a.size), "n_left": int(b.size), "error_right": ea,
            "error_left": eb, "ratio": ea / eb if b.size and eb > 0 else float("nan"),
            "p_value": p}  # fmt: skip


# -- eigenvalues from decays ---------------------------------------------------------------
def decay_eigenvalue(w: Window) -> complex:
    """Weave eigenvalue sigma + i omega fitted to one free decay.

    Model (both channels share sigma, omega): y_c(t) = e^{sigma t}(a_c cos wt + b_c sin wt)
    + d_c e^{-p t} + o_c; sigma, omega, p by nonlinear LS, the rest linear (variable
    projection).  Start: omega from the steer-angle zero crossings.
    """
    t = np.arange(w.n) * 0.01
    ys = [w.delta / np.std(w.delta), w.phidot / np.std(w.phidot)]

    def resid(th):
        sg, om, pp = th
        basis = np.column_stack(
            [np.exp(sg * t) * np.cos(om * t), np.exp(sg * t) * np.sin(om * t),
             np.exp(-pp * t), np.ones_like(t)]
        )  # fmt: skip
        out = []
        for y in ys:
            c, *_ = np.linalg.lstsq(basis, y, rcond=None)
            out.append(basis @ c - y)
        return np.concatenate(out)

    best = None
    for om0 in (5.0, 7.5, 10.0, 12.5):
        sol = least_squares(resid, [-2.0, om0, 1.0], bounds=([-30, 1.0, 0.0], [10, 40, 60]))
        if best is None or sol.cost < best.cost:
            best = sol
    return complex(best.x[0], best.x[1])


# -- before/after ------------------------------------------------------------------------------
def evaluate(
    nominal: ExperimentModel,
    augmented: ExperimentModel,
    windows: list[Window],
    nonlinear: bool = False,
) -> dict:
    """Error before (nominal) and after (augmented), per file and overall.

    ``nonlinear``: both models simulate as the nonlinear plant (defect correction
    attached at each model in turn).

    Metric: mean over windows and the two channels (roll rate, steer angle) of the
    NRMSE ||y_sim - y|| / ||y - mean y|| of the free-decay simulation from the measured
    initial state.  Weave eigenvalue error |lambda_model - lambda_data| / |lambda_data|
    with lambda_data the median (real and imaginary parts) of the damped-oscillation fits
    to the measured decays (``decay_eigenvalue``) and lambda_model the median of the
    *same* fit applied to the model's simulated decays from the same initial states
    (``weave_error_*``: one estimator on both sides, so its bias on the large, nonlinear
    decays at low speed cancels).  ``weave_root_error_*``: lambda_model is instead the
    oscillatory root of the sampled *linear* loop nearest to lambda_data.
    """
    _attach(windows, nominal, nonlinear)
    s0 = nominal.simulate(windows)
    e0 = window_errors(windows, s0)
    _attach(windows, augmented, nonlinear)
    s1 = augmented.simulate(windows)
    e1 = window_errors(windows, s1)

    files = []
    for f in sorted({w.file for w in windows}):
        idx = [i for i, w in enumerate(windows) if w.file == f]
        ws = [windows[i] for i in idx]
        vs = float(np.mean([np.mean(w.v_sensor) for w in ws]))
        lams = [decay_eigenvalue(w) for w in ws]
        lam_data = _median_complex(lams)
        r0, r1 = nominal.weave(vs, lam_data), augmented.weave(vs, lam_data)
        f0, f1 = (
            _simulated_weave(ws, [s0[i] for i in idx]),
            _simulated_weave(ws, [s1[i] for i in idx]),
        )
        files.append(
            {
                "file": f,
                "speed": float(np.mean([w.speed for w in ws])),
                "windows": len(ws),
                "error_before": float(e0[idx].mean()),
                "error_after": float(e1[idx].mean()),
                "error_before_channels": {"phidot": float(e0[idx, 0].mean()),
                                          "delta": float(e0[idx, 1].mean())},
                "error_after_channels": {"phidot": float(e1[idx, 0].mean()),
                                         "delta": float(e1[idx, 1].mean())},
                "weave_data": lam_data,
                "weave_data_rel_std": weave_uncertainty(lams),
                "weave_before": f0,
                "weave_after": f1,
                "weave_error_before": abs(f0 - lam_data) / abs(lam_data),
                "weave_error_after": abs(f1 - lam_data) / abs(lam_data),
                "weave_root_before": r0,
                "weave_root_after": r1,
                "weave_root_error_before": abs(r0 - lam_data) / abs(lam_data),
                "weave_root_error_after": abs(r1 - lam_data) / abs(lam_data),
            }
        )  # fmt: skip
    keys = ("error_before", "error_after", "weave_error_before", "weave_error_after",
            "weave_root_error_before", "weave_root_error_after")  # fmt: skip
    summ = {k: float(np.mean([f[k] for f in files])) for k in keys}
    summ["ratio"] = summ["error_after"] / summ["error_before"]
    summ["weave_ratio"] = summ["weave_error_after"] / max(summ["weave_error_before"], 1e-12)
    unc = [f["weave_data_rel_std"] for f in files if np.isfinite(f["weave_data_rel_std"])]
    summ["weave_data_rel_std"] = float(np.mean(unc)) if unc else float("nan")  # files with >= 3
    summ["push_asymmetry_before"] = push_asymmetry(windows, e0.mean(axis=1))
    summ["push_asymmetry_after"] = push_asymmetry(windows, e1.mean(axis=1))
    return {"files": files, "summary": summ}


def weave_error(windows: list[Window], sims, lam_data) -> float:
    """Mean relative weave-eigenvalue error of simulated decays against measured ones.

    Windows are grouped by (file, speed to 0.1 m/s); per group the weave of the data is
    the median (real, imaginary parts) of ``lam_data`` (:func:`decay_eigenvalue` of each
    measured window) and that of the model the median of the same fit applied to the
    simulated decays ``sims`` from the same initial states.  Returns the mean over groups
    of |lambda_model - lambda_data| / |lambda_data| (the ``weave_error`` of
    :func:`evaluate`).
    """
    groups: dict[tuple, list[int]] = {}
    for i, w in enumerate(windows):
        groups.setdefault((w.file, round(w.speed, 1)), []).append(i)
    errs = []
    for idx in groups.values():
        lam_d = _median_complex([lam_data[i] for i in idx])
        lam_m = _simulated_weave([windows[i] for i in idx], [sims[i] for i in idx])
        errs.append(abs(lam_m - lam_d) / abs(lam_d))
    return float(np.mean(errs))


def _simulated_weave(windows: list[Window], sims) -> complex:
    """Median weave of the damped-oscillation fits to simulated decays (same estimator as
    for the measured ones)."""
    return _median_complex(
        [decay_eigenvalue(replace(w, phidot=s["phidot"], delta=s["delta"]))
         for w, s in zip(windows, sims, strict=True)]
    )  # fmt: skip


def weave_uncertainty(lams, resamples: int = 2000, seed: int = 0) -> float:
    """Relative standard error of the measured weave (the median of the per-decay fits
    ``lams``): rms of |median(resample) - median| / |median| over bootstrap resamples of
    the decays (fixed seed).  A model equal to the truth would still show a weave error
    of about this size; nan with fewer than 3 decays."""
    lams = np.asarray(lams, complex)
    if lams.size < 3:
        return float("nan")
    med = _median_complex(lams)
    idx = np.random.default_rng(seed).integers(0, lams.size, (resamples, lams.size))
    res = lams[idx]
    bs = np.median(res.real, axis=1) + 1j * np.median(res.imag, axis=1)
    return float(np.sqrt(np.mean(np.abs(bs - med) ** 2)) / abs(med))


def _median_complex(lams) -> complex:
    return complex(np.median(np.real(lams)), np.median(np.imag(lams)))


# -- injected-effect trials ------------------------------------------------------------------
def synthetic_windows(
    truth: ExperimentModel, speeds, per_speed: int = 6, noise: float = 0.01, seed: int = 0
) -> list[Window]:
    """Free decays simulated by ``truth`` (linear experiment model, 10 substeps per loop)
    from random initial states like the measured pushes (|phidot0| ~ 0.3-0.6 rad/s),
    1 s long; white noise (``noise`` rad/s on roll rate, noise/5 rad on angles) and the
    steer encoder's 0.000767 rad quantization added to what the "sensors" report."""
    from bikeid.dataset.measured import SPEED_CALIBRATION

    rng = np.random.default_rng(seed)
    a, b = SPEED_CALIBRATION
    clean = []
    for v in speeds:
        vs = a * v + b
        for _ in range(per_speed):
            sgn = rng.choice([-1.0, 1.0])
            x0 = np.array([rng.normal(0, 0.01), sgn * rng.uniform(0.0, 0.08),
                           sgn * rng.uniform(0.3, 0.6), sgn * rng.uniform(0.5, 1.5)])  # fmt: skip
            z = np.zeros(100)
            w = Window("synthetic", float(v), 0, z + x0[0], z + x0[1], z + x0[2], z + x0[3],
                       z + vs, z.copy(), np.zeros(20))  # fmt: skip
            w.phi, w.delta, w.phidot, w.deltadot = (np.full(100, x) for x in x0)
            clean.append(w)
    sims = truth.simulate(clean, nsub=10)
    out = []
    q = 0.000767
    for w, s in zip(clean, sims, strict=True):
        w.phi = s["phi"] + rng.normal(0, noise / 5, w.n)
        w.delta = np.round((s["delta"] + rng.normal(0, noise / 5, w.n)) / q) * q
        w.phidot = s["phidot"] + rng.normal(0, noise, w.n)
        w.deltadot = s["deltadot"] + rng.normal(0, noise * 3, w.n)
        w.file = f"synthetic_{w.speed:g}mps"
        out.append(w)
    return out
