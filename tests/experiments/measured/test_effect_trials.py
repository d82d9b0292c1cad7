"""Randomized undeclared-effect trials on the nonlinear plant (experiments.measured.effect_trials).

Budget: the cheap tests take a few seconds; the grid test runs 8 trials on 2 processes (about
75 s of CPU: ~9 s each) and is marked slow.  Rates over more trials are a benchmark
(``benchmarks/bench_effect_trials.py``), not a test.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from bikeid.dataset.windows import Window
from bikeid.experiments.measured.effect_trials import (
    EFFECTS,
    LIBRARY_EFFECTS,
    OUTSIDE_EFFECTS,
    binomial_ci,
    decay_windows,
    draw_trials,
    run_trials,
)
from bikeid.ident.effects.acceptance import AcceptanceRule
from bikeid.ident.effects.experiment_model import (
    COULOMB_EPS,
    DT,
    ExperimentModel,
    window_errors,
    with_nonlinear_correction,
)
from bikeid.sim.effects import nonlinear_effects


def test_draw_trials_seeded_stratified_and_extendable():
    """Same seed -> same grid; effects cycle through the list; a larger grid extends a
    smaller one (trial i depends only on (seed, i)); four speeds in 1.5-4.5 m/s at least
    0.5 m/s apart; magnitudes inside the stated ranges."""
    a, b = draw_trials(14, 3), draw_trials(20, 3)
    assert a == b[:14] and a != draw_trials(14, 4)
    assert [t.effect for t in a] == [list(EFFECTS)[i % len(EFFECTS)] for i in range(14)]
    for t in b:
        v = np.sort(t.fit_speeds + t.eval_speeds)
        assert v[0] >= 1.5 and v[-1] <= 4.5 and np.all(np.diff(v) >= 0.5)
        e = EFFECTS[t.effect]
        if e.choices:
            assert t.value in e.choices
        else:
            dev = abs(t.value - e.absent)
            assert abs(e.low - e.absent) <= dev + 1e-12 <= abs(e.high - e.absent) + 2e-12
    with pytest.raises(ValueError, match="unknown effects"):
        draw_trials(3, 0, ("steer_stiction",))


def test_binomial_ci_exact_limits():
    """Clopper-Pearson closed forms: k = n gives [(alpha/2)^(1/n), 1], k = 0 gives
    [0, 1 - (alpha/2)^(1/n)] (Clopper & Pearson 1934), alpha = 0.05."""
    lo, hi = binomial_ci(20, 20)
    assert lo == pytest.approx(0.025 ** (1 / 20), rel=1e-9) and hi == 1.0
    lo, hi = binomial_ci(0, 14)
    assert lo == 0.0 and hi == pytest.approx(1 - 0.025 ** (1 / 14), rel=1e-9)
    for n in (18, 24):  # the interior against scipy's beta quantiles
        for k in range(n + 1):
            assert binomial_ci(k, n) == pytest.approx(_scipy_clopper_pearson(k, n), rel=1e-9)


@pytest.mark.parametrize("name", ["steer_coulomb_friction", "command_gain", "input_delay",
                                  "actuator_lag", "roll_stiffness", "steer_stiffness"])  # fmt: skip
def test_experiment_model_effects_match_nonlinear_plant_when_small(name):
    """Second method: the linear experiment model with an effect and the nonlinear plant
    with the same sim.effects object agree for a 100x smaller push from the exact initial
    state (the Whipple nonlinearity scales with the amplitude: NRMSE ~3e-5 at 0.01x, ~0 at
    0.001x).  Bound 5e-4 leaves room for RK4 vs exact ZOH and for the Coulomb tanh, which
    the model evaluates once per substep (10 per loop here; with 1 per loop: 1.4e-3) and
    the plant continuously."""
    spec = EFFECTS[name]
    value = spec.choices[1] if spec.choices else 0.5 * (spec.low + spec.high)
    model = ExperimentModel(effects={name: value})
    if name == "steer_coulomb_friction":  # friction level scaled with the push
        model = ExperimentModel(effects={name: value * 0.01})
    fx, eq = nonlinear_effects(model.effects, 3.0, DT, COULOMB_EPS)
    assert set(eq) == {name}
    small = _small_push_windows(fx, scale=0.01)
    err = window_errors(small, model.simulate(small, nsub=10))
    assert err.max() < 5e-4


def _small_push_windows(fx, scale: float):
    from bikeid.controllers.steer_into_lean import SteerIntoLean
    from bikeid.dataset.closed_loop import simulate_run
    from bikeid.dataset.sensors import Channel, Sensors
    from bikeid.sim.parameters import steer_by_wire

    out = []
    for v in (2.0, 4.0):
        init = {"phi": 0.0, "delta": -0.02 * scale, "phidot": 0.6 * scale, "deltadot": scale}
        sens = Sensors({"v": Channel(scale=1.066, bias=-0.128)})
        run = simulate_run(steer_by_wire(), SteerIntoLean(), v, duration=1.0, sensors=sens,
                           effects=fx, initial=init, substeps=4)  # fmt: skip
        sl = slice(0, 100)
        sig = [run[k][sl] for k in ("phi", "delta", "phidot", "deltadot", "v")]
        # exact initial state: the 5-sample quadratic fit of Window.state0 is biased by the
        # kink where a delayed torque switches on (5 % on deltadot for a 10 ms delay)
        x0 = np.array([init[k] for k in ("phi", "delta", "phidot", "deltadot")])
        out.append(_KnownStart("small", v, 0, *sig, np.zeros(100), np.zeros(20), x0=x0))
    return out


@dataclasses.dataclass(frozen=True)
class _KnownStart(Window):
    """A window whose initial state is given (a value too: ``replace`` keeps it)."""

    x0: np.ndarray | None = None

    def state0(self) -> np.ndarray:
        return self.x0


def test_defect_correction_makes_nominal_exact_on_noise_free_plant():
    """With the nonlinear correction the nominal model reproduces noise-free decays of the
    nonlinear plant at 1.5 m/s, where the linear model alone is off by NRMSE > 0.05 at
    these pushes (identity y_lin + (y_nl - y_lin) up to the initial-state fit over 5
    samples: bound 0.01)."""
    ws = decay_windows([], [1.5], 2, 1e-12, seed=5)
    lin = window_errors(ws, ExperimentModel().simulate(ws))
    ws = with_nonlinear_correction(ws)
    nl = window_errors(ws, ExperimentModel().simulate(ws))
    assert lin.max() > 0.05 and nl.max() < 0.01


def _right_with_reported_set(r: dict) -> bool:
    """The first named effect is the injected one, or the injected one is in the ambiguity set
    the selection reported for it (a set counts only when the pipeline reported it)."""
    named = [n for n in r["verdict"] if n != "unexplained"]
    if not named:
        return False
    return named[0] == r["effect"] or r["effect"] in r["ambiguity"].get(named[0], [])


def _scipy_clopper_pearson(k: int, n: int) -> tuple[float, float]:
    """The exact interval from the beta quantiles (the independent form of binomial_ci)."""
    from scipy import stats

    lo = 0.0 if k == 0 else float(stats.beta.ppf(0.025, k, n - k + 1))
    hi = 1.0 if k == n else float(stats.beta.ppf(0.975, k + 1, n - k))
    return lo, hi


@pytest.mark.slow
def test_one_cycle_of_the_grid_by_the_default_rule():
    """The first 8 trials of the documented grid (seed 1: each of the 8 effects once, 2
    processes), by the default rule (family-wise 5 %, Bonferroni, the default nominal
    uncertainty, the offsets refitted with every candidate).  Known both ways on the same
    run: the two outside-library effects (roll damping, roll stiffness) are answered
    ``unexplained`` first; no library trial names first an effect that is neither the
    injected one nor in the ambiguity set reported with it (a miss is unnamed, not wrong);
    the 10 ms input delay is found: named first, or in the set of the actuator lag it
    resembles (seed 1: the lag, named first because it fits the held-out decays better and the
    paired test cannot separate them, ``selection.first_name``; the delay-first rate over
    seeds is a benchmark's); wherever the injected effect is named first, the held-out error
    at least halves and the magnitude is within 20 %.

    The rates over the first 24 trials (each effect at 5 % alone and by the default rule)
    and over 160 are the benchmark's, with Clopper-Pearson intervals, quoted in
    docs/measured-log.md: ``python benchmarks/bench_effect_trials.py --n 24 --seed 1``
    (a 24-trial rate asserted here cost ~7 min of CPU per rule)."""
    out = run_trials(len(EFFECTS), seed=1, processes=2, rule=AcceptanceRule())
    trials = out["trials"]
    assert [r["effect"] for r in trials] == list(EFFECTS)
    assert {r["effect"] for r in trials if not r["in_library"]} == set(OUTSIDE_EFFECTS)
    assert set(LIBRARY_EFFECTS).isdisjoint(OUTSIDE_EFFECTS)
    for r in trials:
        named = [n for n in r["verdict"] if n != "unexplained"]
        if not r["in_library"]:
            assert r["unexplained"] and r["verdict"][0] == "unexplained", r["verdict"]
        elif named:
            assert _right_with_reported_set(r), (r["effect"], r["verdict"], r["ambiguity"])
    right = [r for r in trials if r["in_library"] and r["ranked_first"]]
    assert right and all(r["error_halved"] for r in right)
    # magnitude within 20 %: the grid's goal is 90 % of the right trials (the 24-trial rate
    # is the benchmark's); at this size that allows one miss (seed 1: the 0.59 N m/rad
    # steer spring, named first with its value off by more than 20 %)
    assert sum(not r["magnitude_ok"] for r in right) <= 1, [r["estimate"] for r in right]
    delay = next(r for r in trials if r["effect"] == "input_delay")
    first = delay["verdict"][0]
    assert first == "input_delay" or "input_delay" in delay["ambiguity"].get(first, []), delay


def test_default_rule_misses_are_unnamed_not_wrong():
    """Known both ways on two trials of the documented grid (seed 1, trials 1 and 2: a
    0.24 N m Coulomb friction and a 0.59 N m/rad steer spring, 4 decays per fit speed): each
    effect alone at 5 % names the injected effect first (the spring with ``unexplained``
    before it), the default rule (family-wise 5 %,
    Bonferroni over 37 tests, 3 degrees of freedom) names nothing and says ``unexplained``:
    the price of a stated error rate with 4 fit-half windows is a miss, not a wrong name."""
    from bikeid.experiments.measured.effect_trials import run_trial

    for spec in draw_trials(24, 1)[1:3]:
        default = run_trial(spec)
        assert default["verdict"] == ["unexplained"], default["verdict"]
        alone = run_trial(spec, rule=AcceptanceRule.exact(correction="none"))
        named = [n for n in alone["verdict"] if n != "unexplained"]
        assert named[:1] == [spec.effect], alone["verdict"]
