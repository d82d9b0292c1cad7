"""Coverage of PEM's confidence intervals where the truth is exact (``bikeid coverage``).

Over seeds 0..N-1: a closed-loop run of the *linear* benchmark bicycle
(:func:`bikeid.dataset.linear_loop.simulate`: exact zero-order hold, default roll PID,
uniform steer-torque dither, unlogged steer-torque disturbance, white sensor noise that the
controller sees), identified by canonical PEM (:func:`bikeid.ident.pem.fit`, all four
measured states, free noise model).  The truth is the linear model itself
(:func:`bikeid.ident.canonical.theta_from_matrices`, eigenvalues of ``sim.linear``), so
for each quantity q with printed standard error s the harness records z = (q_hat - q) / s:

- the 10 canonical parameters a1..a8, b1, b2 (``model.stderr``);
- the real parts of the weave, capsize and caster eigenvalues and the weave frequency
  (first-order intervals, ``eigenvalue_intervals(..., method="delta")``; the
  identified eigenvalues are paired with the true modes by minimum total distance);
- the same four eigenvalue parts by the profile intervals of
  :func:`~bikeid.ident.uncertainty.eigenvalue_intervals` (the default method: the ends over
  the parameters' confidence ellipsoid), counted as contained or not (rows ``... profile``);
- jointly, the 10 parameters: the Mahalanobis distance d2 = r' P^-1 r of r = theta_hat -
  theta (chi-square with 10 degrees of freedom, mean 10, if P is right), counted inside the
  joint region d2 <= chi2_10^-1(level).

Per quantity it reports the mean and standard deviation of z (about 0 and 1 for an
unbiased estimator with correct standard errors) and how many of the N intervals at
``level`` contain the truth, with the Clopper-Pearson interval of that fraction
(:func:`bikeid.ident.validate.binomial_interval`).  The verdict is computed
from that interval: ``consistent`` if it contains the nominal level, ``too narrow`` if it
lies below, ``too wide`` if above.  ``covariance_scale`` multiplies every covariance before
the intervals are formed, to check that the verdict can fail (0.1 must give ``too narrow``).

This calibrates the intervals on the linear plant only; docs/uncertainty.md says what is
measured on the nonlinear plant (a bias that grows with the excitation amplitude).

:func:`run_default_path_coverage` (``bikeid coverage --plant nonlinear``) counts the same on
the README's default path instead (``dataset.closed_loop.simulate_run`` of the nonlinear or
linear plant under the roll PID with a 1 N m dither, ``pem.fit``, ``eigenvalue_intervals``),
separately for the fits that end on their one-step predictor's stability boundary, which
``ident.uncertainty.check_predictor_interior`` refuses.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial
from typing import Any

import numpy as np

from bikeid.experiments.parallel import imap
from bikeid.sim.errors import InputError
from bikeid.sim.parameters import benchmark

__all__ = [
    "CRITICAL_SPEEDS",
    "DEFAULTS",
    "DEFAULT_PATH",
    "DEFAULT_PATH_PARTS",
    "PROFILED",
    "QUANTITIES",
    "CoverageResult",
    "binomial_verdict",
    "default_path_summary",
    "default_path_table",
    "run_coverage",
    "run_default_path_coverage",
    "run_critical_coverage",
    "table_text",
]

#: Quantities whose intervals are counted (canonical parameters, then modes).
QUANTITIES = (
    "a1", "a2", "a3", "a4", "a5", "a6", "a7", "a8", "b1", "b2",
    "weave_re", "weave_im", "capsize_re", "caster_re",
)  # fmt: skip

#: Eigenvalue parts whose profile intervals are counted too.
PROFILED = ("weave_re", "weave_im", "capsize_re", "caster_re")

#: Default experiment: 50 s at 100 Hz, roll PID (-200, -500, -80), dither 3 N m held 50 ms,
#: unlogged disturbance 0.5 N m, sensor noise 1e-3 rad and 1e-2 rad/s.  The dither is 3x
#: that of ``benchmarks/bench_ident.py``, so that the weave pair stays complex in every fit;
#: docs/uncertainty.md shows what happens at 1 N m.
DEFAULTS: dict[str, float] = {
    "speed": 5.0,
    "duration": 50.0,
    "dither": 3.0,
    "dither_hold": 5,
    "disturbance": 0.5,
    "angle_noise": 1e-3,
    "rate_noise": 1e-2,
}


def binomial_verdict(
    count: int, n: int, level: float = 0.95, confidence: float = 0.95
) -> tuple[float, float, str]:
    """Clopper-Pearson interval of a coverage fraction and the verdict it supports.

    Parameters
    ----------
    count : int
        Intervals that contained the truth.
    n : int
        Intervals formed (> 0).
    level : float, optional
        Nominal coverage of each interval (e.g. 0.95).
    confidence : float, optional
        Confidence of the Clopper-Pearson interval.

    Returns
    -------
    low, high : float
        Exact binomial interval of the coverage fraction.
    verdict : str
        ``"consistent"`` (the interval contains ``level``), ``"too narrow"`` (it lies below:
        the intervals miss the truth too often) or ``"too wide"`` (above).

    Raises
    ------
    ValueError
        If ``n`` < 1 or ``count`` is outside 0..n.
    """
    # lazy: `bikeid --help` reads DEFAULTS from this module; scipy.stats stays out of start-up
    from bikeid.ident.validate import binomial_interval

    if n < 1 or not 0 <= count <= n:
        raise ValueError(f"coverage count {count} of {n}: need 0 <= count <= n, n >= 1")
    low, high = binomial_interval(count, n, confidence)
    if high < level:
        verdict = "too narrow"
    elif low > level:
        verdict = "too wide"
    else:
        verdict = "consistent"
    return low, high, verdict


@dataclass
class CoverageResult:
    """z-scores and interval coverage of each quantity over the seeds.

    Attributes
    ----------
    settings : dict
        The experiment (speed [m/s], duration [s], dither [N m], dither_hold [samples],
        disturbance [N m], angle_noise [rad], rate_noise [rad/s], controller, level,
        covariance_scale, seeds).
    z : dict of str to (N,) ndarray
        z = (estimate - truth) / standard error per quantity (:data:`QUANTITIES`), one per
        successful seed.
    failed : list of (int, str)
        Seeds whose fit raised, with the message (excluded from the counts).
    mahalanobis : (N,) ndarray
        d2 = r' P^-1 r of the 10 canonical parameters per successful seed (dimensionless).
    stderr : dict of str to (N,) ndarray
        The printed standard error of each quantity per successful seed (units of theta;
        1/s for the eigenvalue parts).
    profile_inside : dict of str to (N,) bool ndarray
        Whether the profile interval of each eigenvalue part (:data:`PROFILED`) contained
        the truth, per successful seed.
    """

    settings: dict[str, Any]
    z: dict[str, np.ndarray]
    failed: list[tuple[int, str]] = field(default_factory=list)
    mahalanobis: np.ndarray = field(default_factory=lambda: np.zeros(0))
    stderr: dict[str, np.ndarray] = field(default_factory=dict)
    profile_inside: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def n(self) -> int:
        """int: number of successful seeds."""
        return int(next(iter(self.z.values())).size) if self.z else 0

    def covered(self, name: str) -> int:
        """How many intervals of one quantity contained the truth.

        Parameters
        ----------
        name : str
            A quantity of :data:`QUANTITIES`.

        Returns
        -------
        int
            Count of seeds with |z| <= z_level (z_level = Phi^-1((1 + level) / 2)).
        """
        # lazy: `bikeid --help` imports this module for DEFAULTS; numerics load on first use
        from bikeid.ident.uncertainty import z_value

        return int(np.sum(np.abs(self.z[name]) <= z_value(self.settings["level"])))

    def summary(self) -> dict[str, dict[str, Any]]:
        """Per quantity: z mean and std, covered count, its exact interval and verdict.

        Returns
        -------
        dict of str to dict
            ``z_mean``, ``z_std`` (ddof 1; over the finite z, None if too few),
            ``se_median`` (median printed standard error, units of the quantity; None if
            not recorded), ``infinite`` (seeds with a non-finite z: the identified weave
            came out as two real roots, so its frequency has a zero standard error, or a
            fit has no v_w / v_c), ``covered``, ``n``,
            ``fraction``, ``ci``
            (Clopper-Pearson 95 % of the fraction) and ``verdict``
            (:func:`binomial_verdict`); entry ``theta_joint`` has ``d2_mean`` (10 expected)
            instead of the z statistics, and entries ``<part> profile`` only the counts of
            the profile intervals.
        """
        # lazy: `bikeid --help` imports this module for DEFAULTS; numerics load on first use
        from scipy.stats import chi2

        out: dict[str, dict[str, Any]] = {}
        for name, z in self.z.items():
            k = self.covered(name)
            lo, hi, verdict = binomial_verdict(k, z.size, self.settings["level"])
            fin = z[np.isfinite(z)]
            out[name] = {"z_mean": float(np.mean(fin)) if fin.size else None,
                         "z_std": float(np.std(fin, ddof=1)) if fin.size > 1 else None,
                         "infinite": int(z.size - fin.size),
                         "se_median": float(np.nanmedian(self.stderr[name]))
                         if name in self.stderr else None,
                         "covered": k, "n": int(z.size), "fraction": k / z.size,
                         "ci": [lo, hi], "verdict": verdict}  # fmt: skip
        for name, inside in self.profile_inside.items():
            k = int(np.sum(inside))
            lo, hi, verdict = binomial_verdict(k, inside.size, self.settings["level"])
            out[f"{name} profile"] = {"covered": k, "n": int(inside.size),
                                      "fraction": k / inside.size, "ci": [lo, hi],
                                      "verdict": verdict}  # fmt: skip
        d2 = self.mahalanobis
        if d2.size:
            k = int(np.sum(d2 <= chi2.ppf(self.settings["level"], 10)))
            lo, hi, verdict = binomial_verdict(k, d2.size, self.settings["level"])
            out["theta_joint"] = {"d2_mean": float(np.mean(d2)), "covered": k,
                                  "n": int(d2.size), "fraction": k / d2.size, "ci": [lo, hi],
                                  "verdict": verdict}  # fmt: skip
        return out

    def to_json(self) -> dict[str, Any]:
        """Settings, per-quantity summary, z-scores and failures (for ``dump_json``).

        Returns
        -------
        dict
            ``settings``, ``summary`` (:meth:`summary`), ``z`` and ``stderr`` (per quantity,
            one value per seed), ``profile_inside`` (per eigenvalue part and seed),
            ``mahalanobis`` (per seed), ``failed``.
        """
        return {"settings": self.settings, "summary": self.summary(),
                "z": dict(self.z), "stderr": self.stderr,
                "profile_inside": {k: v.tolist() for k, v in self.profile_inside.items()},
                "mahalanobis": self.mahalanobis,
                "failed": [{"seed": s, "error": e} for s, e in self.failed]}  # fmt: skip


def _mode_targets(p, speed: float) -> tuple[list[complex], list[str]]:
    # lazy: `bikeid --help` imports this module for DEFAULTS; numerics load on first use
    from bikeid.experiments.testbed.accuracy import true_modes

    modes = true_modes(p, [speed])[round(float(speed), 6)]
    if set(modes) != {"weave", "capsize", "caster"}:
        raise InputError(
            f"at {speed} m/s the benchmark has no weave pair with two real roots (modes "
            f"{sorted(modes)}); choose a speed between 1 and 15 m/s"
        )
    w = modes["weave"]
    return [w, np.conj(w), modes["capsize"], modes["caster"]], [
        "weave",
        "weave_conj",
        "capsize",
        "caster",
    ]


def _check_settings(seeds: int, covariance_scale: float, level: float) -> None:
    """The checks both harnesses share (InputError naming the bad value)."""
    # lazy: `bikeid --help` imports this module for DEFAULTS; numerics load on first use
    from bikeid.ident.uncertainty import z_value

    if int(seeds) != seeds or seeds < 2:
        raise InputError(f"seeds={seeds}: need at least 2 runs")
    if not (math.isfinite(covariance_scale) and covariance_scale > 0):
        raise InputError(f"covariance_scale={covariance_scale}: need a positive factor")
    z_value(level)


def _scenario(settings: dict[str, Any], speed: float):
    """The :class:`~bikeid.experiments.testbed.scenario.Scenario` of a settings dict."""
    from bikeid.experiments.testbed.scenario import Scenario

    return Scenario(
        controller=settings["controller"], speeds=(float(speed),),
        dither=settings["dither"], dither_hold=settings["dither_hold"],
        disturbance=settings["disturbance"], angle_noise=settings["angle_noise"],
        rate_noise=settings["rate_noise"], durations=(settings["duration"],), seeds=1,
    )  # fmt: skip


def _closed_loop_run(p, settings: dict[str, Any], speed: float, seed: int):
    """One run of the linear closed loop of ``settings`` at ``speed`` [m/s]: the public
    builder :func:`bikeid.experiments.testbed.scenario.closed_loop_run` (the bicycle is the
    benchmark, ``p`` is kept for the existing callers)."""
    from bikeid.experiments.testbed.scenario import closed_loop_run

    return closed_loop_run(_scenario(settings, speed), speed, settings["duration"], seed)


def _canonical(out: Any, speed: float):
    """The canonical model with covariance an estimator returned (coverage needs one)."""
    from bikeid.ident.methods import Identified
    from bikeid.ident.pem import CanonicalModel

    if isinstance(out, Identified) and out.interval_models:
        out = out.interval_models.get(round(float(speed), 6))
    if not isinstance(out, CanonicalModel):
        raise InputError(
            f"coverage counts canonical parameters: the estimator returned "
            f"{type(out).__name__}, not a CanonicalModel with its covariance"
        )
    return out


def _one(p, settings: dict[str, Any], seed: int, theta_true, targets) -> dict[str, float]:
    # lazy: `bikeid --help` imports this module for DEFAULTS; numerics load on first use
    from bikeid.experiments.testbed.consistency import _context
    from bikeid.experiments.testbed.estimator import Estimator
    from bikeid.ident.uncertainty import eigenvalue_intervals
    from bikeid.sim.linear import match_eigenvalues

    run = _closed_loop_run(p, settings, settings["speed"], seed)
    if settings["fit"] == "pem":
        # the free innovation gain (the estimator the documented 1000-seed study measured;
        # its fits end inside the predictor's stability boundary at these lengths), every
        # interval counted: no structure check, no boundary refusal
        from bikeid.ident import pem

        model = pem.fit(run, noise_model="gain", structure=False)
    else:  # any estimator (a table name with settings, a peer, module:function)
        sc = _scenario(settings, settings["speed"])
        est = Estimator(settings["fit"])
        model = _canonical(est.fit([run], _context(sc, settings["level"])), settings["speed"])
    model = dataclasses.replace(model, covariance=model.covariance * settings["covariance_scale"])
    se = np.sqrt(np.diag(model.covariance))
    r = model.theta - theta_true
    z = dict(zip(QUANTITIES[:10], r / se, strict=True))
    z["d2"] = float(r @ np.linalg.solve(model.covariance, r))
    z.update({f"se_{q}": float(e) for q, e in zip(QUANTITIES[:10], se, strict=True)})
    ei = eigenvalue_intervals(model, level=settings["level"],  # profile ends + first-order SE
                              refuse_boundary=False)  # fmt: skip
    _, col = match_eigenvalues(ei.values, targets, return_index=True)
    for i, name in ((0, "weave"), (2, "capsize"), (3, "caster")):
        j = col[i]
        z[f"{name}_re"] = (ei.values[j].real - targets[i].real) / ei.std_real[j]
        z[f"se_{name}_re"] = float(ei.std_real[j])
        z[f"in_{name}_re"] = bool(ei.real_lower[j] <= targets[i].real <= ei.real_upper[j])
    j = col[0]
    t_im = targets[0].imag  # the interval of |Im| of the identified pair (as z below)
    lo_im, hi_im = sorted((abs(ei.imag_lower[j]), abs(ei.imag_upper[j])))
    if ei.imag_lower[j] < 0 < ei.imag_upper[j]:
        lo_im = 0.0
    z["in_weave_im"] = bool(lo_im <= t_im <= hi_im)
    # the identified weave may come out as two real roots: its imaginary-part error is then
    # the whole true frequency with a zero standard error (z = inf, not covered)
    dz = abs(ei.values[j].imag) - targets[0].imag
    z["weave_im"] = dz / ei.std_imag[j] if ei.std_imag[j] > 0 else math.copysign(math.inf, dz)
    z["se_weave_im"] = float(ei.std_imag[j])
    return z


def _seed_job(p, settings: dict[str, Any], theta_true, targets, seed: int):
    """:func:`_one` for one seed, as ``(seed, row, None)`` or ``(seed, None, message)``: a
    picklable job of :func:`bikeid.experiments.parallel.imap`."""
    try:
        return seed, _one(p, settings, seed, theta_true, targets), None
    except ValueError as exc:  # UntrustworthyResult / InputError: count, do not hide
        return seed, None, str(exc).splitlines()[0]


def run_coverage(
    seeds: int = 200,
    *,
    speed: float = DEFAULTS["speed"],
    duration: float = DEFAULTS["duration"],
    dither: float = DEFAULTS["dither"],
    dither_hold: int = int(DEFAULTS["dither_hold"]),
    disturbance: float = DEFAULTS["disturbance"],
    angle_noise: float = DEFAULTS["angle_noise"],
    rate_noise: float = DEFAULTS["rate_noise"],
    controller: str = "pid",
    level: float = 0.95,
    covariance_scale: float = 1.0,
    first_seed: int = 0,
    log: Callable[[str], None] | None = None,
    workers: int = 1,
    dask: str | None = None,
    estimator: str = "pem",
) -> CoverageResult:
    """Identify ``seeds`` linear closed-loop runs and record the z-score of every quantity.

    Parameters
    ----------
    seeds : int, optional
        Number of runs N (seeds ``first_seed`` .. ``first_seed + N - 1``), >= 2.
    speed : float, optional
        Forward speed [m/s] (the benchmark must have weave, capsize and caster modes there).
    duration : float, optional
        Run length [s] (100 Hz sampling).
    dither : float, optional
        Uniform steer-torque dither amplitude [N m].
    dither_hold : int, optional
        Samples each dither value is held.
    disturbance : float, optional
        Standard deviation of the unlogged white steer torque [N m].
    angle_noise, rate_noise : float, optional
        Sensor noise standard deviations [rad], [rad/s].
    controller : str, optional
        ``controllers.registry`` name ("pid" default; "pole" places at ``speed``).
    level : float, optional
        Nominal coverage of the intervals (default 0.95).
    covariance_scale : float, optional
        Factor on every fitted covariance before the intervals are formed (1 = as fitted;
        0.1 shows the verdict failing).
    first_seed : int, optional
        First seed.
    log : callable, optional
        Receives one progress line per seed, in seed order.
    workers : int, optional
        Local worker processes (default 1); the result does not depend on it.
    dask : str or None, optional
        ``"local"`` or a Dask scheduler address (:mod:`bikeid.experiments.parallel`).
    estimator : str, optional
        The estimator (:class:`bikeid.experiments.testbed.estimator.Estimator` text: a
        name of the method table with settings, or ``module:function``) whose intervals are
        counted; it must return a canonical model with covariance (default ``"pem"``, the
        table's canonical PEM per speed, i.e. ``ident.pem.fit``).

    Returns
    -------
    CoverageResult
        z-scores per quantity and the seeds that failed.

    Raises
    ------
    InputError
        On fewer than 2 seeds, a non-positive ``covariance_scale``, a bad ``level`` or a
        speed without the three modes.
    """
    # lazy: `bikeid --help` imports this module for DEFAULTS; numerics load on first use
    from bikeid.ident.canonical import theta_from_matrices
    from bikeid.sim.linear import canonical_matrices

    _check_settings(seeds, covariance_scale, level)
    p = benchmark()
    targets, _ = _mode_targets(p, speed)
    theta_true = theta_from_matrices(canonical_matrices(p), speed)
    settings = {"speed": float(speed), "duration": float(duration), "dither": float(dither),
                "dither_hold": int(dither_hold), "disturbance": float(disturbance),
                "angle_noise": float(angle_noise), "rate_noise": float(rate_noise),
                "controller": controller, "level": float(level),
                "covariance_scale": float(covariance_scale),
                "seeds": [int(first_seed), int(first_seed + seeds - 1)],
                "plant": "benchmark, linear (dataset.linear_loop, exact ZOH)",
                "estimator": f"{estimator} (ident.methods / experiments.testbed.estimator)",
                "fit": str(estimator)}  # fmt: skip
    from bikeid.experiments.testbed.estimator import Estimator

    Estimator(estimator)  # an unknown estimator: one line before any seed
    rows: list[dict[str, float]] = []
    failed: list[tuple[int, str]] = []
    job = partial(_seed_job, p, settings, theta_true, targets)
    seed_list = range(int(first_seed), int(first_seed + seeds))
    for _, (s, row, error) in imap(job, seed_list, workers, dask, ordered=True):
        if error is None:
            rows.append(row)
        else:
            failed.append((s, error))
        if log:
            log(f"seed {s}: {'ok' if error is None else 'failed'}")
    z = {q: np.array([r[q] for r in rows]) for q in QUANTITIES} if rows else {}
    d2 = np.array([r["d2"] for r in rows])
    se = {q: np.array([r[f"se_{q}"] for r in rows]) for q in QUANTITIES} if rows else {}
    inside = {q: np.array([r[f"in_{q}"] for r in rows]) for q in PROFILED} if rows else {}
    return CoverageResult(settings=settings, z=z, failed=failed, mahalanobis=d2, stderr=se,
                          profile_inside=inside)  # fmt: skip


def _critical_job(p, settings: dict[str, Any], seed: int):
    """One seed of :func:`run_critical_coverage`: ``(seed, intervals, None)`` or
    ``(seed, None, message)``; a picklable job of :func:`bikeid.experiments.parallel.imap`."""
    # lazy: `bikeid --help` reads DEFAULTS from this module; scipy.optimize stays out of start-up
    from bikeid.ident import pem
    from bikeid.ident.uncertainty import critical_speed_intervals

    sp = settings["speeds"]
    try:
        runs = [_closed_loop_run(p, settings, v, seed * len(sp) + k) for k, v in enumerate(sp)]
        model = pem.fit_speed_model(runs, structure=False)  # every interval counted
        scale = settings["covariance_scale"]
        model = dataclasses.replace(model, covariance=model.covariance * scale)
        ci = critical_speed_intervals(model, level=settings["level"], vmax=settings["vmax"])
    except ValueError as exc:  # UntrustworthyResult / InputError: count, do not hide
        return seed, None, str(exc).splitlines()[0]
    return seed, ci, None


#: Speeds [m/s] of the critical-speed coverage: 2-8 m/s brackets the benchmark's v_w (4.29)
#: and v_c (6.02).
CRITICAL_SPEEDS = (2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0)


def run_critical_coverage(
    seeds: int = 100,
    *,
    speeds: tuple[float, ...] = CRITICAL_SPEEDS,
    duration: float = DEFAULTS["duration"],
    dither: float = DEFAULTS["dither"],
    level: float = 0.95,
    covariance_scale: float = 1.0,
    first_seed: int = 0,
    vmax: float = 15.0,
    log: Callable[[str], None] | None = None,
    workers: int = 1,
    dask: str | None = None,
) -> CoverageResult:
    """Coverage of the v_w and v_c intervals of speed-parameterized PEM fits.

    Per seed s, one run per speed (seed ``s * len(speeds) + k`` for the k-th speed; the other
    settings are :data:`DEFAULTS`, roll PID) identified jointly by
    :func:`bikeid.ident.pem.fit_speed_model`; the truth is
    :func:`bikeid.sim.linear.critical_speeds` of the benchmark.  A fit without the speed in
    (0, ``vmax``] counts as not covering it (z = NaN).

    Parameters
    ----------
    seeds : int, optional
        Number of seeds N (>= 2).
    speeds : tuple of float, optional
        Run speeds [m/s] (>= 2 distinct, each 1-15).
    duration, dither : float, optional
        Run length [s] and dither amplitude [N m] of each run.
    level : float, optional
        Nominal coverage of the intervals.
    covariance_scale : float, optional
        Factor on each fitted covariance (as in :func:`run_coverage`).
    first_seed : int, optional
        First seed.
    vmax : float, optional
        Highest speed searched for v_w and v_c [m/s].
    log : callable, optional
        Receives one progress line per seed, in seed order.
    workers : int, optional
        Local worker processes (default 1); the result does not depend on it.
    dask : str or None, optional
        ``"local"`` or a Dask scheduler address (:mod:`bikeid.experiments.parallel`).
    estimator : str, optional
        The estimator (:class:`bikeid.experiments.testbed.estimator.Estimator` text: a
        name of the method table with settings, or ``module:function``) whose intervals are
        counted; it must return a canonical model with covariance (default ``"pem"``, the
        table's canonical PEM per speed, i.e. ``ident.pem.fit``).

    Returns
    -------
    CoverageResult
        ``z``, ``stderr`` and ``profile_inside`` for ``v_w`` and ``v_c`` (no joint row).

    Raises
    ------
    InputError
        On fewer than 2 seeds or distinct speeds, a speed outside 1-15 m/s, a non-positive
        ``covariance_scale`` or a bad ``level``.
    """
    from bikeid.sim.linear import canonical_matrices, critical_speeds

    sp = tuple(float(v) for v in speeds)
    _check_settings(seeds, covariance_scale, level)
    if len(set(sp)) < 2 or not all(1.0 <= v <= 15.0 for v in sp):
        raise InputError(f"speeds={sp}: need at least 2 distinct speeds within 1-15 m/s")
    p = benchmark()
    truth = critical_speeds(canonical_matrices(p), vmax)
    settings = {**{k: v for k, v in DEFAULTS.items() if k != "speed"},
                "duration": float(duration), "dither": float(dither),
                "dither_hold": int(DEFAULTS["dither_hold"]), "speeds": list(sp),
                "controller": "pid", "level": float(level), "vmax": float(vmax),
                "covariance_scale": float(covariance_scale),
                "seeds": [int(first_seed), int(first_seed + seeds - 1)],
                "truth": {"v_w": truth["v_w"], "v_c": truth["v_c"]},
                "plant": "benchmark, linear (dataset.linear_loop, exact ZOH)",
                "estimator": "ident.pem.fit_speed_model, 4 outputs"}  # fmt: skip
    names = ("v_w", "v_c")
    z: dict[str, list[float]] = {n: [] for n in names}
    se: dict[str, list[float]] = {n: [] for n in names}
    inside: dict[str, list[bool]] = {n: [] for n in names}
    failed: list[tuple[int, str]] = []
    job = partial(_critical_job, p, settings)
    seed_list = range(int(first_seed), int(first_seed + seeds))
    for _, (s, ci, error) in imap(job, seed_list, workers, dask, ordered=True):
        if error is not None:
            failed.append((s, error))
        for n in names if ci is not None else ():
            val, sd, iv = getattr(ci, n), getattr(ci, f"std_{n}"), ci.interval(n)
            z[n].append((val - truth[n]) / sd if val is not None and sd > 0 else math.nan)
            se[n].append(sd if sd is not None else math.nan)
            inside[n].append(iv is not None and iv[0] <= truth[n] <= iv[1])
        if log:
            log(f"seed {s}: {'failed' if failed and failed[-1][0] == s else 'ok'}")
    return CoverageResult(
        settings=settings, z={n: np.array(v) for n, v in z.items()}, failed=failed,
        stderr={n: np.array(v) for n, v in se.items()},
        profile_inside={n: np.array(v, dtype=bool) for n, v in inside.items()},
    )  # fmt: skip


def table_text(result: CoverageResult) -> str:
    """A plain-text table of :meth:`CoverageResult.summary`.

    Parameters
    ----------
    result : CoverageResult
        The coverage run.

    Returns
    -------
    str
        One line per quantity: z mean, z std, covered/N, Clopper-Pearson 95 % interval and
        verdict, after a header naming the settings.
    """
    s = result.settings
    where = (f"{s['speed']:g} m/s" if "speeds" not in s else
             "speeds " + ", ".join(f"{v:g}" for v in s["speeds"]) + " m/s (speed-parameterized)")
    lines = [
        f"coverage of {100 * s['level']:g} % intervals: linear benchmark at {where}, "
        f"{s['controller']}, {s['duration']:g} s, dither {s['dither']:g} N m held "
        f"{s['dither_hold']} samples, disturbance {s['disturbance']:g} N m, noise "
        f"{s['angle_noise']:g} rad / {s['rate_noise']:g} rad/s, covariance x "
        f"{s['covariance_scale']:g}, seeds {s['seeds'][0]}..{s['seeds'][1]}",
        f"{'quantity':<11} {'med. SE':>9} {'z mean':>7} {'z std':>6} {'covered':>9} "
        f"{'95% CI':>15}  verdict",
    ]
    for name, row in result.summary().items():
        if "z_mean" not in row and "d2_mean" not in row:  # a profile row: counts only
            lines.append(
                f"{name:<18} {'':>16} {row['covered']:>4}/{row['n']:<4} "
                f"[{row['ci'][0]:.3f}, {row['ci'][1]:.3f}]  {row['verdict']}"
            )
            continue
        if "d2_mean" in row:
            lines.append(
                f"{name:<11} {'':>9} mean d2 {row['d2_mean']:.2f} (10 if P is right) "
                f"{row['covered']:>4}/{row['n']:<4} [{row['ci'][0]:.3f}, {row['ci'][1]:.3f}]  "
                f"{row['verdict']}"
            )
            continue
        zm, zs = (f"{row[k]:.2f}" if row[k] is not None else "-" for k in ("z_mean", "z_std"))
        what = "found no " + name if name.startswith("v_") else "real weave, z infinite"
        inf = f" ({row['infinite']} seeds {what})" if row["infinite"] else ""
        se = f"{row['se_median']:.3g}" if row["se_median"] is not None else "-"
        lines.append(
            f"{name:<11} {se:>9} {zm:>7} {zs:>6} "
            f"{row['covered']:>4}/{row['n']:<4} [{row['ci'][0]:.3f}, {row['ci'][1]:.3f}]  "
            f"{row['verdict']}{inf}"
        )
    if result.failed:
        lines.append(f"{len(result.failed)} seeds failed: " + "; ".join(
            f"{s}: {e}" for s, e in result.failed[:3]))  # fmt: skip
    return "\n".join(lines)


#: The default path of the README: benchmark bicycle, roll PID at 100 Hz, uniform dither
#: 1 N m held 10 ms (``controllers.UniformDither``), default sensors, no disturbance,
#: ``dataset.closed_loop.simulate_run`` at 5 m/s, ``pem.fit``, ``eigenvalue_intervals``.
DEFAULT_PATH: dict[str, Any] = {"speed": 5.0, "dither": 1.0, "controller": "pid"}

#: Eigenvalue real parts counted on the default path, in table order.
DEFAULT_PATH_PARTS = ("caster_re", "weave_re", "capsize_re")


def _common_costs(run, models, theta_true=None) -> list[float]:
    """Prediction cost of each model's optimum under one set of output weights.

    Each fit re-estimates its own output weights, so their costs are not comparable; here
    every model is polished (Levenberg-Marquardt, ftol 1e-9, 400 evaluations) with the
    weights of the first model and the weighted squared prediction errors are returned
    (whitened units: a difference of 4 is about a 95 % likelihood-ratio difference).
    """
    from bikeid.ident.predictor import PredictionProblem, levenberg_marquardt, run_data

    outputs = models[0].outputs
    data = run_data([run], outputs)
    w = 1.0 / np.sqrt(np.diag(models[0].noise_covariance))
    out = []
    for m in models:
        prob = PredictionProblem(data, [np.eye(10)], [m.K], True, w, outputs)
        x0 = np.concatenate([m.theta, np.asarray(m.K).ravel()])
        try:
            levenberg_marquardt(prob, x0, 400, ftol=1e-9)
            out.append(float(prob._r @ prob._r))
        except (ValueError, TypeError):  # the polish met an unstable predictor: its start cost
            r = prob.residual(x0)
            out.append(float(r @ r) if r is not None else math.inf)
    return out


def _default_path_job(settings: dict[str, Any], targets, theta_true, seed: int):
    """One seed of :func:`run_default_path_coverage`: ``(seed, row, None)`` or
    ``(seed, None, message)``; a picklable job of :func:`bikeid.experiments.parallel.imap`."""
    from bikeid.controllers import UniformDither, make
    from bikeid.dataset.closed_loop import simulate_run
    from bikeid.ident import pem
    from bikeid.ident.uncertainty import eigenvalue_intervals
    from bikeid.sim.linear import match_eigenvalues

    p = benchmark()
    try:
        run = simulate_run(
            p, make(settings["controller"], p), speed=settings["speed"],
            duration=settings["duration"], dither=UniformDither(settings["dither"], seed=seed,
            max_amplitude=max(1.0, settings["dither"])), seed=seed, plant=settings["plant"],
        )  # fmt: skip
        model = pem.fit(run, noise_model=settings["noise_model"])
        ei = eigenvalue_intervals(model, level=settings["level"], refuse_boundary=False,
                                  refuse_structure=False, refuse_output_error=False,
                                  refuse_amplitude=False)  # every fit counted  # fmt: skip
    except ValueError as exc:  # UntrustworthyResult / InputError: count, do not hide
        return seed, None, str(exc).splitlines()[0]
    _, col = match_eigenvalues(ei.values, targets, return_index=True)
    row: dict[str, Any] = {
        "radius": ei.predictor_radius,
        "boundary": ei.at_predictor_boundary,
        "rms_roll_deg": float(np.degrees(np.std(run.truth["phi"]))),
    }
    for name, i in zip(DEFAULT_PATH_PARTS, (3, 0, 2), strict=True):
        j = col[i]
        row[f"est_{name}"] = float(ei.values[j].real)
        row[f"se_{name}"] = float(ei.std_real[j])
        row[f"in_{name}"] = bool(ei.real_lower[j] <= targets[i].real <= ei.real_upper[j])
    if settings["restart"]:
        try:
            other = pem.fit(run, noise_model=settings["noise_model"], theta0=theta_true)
            c_def, c_tru = _common_costs(run, [model, other])
            row["truth_start_gain"] = c_def - c_tru
        except ValueError:
            row["truth_start_gain"] = math.nan
    return seed, row, None


def run_default_path_coverage(
    seeds: int = 20,
    *,
    duration: float = 30.0,
    plant: str = "nonlinear",
    dither: float = DEFAULT_PATH["dither"],
    speed: float = DEFAULT_PATH["speed"],
    noise_model: str = "free",
    restart: bool = False,
    level: float = 0.95,
    first_seed: int = 0,
    log: Callable[[str], None] | None = None,
    workers: int = 1,
    dask: str | None = None,
) -> dict[str, Any]:
    """Coverage of the default path's eigenvalue intervals, and why they miss.

    Per seed s: ``simulate_run`` of the benchmark under the roll PID with
    ``UniformDither(dither, seed=s)`` and sensor seed s, ``pem.fit`` and
    ``eigenvalue_intervals`` (profile); the truth is the linearization
    (``sim.linear.eigenvalues``), modes paired by ``match_eigenvalues``.  Counted for the
    caster, weave and capsize real parts: intervals containing the truth over all fits,
    over the fits whose one-step predictor is inside its stability boundary
    (:func:`bikeid.ident.uncertainty.check_predictor_interior` passes), and over those it
    refuses; the Monte Carlo scatter of the estimates over seeds against the median printed
    standard error (the finite-sample covariance check); with ``restart``, how often a fit
    started at the truth reaches a lower cost (local optima).

    Parameters
    ----------
    seeds : int, optional
        Number of runs (>= 2).
    duration : float, optional
        Record length [s].
    plant : {"nonlinear", "linear"}, optional
        ``simulate_run``'s plant (the linear one isolates the nonlinearity).
    dither : float, optional
        Dither amplitude [N m] (1 on the default path).
    speed : float, optional
        Forward speed [m/s].
    noise_model : {"free", "kalman", "gain", "none"}, optional
        ``pem.fit``'s noise model ("free": its default, the Kalman gain; "gain": the free
        innovation gain of the study in docs/uncertainty.md).
    restart : bool, optional
        Also fit from the true parameters and compare costs under common weights.
    level : float, optional
        Nominal coverage of the intervals.
    first_seed : int, optional
        First seed.
    log : callable, optional
        Receives one progress line per seed.
    workers : int, optional
        Local worker processes (the result does not depend on it).
    dask : str or None, optional
        ``"local"`` or a Dask scheduler address.

    Returns
    -------
    dict
        ``settings``; ``rows`` (per seed: predictor ``radius``, ``boundary``,
        ``rms_roll_deg`` [deg], per part ``est_``, ``se_`` [1/s] and ``in_``, and with
        ``restart`` ``truth_start_gain``: default cost minus truth-start cost, positive
        when the truth start found a lower optimum); ``failed``; ``summary`` per part:
        ``all``, ``interior`` and ``boundary`` (each ``covered``, ``n``, ``ci``,
        ``verdict``), ``mc_sd`` and ``se_median`` [1/s] and their ratio; ``boundary`` (count)
        and ``lower_optimum`` (count of truth starts lower by more than 4, or None).

    Raises
    ------
    InputError
        On fewer than 2 seeds, a bad ``plant``, ``noise_model`` or ``level``, or a speed
        without the three modes.
    """
    from bikeid.ident.canonical import theta_from_matrices
    from bikeid.sim.linear import canonical_matrices

    _check_settings(seeds, 1.0, level)
    if plant not in ("nonlinear", "linear"):
        raise InputError(f"plant={plant!r}: choose nonlinear or linear")
    if noise_model not in ("free", "kalman", "gain", "none"):
        raise InputError(f"noise_model={noise_model!r}: choose free, kalman, gain or none")
    p = benchmark()
    targets, _ = _mode_targets(p, speed)
    theta_true = theta_from_matrices(canonical_matrices(p), speed)
    settings = {"speed": float(speed), "duration": float(duration), "dither": float(dither),
                "plant": plant, "controller": DEFAULT_PATH["controller"],
                "noise_model": noise_model, "restart": bool(restart), "level": float(level),
                "seeds": [int(first_seed), int(first_seed + seeds - 1)],
                "truth": {n: float(targets[i].real) for n, i in
                          zip(DEFAULT_PATH_PARTS, (3, 0, 2), strict=True)}}  # fmt: skip
    job = partial(_default_path_job, settings, targets, theta_true)
    rows, failed = [], []
    for _, (s, row, error) in imap(job, range(first_seed, first_seed + seeds), workers, dask,
                                   ordered=True):  # fmt: skip
        if error is None:
            rows.append({"seed": s, **row})
        else:
            failed.append({"seed": s, "error": error})
        if log:
            log(f"seed {s}: {'ok' if error is None else 'failed'}")
    return {"settings": settings, "rows": rows, "failed": failed,
            "summary": default_path_summary(rows, level)}  # fmt: skip


def default_path_summary(rows: list[dict[str, Any]], level: float = 0.95) -> dict[str, Any]:
    """Counts, binomial intervals and verdicts of :func:`run_default_path_coverage`'s rows.

    Parameters
    ----------
    rows : list of dict
        Per-seed rows with ``boundary`` and, per part of :data:`DEFAULT_PATH_PARTS`,
        ``in_``, ``est_`` and ``se_``.
    level : float, optional
        Nominal coverage.

    Returns
    -------
    dict
        Per part: ``all``, ``interior``, ``boundary`` (``covered``, ``n``, ``ci``,
        ``verdict``; None where n is 0), ``mc_sd``, ``se_median`` [1/s], ``sd_ratio`` and
        ``sd_ratio_interior`` (over the fits inside the boundary; NaN below 3 of them);
        ``boundary`` (fits on the predictor boundary, refused by
        ``check_predictor_interior``), ``n``, and ``lower_optimum``.
    """

    def count(sel: list[dict[str, Any]], name: str) -> dict[str, Any] | None:
        if not sel:
            return None
        k = sum(bool(r[f"in_{name}"]) for r in sel)
        lo, hi, verdict = binomial_verdict(k, len(sel), level)
        return {"covered": k, "n": len(sel), "ci": [lo, hi], "verdict": verdict}

    inner = [r for r in rows if not r["boundary"]]
    edge = [r for r in rows if r["boundary"]]
    out: dict[str, Any] = {"n": len(rows), "boundary": len(edge)}
    for name in DEFAULT_PATH_PARTS:
        est = np.array([r[f"est_{name}"] for r in rows])
        se = np.array([r[f"se_{name}"] for r in rows])
        sd = float(np.std(est, ddof=1)) if est.size > 1 else math.nan
        med = float(np.median(se)) if se.size else math.nan
        e_in = np.array([r[f"est_{name}"] for r in inner])
        m_in = float(np.median([r[f"se_{name}"] for r in inner])) if inner else math.nan
        r_in = float(np.std(e_in, ddof=1)) / m_in if e_in.size > 2 and m_in > 0 else math.nan
        out[name] = {"all": count(rows, name), "interior": count(inner, name),
                     "boundary": count(edge, name), "mc_sd": sd, "se_median": med,
                     "sd_ratio": sd / med if med > 0 else math.nan,
                     "sd_ratio_interior": r_in}  # fmt: skip
    gains = [r["truth_start_gain"] for r in rows if "truth_start_gain" in r]
    out["lower_optimum"] = sum(g > 4.0 for g in gains) if gains else None
    return out


def default_path_table(result: dict[str, Any]) -> str:
    """Plain-text table of :func:`run_default_path_coverage`.

    Parameters
    ----------
    result : dict
        Its return value.

    Returns
    -------
    str
        Settings line, then per real part: covered/n over all fits, over the fits inside
        the predictor boundary, over the fits on it, with Clopper-Pearson intervals and
        verdicts, and the scatter over seeds against the median printed standard error.
    """
    s, m = result["settings"], result["summary"]

    def cell(c: dict[str, Any] | None) -> str:
        if c is None:
            return "-"
        return f"{c['covered']}/{c['n']} [{c['ci'][0]:.2f}, {c['ci'][1]:.2f}] {c['verdict']}"

    lines = [
        f"default path: benchmark, {s['plant']} plant, {s['controller']}, {s['speed']:g} m/s, "
        f"{s['duration']:g} s, dither {s['dither']:g} N m, pem.fit noise_model="
        f"{s['noise_model']}, {100 * s['level']:g} % profile intervals, seeds "
        f"{s['seeds'][0]}..{s['seeds'][1]}",
        f"fits ending on the predictor's stability boundary (refused by "
        f"check_predictor_interior): {m['boundary']} of {m['n']}"
        + ("" if m["lower_optimum"] is None else
           f"; a start at the truth reached a lower cost (by > 4) in {m['lower_optimum']}"),
        f"{'part (truth)':<24} {'all fits':<34} {'inside boundary':<34} {'on boundary':<34} "
        "scatter / median SE (inside boundary)",
    ]  # fmt: skip
    for name in DEFAULT_PATH_PARTS:
        r = m[name]
        lines.append(
            f"{name + ' (' + format(s['truth'][name], '.3f') + ')':<24} {cell(r['all']):<34} "
            f"{cell(r['interior']):<34} {cell(r['boundary']):<34} "
            f"{r['mc_sd']:.3f} / {r['se_median']:.3f} = {r['sd_ratio']:.2f} "
            f"({r['sd_ratio_interior']:.2f})"
        )
    if result["failed"]:
        lines.append(f"{len(result['failed'])} seeds failed: " + "; ".join(
            f"{f['seed']}: {f['error']}" for f in result["failed"][:3]))  # fmt: skip
    return "\n".join(lines)
