"""Evidence of the effect selection: noise floors under coloured noise, the evidence record
and its printed lines, and the verdicts on blind-generator logs whose answer is known."""

import numpy as np
import pytest

from bikeid.ident.effects.fit import noise_floor, residual_noise_floor
from bikeid.ident.effects.selection import evidence_lines

T = np.arange(100) * 0.01
DECAY = 0.5 * np.exp(-T) * np.sin(2 * np.pi * 1.5 * T)  # a weave-like decay [rad/s]


def _ar1(rng: np.random.Generator, a: float, std: float, n: int = 100) -> np.ndarray:
    e, x = np.empty(n), rng.normal(0.0, std)
    for k in range(n):
        x = a * x + rng.normal(0.0, std * np.sqrt(1 - a * a))
        e[k] = x
    return e


@pytest.mark.parametrize("a", [0.0, 0.7])
def test_residual_floor_recovers_coloured_noise(a):
    """The residual floor is the noise variance whatever its colour; the second-difference
    floor is right for white noise and, analytically, (1 - a)(3 - a) / 3 = 0.23 of it for
    AR(1) with a = 0.7 (why the old 'unexplained' verdict failed on coloured noise).
    40 windows of 100 samples: the relative standard error of a variance estimate from
    ~4000 samples with correlation 0.7 is ~ sqrt(2 (1 + a^2) / (1 - a^2) / 4000) ~ 0.04, so
    15 % is about 4 standard errors; the residual carries a smooth model error of 3 % of the
    decay (what a good model leaves)."""
    rng = np.random.default_rng(1)
    std = 0.01
    res = np.concatenate([0.03 * DECAY + _ar1(rng, a, std) for _ in range(40)])
    got = residual_noise_floor(res, [100] * 40) / (res.size * std**2)
    assert got == pytest.approx(1.0, abs=0.15)
    # the second-difference estimate on the same noise, for contrast (analytic ratio)
    sd = np.mean([np.mean(np.diff(res[i : i + 100], 2) ** 2) / 6 for i in range(0, res.size, 100)])
    assert sd / std**2 == pytest.approx((1 - a) * (3 - a) / 3, abs=0.15)


def test_noise_floor_rejects_unknown_method():
    """A misspelt method is an error, not a silent default."""
    with pytest.raises(ValueError, match="noise-floor method"):
        noise_floor([], "colored")


def test_evidence_lines_state_the_numbers():
    """The printed evidence carries the numbers of the record (held-out ratio, windows
    improved, floors, the rule's statistic and the answer)."""
    ev = {
        "min_heldout_gain": 0.02,
        "effects": {"steer_viscous_damping": {
            "round": 1, "fit_gain": 0.65, "heldout_cost_ratio": 0.483, "heldout_gain": 0.517,
            "heldout_windows_improved": 6, "heldout_windows": 6, "t_joint": 21.4}},
        "unexplained": {
            "rule": "residual", "threshold": 2.0, "unexplained": False, "cost_nominal": 9.3,
            "cost_final": 1.3, "floor_second_difference": 0.05, "floor_coloured": 0.17,
            "floor_residual": 0.9, "explained": 0.86, "explained_coloured": 0.87,
            "final_over_residual_floor": 1.44},
    }  # fmt: skip
    lines = evidence_lines(ev)
    assert "held-out cost ratio 0.483" in lines[0] and "6/6" in lines[0]
    assert "1.44" in lines[1] and lines[1].endswith("-> explained")
    ev["nominal_calibration"] = {
        "uncertainty": {"inertia": 0.05, "trail": 0.002}, "at_edge": ["inertia_R"],
        "offsets": {"inertia_R": -0.05, "inertia_B": 0.012, "trail": 0.0015},
        "cost_stated": 9.277, "cost_calibrated": 7.944, "heldout_gain": 0.123}  # fmt: skip
    first = evidence_lines(ev)[0]
    for text in ("inertia_R -5.0 %", "inertia_B +1.2 %", "trail +1.50 mm", "edge: inertia_R",
                 "9.277 -> 7.944", "held-out gain 12.3 %"):  # fmt: skip
        assert text in first, first


def _quiet_trial(effect: str, value: float, seed: int = 11):
    """Blind-generator decays (independent linear plant) with nuisances off but white roll-rate
    noise 0.008 rad/s and a 8192-count steer encoder; the answer is known."""
    from bikeid.experiments.measured.blind_trials import BlindTrial, Nuisance, generate_windows

    nz = Nuisance(
        plant="independent_linear", push="state", pulse_duration=0.2, pulse_torque=0.0,
        noise=0.008, colour=0.0, steer_noise=0.0, encoder_counts=8192, gyro_bias=0.0,
        gyro_walk=0.0, steer_rate="gyro", speed_wander=0.0, wander_freq=0.5,
    )  # fmt: skip
    tr = BlindTrial(0, seed, effect, value, (2.0, 3.5), (2.7, 4.2), nz)
    return generate_windows(tr, tr.fit_speeds, 4, tr.seed, "fit")


