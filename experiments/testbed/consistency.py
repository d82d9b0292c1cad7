"""Is an estimator consistent in closed loop?  A study for anyone's estimator.

Front door: :class:`~bikeid.experiments.testbed.scenario.Scenario` (what is simulated),
:class:`~bikeid.experiments.testbed.estimator.Estimator` (a table method, a peer or any
callable) and :func:`run_consistency`; ``bikeid consistency`` on the command line.

For every estimator, record length N (``scenario.durations``) and seed, the scenario's runs
(one per speed) are simulated and the estimator fitted; per speed the weave's real and
imaginary parts and the capsize and caster eigenvalues (:data:`COMPONENTS`) are compared
with the truth (the exact linear model, or on the nonlinear plant its upright
linearization).  Per estimator, length and speed the study reports the bias, standard
deviation and root-mean-square error of each component over the seeds; where the estimator
gives standard errors, how often its intervals at ``level`` contain the truth and the mean
normalized estimation error squared (NEES, 4 per speed if the standard errors are right);
the efficiency, the Monte Carlo variance over the first-order variance of PEM started at
the truth on the first seed's runs (PEM's asymptotic covariance near the truth, about 1 for
an efficient estimator); and over lengths the slope of log RMSE (all components and speeds)
against log N with a 95 % seed-bootstrap interval.

The verdict, in this order:

1. ``refused``: the estimator raised on more than 10 % of (length, seed) fits;
2. ``inconclusive``: fewer than 8 seeds fitted at the largest N, or fewer than 3 lengths;
3. ``biased``: Hotelling's T^2 of the error vector at the largest N rejects a zero mean at
   0.01 (per speed, Bonferroni over the speeds: T^2 with 4 components needs only n > 4);
4. ``consistent with 1/sqrt(N)``: not biased, and the upper end of the slope's interval is
   below -0.25;
5. otherwise ``inconclusive``, with the number of seeds that would settle it (the slope's
   interval narrowing as 1/sqrt(seeds)).

Each verdict states the smallest bias the T^2 test could detect (its critical value in
the units of each component's standard deviation over the seeds).

**At scale.**  Every (estimator, length, seed) is one job of
:func:`bikeid.experiments.parallel.imap` (local processes or Dask); it carries its seed,
so the numbers do not depend on how it runs.  With ``out`` each finished job is written at
once as one JSON file (``out/jobs/<key>.json``, atomic); a rerun reads those and computes
only the rest.  The key hashes the scenario, estimator name, level, length and seed.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Callable, Sequence
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from bikeid.experiments.parallel import imap
from bikeid.experiments.testbed.estimator import COMPONENTS, Context, Estimator
from bikeid.experiments.testbed.scenario import Scenario, true_modes
from bikeid.sim.errors import InputError

__all__ = [
    "CONSISTENT",
    "COMPONENTS",
    "Estimator",
    "Scenario",
    "run_consistency",
    "summarize",
    "table_text",
    "verdict",
]

CONSISTENT = "consistent with 1/sqrt(N)"
#: Verdict thresholds: refused share, minimum seeds and lengths, test level, slope bound.
MAX_REFUSED, MIN_SEEDS, MIN_LENGTHS, ALPHA, SLOPE_BOUND = 0.10, 8, 3, 0.01, -0.25
#: Bootstrap resamples of the slope interval (seeded: the interval is reproducible).
BOOTSTRAP, BOOTSTRAP_SEED = 2000, 20260


def _context(scenario: Scenario, level: float) -> Context:
    from bikeid.controllers.registry import make
    from bikeid.sim.parameters import by_name

    p = by_name(scenario.bicycle)
    return Context(
        scenario, p, make(scenario.controller, p, sample_time=scenario.sample_time), level
    )


def _job(scenario: Scenario, level: float, job: tuple[Any, float, int]) -> dict[str, Any]:
    """One fit: ``job`` = (estimator or ``"reference"``, duration [s], seed); a record.

    ``"reference"``: PEM started at the truth on the seed's runs, its first-order standard
    errors (the efficiency's denominator)."""
    est, duration, seed = job
    truth = true_modes(scenario)
    rec: dict[str, Any] = {"duration": float(duration), "seed": int(seed)}
    try:
        runs = scenario.runs(duration, seed)
    except ValueError as exc:  # the loop fell: not the estimator's fault
        return {**rec, "error": f"simulation: {str(exc).splitlines()[0]}"}
    ctx = _context(scenario, level)
    try:
        if est == "reference":
            res = _reference(scenario, runs, ctx, truth)
        else:
            res = est.estimate(runs, ctx, truth)
    except Exception as exc:  # noqa: BLE001 - any failure of anyone's estimator is a refusal
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        return {**rec, "refused": f"{type(exc).__name__}: {msg}"}
    return {**rec, "speeds": {f"{v:g}": r for v, r in res.items()}}


def _reference(scenario: Scenario, runs, ctx: Context, truth) -> dict[float, dict[str, Any]]:
    from bikeid.ident import pem
    from bikeid.ident.canonical import theta_from_matrices
    from bikeid.sim.linear import canonical_matrices

    out = {}
    for r, v in zip(runs, scenario.speeds, strict=True):
        theta = theta_from_matrices(canonical_matrices(ctx.bicycle), v)
        m = pem.fit(r, theta0=theta, multistart=False)
        out[v] = Estimator(lambda runs, c, m=m: m).estimate([r], ctx, {v: truth[v]})[v]
    return out


def _key(scenario: Scenario, name: str, level: float, duration: float, seed: int) -> str:
    text = json.dumps([scenario.to_json(), name, level, duration, seed], sort_keys=True)
    return hashlib.sha1(text.encode()).hexdigest()[:20]


def run_consistency(
    estimators: Sequence[Estimator | str | Callable[..., Any]],
    scenario: Scenario | None = None,
    *,
    level: float = 0.95,
    out: str | Path | None = None,
    workers: int = 1,
    dask: str | None = None,
    progress: Callable[[int, int, str], None] | None = None,
    efficiency: bool = True,
) -> dict[str, Any]:
    """Run the consistency study of ``estimators`` on ``scenario``.

    Parameters
    ----------
    estimators : sequence of Estimator, str or callable
        The estimators (strings and callables are wrapped in :class:`Estimator`); their
        names must be distinct.
    scenario : Scenario, optional
        What is simulated (default ``Scenario()``: the coverage defaults at 5 m/s, lengths
        25, 100, 400 s, 12 seeds).
    level : float, optional
        Nominal level of the intervals whose coverage is counted (default 0.95).
    out : str or Path, optional
        Folder for the finished jobs (one JSON file each, written as each finishes); a rerun
        with the same folder computes only the missing ones.
    workers : int, optional
        Local worker processes (the numbers do not depend on it).
    dask : str, optional
        ``"local"`` or a Dask scheduler address.  A ``module:function`` estimator's module
        file is sent to the workers (``Client.upload_file``); a package is refused.
    progress : callable, optional
        ``progress(done, total, label)`` after each job (:mod:`bikeid.experiments.progress`).
    efficiency : bool, optional
        Also fit the PEM reference for the efficiency (one fit per length and speed).

    Returns
    -------
    dict
        ``scenario``, ``level``, ``against``, ``methods`` (per estimator name:
        :func:`summarize`'s figures and verdict) and ``jobs`` (computed, reused).

    Raises
    ------
    InputError
        On no estimator, repeated names, a bad level, or a speed without the three modes.
    """
    from bikeid.ident.uncertainty import z_value

    scenario = scenario or Scenario()
    z_value(level)
    ests = [e if isinstance(e, Estimator) else Estimator(e) for e in estimators]
    if not ests:
        raise InputError("give at least one estimator")
    names = [e.name for e in ests]
    if len(set(names)) != len(names):
        raise InputError(f"estimator names {names}: give each once (name= to tell them apart)")
    truth = true_modes(scenario)  # refuses a speed without the three modes, up front
    _context(scenario, level)  # and an unknown bicycle or controller
    uploads = _uploads(ests, dask)
    kinds: list[tuple[str, Any]] = [(e.name, e) for e in ests]
    if efficiency:
        kinds.append(("reference", "reference"))
    jobs, keys = [], []
    for name, e in kinds:
        for d in scenario.durations:
            for s in scenario.seed_list():
                jobs.append((name, (e, d, s)))
                keys.append(_key(scenario, name, level, d, s))
    folder = Path(out) / "jobs" if out is not None else None
    records: dict[int, dict[str, Any]] = {}
    if folder is not None:
        folder.mkdir(parents=True, exist_ok=True)
        for i, k in enumerate(keys):
            f = folder / f"{k}.json"
            if f.exists():
                try:
                    records[i] = json.loads(f.read_text())
                except ValueError:  # unreadable: computed again
                    pass
    todo = [i for i in range(len(jobs)) if i not in records]
    reused = len(records)
    fn = partial(_job, scenario, float(level))
    done = reused
    if progress:
        progress(done, len(jobs), f"{reused} jobs done before")
    for j, rec in imap(fn, [jobs[i][1] for i in todo], workers, dask, upload=uploads):
        i = todo[j]
        records[i] = rec
        if folder is not None:
            from bikeid.dataset.files import atomic_write_text

            atomic_write_text(folder / f"{keys[i]}.json", json.dumps(rec))
        done += 1
        if progress:
            progress(done, len(jobs), f"{jobs[i][0]} {rec['duration']:g} s seed {rec['seed']}")
    by_name: dict[str, list[dict[str, Any]]] = {n: [] for n, _ in kinds}
    for i, (name, _) in enumerate(jobs):
        by_name[name].append(records[i])
    ref = by_name.pop("reference", None)
    methods = {n: summarize(by_name[n], scenario, truth, ref) for n in names}
    return {
        "scenario": scenario.to_json(),
        "level": float(level),
        "against": scenario.against,
        "methods": methods,
        "jobs": {"computed": len(todo), "reused": reused},
    }


def _uploads(ests: Sequence[Estimator], dask: str | None) -> list[str]:
    if not dask:
        return []
    from bikeid.experiments.testbed.estimator import module_file_of

    files = []
    for e in ests:
        if e.kind != "module":
            continue
        f = module_file_of(str(e.spec))
        if f is None:
            raise InputError(
                f"estimator {e.spec!r}: only a single-file module can be sent to "
                "the Dask workers; install the package on every worker or put "
                "its folder on the workers' PYTHONPATH"
            )
        files.append(str(f))
    return files


def _truth_vec(truth: np.ndarray) -> np.ndarray:
    w = truth[0]
    return np.array([w.real, abs(w.imag), truth[2].real, truth[3].real])


def _slope(logn: np.ndarray, errs: list[np.ndarray]) -> tuple[float, list[float]]:
    """Least-squares slope of log RMSE on log N and its 95 % seed-bootstrap interval
    (seeds resampled with replacement within each length, :data:`BOOTSTRAP` times)."""
    x = logn - logn.mean()
    sq = [np.sum(e**2, axis=1) for e in errs]  # squared error norm per seed
    y = np.log([math.sqrt(np.mean(q)) for q in sq])
    slope = float(x @ (y - y.mean()) / (x @ x))
    rng = np.random.default_rng(BOOTSTRAP_SEED)
    yb = np.column_stack(
        [np.log(np.sqrt(q[rng.integers(0, len(q), (BOOTSTRAP, len(q)))].mean(axis=1))) for q in sq]
    )
    boots = (yb - yb.mean(axis=1, keepdims=True)) @ x / (x @ x)
    return slope, [float(np.quantile(boots, 0.025)), float(np.quantile(boots, 0.975))]


def hotelling(errors: np.ndarray) -> tuple[float, float, float]:
    """Hotelling's one-sample T^2 test of a zero mean.

    Parameters
    ----------
    errors : (n, p) ndarray
        One error vector per seed, n > p.

    Returns
    -------
    t2 : float
        n m' S^-1 m (m the mean, S the sample covariance).  A component that does not
        vary over the seeds (a fixed model) but has a non-zero mean gives infinity; one
        that does not vary and is zero is left out.
    p_value : float
        From (n - q) T^2 / (q (n - 1)) ~ F(q, n - q), q the components kept (the rank of
        the sample covariance: collinear errors are tested in its range; a mean error
        outside it, where the errors never vary, gives infinity).
    scale : float
        q (n - 1) / (n - q): T^2 = scale * F.
    """
    from scipy.stats import f as fdist

    n = errors.shape[0]
    m = errors.mean(axis=0)
    sd = errors.std(axis=0, ddof=1)
    flat = sd <= 1e-12 * np.maximum(np.abs(errors).max(axis=0), 1e-300)
    if np.any(flat & (np.abs(m) > 0)):
        return math.inf, 0.0, math.nan
    e, m = errors[:, ~flat], m[~flat]
    q = e.shape[1]
    if q == 0:
        return 0.0, 1.0, math.nan
    S = np.atleast_2d(np.cov(e, rowvar=False, ddof=1))
    w, V = np.linalg.eigh(S)  # a singular S (collinear errors): the test in its range
    keep = w > 1e-12 * w.max()
    proj = V.T @ m
    if np.any(np.abs(proj[~keep]) > 1e-9 * np.linalg.norm(m)):
        return math.inf, 0.0, math.nan  # a mean error where the errors never vary
    q = int(keep.sum())
    if q >= n:
        return math.nan, math.nan, math.nan  # too few seeds for this many components
    t2 = float(n * np.sum(proj[keep] ** 2 / w[keep]))
    scale = q * (n - 1) / (n - q)
    return t2, float(fdist.sf(t2 / scale, q, n - q)), scale


def summarize(
    records: list[dict[str, Any]],
    scenario: Scenario,
    truth: dict[float, np.ndarray],
    reference: list[dict[str, Any]] | None = None,
) -> dict[str, Any]:
    """Figures and verdict of one estimator from its job records.

    Parameters
    ----------
    records : list of dict
        One per (length, seed): ``speeds`` (per speed ``est`` and optional ``se``), or
        ``refused`` (message), or ``error`` (the simulation failed: not counted).
    scenario : Scenario
        The scenario.
    truth : dict of float to ndarray
        :func:`~bikeid.experiments.testbed.scenario.true_modes`.
    reference : list of dict, optional
        The PEM reference's records (efficiency).

    Returns
    -------
    dict
        ``durations`` [s]; ``n`` (fitted seeds per length); ``refused`` (count and first
        messages); ``bias``, ``std``, ``rmse_by``: per speed per component a list over
        lengths [1/s]; ``rmse``: over lengths, the RMS of the whole error vector [1/s];
        ``slope``, ``slope_ci``; ``coverage``: per length ``covered``, ``n``, ``fraction``,
        ``nees`` (mean over the seeds with finite ratios, ``nees_seeds`` of them; 4 per
        speed if the standard errors are right), or None;
        ``efficiency``: per speed per component, over lengths, or None; ``verdict`` and
        ``verdict_detail`` (reason, ``t2``, ``p_value``, ``smallest_detectable_bias`` per
        speed per component [1/s], ``seeds_needed``, ``against``).
    """
    from bikeid.ident.uncertainty import z_value

    durs = list(scenario.durations)
    speeds = list(scenario.speeds)
    tv = {v: _truth_vec(truth[v]) for v in speeds}
    z = z_value(0.95)
    refused = [r for r in records if "refused" in r]
    fitted = {d: [r for r in records if r["duration"] == d and "speeds" in r] for d in durs}
    tried = sum(1 for r in records if "error" not in r)
    errs: dict[float, np.ndarray] = {}
    out: dict[str, Any] = {
        "durations": durs,
        "n": [len(fitted[d]) for d in durs],
        "refused": {
            "count": len(refused),
            "of": tried,
            "messages": sorted({r["refused"] for r in refused})[:3],
        },
        "bias": {},
        "std": {},
        "rmse_by": {},
    }
    for d in durs:
        rows = fitted[d]
        errs[d] = np.array(
            [
                np.concatenate([np.asarray(r["speeds"][f"{v:g}"]["est"]) - tv[v] for v in speeds])
                for r in rows
            ]
        ).reshape(len(rows), 4 * len(speeds))
    for k, v in enumerate(speeds):
        key = f"{v:g}"
        for what, f in (
            ("bias", lambda e: e.mean(0)),
            ("std", lambda e: e.std(0, ddof=1) if len(e) > 1 else e * np.nan),
            ("rmse_by", lambda e: np.sqrt((e**2).mean(0))),
        ):
            out[what][key] = {
                c: [
                    float(f(errs[d][:, 4 * k : 4 * k + 4])[i]) if len(errs[d]) else None
                    for d in durs
                ]
                for i, c in enumerate(COMPONENTS)
            }
    out["rmse"] = [
        float(np.sqrt(np.mean(np.sum(errs[d] ** 2, axis=1)))) if len(errs[d]) else None
        for d in durs
    ]
    logn = np.log(np.array(durs) / scenario.sample_time)
    ok = [d for d in durs if len(errs[d]) >= 2 and np.any(errs[d])]
    if len(ok) >= 2:
        out["slope"], out["slope_ci"] = _slope(
            logn[[durs.index(d) for d in ok]], [errs[d] for d in ok]
        )
    else:
        out["slope"], out["slope_ci"] = None, None
    # coverage and NEES of the estimator's own intervals
    cov = []
    for d in durs:
        rows = [r for r in fitted[d] if all("se" in r["speeds"][f"{v:g}"] for v in speeds)]
        if not rows:
            cov.append(None)
            continue
        e = np.array(
            [
                np.concatenate([np.asarray(r["speeds"][f"{v:g}"]["est"]) - tv[v] for v in speeds])
                for r in rows
            ]
        )
        se = np.array([np.concatenate([r["speeds"][f"{v:g}"]["se"] for v in speeds]) for r in rows])
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.abs(e) / se
        covered = int(np.sum(ratio <= z))
        finite = np.all(np.isfinite(ratio), axis=1)  # a zero SE (a real weave pair): no NEES
        cov.append(
            {
                "covered": covered,
                "n": int(ratio.size),
                "fraction": covered / ratio.size,
                "nees": float(np.mean(np.sum(ratio[finite] ** 2, axis=1)))
                if finite.any()
                else None,
                "nees_seeds": int(finite.sum()),
            }
        )
    out["coverage"] = cov if any(c is not None for c in cov) else None
    out["efficiency"] = _efficiency(errs, reference, scenario, tv) if reference else None
    out["verdict"], out["verdict_detail"] = verdict(out, errs[durs[-1]], scenario)
    return out


def _efficiency(errs, reference, scenario: Scenario, tv) -> dict[str, Any] | None:
    out: dict[str, Any] = {}
    for k, v in enumerate(scenario.speeds):
        key = f"{v:g}"
        out[key] = {c: [] for c in COMPONENTS}
        for d in scenario.durations:
            ses = [
                np.asarray(r["speeds"][key]["se"])
                for r in reference
                if r["duration"] == d and "speeds" in r and "se" in r["speeds"][key]
            ]
            e = errs[d][:, 4 * k : 4 * k + 4]
            for i, c in enumerate(COMPONENTS):
                ok = bool(ses) and len(e) > 1
                val = (
                    float(np.var(e[:, i], ddof=1) / np.mean([s[i] for s in ses]) ** 2)
                    if ok
                    else None
                )
                out[key][c].append(val)
    return out


def verdict(fig: dict[str, Any], last: np.ndarray, scenario: Scenario) -> tuple[str, dict]:
    """The verdict of one estimator's figures (module docstring, in that order).

    Parameters
    ----------
    fig : dict
        :func:`summarize`'s figures (``refused``, ``slope``, ``slope_ci``).
    last : (n, 4 * speeds) ndarray
        Error vectors at the largest N, one row per fitted seed [1/s].
    scenario : Scenario
        The scenario (speeds, lengths, plant).

    Returns
    -------
    verdict : str
        ``refused``, ``inconclusive``, ``biased`` or :data:`CONSISTENT`.
    detail : dict
        ``reason`` (one line), ``against``, ``t2`` and ``p_value`` per speed (where tested),
        ``smallest_detectable_bias`` per speed per component [1/s], ``seeds_needed``.
    """
    from scipy.stats import f as fdist

    against = scenario.against
    det: dict[str, Any] = {"against": against, "seeds_needed": None}
    ref = fig["refused"]
    n, nspeeds = last.shape[0], len(scenario.speeds)
    alpha = ALPHA / nspeeds
    if n > 4:  # the T^2 test and its detectable bias
        det["t2"], det["p_value"], det["smallest_detectable_bias"] = {}, {}, {}
        for k, v in enumerate(scenario.speeds):
            e = last[:, 4 * k : 4 * k + 4]
            t2, pv, _ = hotelling(e)
            crit = 4 * (n - 1) / (n - 4) * float(fdist.isf(alpha, 4, n - 4))
            sd = e.std(0, ddof=1)
            det["t2"][f"{v:g}"], det["p_value"][f"{v:g}"] = t2, pv
            det["smallest_detectable_bias"][f"{v:g}"] = {
                c: float(sd[i] * math.sqrt(crit / n)) for i, c in enumerate(COMPONENTS)
            }
    sdb = det.get("smallest_detectable_bias")
    sdb_txt = (
        (
            "; smallest detectable bias at the largest N: "
            + ", ".join(f"{c} {max(b[c] for b in sdb.values()):.3g}" for c in COMPONENTS)
            + " 1/s"
        )
        if sdb
        else ""
    )
    tail = f" (against {against}){sdb_txt}"
    if ref["of"] and ref["count"] / ref["of"] > MAX_REFUSED:
        det["reason"] = (
            f"raised on {ref['count']} of {ref['of']} fits (> 10 %): "
            f"{ref['messages'][0] if ref['messages'] else ''}"
        )
        return "refused", det
    if n < MIN_SEEDS or len(scenario.durations) < MIN_LENGTHS:
        det["reason"] = (
            f"{n} seeds fitted at the largest N and {len(scenario.durations)} "
            f"lengths: need >= {MIN_SEEDS} and >= {MIN_LENGTHS}{tail}"
        )
        det["seeds_needed"] = MIN_SEEDS if n < MIN_SEEDS else None
        return "inconclusive", det
    worst = min(det["p_value"].values())
    if worst < alpha:
        v = min(det["p_value"], key=det["p_value"].get)
        det["reason"] = (
            f"Hotelling T^2 = {det['t2'][v]:.1f} at {v} m/s rejects a zero mean "
            f"error at the largest N (p = {worst:.2g} < {alpha:.2g}){tail}"
        )
        return "biased", det
    if fig["slope"] is None:
        det["reason"] = f"no slope: fewer than 2 lengths with non-zero errors{tail}"
        return "inconclusive", det
    slope, (lo, hi) = fig["slope"], fig["slope_ci"]
    if hi < SLOPE_BOUND:
        det["reason"] = (
            f"no bias detected (smallest p = {worst:.2g}) and log RMSE falls "
            f"with slope {slope:.2f} [{lo:.2f}, {hi:.2f}] in log N{tail}"
        )
        return CONSISTENT, det
    if slope < SLOPE_BOUND:
        det["seeds_needed"] = int(math.ceil(n * ((hi - slope) / (SLOPE_BOUND - slope)) ** 2))
        more = f"about {det['seeds_needed']} seeds would settle it"
    else:
        more = "no number of seeds settles it: the RMSE does not fall like 1/sqrt(N) here"
    det["reason"] = (
        f"no bias detected but the slope {slope:.2f} [{lo:.2f}, {hi:.2f}] does "
        f"not lie below {SLOPE_BOUND}; {more}{tail}"
    )
    return "inconclusive", det


def table_text(result: dict[str, Any]) -> str:
    """Plain-text report of :func:`run_consistency`: per estimator the RMSE per length, the
    slope, coverage and the verdict with its reason.

    Parameters
    ----------
    result : dict
        Its return value.

    Returns
    -------
    str
        The report (no trailing newline).
    """
    s = result["scenario"]
    lines = [
        f"consistency: {s['bicycle']}, {s['plant']} plant, {s['controller']}, speeds "
        f"{','.join(f'{v:g}' for v in s['speeds'])} m/s, dither {s['dither']:g} N m, "
        f"process noise {s['disturbance']:g} N m, sensors {s['angle_noise']:g} rad / "
        f"{s['rate_noise']:g} rad/s, {s['seeds']} seeds; truth: {result['against']}"
    ]
    for name, m in result["methods"].items():
        rm = ", ".join("-" if r is None else f"{r:.3g}" for r in m["rmse"])
        sl = (
            "-"
            if m["slope"] is None
            else (f"{m['slope']:.2f} [{m['slope_ci'][0]:.2f}, {m['slope_ci'][1]:.2f}]")
        )
        cov = ""
        if m["coverage"]:
            c = m["coverage"][-1]
            nees = "-" if not c or c["nees"] is None else f"{c['nees']:.1f}"
            cov = (
                f"; coverage at the largest N {c['covered']}/{c['n']}, NEES {nees} "
                f"({4 * len(s['speeds'])} if the SEs are right)"
                if c
                else ""
            )
        lines.append(
            f"{name}: RMSE [1/s] at {','.join(f'{d:g}' for d in m['durations'])} s: "
            f"{rm}; slope {sl}{cov}; refused {m['refused']['count']}/"
            f"{m['refused']['of']}"
        )
        lines.append(f"  verdict: {m['verdict']}: {m['verdict_detail']['reason']}")
    return "\n".join(lines)
