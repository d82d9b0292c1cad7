"""Blind effect-selection trials: logs from a generator the pipeline was not built from.

The undeclared-effect trials of :mod:`bikeid.experiments.measured.effect_trials` draw their
data from
bikeid's own nonlinear plant and instrument model, the code the pipeline's experiment model
is built from.  These trials draw steer-by-wire-format free decays from a generator that
shares none of the pipeline's plant code, randomize every nuisance a real log shows, and
score what a user suffers, not only whether the right name comes first.

Generator (per trial, everything drawn from the trial's seed):

- **Plant**: with probability 3/4 the *independent linear* plant: the canonical matrices
  M, C1, K0, K2 of ``bicycleparameters.bicycle.benchmark_par_to_canonical`` (Moore's
  implementation of Meijaard 2007, not :mod:`bikeid.sim.linear`) for the steer-by-wire
  bicycle's parameters *perturbed within their measurement uncertainty* (the data README
  gives none; we use +-5 % on each body's inertia tensor and +-2 mm on the trail, uniform),
  integrated by RK4 with 10 substeps per 10 ms sample, written here.  Otherwise bikeid's
  nonlinear plant (:func:`bikeid.dataset.closed_loop.simulate_run`) with the same perturbed
  parameters.
- **Hidden effect**: one of six library effects, one of two effects outside the library
  (roll viscous damping, roll stiffness), or none.  The linear plant applies them here:
  steer torques -c deltadot, -T_c tanh(deltadot / 0.01 rad/s), -k delta; roll torques
  -c_r phidot, -k_r phi; the command path delay (whole samples) -> gain -> first-order lag.
- **Injected terms** (optional, :func:`with_terms`): any term of the discovery's dictionary
  with a coefficient, added by the independent linear plant as generalized torque to its
  equation (:mod:`bikeid.experiments.measured.injected_terms`).
- **Loop**: the firmware's steer-into-lean law T = 2 (6.5 - v_s) phidot_m on the measured
  roll rate and the sensor speed v_s = 1.066 v - 0.128 (data README), zero-order hold.
- **Push**: an initial state like the logs' window starts, or a half-sine roll-torque pulse
  of 0.1-0.4 s and 15-45 N m (the window starts when the pulse ends; the commands during
  the pulse are the window's history).
- **Instruments** (linear plant): roll-rate noise std 0.004-0.02 rad/s, AR(1) coloured with
  coefficient 0-0.7 (same marginal std), roll angle noise std/5, steer noise 1e-4-5e-4 rad,
  steer encoder of 4096, 8192 or 16384 counts per turn, steer rate from encoder differences or
  a rate sensor (the data README does not say which),
  gyro bias 0-0.005 rad/s plus a random walk of 0-0.003 rad/s per sqrt(s); treadmill speed
  wander of 0-3 % (a 0.2-1 Hz sine) seen by the plant, the sensor speed following it.
  The nonlinear plant uses :mod:`bikeid.dataset.sensors` (white noise, quantization, bias)
  and a constant speed.

Scores per trial (:func:`score`): ``right_first`` (library effect named first, value within
20 % of its deviation from absent), ``extras`` (accepted effects other than the true one),
``false_positive`` (no-effect log: any effect accepted), ``misattributed`` (outside-library
effect: a library effect named first instead of ``unexplained``).  :func:`summarize` gives
the four rates with exact (Clopper-Pearson) 95 % intervals.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import math
import time
from collections import Counter
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
from bicycleparameters.bicycle import benchmark_par_to_canonical
from scipy.signal import lfilter

from bikeid.controllers.steer_into_lean import SteerIntoLean
from bikeid.dataset.closed_loop import simulate_run
from bikeid.dataset.logs import LogOptions
from bikeid.dataset.sbw_logs import SPEED_CALIBRATION
from bikeid.dataset.sensors import Channel, Sensors
from bikeid.dataset.windows import Window
from bikeid.experiments.measured.effect_trials import (
    DELTA0,
    DT,
    EFFECTS,
    EVAL_PER_SPEED,
    FIT_PER_SPEED,
    LIBRARY_EFFECTS,
    N_SAMPLES,
    OUTSIDE_EFFECTS,
    _speeds,
    rate,
)
from bikeid.experiments.measured.injected_terms import InjectedTerms, normalized_terms
from bikeid.ident.effects.diagnostics import evaluate
from bikeid.ident.effects.experiment_model import ExperimentModel
from bikeid.ident.effects.selection import (
    PLANT_UNCERTAIN,
    choose_nominal_plant,
    compare_nominal_plants,
    select_effects,
)
from bikeid.sim.effects import nonlinear_effects
from bikeid.sim.parameters import steer_by_wire

__all__ = [
    "CLOSURE_EFFECTS",
    "INERTIA_UNCERTAINTY",
    "LOG_OUTCOMES",
    "LOG_COLUMNS",
    "TRAIL_UNCERTAINTY",
    "VALUE_TOLERANCE",
    "BlindTrial",
    "Nuisance",
    "CLASSES",
    "band_edge_nuisance",
    "closure_rates",
    "draw_blind_classes",
    "draw_blind_trials",
    "draw_term_trials",
    "generate_windows",
    "nominal_comparison",
    "parse_per_class",
    "linear_plant_matrices",
    "log_import_options",
    "log_signals",
    "rescore_unexplained",
    "run_blind_trial",
    "run_log_trial",
    "score_log_fit",
    "score",
    "summarize_blind",
    "with_terms",
    "write_trial_logs",
]

INERTIA_UNCERTAINTY = 0.05  # relative, every inertia (no published uncertainty: +-5 %)
TRAIL_UNCERTAINTY = 0.002  # m, trail (+-2 mm)
SUBSTEPS = 10
HIST = 20  # commands before a window start kept as its history
CONTROL_GAIN, CONTROL_SPEED = 2.0, 6.5  # T = K (V - v_s) phidot_m (data README)
BODY_INERTIAS = {"R": ("IRxx", "IRyy"), "B": ("IBxx", "IByy", "IBzz", "IBxz"),
                 "H": ("IHxx", "IHyy", "IHzz", "IHxz"), "F": ("IFxx", "IFyy")}  # fmt: skip
INERTIAS = tuple(k for ks in BODY_INERTIAS.values() for k in ks)
TRIAL_EFFECTS = (*EFFECTS, "none")
#: The trial classes of :func:`draw_blind_classes` and the hidden effects each cycles through.
CLASSES = {"library": LIBRARY_EFFECTS, "outside": OUTSIDE_EFFECTS, "none": ("none",)}


@dataclass(frozen=True)
class Nuisance:
    """The randomized nuisances of one blind trial (JSON-friendly).

    Attributes
    ----------
    plant : str
        ``"independent_linear"`` or ``"bikeid_nonlinear"``.
    push : str
        ``"state"`` (initial state) or ``"pulse"`` (half-sine roll-torque pulse).
    pulse_duration, pulse_torque : float
        Pulse length [s] and peak [N m] (pulse pushes).
    noise : float
        Roll-rate white-noise std [rad/s] (marginal std of the coloured noise).
    colour : float
        AR(1) coefficient of the roll-rate and roll-angle noise [-], 0 = white.
    steer_noise : float
        Steer-angle white-noise std before quantization [rad].
    encoder_counts : int
        Steer encoder counts per turn.
    gyro_bias : float
        Constant roll-rate bias [rad/s].
    gyro_walk : float
        Roll-rate bias random-walk intensity [rad/s per sqrt(s)].
    steer_rate : str
        ``"encoder_difference"`` (backward difference of the quantized steer angle) or
        ``"gyro"`` (true rate + roll-rate-sized white noise).
    speed_wander : float
        Relative amplitude of the treadmill speed sine [-].
    wander_freq : float
        Its frequency [Hz].
    inertia_scale : dict
        Scale of each body's inertia tensor (body R, B, H or F -> factor; one factor per
        body keeps the tensor physical).
    trail_shift : float
        Trail perturbation [m].
    """

    plant: str
    push: str
    pulse_duration: float
    pulse_torque: float
    noise: float
    colour: float
    steer_noise: float
    encoder_counts: int
    gyro_bias: float
    gyro_walk: float
    steer_rate: str
    speed_wander: float
    wander_freq: float
    inertia_scale: dict = field(default_factory=dict)
    trail_shift: float = 0.0


@dataclass(frozen=True)
class BlindTrial:
    """One blind trial: hidden effect, speeds, nuisances and seed (JSON-friendly).

    Attributes
    ----------
    index, seed : int
        Trial number and simulation seed.
    effect : str
        Hidden effect (a key of :data:`bikeid.experiments.measured.effect_trials.EFFECTS`) or
        ``"none"``.
    value : float
        Its value [registry unit] (NaN for ``"none"``).
    fit_speeds, eval_speeds : tuple of float
        Treadmill speeds [m/s] of the decays fitted and held out.
    nuisance : Nuisance
        The nuisances.
    terms : dict of str to float
        Dictionary terms the independent linear plant adds on top of the hidden effect,
        coefficient [SI] by ``"equation: term"`` label (default none;
        :mod:`bikeid.experiments.measured.injected_terms`, :func:`with_terms`).
    """

    index: int
    seed: int
    effect: str
    value: float
    fit_speeds: tuple[float, float]
    eval_speeds: tuple[float, float]
    nuisance: Nuisance
    terms: dict = field(default_factory=dict)


def _perturbed(p, nz: Nuisance):
    kw = {k: getattr(p, k) * s for b, s in nz.inertia_scale.items() for k in BODY_INERTIAS[b]}
    return replace(p, c=p.c + nz.trail_shift, **kw)


def linear_plant_matrices(p) -> tuple[np.ndarray, ...]:
    """M, C1, K0, K2 of the bicycle ``p`` from ``bicycleparameters`` (independent code).

    Parameters
    ----------
    p : bikeid.sim.parameters.BicycleParameters
        Meijaard 2007 parameters, SI units.

    Returns
    -------
    tuple of (2, 2) ndarray
        M [kg m^2], C1 [kg m^2/s... per m/s], K0 [per g], K2 [per v^2], in the roll/steer
        order of Meijaard 2007 (positive to the right).
    """

    par = {k: float(getattr(p, k)) for k in ("w", "c", "lam", "g", "rR", "mR", "xB", "zB", "mB",
                                              "xH", "zH", "mH", "rF", "mF", *INERTIAS)}  # fmt: skip
    M, C1, K0, K2 = benchmark_par_to_canonical(par)
    return tuple(np.asarray(x, dtype=float) for x in (M, C1, K0, K2))


def band_edge_nuisance() -> Nuisance:
    """A known case for the nominal's uncertainty: the independent linear plant with every
    body's inertia 5 % off (alternating signs: R +, B -, H +, F -) and the trail 2 mm long,
    the edges of the default band
    (:class:`~bikeid.ident.effects.nominal_uncertainty.NominalUncertainty`); decays from a
    state, white roll-rate noise 8 mrad/s, an 8192-count encoder, a steer-rate gyro, no
    other nuisance.

    Returns
    -------
    Nuisance
    """
    return Nuisance(
        plant="independent_linear", push="state", pulse_duration=0.2, pulse_torque=0.0,
        noise=0.008, colour=0.0, steer_noise=0.0, encoder_counts=8192, gyro_bias=0.0,
        gyro_walk=0.0, steer_rate="gyro", speed_wander=0.0, wander_freq=0.5,
        inertia_scale={"R": 1.05, "B": 0.95, "H": 1.05, "F": 0.95}, trail_shift=0.002,
    )  # fmt: skip


def draw_blind_trials(
    n: int, seed: int = 0, effects: tuple[str, ...] | None = None, first: int = 0
) -> list[BlindTrial]:
    """``n`` blind trials, effects cycling through ``effects`` (default all and "none").

    Trial i depends only on (seed, i), as
    :func:`bikeid.experiments.measured.effect_trials.draw_trials`.

    Parameters
    ----------
    n : int
        Number of trials (>= 1).
    seed : int, optional
        Grid seed (>= 0).
    effects : tuple of str, optional
        Names from :data:`TRIAL_EFFECTS`.
    first : int, optional
        Index of the first trial (>= 0): the trials are ``first .. first + n - 1``, each
        drawn from (seed, its index), the effects cycling from the first name.

    Returns
    -------
    list of BlindTrial

    Raises
    ------
    ValueError
        If ``n`` or ``seed`` is not a valid integer, or an effect name is unknown.
    """
    if int(n) != n or n < 1:
        raise ValueError(f"number of trials must be a positive integer, got {n!r}")
    if int(seed) != seed or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    names = tuple(effects) if effects else TRIAL_EFFECTS
    bad = [e for e in names if e not in TRIAL_EFFECTS]
    if bad:
        raise ValueError(f"unknown effects {bad}; choose from {list(TRIAL_EFFECTS)}")
    if int(first) != first or first < 0:
        raise ValueError(f"first index must be a non-negative integer, got {first!r}")

    out = []
    for i in range(int(first), int(first) + int(n)):
        rng = np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(7, i)))
        name = names[(i - int(first)) % len(names)]
        if name == "none":
            value = float("nan")
            v = _speeds(rng, "command_gain", 1.0)  # stability of the nominal loop
        else:
            value = EFFECTS[name].draw(rng)
            v = _speeds(rng, name, value)
        nz = Nuisance(
            plant="independent_linear" if rng.random() < 0.75 else "bikeid_nonlinear",
            push="state" if rng.random() < 0.5 else "pulse",
            pulse_duration=float(rng.uniform(0.1, 0.4)),
            pulse_torque=float(rng.uniform(15.0, 45.0)),
            noise=float(rng.uniform(0.004, 0.02)),
            colour=float(rng.uniform(0.0, 0.7)),
            steer_noise=float(rng.uniform(1e-4, 5e-4)),
            encoder_counts=int(rng.choice([4096, 8192, 16384])),
            gyro_bias=float(rng.uniform(-0.005, 0.005)),
            gyro_walk=float(rng.uniform(0.0, 0.003)),
            steer_rate="gyro" if rng.random() < 0.5 else "encoder_difference",
            speed_wander=float(rng.uniform(0.0, 0.03)),
            wander_freq=float(rng.uniform(0.2, 1.0)),
            inertia_scale={
                b: float(1 + rng.uniform(-1, 1) * INERTIA_UNCERTAINTY) for b in BODY_INERTIAS
            },  # fmt: skip
            trail_shift=float(rng.uniform(-1, 1) * TRAIL_UNCERTAINTY),
        )
        out.append(BlindTrial(i, int(rng.integers(2**31)), name, value, (v[0], v[1]),
                              (v[2], v[3]), nz))  # fmt: skip
    return out


_NONLINEAR_TERMS = ("injected dictionary terms need the independent linear plant; draw the "
                    "trial with with_terms() or pass plant='independent_linear'")  # fmt: skip


def with_terms(trial: BlindTrial, terms: dict[str, float]) -> BlindTrial:
    """The trial with dictionary terms injected, on the independent linear plant.

    Parameters
    ----------
    trial : BlindTrial
        A drawn trial (its hidden effect, speeds, nuisances and seed are kept).
    terms : dict of str to float
        Coefficient [SI, the term's unit] by term, ``{"steer: v*deltadot": -0.1}``: the
        generalized torque ``coefficient * term`` [N m] added to the term's equation,
        positive adding torque (:mod:`bikeid.experiments.measured.injected_terms`).

    Returns
    -------
    BlindTrial
        A copy with ``terms`` (keyed by the dictionary's labels) and ``nuisance.plant``
        ``"independent_linear"`` (bikeid's nonlinear plant carries no injected term).

    Raises
    ------
    ValueError
        One line naming an unknown term or a coefficient that is not finite.
    """
    nz = replace(trial.nuisance, plant="independent_linear")
    return replace(trial, terms=normalized_terms(terms), nuisance=nz)


def draw_term_trials(n: int, seed: int, terms: dict[str, float] | None,
                     first: int = 0) -> list[BlindTrial]:  # fmt: skip
    """``n`` trials without a hidden library effect, each carrying ``terms``.

    The draws of :func:`draw_blind_trials` with the effect ``"none"`` (speeds, nuisances
    and seeds from (seed, index)), then :func:`with_terms`.

    Parameters
    ----------
    n, seed, first : int
        As :func:`draw_blind_trials`.
    terms : dict of str to float, optional
        The injected terms (none: no-effect trials on the independent linear plant).

    Returns
    -------
    list of BlindTrial
    """
    return [with_terms(t, terms or {}) for t in draw_blind_trials(n, seed, ("none",), first)]


def parse_per_class(text: str) -> dict[str, int]:
    """``--per-class`` text ``CLASS=N,...`` as an ordered dict of class -> count.

    Parameters
    ----------
    text : str
        Comma-separated ``CLASS=N`` pairs; a class is a key of :data:`CLASSES` (``library``,
        ``outside``, ``none``) or one hidden effect of :data:`TRIAL_EFFECTS`; N >= 1.

    Returns
    -------
    dict of str to int
        The counts, in the order given.

    Raises
    ------
    ValueError
        One line naming the bad pair and the allowed classes.
    """
    allowed = [*CLASSES, *(e for e in TRIAL_EFFECTS if e != "none")]
    out: dict[str, int] = {}
    for pair in (p.strip() for p in text.split(",")):
        if not pair:
            continue
        name, sep, num = (x.strip() for x in pair.partition("="))
        if not sep or name not in allowed or not num.isdigit() or int(num) < 1 or name in out:
            raise ValueError(f"--per-class: {pair!r} is not CLASS=N with N >= 1 and a class "
                             f"given once, out of {', '.join(allowed)}")  # fmt: skip
        out[name] = int(num)
    if not out:
        raise ValueError("--per-class: give CLASS=N pairs, e.g. none=24,outside=24")
    return out


def draw_blind_classes(counts: dict[str, int], seed: int = 0) -> list[BlindTrial]:
    """Blind trials of chosen classes: ``counts[c]`` trials of each class ``c`` in turn.

    Each class cycles through its hidden effects (:data:`CLASSES`, or one effect), the
    classes taking consecutive index ranges in the order given, so that every trial has its
    own index and depends only on (seed, index, the counts before it): the draw is
    reproducible by seed, as :func:`draw_blind_trials`.

    Parameters
    ----------
    counts : dict of str to int
        Class (``library``, ``outside``, ``none`` or an effect name) -> number of trials.
    seed : int, optional
        Grid seed (>= 0).

    Returns
    -------
    list of BlindTrial
    """
    out: list[BlindTrial] = []
    for name, k in counts.items():
        effects = CLASSES.get(name, (name,))
        out += draw_blind_trials(k, seed, effects, first=len(out))
    return out


def _ar1(rng: np.random.Generator, n: int, std: float, a: float) -> np.ndarray:
    """AR(1) noise with marginal std ``std`` and coefficient ``a``."""

    e = rng.normal(0.0, std * math.sqrt(1 - a * a), n)
    x = rng.normal(0.0, std)  # stationary start
    return lfilter([1.0], [1.0, -a], e, zi=[a * x])[0]


class _LinearPlant:
    """The independent linear plant with the hidden effect (module docstring) and any
    injected dictionary terms (``terms``: ``{"roll: phidot": -3.0}``, the generalized torque
    ``coefficient * term`` [N m] added to its equation, positive adding torque, as the
    discovery's ``coefficient``; an acceleration term enters the mass matrix:
    :mod:`bikeid.experiments.measured.injected_terms`)."""

    def __init__(self, p, effect: str, value: float, terms: dict | None = None):
        self.M, self.C1, self.K0, self.K2 = linear_plant_matrices(p)
        self.injected = InjectedTerms.from_mapping(terms)
        self.Minv = np.linalg.inv(self.injected.mass_matrix(self.M))
        self.g = float(p.g)
        self._Minv = self.Minv.tolist()
        self._C1 = np.asarray(self.C1, dtype=float).tolist()
        self._gK0 = (self.g * np.asarray(self.K0, dtype=float)).tolist()
        self._K2 = np.asarray(self.K2, dtype=float).tolist()
        fx = {} if effect == "none" else {effect: value}
        self.c = fx.get("steer_viscous_damping", 0.0)
        self.tc = fx.get("steer_coulomb_friction", 0.0)
        self.k = fx.get("steer_stiffness", 0.0)
        self.gain = fx.get("command_gain", 1.0)
        self.tau = fx.get("actuator_lag", 0.0)
        self.delay = int(round(fx.get("input_delay", 0.0) / DT))
        self.cr = fx.get("roll_viscous_damping", 0.0)
        self.kr = fx.get("roll_stiffness", 0.0)

    def rhs(self, x, v: float, T_cmd: float, T_phi: float) -> tuple[float, ...]:
        """x = (phi, delta, phidot, deltadot, T_applied); the derivative as floats.

        Written out in scalars (with the matrix products' order of operations) because this
        loop runs 40 times per sample: numpy's per-call overhead on 2 x 2 arrays made the
        generator ~5x slower with the same numbers.
        """
        q0, q1, qd0, qd1, Ta = x
        T_target = self.gain * T_cmd
        Td = T_target if self.tau == 0.0 else Ta
        t0 = T_phi - self.cr * qd0 - self.kr * q0
        t1 = Td - self.c * qd1 - self.tc * math.tanh(qd1 / 0.01) - self.k * q1
        if self.injected:
            extra = self.injected.torques(v, np.array([q0, q1]), np.array([qd0, qd1]), Td)
            t0, t1 = t0 + float(extra[0]), t1 + float(extra[1])
        (c00, c01), (c10, c11) = self._C1
        (a00, a01), (a10, a11) = self._gK0
        (b00, b01), (b10, b11) = self._K2
        vv = v * v
        f0 = (t0 - (v * c00 * qd0 + v * c01 * qd1)
              - ((a00 + vv * b00) * q0 + (a01 + vv * b01) * q1))  # fmt: skip
        f1 = (t1 - (v * c10 * qd0 + v * c11 * qd1)
              - ((a10 + vv * b10) * q0 + (a11 + vv * b11) * q1))  # fmt: skip
        (m00, m01), (m10, m11) = self._Minv
        dTa = 0.0 if self.tau == 0.0 else (T_target - Ta) / self.tau
        return (qd0, qd1, m00 * f0 + m01 * f1, m10 * f0 + m11 * f1, dTa)

    def rk4(self, x, h: float, v: float, T_cmd: float, T_phi) -> tuple[float, ...]:
        """One classical Runge-Kutta step of length ``h`` [s]; ``T_phi`` [N m] at the
        step's start, middle and end (the command held)."""
        v, T_cmd, T_phi = float(v), float(T_cmd), [float(f) for f in T_phi]
        k1 = self.rhs(x, v, T_cmd, T_phi[0])
        k2 = self.rhs(_step(x, h / 2, k1), v, T_cmd, T_phi[1])
        k3 = self.rhs(_step(x, h / 2, k2), v, T_cmd, T_phi[1])
        k4 = self.rhs(_step(x, h, k3), v, T_cmd, T_phi[2])
        return tuple(a + h / 6 * (b + 2 * c + 2 * d + e)
                     for a, b, c, d, e in zip(x, k1, k2, k3, k4, strict=True))  # fmt: skip


def _step(x: tuple[float, ...], h: float, k: tuple[float, ...]) -> tuple[float, ...]:
    """``x + h k`` on tuples of floats."""
    return tuple(a + h * b for a, b in zip(x, k, strict=True))


def _linear_decay(plant: _LinearPlant, v0: float, nz: Nuisance, init: dict, rng) -> dict:
    """One push + 1 s window on the independent linear plant; measured signals."""
    n_pre = int(round(nz.pulse_duration / DT)) if nz.push == "pulse" else 0
    n_all = HIST + n_pre + N_SAMPLES
    t = np.arange(n_all) * DT
    phase = rng.uniform(0, 2 * math.pi)
    v_true = v0 * (1 + nz.speed_wander * np.sin(2 * math.pi * nz.wander_freq * t + phase))
    x = np.zeros(5)
    if nz.push == "state":
        x[:4] = [init["phi"], init["delta"], init["phidot"], init["deltadot"]]
    x = tuple(map(float, x))
    noise_pr = _ar1(rng, n_all, nz.noise, nz.colour)
    noise_phi = _ar1(rng, n_all, nz.noise / 5, nz.colour)
    walk = nz.gyro_bias + np.cumsum(rng.normal(0.0, nz.gyro_walk * math.sqrt(DT), n_all))
    step = 2 * math.pi / nz.encoder_counts
    cmd = np.zeros(n_all)
    queue = [0.0] * plant.delay
    meas = {k: np.zeros(n_all) for k in ("phi", "delta", "phidot", "deltadot", "v")}
    h = DT / SUBSTEPS
    prev_enc = None
    rate_noise = rng.normal(0.0, nz.noise, n_all)
    for k in range(n_all):
        live = k >= HIST  # the first HIST samples are upright running: nothing moves
        enc = step * np.round((x[1] + rng.normal(0, nz.steer_noise)) / step)
        meas["delta"][k] = enc
        if nz.steer_rate == "gyro":
            meas["deltadot"][k] = x[3] + rate_noise[k]
        elif prev_enc is None or (nz.push == "state" and k == HIST):  # moving before the push
            meas["deltadot"][k] = (enc - step * np.round((x[1] - x[3] * DT) / step)) / DT
        else:
            meas["deltadot"][k] = (enc - prev_enc) / DT
        prev_enc = enc
        meas["phi"][k] = x[0] + noise_phi[k]
        meas["phidot"][k] = x[2] + noise_pr[k] + walk[k]
        vs = SPEED_CALIBRATION[0] * v_true[k] + SPEED_CALIBRATION[1]
        meas["v"][k] = vs
        cmd[k] = CONTROL_GAIN * (CONTROL_SPEED - vs) * meas["phidot"][k] if live else 0.0
        queue.append(cmd[k])
        T_cmd = queue.pop(0)
        if not live:
            continue
        for j in range(SUBSTEPS):
            tt = (k - HIST) * DT + j * h
            pulse = 0.0
            if nz.push == "pulse" and k < HIST + n_pre:
                pulse = nz.pulse_torque * init["sign"]
                T_phi = [pulse * math.sin(math.pi * (tt + a) / nz.pulse_duration)
                         for a in (0.0, h / 2, h)]  # fmt: skip
            else:
                T_phi = [0.0, 0.0, 0.0]
            x = plant.rk4(x, h, v_true[k], T_cmd, T_phi)
        if not all(map(math.isfinite, x)) or abs(x[0]) > 1.0:
            raise RuntimeError("blind-trial plant fell")
    s = HIST + n_pre
    out = {k: a[s : s + N_SAMPLES].copy() for k, a in meas.items()}
    out["hist"] = cmd[s - HIST : s].copy()
    return out


def _nonlinear_decay(p, effects, v0: float, nz: Nuisance, init: dict, seed: int) -> dict:
    step = 2 * math.pi / nz.encoder_counts
    sensors = Sensors({
        "v": Channel(scale=SPEED_CALIBRATION[0], bias=SPEED_CALIBRATION[1]),
        "phi": Channel(std=nz.noise / 5),
        "phidot": Channel(std=nz.noise, bias=nz.gyro_bias),
        "delta": Channel(std=nz.steer_noise, step=step),
        "deltadot": Channel(std=nz.noise, step=step / DT),
    })  # fmt: skip
    st = {k: init[k] for k in ("phi", "delta", "phidot", "deltadot")}
    run = simulate_run(p, SteerIntoLean(), float(v0), duration=N_SAMPLES * DT, substeps=4,
                       sensors=sensors, effects=effects, seed=seed, initial=st)  # fmt: skip
    if run.meta["fell_at"] is not None or run.n < N_SAMPLES:
        raise RuntimeError("blind-trial plant fell")
    sl = slice(0, N_SAMPLES)
    out = {k: run[k][sl].copy() for k in ("phi", "delta", "phidot", "deltadot", "v")}
    out["hist"] = np.zeros(HIST)
    return out


def generate_windows(trial: BlindTrial, speeds, per_speed: int, seed: int, label: str) -> list:
    """Free decays of the blind generator as experiment-model windows.

    Parameters
    ----------
    trial : BlindTrial
        Hidden effect and nuisances.
    speeds : iterable of float
        Treadmill speeds [m/s].
    per_speed : int
        Decays per speed.
    seed : int
        Generator seed of the decays.
    label : str
        File-name prefix.

    Returns
    -------
    list of bikeid.dataset.windows.Window
        1 s windows: measured angles [rad], rates [rad/s], sensor speed [m/s], zero external
        torque, the commands of the 20 samples before the start [N m].
    """

    nz = trial.nuisance
    p = _perturbed(steer_by_wire(), nz)
    rng = np.random.default_rng(seed)
    lin = None
    fx: list = []
    if nz.plant == "independent_linear":
        lin = _LinearPlant(p, trial.effect, trial.value, trial.terms)
    elif trial.terms:
        raise ValueError(_NONLINEAR_TERMS)
    elif trial.effect != "none":
        fx, _ = nonlinear_effects({trial.effect: trial.value}, 1.0, DT, 0.01)
    out = []
    for v in speeds:
        for j in range(per_speed):
            sgn = float(rng.choice([-1.0, 1.0]))
            init = {"phi": float(rng.normal(0.0, 0.01)),
                    "delta": float(-sgn * rng.uniform(0.0, DELTA0 / v)),
                    "phidot": float(sgn * rng.uniform(0.35, 0.95)),
                    "deltadot": float(sgn * rng.uniform(0.4, 1.5)), "sign": sgn}  # fmt: skip
            sub = int(rng.integers(2**31))
            for _ in range(4):
                try:
                    if lin is not None:
                        d = _linear_decay(lin, float(v), nz, init, np.random.default_rng(sub))
                    else:
                        d = _nonlinear_decay(p, fx, float(v), nz, init, sub)
                    break
                except RuntimeError:
                    init = {k: (0.7 * x if k != "sign" else x) for k, x in init.items()}
            else:
                raise RuntimeError(f"blind-trial plant fell at {v} m/s ({trial.effect})")
            out.append(Window(file=f"{label}_{v:.2f}mps", speed=float(v), start=j * N_SAMPLES,
                              phi=d["phi"], delta=d["delta"], phidot=d["phidot"],
                              deltadot=d["deltadot"], v_sensor=d["v"],
                              T_ext=np.zeros(N_SAMPLES), hist=d["hist"]))  # fmt: skip
    return out


#: The CSV log format of :func:`write_trial_logs`, a lab other than the steer-by-wire one:
#: bikeid signal -> column, the ``--units`` and ``--flip`` that read it back (roll positive
#: to the left, time in ms, angles in degrees, speed in km/h).
LOG_COLUMNS = {"phi": "roll_left_deg", "phidot": "roll_rate_left_dps", "delta": "steer_deg",
               "deltadot": "steer_rate_dps", "v": "speed_kmh", "T_delta": "steer_torque_Nm"}
LOG_UNITS = "t=ms,phi=deg,phidot=deg/s,delta=deg,deltadot=deg/s,v=km/h"
LOG_FLIP = "phi,phidot"
LOG_TIME = "time_ms"
LOG_PUSHES = 8  # pushes per log (one log per speed)
LOG_LEAD, LOG_GAP = 1.5, 4.5  # s of upright running before the first push; s between pushes
#: Roll-torque impulse of the largest push [N m s] (each 0.6-1 x): peak roll rates about
#: 0.4-0.9 rad/s, like the steer-by-wire pushes (window starts 0.35-0.95 rad/s).
LOG_IMPULSE = 10.0
PLANTS = ("independent_linear", "bikeid_nonlinear")


def log_options() -> LogOptions:
    """The :class:`~bikeid.dataset.logs.LogOptions` that read :func:`write_trial_logs`'s CSV
    logs (the Python form of :func:`log_import_options`; the steer-by-wire bicycle checks
    their signs).

    Returns
    -------
    bikeid.dataset.logs.LogOptions
    """
    units = dict(pair.split("=", 1) for pair in LOG_UNITS.split(","))
    return LogOptions(format="csv", time=LOG_TIME, columns=dict(LOG_COLUMNS), units=units,
                      flip=LOG_FLIP, bicycle="steer-by-wire")  # fmt: skip


def log_import_options() -> list[str]:
    """The ``bikeid measured fit`` options that read :func:`write_trial_logs`'s CSV logs.

    Returns
    -------
    list of str
        ``--format csv --time ... --columns ... --units ... --flip ... --bicycle
        steer-by-wire --controller steer-into-lean --gains K=2,V=6.5`` as argument strings.
    """
    cols = ",".join(f"{k}={c}" for k, c in LOG_COLUMNS.items())
    return ["--format", "csv", "--time", LOG_TIME, "--columns", cols, "--units", LOG_UNITS,
            "--flip", LOG_FLIP, "--bicycle", "steer-by-wire", "--controller",
            "steer-into-lean", "--gains", f"K={CONTROL_GAIN:g},V={CONTROL_SPEED:g}"]  # fmt: skip


def _push_plan(nz: Nuisance, pushes: int, rng) -> tuple[list[int], list[float]]:
    """Start samples and signed peak torques [N m] of a log's roll-torque pulses."""
    starts = [int(round((LOG_LEAD + j * LOG_GAP) / DT)) for j in range(pushes)]
    sign = float(rng.choice([-1.0, 1.0]))
    peak = LOG_IMPULSE / (2.0 / math.pi * nz.pulse_duration)  # half-sine of that impulse
    peaks = [sign * (-1) ** j * peak * float(rng.uniform(0.6, 1.0))
             for j in range(pushes)]  # fmt: skip
    return starts, peaks


def _pulse(t: float, starts: list[int], peaks: list[float], dur: float) -> float:
    """The half-sine roll-torque pulses of :func:`_push_plan` at time ``t`` [s] (N m)."""
    for s, a in zip(starts, peaks, strict=True):
        u = t - s * DT
        if 0.0 <= u < dur:
            return a * math.sin(math.pi * u / dur)
    return 0.0


def _linear_log(plant: _LinearPlant, v0: float, nz: Nuisance, pushes: int, scale: float,
                rng) -> dict:  # fmt: skip
    """A continuous log of pushes and free decays on the independent linear plant.

    The loop is T = K (V - v) phidot_m on the logged speed (this lab logs the treadmill's
    true speed); the logged torque is the command, before the hidden delay/gain/lag.
    """
    n_all = int(round((LOG_LEAD + pushes * LOG_GAP) / DT))
    starts, peaks = _push_plan(nz, pushes, rng)
    peaks = [scale * a for a in peaks]
    t = np.arange(n_all) * DT
    v_true = v0 * (1 + nz.speed_wander * np.sin(2 * math.pi * nz.wander_freq * t
                                                 + rng.uniform(0, 2 * math.pi)))  # fmt: skip
    noise_pr = _ar1(rng, n_all, nz.noise, nz.colour)
    noise_phi = _ar1(rng, n_all, nz.noise / 5, nz.colour)
    walk = nz.gyro_bias + np.cumsum(rng.normal(0.0, nz.gyro_walk * math.sqrt(DT), n_all))
    rate_noise = rng.normal(0.0, nz.noise, n_all)
    steer_noise = rng.normal(0.0, nz.steer_noise, n_all)
    step = 2 * math.pi / nz.encoder_counts
    out = {k: np.zeros(n_all) for k in ("phi", "delta", "phidot", "deltadot", "T_delta")}
    out["t"], out["v"] = t, v_true.copy()
    queue = [0.0] * plant.delay
    x = (0.0,) * 5
    h = DT / SUBSTEPS
    prev = 0.0
    for k in range(n_all):
        enc = step * np.round((x[1] + steer_noise[k]) / step)
        out["delta"][k] = enc
        out["deltadot"][k] = x[3] + rate_noise[k] if nz.steer_rate == "gyro" else (enc - prev) / DT
        prev = enc
        out["phi"][k] = x[0] + noise_phi[k]
        out["phidot"][k] = x[2] + noise_pr[k] + walk[k]
        cmd = CONTROL_GAIN * (CONTROL_SPEED - v_true[k]) * out["phidot"][k]
        out["T_delta"][k] = cmd
        queue.append(cmd)
        T_cmd = queue.pop(0)
        for j in range(SUBSTEPS):
            tt = k * DT + j * h
            f = [_pulse(tt + a, starts, peaks, nz.pulse_duration) for a in (0.0, h / 2, h)]
            x = plant.rk4(x, h, v_true[k], T_cmd, f)
        if not all(map(math.isfinite, x)) or abs(x[0]) > 1.0:
            raise RuntimeError("blind-trial plant fell")
    return out


def _nonlinear_log(p, effects, v0: float, nz: Nuisance, pushes: int, scale: float,
                   rng) -> dict:  # fmt: skip
    """A log of pushes and free decays on bikeid's nonlinear plant (constant speed): upright
    running, then each push as an impulsive one, a start state like the steer-by-wire
    windows' (as :func:`generate_windows`), followed by ``LOG_GAP`` s of the closed loop."""
    step = 2 * math.pi / nz.encoder_counts
    sensors = Sensors({
        "phi": Channel(std=nz.noise / 5),
        "phidot": Channel(std=nz.noise, bias=nz.gyro_bias),
        "delta": Channel(std=nz.steer_noise, step=step),
        "deltadot": Channel(std=nz.noise, step=step / DT),
    })  # fmt: skip
    keys = ("phi", "delta", "phidot", "deltadot", "v", "T_delta")
    parts: dict = {k: [] for k in keys}
    sgn = float(rng.choice([-1.0, 1.0]))
    for j in range(pushes + 1):
        if j == 0:
            init, dur = {"phi": 0.0, "delta": 0.0, "phidot": 0.0, "deltadot": 0.0}, LOG_LEAD
        else:
            sgn = -sgn
            init = {"phi": float(rng.normal(0.0, 0.01)),
                    "delta": float(-sgn * rng.uniform(0.0, DELTA0 / v0)),
                    "phidot": float(scale * sgn * rng.uniform(0.35, 0.95)),
                    "deltadot": float(scale * sgn * rng.uniform(0.4, 1.5))}  # fmt: skip
            dur = LOG_GAP
        n = int(round(dur / DT))
        run = simulate_run(p, SteerIntoLean(CONTROL_GAIN, CONTROL_SPEED), float(v0),
                           duration=n * DT, substeps=4, sensors=sensors, effects=effects,
                           seed=int(rng.integers(2**31)), initial=init)  # fmt: skip
        if run.meta["fell_at"] is not None or run.n < n:
            raise RuntimeError("blind-trial plant fell")
        for k in keys:
            parts[k].append(np.asarray(run[k], float)[:n])
    out = {k: np.concatenate(v) for k, v in parts.items()}
    out["t"] = np.arange(out["phi"].size) * DT
    return out


def log_signals(trial: BlindTrial, speed: float, seed: int, plant: str | None = None,
                pushes: int = LOG_PUSHES) -> dict:  # fmt: skip
    """One continuous log of the blind generator: upright running, pushes, free decays.

    ``pushes`` pushes ``LOG_GAP`` s apart after ``LOG_LEAD`` s of upright running, signs
    alternating: on the independent linear plant half-sine roll-torque pulses (the trial's
    duration, an impulse of 0.6-1 x :data:`LOG_IMPULSE`); on bikeid's nonlinear plant
    impulsive pushes (a start state like the steer-by-wire windows'; a lateral-force pulse
    at the rear frame, tried first, gave a roll lobe followed by a larger opposite one that
    the decay detector rejects). The loop is the steer-into-lean law on
    the logged speed; the trial's hidden effect and
    instrument nuisances (module docstring).  A log whose plant falls is redrawn with the
    pulses scaled by 0.7 (up to three times).

    Parameters
    ----------
    trial : BlindTrial
        Hidden effect and nuisances.
    speed : float
        Treadmill speed [m/s].
    seed : int
        Generator seed of this log.
    plant : str, optional
        ``"independent_linear"`` or ``"bikeid_nonlinear"`` (default: the trial's
        ``nuisance.plant``).
    pushes : int, optional
        Number of pushes (>= 1).

    Returns
    -------
    dict of ndarray
        ``t`` [s], ``phi``, ``delta`` [rad], ``phidot``, ``deltadot`` [rad/s], ``v`` [m/s],
        ``T_delta`` (the logged command) [N m], bikeid's signs (roll positive right).

    Raises
    ------
    ValueError
        If ``plant`` is not one of :data:`PLANTS`.
    RuntimeError
        If the plant falls with every pulse scale.
    """
    plant = trial.nuisance.plant if plant is None else plant
    if plant not in PLANTS:
        raise ValueError(f"plant must be one of {', '.join(PLANTS)}, got {plant!r}")
    nz = trial.nuisance
    p = _perturbed(steer_by_wire(), nz)
    scale = 1.0
    for _ in range(4):
        rng = np.random.default_rng(seed)
        try:
            if plant == "independent_linear":
                lin = _LinearPlant(p, trial.effect, trial.value, trial.terms)
                return _linear_log(lin, float(speed), nz, int(pushes), scale, rng)
            if trial.terms:
                raise ValueError(_NONLINEAR_TERMS)
            hidden = {} if trial.effect == "none" else {trial.effect: trial.value}
            fx = nonlinear_effects(hidden, 1.0, DT, 0.01)[0] if hidden else []
            return _nonlinear_log(p, fx, float(speed), nz, int(pushes), scale, rng)
        except RuntimeError:
            scale *= 0.7
    raise RuntimeError(f"blind-trial plant fell at {speed} m/s ({trial.effect})")


def write_trial_logs(trial: BlindTrial, folder, plant: str | None = None,
                     pushes: int = LOG_PUSHES) -> list:  # fmt: skip
    """A blind trial's fit speeds as CSV logs of another lab's format (:data:`LOG_COLUMNS`).

    One log per fit speed, in the order of ``trial.fit_speeds``: time in ms, angles in
    degrees, rates in deg/s, speed in km/h, roll angle and roll rate positive to the
    **left**; read back by ``bikeid measured fit FILE...`` with :func:`log_import_options`.

    Parameters
    ----------
    trial : BlindTrial
        Hidden effect and nuisances.
    folder : str or Path
        Existing folder to write ``trial<index>_<speed>mps.csv`` into.
    plant : str, optional
        The truth's plant (:func:`log_signals`).
    pushes : int, optional
        Pushes per log.

    Returns
    -------
    list of Path
        The files written.
    """

    out = []
    for i, v in enumerate(trial.fit_speeds):
        s = log_signals(trial, v, trial.seed + 10 * i, plant, pushes)
        path = Path(folder) / f"trial{trial.index}_{v:.2f}mps.csv"
        cols = [
            1000.0 * s["t"], -np.degrees(s["phi"]), -np.degrees(s["phidot"]),
            np.degrees(s["delta"]), np.degrees(s["deltadot"]), 3.6 * s["v"], s["T_delta"],
        ]  # fmt: skip
        with open(path, "w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow([LOG_TIME, *LOG_COLUMNS.values()])
            for row in zip(*cols, strict=True):
                w.writerow([f"{row[0]:.1f}", *(repr(float(x)) for x in row[1:])])
        out.append(path)
    return out


def _kind(effect: str) -> str:
    """The class of a hidden effect: "none", "library" or "outside"."""
    if effect == "none":
        return "none"
    return "library" if EFFECTS[effect].in_library else "outside"


def score(trial: BlindTrial, verdict: list[str], estimates: dict[str, float]) -> dict:
    """What a user suffers in one trial (module docstring).

    Parameters
    ----------
    trial : BlindTrial
        The truth.
    verdict : list of str
        The pipeline's verdict (``"unexplained"`` first when it says so).
    estimates : dict
        Accepted effects -> value [registry unit].

    Returns
    -------
    dict
        ``kind`` ("library", "outside" or "none"), ``extras`` (int) and the kind's verdict:
        ``right_first`` (library), ``misattributed`` (outside), ``false_positive`` (none).
    """
    accepted = list(estimates)
    kind = _kind(trial.effect)
    if kind == "none":
        return {"kind": "none", "extras": len(accepted), "false_positive": bool(accepted)}
    es = EFFECTS[trial.effect]
    if kind == "outside":
        return {"kind": "outside", "extras": len(accepted),
                "misattributed": bool(verdict and verdict[0] != "unexplained")}  # fmt: skip
    first = bool(verdict and verdict[0] == trial.effect)
    x = estimates.get(trial.effect)
    band = 0.2 * abs(trial.value - es.absent)
    ok = bool(first and x is not None and abs(x - trial.value) <= band)
    extras = len([n for n in accepted if n != trial.effect])
    return {"kind": "library", "extras": extras, "right_first": ok}


def run_blind_trial(
    trial: BlindTrial,
    nonlinear: bool | str = "auto",
    max_effects: int = 2,
    plant_margin: float | None = None,
    **select_kw,
) -> dict:
    """Generate, select (not told), evaluate on held-out speeds, score.

    Parameters
    ----------
    trial : BlindTrial
        The trial.
    nonlinear : bool or "auto", optional
        Nominal plant of the pipeline: "auto" (default, as ``bikeid measured fit``): the
        linear plant only when its nominal cost on the fit windows is lower by more than
        :data:`bikeid.ident.effects.selection.LINEAR_PLANT_MARGIN`
        (:func:`bikeid.ident.effects.selection.choose_nominal_plant`); True: nonlinear;
        False: linear.
    max_effects : int, optional
        Selection rounds.
    plant_margin : float, optional
        The margin of "auto" (default
        :data:`bikeid.ident.effects.selection.LINEAR_PLANT_MARGIN`; 1 takes whichever plant
        fits better, the "auto" of earlier runs).
    **select_kw
        Further options of :func:`bikeid.ident.effects.selection.select_effects`, e.g.
        ``rule`` (an :class:`bikeid.ident.effects.acceptance.AcceptanceRule`; default: the
        default rule with the stated bicycle taken as exact).

    Returns
    -------
    dict
        The trial, verdict, estimates, held-out errors before/after (NRMSE), score, seconds,
        the nominal costs (``nominal_costs``), the plant used (``nominal_plant``) and why
        (``plant_reason``), the selection's ``evidence`` and round log (``rounds``);
        ``error`` is the pipeline's message when it failed (verdict ``["error"]``, scored as
        not right and not a false positive, and counted by :func:`summarize_blind`).
    """

    t0 = time.perf_counter()
    fit = generate_windows(trial, trial.fit_speeds, FIT_PER_SPEED, trial.seed, "fit")
    held = generate_windows(trial, trial.eval_speeds, EVAL_PER_SPEED, trial.seed + 1, "eval")
    nominal = ExperimentModel()
    plants = compare_nominal_plants(nominal, fit)
    if nonlinear == "auto":
        choice = choose_nominal_plant(plants, *(() if plant_margin is None else (plant_margin,)))
        nonlinear, why = choice["plant"] == "nonlinear", choice["reason"]
    else:
        why = f"{'nonlinear' if nonlinear else 'linear'} plant as asked"
    try:
        res = select_effects(
            nominal, fit, max_effects=max_effects, nonlinear=nonlinear, **select_kw
        )
        ev = evaluate(nominal, res.model, held, nonlinear=nonlinear)["summary"]
    except (ValueError, ArithmeticError) as exc:  # e.g. a candidate's nonlinear run fell
        row = {**asdict(trial), "verdict": ["error"], "estimates": {}, "error": str(exc)}
        row.update(score(trial, ["error"], {}))
        row["seconds"] = time.perf_counter() - t0
        return row
    est = {e.name: float(e.value) for e in res.effects}
    row = {**asdict(trial), "verdict": res.verdict, "estimates": est,
           "error_before": ev["error_before"], "error_after": ev["error_after"],
           "explained_fraction": res.explained, "error": None, "nominal_costs": plants,
           "nominal_plant": "nonlinear" if nonlinear else "linear", "plant_reason": why,
           "evidence": res.evidence, "rounds": res.rounds}  # fmt: skip
    row.update(score(trial, res.verdict, est))
    row["seconds"] = time.perf_counter() - t0
    return row


def nominal_comparison(trial: BlindTrial) -> dict:
    """The nominal plants' costs on a trial's fit decays, without any selection.

    The same decays :func:`run_blind_trial` fits (a fraction of its time), so the ratios of
    many trials calibrate :data:`bikeid.ident.effects.selection.LINEAR_PLANT_MARGIN`.

    Parameters
    ----------
    trial : BlindTrial
        The trial.

    Returns
    -------
    dict
        ``index``, ``effect``, ``kind`` (``library``, ``outside``, ``none``), ``plant`` (the
        truth: ``nuisance.plant``) and, from
        :func:`bikeid.ident.effects.selection.compare_nominal_plants`, ``linear``,
        ``nonlinear`` (summed squared NRMSE) and ``ratio`` (nonlinear / linear).
    """

    fit = generate_windows(trial, trial.fit_speeds, FIT_PER_SPEED, trial.seed, "fit")
    c = compare_nominal_plants(ExperimentModel(), fit)
    return {"index": trial.index, "effect": trial.effect, "kind": _kind(trial.effect),
            "plant": trial.nuisance.plant, "linear": c["linear"], "nonlinear": c["nonlinear"],
            "ratio": c["ratio"]}  # fmt: skip


def rescore_unexplained(rows: list[dict], rule: str, threshold: float) -> list[dict]:
    """The trials rescored with another ``unexplained`` rule, the accepted effects kept.

    The verdict ``unexplained`` is decided after the selection from numbers every trial
    logs (``evidence.unexplained`` of :func:`run_blind_trial`), so the trade-off between
    right answers and misattributions over a rule's threshold is exact without rerunning.

    Parameters
    ----------
    rows : list of dict
        :func:`run_blind_trial` results (with ``evidence``; failed trials are kept as they
        are).
    rule : str
        ``"floor"`` or ``"coloured"`` (unexplained when the explained fraction is below
        ``threshold``) or ``"residual"`` (when the final cost over the residual noise floor
        is above it); see :func:`bikeid.ident.effects.selection.select_effects`.
    threshold : float
        The rule's threshold (dimensionless).

    Returns
    -------
    list of dict
        New rows with the verdict and the scores of :func:`score` recomputed.
    """
    key = {"floor": "explained", "coloured": "explained_coloured",
           "residual": "final_over_residual_floor"}[rule]  # fmt: skip
    out = []
    for r in rows:
        ev = (r.get("evidence") or {}).get("unexplained")
        if r.get("error") or not ev:
            out.append(dict(r))
            continue
        x = ev[key]
        flag = x > threshold if rule == "residual" else x < threshold
        names = [n for n in r["verdict"] if n != "unexplained"]
        verdict = (["unexplained"] if flag or not names else []) + names
        nz = Nuisance(**r["nuisance"])
        value = float("nan") if r["value"] is None else float(r["value"])  # JSON null
        tr = BlindTrial(r["index"], r["seed"], r["effect"], value,
                        tuple(r["fit_speeds"]), tuple(r["eval_speeds"]), nz)  # fmt: skip
        out.append({**r, "verdict": verdict, **score(tr, verdict, r["estimates"])})
    return out


def summarize_blind(rows: list[dict]) -> dict:
    """The four rates of the blind trials with exact 95 % intervals.

    Parameters
    ----------
    rows : list of dict
        :func:`run_blind_trial` results.

    Returns
    -------
    dict
        ``right_first`` (library trials), ``with_extras`` (library trials with >= 1 extra
        effect) and ``mean_extras`` (per library trial, with a normal-approximation 95 %
        interval), ``false_positive`` (no-effect trials), ``misattributed`` (outside trials),
        each ``{k, n, rate, ci95}``; ``pipeline_errors`` (trials the pipeline failed on);
        ``per_plant`` splits the first four by plant.
    """
    lib = [r for r in rows if r["kind"] == "library"]
    none = [r for r in rows if r["kind"] == "none"]
    outside = [r for r in rows if r["kind"] == "outside"]
    ex = np.array([r["extras"] for r in lib], dtype=float)
    half = 1.96 * ex.std(ddof=1) / math.sqrt(len(ex)) if len(ex) > 1 else float("nan")
    s = {
        "trials": len(rows),
        "right_first": rate(lib, "right_first"),
        "with_extras": rate([{"has_extra": r["extras"] > 0} for r in lib], "has_extra"),
        "mean_extras": {
            "mean": float(ex.mean()) if len(ex) else float("nan"),
            "ci95": [float(ex.mean() - half), float(ex.mean() + half)] if len(ex) > 1 else None,
            "n": len(ex),
        },  # fmt: skip
        "false_positive": rate(none, "false_positive"),
        "misattributed": rate(outside, "misattributed"),
        "pipeline_errors": sum(1 for r in rows if r.get("error")),
    }
    per = {}
    for plant in ("independent_linear", "bikeid_nonlinear"):
        rs = [r for r in rows if r["nuisance"]["plant"] == plant]
        per[plant] = {
            "right_first": rate([r for r in rs if r["kind"] == "library"], "right_first"),
            "false_positive": rate([r for r in rs if r["kind"] == "none"], "false_positive"),
            "misattributed": rate([r for r in rs if r["kind"] == "outside"], "misattributed"),
        }
    s["per_plant"] = per
    return s


#: The hidden effects of the closure-rate trials (:func:`run_log_trial`): steer friction
#: (viscous steer damping), an input delay, an actuator gain, an effect outside the library
#: (roll damping) and none.
CLOSURE_EFFECTS = ("steer_viscous_damping", "input_delay", "command_gain",
                   "roll_viscous_damping", "none")  # fmt: skip
#: The outcomes of :func:`score_log_fit`, one per trial.
LOG_OUTCOMES = ("right", "right_in_set", "right_with_extras", "wrong_first", "unexplained",
                "nothing", "plant_uncertain", "refused")
#: A named library effect's value is right within this fraction of the injected value's
#: deviation from absent (the closure's magnitude criterion: 35 %).
VALUE_TOLERANCE = 0.35


def score_log_fit(trial: BlindTrial, model: dict | None) -> dict:
    """The outcome of ``bikeid measured fit`` on a trial's logs, as the closure asks.

    Library effect: outcome ``right`` when the accepted effects are the hidden one alone
    (first, nothing extra, ``unexplained`` not said), and the trial is right when its value
    is also within :data:`VALUE_TOLERANCE` of the injected value's deviation from absent;
    ``right_in_set`` when one effect alone is accepted and the fit reported the hidden one in
    its ambiguity set (the data cannot tell them apart, and the fit said so; reported, not
    counted right: the hidden effect's magnitude is not estimated); outside-library effect:
    right when no effect is accepted and the verdict is ``unexplained`` (evidence only where
    the same generator's no-effect logs stay silent: :func:`closure_rates`); no effect: right
    when nothing is said (no effect and no ``unexplained``).

    Parameters
    ----------
    trial : BlindTrial
        The truth.
    model : dict or None
        The model file ``measured fit`` wrote (``{"model": ..., "results": ...}``), None when
        it refused the logs (too few usable decays).

    Returns
    -------
    dict
        ``kind``, ``outcome`` (one of :data:`LOG_OUTCOMES`), ``right`` (bool), ``verdict``,
        ``effects`` (name -> value), ``value_ok`` (library: the hidden effect's value within
        35 % of its deviation from absent, None otherwise), ``in_set`` (library: the hidden
        effect in the ambiguity set of an accepted effect, as the fit reported it),
        ``named_first`` (library: the hidden effect named first and alone, the strict
        count),
        ``plant`` and ``plant_ratio`` (the nominal plant used, cost ratio nonlinear/linear).
    """
    kind = _kind(trial.effect)
    out = {"kind": kind, "effect": trial.effect, "value": trial.value, "value_ok": None,
           "in_set": None, "named_first": None, "verdict": None,
           "effects": {}, "plant": None, "plant_ratio": None}  # fmt: skip
    if model is None:
        return {**out, "outcome": "refused", "right": False}
    res = model["results"]
    ident = res["identification"]
    eff = dict(model["model"]["effects"])
    verdict = list(ident["verdict"])
    out.update(verdict=verdict, effects=eff, plant=res["plant_choice"]["plant"],
               plant_ratio=res["plant_choice"]["ratio"])
    if verdict == [PLANT_UNCERTAIN]:
        return {**out, "outcome": "plant_uncertain", "right": False}
    names = [n for n in verdict if n != "unexplained"]
    if kind == "library":
        es = EFFECTS[trial.effect]
        x = eff.get(trial.effect)
        out["value_ok"] = bool(x is not None and abs(x - trial.value)
                               <= VALUE_TOLERANCE * abs(trial.value - es.absent))  # fmt: skip
        out["in_set"] = any(trial.effect in s for s in ident.get("ambiguity", {}).values())
    alone = len(names) == 1 and "unexplained" not in verdict
    if not names:
        outcome = "unexplained" if "unexplained" in verdict else "nothing"
    elif names[0] != trial.effect:
        own = ident.get("ambiguity", {}).get(names[0], [])
        outcome = "right_in_set" if alone and trial.effect in own else "wrong_first"
    elif alone:
        outcome = "right"
    else:
        outcome = "right_with_extras"
    if kind == "library":
        out["named_first"] = outcome == "right"
    right = {"library": outcome == "right" and out["value_ok"],
             "outside": outcome == "unexplained", "none": outcome == "nothing"}[kind]  # fmt: skip
    return {**out, "outcome": outcome, "right": right}


def closure_rates(rows: list[dict]) -> dict:
    """The closure's rates over :func:`score_log_fit` rows of one generator and format.

    Per hidden effect, the right answers with their exact 95 % interval
    (:func:`bikeid.experiments.measured.effect_trials.rate`) and the outcomes.  An
    outside-library effect's ``unexplained`` is evidence only if ``unexplained`` is not also
    what the pipeline says without any effect: it is counted right only when every no-effect
    log among ``rows`` said nothing (``silent_none``); otherwise, or with no no-effect log
    among ``rows``, the outside effects' right count is 0 and ``unexplained_is_evidence`` is
    False.  ``all`` pools every row under the same rule.

    Parameters
    ----------
    rows : list of dict
        :func:`run_log_trial` rows (``effect``, ``kind``, ``outcome``, ``right``), all from
        one generator and one format.

    Returns
    -------
    dict
        Per effect and ``all``: ``right`` (k), ``n``, ``ci95``, ``outcomes`` (counts); a
        library effect adds ``named_first`` and ``value_ok`` (counts); and the top-level
        ``silent_none`` (k/n of no-effect logs that said nothing) and
        ``unexplained_is_evidence``.
    """
    none = [r for r in rows if r["kind"] == "none"]
    evidence = bool(none) and all(r["outcome"] == "nothing" for r in none)
    scored = [{**r, "right": bool(r["right"]) and (r["kind"] != "outside" or evidence)}
              for r in rows]  # fmt: skip

    def counts(rs):
        k = rate(rs, "right")
        return {"right": k["k"], "n": k["n"], "ci95": k["ci95"],
                "outcomes": dict(Counter(r["outcome"] for r in rs))}  # fmt: skip

    out: dict = {}
    for eff in dict.fromkeys(r["effect"] for r in scored):
        rs = [r for r in scored if r["effect"] == eff]
        out[eff] = counts(rs)
        if rs[0]["kind"] == "library":
            out[eff]["named_first"] = sum(bool(r["named_first"]) for r in rs)
            out[eff]["value_ok"] = sum(bool(r["value_ok"]) for r in rs)
    out["all"] = counts(scored)
    out["silent_none"] = {"k": sum(r["outcome"] == "nothing" for r in none), "n": len(none)}
    out["unexplained_is_evidence"] = evidence
    return out


def run_log_trial(trial: BlindTrial, folder, plant: str | None = None,
                  extra_args: tuple[str, ...] = (), torque_only: bool = False
                  ) -> dict:  # fmt: skip
    """Write a trial's logs as CSV (:func:`write_trial_logs`), fit them with ``bikeid
    measured fit`` and its import options, and score the fit (:func:`score_log_fit`).

    Parameters
    ----------
    trial : BlindTrial
        The truth.
    folder : str or Path
        An existing empty folder for the logs and the model file.
    plant : str, optional
        The truth's plant (:func:`log_signals`; default the trial's).
    extra_args : tuple of str, optional
        More ``measured fit`` options (e.g. ``("--plant", "linear")``).
    torque_only : bool, optional
        Read the logs without the controller law (no ``--controller``/``--gains``): the
        logged torque only, as a stranger's logs come.

    Returns
    -------
    dict
        The trial (index, seed, effect, value, fit speeds, truth plant), the command's exit
        status ``rc`` and its one-line refusal ``error`` (None when it ran), and
        :func:`score_log_fit`'s fields.
    """
    # the command line itself (not a library call), as a user runs it; imported here so
    # that the trials' library stays importable without the CLI package
    from bikeid.experiments.cli import main

    folder = Path(folder)
    files = write_trial_logs(trial, folder, plant)
    out = folder / "model.json"
    err = io.StringIO()
    opts = log_import_options()
    if torque_only:
        opts = opts[: opts.index("--controller")]
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        rc = main(["measured", "fit", *map(str, files), *opts, "--out", str(out), "--quiet",
                   *extra_args])  # fmt: skip
    model = json.loads(out.read_text()) if rc == 0 else None
    row = {"index": trial.index, "seed": trial.seed, "fit_speeds": list(trial.fit_speeds),
           "truth_plant": plant or trial.nuisance.plant, "rc": rc,
           "error": None if rc == 0 else err.getvalue().strip().splitlines()[-1:]}  # fmt: skip
    return {**row, **score_log_fit(trial, model)}