@pytest.mark.slow
@pytest.mark.parametrize(
    "effect, value, accepted, unexplained",
    [("steer_viscous_damping", 0.7, "steer_viscous_damping", False),
     ("none", float("nan"), None, None),
     ("roll_viscous_damping", 6.0, "any", True)],
)  # fmt: skip
def test_evidence_verdicts_both_ways(effect, value, accepted, unexplained):
    """Known answers, linear nominal (the plant the data come from): a strong steer damping
    is accepted by the held-out rule (every held-out decay improved, held-out gain far above
    the 0.1 asked) and the residual rule calls the rest noise (final cost / residual floor
    below RESIDUAL_MAX; with white noise and the right model it is ~1 plus the
    start-state error); a no-effect log gets no effect under the held-out rule; an
    outside-library roll damping leaves structure the residual rule calls unexplained,
    whatever library effect absorbs part of it."""
    from bikeid.ident.effects.acceptance import AcceptanceRule
    from bikeid.ident.effects.experiment_model import ExperimentModel
    from bikeid.ident.effects.selection import RESIDUAL_MAX, select_effects

    ws = _quiet_trial(effect, value)
    rule = AcceptanceRule.exact(min_heldout_gain=0.1, min_improved=1.0,
                                unexplained_rule="residual")  # fmt: skip
    res = select_effects(ExperimentModel(), ws, max_effects=2, nonlinear=False, rule=rule)
    ev = res.evidence
    names = [e.name for e in res.effects]
    if accepted is None:
        assert names == [], ev
    elif accepted != "any":
        assert names[0] == accepted, ev
        e = ev["effects"][accepted]
        assert e["heldout_windows_improved"] == e["heldout_windows"]
        assert e["heldout_gain"] > 0.5
    if unexplained is not None:
        u = ev["unexplained"]
        assert u["unexplained"] is unexplained, u
        assert (u["final_over_residual_floor"] > RESIDUAL_MAX) is unexplained
        assert (res.verdict[0] == "unexplained") is unexplained


def test_rescore_unexplained_both_ways():
    """Rescoring a logged trial with another 'unexplained' threshold recomputes the verdict
    and its score from the logged statistic: a right library answer with final cost / residual
    floor 1.4 stays right under threshold 2 and turns into 'unexplained' first (not right
    first) under 1.2; an outside effect answered by a library effect with ratio 3 is
    misattributed under threshold 4 and not under 2."""
    from dataclasses import asdict

    from bikeid.experiments.measured.blind_trials import draw_blind_trials, rescore_unexplained

    tr = {t.effect: t for t in draw_blind_trials(9, 0)}
    lib, out = tr["steer_viscous_damping"], tr["roll_stiffness"]

    def row(t, ratio, est):
        ev = {"unexplained": {"explained": 0.5, "explained_coloured": 0.5,
                              "final_over_residual_floor": ratio}}  # fmt: skip
        return {**asdict(t), "verdict": list(est), "estimates": est, "evidence": ev}

    r1 = row(lib, 1.4, {lib.effect: lib.value})
    assert rescore_unexplained([r1], "residual", 2.0)[0]["right_first"]
    low = rescore_unexplained([r1], "residual", 1.2)[0]
    assert low["verdict"][0] == "unexplained" and not low["right_first"]
    r2 = row(out, 3.0, {"steer_stiffness": 0.4})
    assert rescore_unexplained([r2], "residual", 4.0)[0]["misattributed"]
    assert not rescore_unexplained([r2], "residual", 2.0)[0]["misattributed"]


def test_out_of_fold_costs_known_constructions():
    """Two constructions with known per-decay costs: (1) a selection with no effect and the
    bicycle taken as exact has nothing to refit, so each decay's out-of-fold cost is the
    nominal's own cost on it (window_errors computed here; equal to round-off); (2) decays drawn
    from the linear model with a steer damping of 0.5 N m s/rad, scored with the damping
    refitted on the other half: each decay costs what the truth itself costs on it (the
    noise, the noisy start state and the generator's finer integration), to 5 % in the sum
    and 15 % per decay (one parameter fitted on 4 decays of 200 samples: its error adds
    ~1/800 of the cost; measured 0.3 % in the sum, at most 6 % per decay).  The nominal
    without the damping costs more than 10 times as much on the same decays (the penalty
    the plant comparison needs)."""
    from types import SimpleNamespace

    from bikeid.ident.effects.experiment_model import ExperimentModel, window_errors
    from bikeid.ident.effects.selection import Identification, out_of_fold_costs
    from bikeid.ident.effects.synthetic_decays import synthetic_windows

    truth = ExperimentModel(effects={"steer_viscous_damping": 0.5})
    ws = synthetic_windows(truth, (2.5, 4.5), per_speed=4, noise=0.01, seed=2)

    def ident(model, names):
        return Identification(model=model, effects=[SimpleNamespace(name=n) for n in names],
                              ranking=[], verdict=list(names), cost_nominal=1.0,
                              cost_final=1.0, cost_floor=0.0, explained=0.0,
                              windows=ws)  # fmt: skip

    nominal = ExperimentModel()
    got = out_of_fold_costs(nominal, ident(nominal, []), nonlinear=False)
    own = np.sum(window_errors(ws, nominal.simulate(ws)) ** 2, axis=1)
    np.testing.assert_allclose(got, own, rtol=1e-12)
    fitted = out_of_fold_costs(nominal, ident(truth, ["steer_viscous_damping"]), False)
    at_truth = np.sum(window_errors(ws, truth.simulate(ws)) ** 2, axis=1)
    assert np.sum(fitted) == pytest.approx(np.sum(at_truth), rel=0.05)
    np.testing.assert_allclose(fitted, at_truth, rtol=0.15)
    assert np.sum(own) > 10 * np.sum(fitted)
