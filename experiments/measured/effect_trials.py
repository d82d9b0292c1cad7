"""Randomized undeclared-effect trials on the nonlinear plant (``bikeid measured trials``).

Each trial imitates the treadmill experiment of the measured data with one hidden effect:

- **Plant**: the nonlinear Carvallo-Whipple model (:mod:`sim.integrate`, RK4, 4 substeps per
  10 ms sample) of the steer-by-wire bicycle, speed held by the ideal rear drive, with one
  :mod:`sim.effects` object injected.
- **Loop**: the firmware's steer-into-lean law ``T = 2 (6.5 - v_s) phidot_m`` evaluated every
  10 ms on the *measured* roll rate and the *sensor* speed ``v_s = 1.066 v - 0.128`` (the
  data README's calibration), zero-order hold (:class:`controllers.SteerIntoLean`).
- **Pushes**: free decays of 1 s (100 samples) from random initial states like those of the
  logs (|phidot0| 0.35-0.95 rad/s, |deltadot0| 0.4-1.5 rad/s, steer 0-0.15 rad, same sign).
- **Sensors** (:mod:`dataset.sensors`): white noise on roll rate (std drawn 0.005-0.015
  rad/s, the second-difference noise of the logs' lean_rate is 0.006-0.017), on roll angle
  (std/5 rad) and steer angle (3e-4 rad), steer encoder quantization 0.000767 rad
  (2 pi / 8192) and steer-rate quantization 0.0767 rad/s (encoder difference over 10 ms).
- **Speeds**: four treadmill speeds drawn from 1.5-4.5 m/s at least 0.5 m/s apart, redrawn
  unless the sampled linear loop with the effect is stable at all four with the weave
  decaying faster than 0.3 1/s (an unstable combination, e.g. a 40 ms delay at 3.5 m/s,
  cannot be logged); a push after which the nonlinear plant falls is repeated at 0.7 times
  its size (up to 3 times), as an experimenter would; two
  (4 decays each) are given to :func:`bikeid.ident.effects.selection.select_effects`, the other
  two (3 decays each) are held out for :func:`bikeid.ident.effects.diagnostics.evaluate`.

The pipeline is not told the effect.  Scored per trial (library effects): the effect ranks
first (``verdict[0]``), its magnitude is within 20 % (of the deviation from "absent",
``|x_hat - x| <= 0.2 |x - absent|``, so a command gain 0.8 must come out in 0.76-0.84) and
the held-out error (NRMSE of roll rate and steer angle) at least halves.  For effects outside
the library (``roll_viscous_damping``, ``roll_stiffness``) the score is whether the verdict
starts with ``unexplained``.  Rates come with exact (Clopper-Pearson) 95 % intervals.

Magnitude ranges (physically plausible; Moore's Davis bicycle has steer viscous damping
0.34 N m s/rad and Coulomb friction 0.15 N m, identification.md section 5): see
:data:`EFFECTS`.  Input delays are whole 10 ms samples (the plant's loop is sampled).  The
loop bounds them: with this controller a 40 ms delay or a 50 ms lag makes the weave unstable
at 3-4.5 m/s and a gain of 0.6 at 1.5 m/s (linear sampled loop), so such a bicycle could not
have been logged; the ranges stop short of that.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass
from functools import partial

import numpy as np

from bikeid.controllers.steer_into_lean import SteerIntoLean
from bikeid.dataset.closed_loop import simulate_run
from bikeid.dataset.sbw_logs import SPEED_CALIBRATION
from bikeid.dataset.sensors import Channel, Sensors
from bikeid.dataset.windows import Window
from bikeid.experiments.parallel import imap
from bikeid.ident.effects.before_after import GOAL_RATIO
from bikeid.ident.effects.diagnostics import evaluate
from bikeid.ident.effects.experiment_model import ExperimentModel
from bikeid.ident.effects.selection import select_effects
from bikeid.ident.validate import binomial_interval as binomial_ci
from bikeid.sim.effect_registry import RegistryFacts, effect
from bikeid.sim.effects import nonlinear_effects
from bikeid.sim.parameters import steer_by_wire

__all__ = [
    "EFFECTS",
    "LIBRARY_EFFECTS",
    "OUTSIDE_EFFECTS",
    "EffectSpec",
    "TrialSpec",
    "binomial_ci",
    "decay_windows",
    "draw_trials",
    "rate",
    "run_trial",
    "run_trials",
    "summarize",
]

DT = 0.01
N_SAMPLES = 100  # 1 s decay windows, like eigen/segments.csv
SUBSTEPS = 4
STEER_STEP = 2 * math.pi / 8192  # steer encoder resolution [rad]
SPEED_RANGE = (1.5, 4.5)  # treadmill speeds of the logs [m/s]
DELTA0 = 0.2  # |delta0| <= DELTA0 / v [rad]: logs 0.06-0.21 at 1.5, 0.01-0.05 at 4.5 m/s
FIT_PER_SPEED = 4
EVAL_PER_SPEED = 3
TRIAL_COULOMB_SMOOTHING = 0.01  # rad/s, tanh smoothing of the injected steer Coulomb friction


@dataclass(frozen=True)
class EffectSpec(RegistryFacts):
    """How the trials draw one injected effect (its facts are the registry's).

    Attributes
    ----------
    name : str
        Registry name (:mod:`bikeid.sim.effect_registry`); the nonlinear plant must carry it
        without a speed dependence.
    low, high : float
        Magnitude range drawn from [the effect's unit].
    choices : tuple of float
        Discrete values instead of [low, high].
    two_sided : bool
        Draw absent -/+ [|low - absent|, |high - absent|].
    doc : str
        Why this range.
    """

    name: str
    low: float
    high: float
    choices: tuple[float, ...] = ()
    two_sided: bool = False
    doc: str = ""

    def __post_init__(self) -> None:
        e = effect(self.name)
        if e.plant_term is None or e.per_speed:
            raise ValueError(f"trial effect {self.name}: the nonlinear plant must carry it "
                             "at every speed alike")  # fmt: skip

    def draw(self, rng: np.random.Generator) -> float:
        """One magnitude [unit] from the generator ``rng``.

        Parameters
        ----------
        rng : numpy.random.Generator
            Source of the draw (advanced by one or two draws).

        Returns
        -------
        float
            One of ``choices``, or uniform in [low, high] (mirrored about ``absent`` with
            probability 1/2 when ``two_sided``), in the effect's unit.
        """
        if self.choices:
            return float(rng.choice(self.choices))
        x = float(rng.uniform(self.low, self.high))
        if self.two_sided and rng.random() < 0.5:
            x = 2 * self.absent - x
        return x

    def sim_effects(self, value: float) -> list:
        """The :mod:`bikeid.sim.effects` objects injecting ``value`` [unit].

        Through :func:`bikeid.sim.effects.nonlinear_effects` with the trials' steer
        Coulomb smoothing TRIAL_COULOMB_SMOOTHING (0.01 rad/s; the experiment model smooths
        with 0.1 rad/s).  The speed does not enter (no 1/v effect is drawn).

        Parameters
        ----------
        value : float
            Magnitude [unit].

        Returns
        -------
        list
            Non-empty.
        """
        objects, _ = nonlinear_effects({self.name: value}, 1.0, DT, TRIAL_COULOMB_SMOOTHING)
        if not objects:
            raise ValueError(f"{self.name} = {value} is absent on the plant")
        return objects


EFFECTS: dict[str, EffectSpec] = {
    e.name: e
    for e in (
        EffectSpec(
            "steer_viscous_damping", 0.2, 0.8, doc="bearing + motor viscous damping (Moore: 0.34)"
        ),
        EffectSpec(
            "steer_coulomb_friction",
            0.1,
            0.4,
            doc="bearing/motor dry friction, tanh smoothing 0.01 rad/s (Moore: 0.15)",
        ),
        EffectSpec(
            "steer_stiffness",
            0.4,
            1.2,
            doc="centring spring of the fork: cables, belt, tyre twist (real logs: ~1.1; "
            "above ~1.2 the capsize mode of this loop is unstable at 4.5 m/s)",
        ),
        EffectSpec(
            "command_gain",
            1.15,
            1.35,
            two_sided=True,
            doc="motor torque-constant error 15-35 % either way",
        ),
        EffectSpec("actuator_lag", 0.005, 0.03, doc="motor current/torque lag"),
        EffectSpec(
            "input_delay",
            0.0,
            0.0,
            choices=(0.01, 0.02, 0.03),
            doc="transport delay of 1-3 loop samples",
        ),
        EffectSpec(
            "roll_viscous_damping",
            1.0,
            4.0,
            doc="roll damping (air, treadmill belt), outside the library",
        ),
        EffectSpec(
            "roll_stiffness", 20.0, 60.0, doc="roll spring of a tether/support, outside the library"
        ),
    )  # fmt: skip
}
LIBRARY_EFFECTS = tuple(k for k, e in EFFECTS.items() if e.in_library)
OUTSIDE_EFFECTS = tuple(k for k, e in EFFECTS.items() if not e.in_library)


@dataclass(frozen=True)
class TrialSpec:
    """Everything that defines one trial (JSON-friendly).

    Attributes
    ----------
    index : int
        Trial number.
    seed : int
        Seed of the simulated decays of the fit windows (``seed + 1`` for the held-out
        ones).
    effect : str
        Name of the hidden effect (a key of ``EFFECTS`` of this module).
    value : float
        Its true value, in the effect's registry unit.
    fit_speeds : (float, float)
        Treadmill speeds [m/s] of the decays the pipeline fits.
    eval_speeds : (float, float)
        Held-out treadmill speeds [m/s] of the evaluation.
    noise : float
        Roll-rate sensor noise standard deviation [rad/s].
    """

    index: int
    seed: int
    effect: str
    value: float
    fit_speeds: tuple[float, float]
    eval_speeds: tuple[float, float]
    noise: float  # roll-rate noise std [rad/s]


MIN_DECAY = 0.3  # required decay rate of the weave root [1/s]


def _stable(name: str, value: float, speeds) -> bool:
    """The sampled linear loop with the effect is stable at every speed and its weave decays
    faster than MIN_DECAY (a free decay must be visible within the 1 s window).

    An unstable combination (e.g. a 40 ms delay at 3.5 m/s) cannot be logged: the bicycle
    falls or oscillates.
    """

    m = ExperimentModel(effects={name: value})
    for v in speeds:
        vs = SPEED_CALIBRATION[0] * v + SPEED_CALIBRATION[1]
        if m.eigenvalues(vs)[0].real >= 0 or m.weave(vs).real >= -MIN_DECAY:
            return False
    return True


def _speeds(
    rng: np.random.Generator, name: str, value: float, k: int = 4, gap: float = 0.5
) -> list[float]:
    for _ in range(1000):
        v = np.sort(rng.uniform(*SPEED_RANGE, size=k))
        if np.all(np.diff(v) >= gap) and _stable(name, value, v):
            return [float(x) for x in rng.permutation(v)]
    raise RuntimeError(f"no stable speeds for {name}={value}")  # pragma: no cover


def draw_trials(n: int, seed: int = 0, effects: tuple[str, ...] | None = None) -> list[TrialSpec]:
    """``n`` trials; effects cycle through ``effects`` (stratified), all else random.

    Trial i depends only on (seed, i): its generator is ``SeedSequence(seed).spawn(n)[i]``
    without the count mattering (``spawn_key=(i,)``), so a larger grid extends a smaller one.

    Parameters
    ----------
    n : int
        Number of trials.
    seed : int, optional
        Grid seed.
    effects : tuple of str, optional
        Names of :data:`EFFECTS` (default all).

    Returns
    -------
    list of TrialSpec
        Trials 0..n-1 with their effect, value [effect unit], fit and held-out speeds
        [m/s], roll-rate noise [rad/s] and simulation seed.

    Raises
    ------
    ValueError
        If ``n`` is not a positive integer, ``seed`` not a non-negative integer, or an
        effect name is unknown.
    """
    if int(n) != n or n < 1:
        raise ValueError(f"number of trials must be a positive integer, got {n!r}")
    if int(seed) != seed or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    names = tuple(effects) if effects else tuple(EFFECTS)
    bad = [e for e in names if e not in EFFECTS]
    if bad:
        raise ValueError(f"unknown effects {bad}; choose from {list(EFFECTS)}")
    out = []
    for i in range(int(n)):
        rng = np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(i,)))
        name = names[i % len(names)]
        value = EFFECTS[name].draw(rng)
        v = _speeds(rng, name, value)
        noise = float(rng.uniform(0.005, 0.015))
        sub_seed = int(rng.integers(2**31))
        out.append(TrialSpec(i, sub_seed, name, value, (v[0], v[1]), (v[2], v[3]), noise))
    return out


def _sensors(noise: float):
    return Sensors(
        {
            "v": Channel(scale=SPEED_CALIBRATION[0], bias=SPEED_CALIBRATION[1]),
            "phi": Channel(std=noise / 5),
            "phidot": Channel(std=noise),
            "delta": Channel(std=3e-4, step=STEER_STEP),
            "deltadot": Channel(std=noise, step=STEER_STEP / DT),
        }
    )


def decay_windows(
    effects: list, speeds, per_speed: int, noise: float, seed: int, label: str = "trial"
):
    """Free decays of the nonlinear plant with ``effects`` as experiment-model windows.

    Returns ``bikeid.dataset.windows.Window`` objects (measured signals, sensor speed,
    zero command history: the loop starts with the push).

    Parameters
    ----------
    effects : list
        :mod:`bikeid.sim.effects` objects injected into the plant.
    speeds : iterable of float
        Treadmill speeds [m/s].
    per_speed : int
        Decays per speed.
    noise : float
        Roll-rate noise std [rad/s].
    seed : int
        Generator seed.
    label : str, optional
        File-name prefix.

    Returns
    -------
    list of Window
        ``len(speeds) * per_speed`` windows of :data:`N_SAMPLES` samples (1 s): measured
        roll and steer angles [rad] and rates [rad/s], sensor speed [m/s], zero external
        torque.
    """

    p = steer_by_wire()
    rng = np.random.default_rng(seed)
    out = []
    for v in speeds:
        for j in range(per_speed):
            sgn = rng.choice([-1.0, 1.0])
            init = {  # as the logs' window starts: steer opposite to the roll rate
                "phi": float(rng.normal(0.0, 0.01)),
                "delta": float(-sgn * rng.uniform(0.0, DELTA0 / v)),
                "phidot": float(sgn * rng.uniform(0.35, 0.95)),
                "deltadot": float(sgn * rng.uniform(0.4, 1.5)),
            }
            sseed = int(rng.integers(2**31))
            for _ in range(4):
                run = simulate_run(
                    p, SteerIntoLean(), float(v), duration=N_SAMPLES * DT, substeps=SUBSTEPS,
                    sensors=_sensors(noise), effects=effects, seed=sseed, initial=init,
                )  # fmt: skip
                if run.meta["fell_at"] is None and run.n >= N_SAMPLES:
                    break
                init = {k: 0.7 * x for k, x in init.items()}  # a gentler push
            else:
                raise RuntimeError(f"trial plant fell at {v} m/s with {effects}")
            sl = slice(0, N_SAMPLES)
            z = np.zeros(N_SAMPLES)
            out.append(
                Window(
                    file=f"{label}_{v:.2f}mps",
                    speed=float(v),
                    start=j * N_SAMPLES,
                    phi=run["phi"][sl].copy(),
                    delta=run["delta"][sl].copy(),
                    phidot=run["phidot"][sl].copy(),
                    deltadot=run["deltadot"][sl].copy(),
                    v_sensor=run["v"][sl].copy(),
                    T_ext=z,
                    hist=np.zeros(20),
                )  # fmt: skip
            )
    return out


def run_trial(
    spec: TrialSpec,
    max_effects: int = 2,
    nonlinear: bool = True,
    weave_weight="auto",
    **select_kw,
) -> dict:
    """Simulate, identify (not told), evaluate on held-out speeds; returns a JSON-able dict.

    ``nonlinear``: the pipeline's nominal model is the nonlinear Whipple model
    (:func:`ident.effects.experiment_model.with_nonlinear_correction`); False uses the linear one.
    ``weave_weight``: as for :func:`bikeid.ident.effects.selection.select_effects` (default
    "auto").

    Parameters
    ----------
    spec : TrialSpec
        The trial.
    max_effects : int, optional
        Selection rounds allowed (:func:`bikeid.ident.effects.selection.select_effects`).
    nonlinear : bool, optional
        Nominal model is the nonlinear plant by defect correction.
    weave_weight : float or "auto", optional
        Weight of the weave-eigenvalue term.
    **select_kw
        Further keywords of :func:`bikeid.ident.effects.selection.select_effects`, e.g.
        ``rule`` (an :class:`bikeid.ident.effects.acceptance.AcceptanceRule`; default: the
        default rule with the stated bicycle taken as exact).

    Returns
    -------
    dict
        The spec, verdict, the ambiguity set of each accepted effect as the selection
        reported it (``ambiguity``), estimate [unit] and its std, errors before/after (NRMSE)
        and the scores.
    """

    t0 = time.perf_counter()
    es = EFFECTS[spec.effect]
    fx = es.sim_effects(spec.value)
    fit = decay_windows(fx, spec.fit_speeds, FIT_PER_SPEED, spec.noise, spec.seed, "fit")
    held = decay_windows(fx, spec.eval_speeds, EVAL_PER_SPEED, spec.noise, spec.seed + 1, "eval")
    nominal = ExperimentModel()
    res = select_effects(
        nominal, fit, max_effects=max_effects, nonlinear=nonlinear, weave_weight=weave_weight,
        **select_kw,
    )  # fmt: skip
    ev = evaluate(nominal, res.model, held, nonlinear=nonlinear)["summary"]
    first = res.verdict[0] if res.verdict else None  # empty: nothing found, nothing said
    est = next((e for e in res.effects if e.name == spec.effect), None)
    value = None if est is None else float(est.value)
    dev = abs(spec.value - es.absent)
    mag_ok = bool(value is not None and abs(value - spec.value) <= 0.2 * dev)
    ratio = ev["error_after"] / ev["error_before"]
    out = {
        **asdict(spec),
        "in_library": es.in_library,
        "verdict": res.verdict,
        "ambiguity": res.ambiguity,
        "estimate": value,
        "estimate_std": None if est is None else float(est.std),
        "explained_fraction": res.explained,
        "error_before": ev["error_before"],
        "error_after": ev["error_after"],
        "error_ratio": ratio,
        "seconds": time.perf_counter() - t0,
    }
    if es.in_library:
        out["ranked_first"] = first == spec.effect
        out["magnitude_ok"] = bool(out["ranked_first"] and mag_ok)
        out["error_halved"] = bool(ratio <= GOAL_RATIO)  # point ratio: one synthetic trial
        out["success"] = bool(out["magnitude_ok"] and out["error_halved"])
    else:
        out["unexplained"] = first == "unexplained"
        out["success"] = out["unexplained"]
    return out


def rate(rows: list[dict], key: str) -> dict:
    """How many rows have ``key`` true, as a rate with its exact 95 % interval.

    Parameters
    ----------
    rows : list of dict
        Trial results.
    key : str
        A boolean field of each row.

    Returns
    -------
    dict
        ``k``, ``n``, ``rate`` (k / n, NaN without rows) and ``ci95`` (Clopper-Pearson,
        :func:`binomial_ci`; NaN without rows).
    """
    k = sum(bool(r[key]) for r in rows)
    n = len(rows)
    lo, hi = binomial_ci(k, n) if n else (float("nan"), float("nan"))
    return {"k": k, "n": n, "rate": k / n if n else float("nan"), "ci95": [lo, hi]}


def summarize(rows: list[dict]) -> dict:
    """Rates over trials (overall and per effect) with 95 % Clopper-Pearson intervals.

    Parameters
    ----------
    rows : list of dict
        :func:`run_trial` results.

    Returns
    -------
    dict
        ``trials``; ``library`` (rates of ranked_first, magnitude_ok, error_halved,
        success) and ``outside`` (rate of unexplained), each ``{k, n, rate, ci95}``;
        ``per_effect`` (rates, names ranked first, median error ratio);
        ``seconds_per_trial`` [s].
    """
    lib = [r for r in rows if r["in_library"]]
    out_ = [r for r in rows if not r["in_library"]]
    summ: dict = {"trials": len(rows)}
    if lib:
        summ["library"] = {k: rate(lib, k) for k in
                           ("ranked_first", "magnitude_ok", "error_halved", "success")}  # fmt: skip
    if out_:
        summ["outside"] = {"unexplained": rate(out_, "unexplained")}
    per = {}
    for name in dict.fromkeys(r["effect"] for r in rows):
        rs = [r for r in rows if r["effect"] == name]
        keys = ("ranked_first", "magnitude_ok", "error_halved") if rs[0]["in_library"] else (
            "unexplained",)  # fmt: skip
        d = {k: rate(rs, k) for k in keys}
        firsts: dict[str, int] = {}
        for r in rs:
            name = r["verdict"][0] if r["verdict"] else "nothing"
            firsts[name] = firsts.get(name, 0) + 1
        d["named_first"] = firsts
        d["median_error_ratio"] = float(np.median([r["error_ratio"] for r in rs]))
        per[name] = d
    summ["per_effect"] = per
    summ["seconds_per_trial"] = float(np.mean([r["seconds"] for r in rows])) if rows else 0.0
    return summ


def format_summary(s: dict) -> str:
    """The rates of :func:`summarize` as text: library and outside-library rates with 95 %
    Clopper-Pearson intervals, then per effect what was named first.

    Parameters
    ----------
    s : dict
        :func:`summarize` output.

    Returns
    -------
    str
        One line per rate, then one per effect (no trailing newline).
    """
    lines = []
    for k, r in s.get("library", {}).items():
        lines.append(f"library {k:14s} {r['k']:3d}/{r['n']:<3d} = {r['rate']:.3f} "
                     f"(95 % CI {r['ci95'][0]:.3f}-{r['ci95'][1]:.3f})")  # fmt: skip
    if "outside" in s:
        r = s["outside"]["unexplained"]
        lines.append(f"outside unexplained    {r['k']:3d}/{r['n']:<3d} = {r['rate']:.3f} "
                     f"(95 % CI {r['ci95'][0]:.3f}-{r['ci95'][1]:.3f})")  # fmt: skip
    for name, d in s["per_effect"].items():
        rates = {k: f"{v['k']}/{v['n']}" for k, v in d.items() if isinstance(v, dict) and "k" in v}
        lines.append(f"  {name:24s} {rates} named first {d['named_first']} "
                     f"median error ratio {d['median_error_ratio']:.2f}")  # fmt: skip
    return "\n".join(lines)


def run_trials(
    n: int,
    seed: int = 0,
    processes: int = 2,
    effects: tuple[str, ...] | None = None,
    nonlinear: bool = True,
    progress=None,
    weave_weight="auto",
    dask: str | None = None,
    **select_kw,
) -> dict:
    """Run a seeded grid of ``n`` trials on a process pool; returns trials and summary.

    ``progress(row)`` is called with each finished trial (in trial order).

    Parameters
    ----------
    n : int
        Number of trials.
    seed : int, optional
        Grid seed (:func:`draw_trials`).
    processes : int, optional
        Worker processes (or the size of a ``dask="local"`` cluster).
    effects : tuple of str, optional
        Effects to cycle through (default all of :data:`EFFECTS`).
    nonlinear : bool, optional
        Nominal model is the nonlinear plant (:func:`run_trial`).
    progress : callable, optional
        Called with each finished trial's dict.
    weave_weight : float or "auto", optional
        Weight of the weave-eigenvalue term.
    dask : str or None, optional
        ``"local"`` or a Dask scheduler address (:mod:`bikeid.experiments.parallel`); the
        trials do not depend on where they run.
    **select_kw
        Acceptance options for every trial (:func:`run_trial`).

    Returns
    -------
    dict
        ``trials`` (list of dict) and ``summary`` (:func:`summarize` plus
        ``wall_seconds`` [s], ``seed``, ``processes``, ``nominal_plant``,
        ``weave_weight``, ``acceptance``: the options given).

    Raises
    ------
    ValueError
        If ``processes`` is not a positive integer or :func:`draw_trials` refuses its
        arguments.
    """
    if int(processes) != processes or processes < 1:
        raise ValueError(f"processes must be a positive integer, got {processes!r}")
    specs = draw_trials(n, seed, effects)
    t0 = time.perf_counter()
    rows = []
    job = partial(run_trial, nonlinear=nonlinear, weave_weight=weave_weight, **select_kw)
    for _, r in imap(job, specs, int(processes), dask, ordered=True):
        rows.append(r)
        if progress:
            progress(r)
    summ = summarize(rows)
    summ["wall_seconds"] = time.perf_counter() - t0
    summ["seed"] = int(seed)
    summ["processes"] = int(processes)
    summ["nominal_plant"] = "nonlinear" if nonlinear else "linear"
    summ["weave_weight"] = weave_weight
    summ["acceptance"] = {k: v.as_dict() if hasattr(v, "as_dict") else v
                          for k, v in select_kw.items()}  # fmt: skip
    return {"trials": rows, "summary": summ}
