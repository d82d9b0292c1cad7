"""The consistency study's verdicts where the answer is known, both ways, and its plumbing.

Cheap by construction: the synthetic estimators return the true eigenvalues (exact linear
plant, ``sim.linear``) plus a known error, so the verdict each must get follows from the
error's law; the real estimators run on short records (their slow full-size study is
``benchmarks/bench_consistency.py``, its output in docs/consistency.md).  Tolerances are
derived per test in its docstring.
"""

from __future__ import annotations

import argparse
import hashlib

import numpy as np
import pytest

from bikeid.experiments.testbed.consistency import (
    CONSISTENT,
    hotelling,
    run_consistency,
)
from bikeid.experiments.testbed.estimator import Estimator
from bikeid.experiments.testbed.scenario import Scenario, true_modes
from bikeid.sim.errors import InputError

#: 12 seeds at lengths 1, 4, 16 s (N = 100, 400, 1600): a synthetic study costs < 1 s.
SMALL = Scenario(speeds=(5.0,), durations=(1.0, 4.0, 16.0), seeds=12)
_RUNS: dict = {}
_simulate = Scenario.runs


@pytest.fixture(autouse=True)
def _shared_runs(monkeypatch):
    """The synthetic studies share their simulated runs (read only) within this file."""

    def runs(self, duration, seed):
        key = (self, duration, seed)
        if key not in _RUNS:
            _RUNS[key] = _simulate(self, duration, seed)
        return _RUNS[key]

    monkeypatch.setattr(Scenario, "runs", runs)


def _rng(run) -> np.random.Generator:
    """A generator drawn from the run's data: the same seed gives the same error."""
    return np.random.default_rng(int(hashlib.sha1(run["phi"].tobytes()).hexdigest()[:8], 16))


def _model(lam: np.ndarray):
    """A continuous StateSpace with eigenvalues weave pair, capsize, caster."""
    import control

    w = lam[0]
    A = np.zeros((4, 4))
    A[:2, :2] = [[w.real, w.imag], [-w.imag, w.real]]
    A[2, 2], A[3, 3] = lam[2].real, lam[3].real
    return control.ss(A, np.ones((4, 1)), np.eye(4), np.zeros((4, 1)))


def _synthetic(bias: float, shrink: bool):
    def fit(runs, ctx):
        truth = true_modes(ctx.scenario)
        out = {}
        for r in runs:
            t = truth[r.speed]
            sd = 1.0 / np.sqrt(r.n) * 40 if shrink else 0.05  # 1.0 at N = 1600 for shrink
            e = _rng(r).normal(scale=sd, size=4) * 0.025 + bias
            lam = np.array([t[0] + e[0] + 1j * e[1], 0, t[2] + e[2], t[3] + e[3]])
            out[r.speed] = _model(lam)
        return out

    return fit


def shrinking(runs, ctx):
    """Truth plus white errors of SD 1/sqrt(N) (x0.025 x40 = 1.0 at N = 1600)."""
    return _synthetic(0.0, True)(runs, ctx)


def offset(runs, ctx):
    """As :func:`shrinking` plus 0.05 1/s on every component."""
    return _synthetic(0.05, True)(runs, ctx)


def stuck(runs, ctx):
    """Truth plus errors of SD 0.05 x 0.025 whatever N."""
    return _synthetic(0.0, False)(runs, ctx)


def fixed_wrong(runs, ctx):
    """The truth with every eigenvalue 0.1 1/s to the right, whatever the data."""
    truth = true_modes(ctx.scenario)
    return {r.speed: _model(truth[r.speed] + 0.1) for r in runs}


def raises(runs, ctx):
    raise ValueError("this estimator never answers")


@pytest.mark.parametrize(
    ("fn", "verdict"),
    [(shrinking, CONSISTENT), (offset, "biased"), (fixed_wrong, "biased"),
     (stuck, "inconclusive"), (raises, "refused")],
)  # fmt: skip
def test_verdicts_of_known_estimators(fn, verdict):
    """The verdict follows the error's law.  shrinking: slope -0.5 in truth; the RMSE of 12
    seeds x 4 components has ~10 % relative scatter, so the slope over ln(16) = 2.8 has a
    standard error ~0.05 and the interval's upper end (~-0.4) is 3 SE below -0.25; no bias
    (T^2 rejects a true zero mean with probability 1 % at these fixed seeds; it does not).
    offset: a bias of 0.05 against a scatter of 0.025 at N = 1600 is t = 6.9 over 12
    seeds per component.  fixed_wrong: no scatter, non-zero mean: T^2 infinite.  stuck:
    slope 0 in truth, the interval straddles it: no number of seeds helps.  raises:
    36 of 36 fits refused (> 10 %)."""
    res = run_consistency([Estimator(fn)], SMALL, efficiency=False)["methods"][fn.__name__]
    assert res["verdict"] == verdict, res["verdict_detail"]["reason"]
    if fn is shrinking:
        assert res["slope"] == pytest.approx(-0.5, abs=0.15)
    if fn is stuck:
        assert res["verdict_detail"]["seeds_needed"] is None
        assert abs(res["slope"]) < 0.15
    if fn is fixed_wrong:
        assert res["verdict_detail"]["t2"]["5"] == np.inf
    if verdict != "refused":
        sdb = res["verdict_detail"]["smallest_detectable_bias"]["5"]
        assert set(sdb) == {"weave_re", "weave_im", "capsize", "caster"}


def test_assert_consistent_passes_and_fails():
    """``bikeid.testing.assert_consistent`` passes the estimator the study calls consistent
    and raises AssertionError naming the verdict for the biased one (same fixed seeds as
    :func:`test_verdicts_of_known_estimators`)."""
    from bikeid.testing import assert_consistent

    assert assert_consistent(shrinking, SMALL)["verdict"] == CONSISTENT
    with pytest.raises(AssertionError, match="offset: biased"):
        assert_consistent(offset, SMALL)


def test_too_few_seeds_or_lengths_is_inconclusive():
    """7 seeds (< 8) of the estimator the full study calls consistent: inconclusive, and 8
    seeds named as what settles it; likewise 2 lengths."""
    few = Scenario(speeds=(5.0,), durations=(1.0, 4.0, 16.0), seeds=7)
    res = run_consistency([shrinking], few, efficiency=False)["methods"]["shrinking"]
    assert res["verdict"] == "inconclusive"
    assert res["verdict_detail"]["seeds_needed"] == 8
    short = Scenario(speeds=(5.0,), durations=(1.0, 16.0), seeds=12)
    res = run_consistency([shrinking], short, efficiency=False)["methods"]["shrinking"]
    assert res["verdict"] == "inconclusive" and "2 lengths" in res["verdict_detail"]["reason"]


def test_hotelling_matches_the_one_dimensional_t_test():
    """With one component T^2 = t^2 and its F(1, n-1) p-value is the two-sided t-test's
    (scipy.stats.ttest_1samp, an independent implementation), to 1e-12."""
    from scipy.stats import ttest_1samp

    x = np.random.default_rng(3).normal(0.3, 1.0, size=(15, 1))
    t2, p, _ = hotelling(x)
    ref = ttest_1samp(x[:, 0], 0.0)
    assert t2 == pytest.approx(ref.statistic**2, rel=1e-12)
    assert p == pytest.approx(ref.pvalue, rel=1e-12)


@pytest.mark.slow  # 24 s measured under load 8 on 2 cores (direct fits of 48 runs)
def test_moore_hubbard_least_squares_in_closed_loop_is_biased():
    """Moore & Hubbard's least squares (``direct_ls``) with sensor noise in the loop: the
    noise enters the regressors through the controller, so the estimate converges to the
    wrong value.  On 8 seeds of 3, 6, 12 s at 3 and 5 m/s the RMSE stays ~12 1/s (flat in
    N, measured: slope ~0, against -0.5 for a consistent estimator) and T^2 rejects a zero
    mean error at 0.01/2 (measured p ~1e-4 at 5-20 s), verdict ``biased``; the other way
    round, the synthetic estimators above show the same study calling an unbiased one
    consistent."""
    sc = Scenario(speeds=(3.0, 5.0), durations=(3.0, 6.0, 12.0), seeds=8)
    res = run_consistency(["direct_ls"], sc, efficiency=False)["methods"]["direct_ls"]
    assert res["verdict"] == "biased", res["verdict_detail"]["reason"]
    assert res["slope"] > -0.25


def test_resume_reuses_finished_jobs_with_the_same_numbers(tmp_path):
    """A rerun in the same folder computes nothing and gives the same figures; a new seed
    count computes only the new seeds."""
    first = run_consistency([shrinking], SMALL, out=tmp_path, efficiency=False)
    again = run_consistency([shrinking], SMALL, out=tmp_path, efficiency=False)
    assert first["jobs"] == {"computed": 36, "reused": 0}
    assert again["jobs"] == {"computed": 0, "reused": 36}
    assert again["methods"] == first["methods"]
    more = Scenario(speeds=(5.0,), durations=(1.0, 4.0, 16.0), seeds=13)
    assert (
        run_consistency([shrinking], more, out=tmp_path, efficiency=False)["jobs"]["computed"] == 39
    )  # the scenario is part of the key: a different study is not mixed in


def test_bad_estimators_are_one_line_refusals():
    with pytest.raises(InputError, match="choose one of|give one of"):
        Estimator("subspace")
    with pytest.raises(InputError, match="KEY=VALUE with KEY one of"):
        Estimator("pem:noise=none")
    with pytest.raises(InputError, match="cannot import"):
        Estimator("no_such_module_xyz:fit")
    with pytest.raises(InputError, match="give each once"):
        run_consistency(["pem", "pem"], SMALL)


def test_a_method_added_to_the_table_appears_everywhere(monkeypatch):
    """A toy method added to ``ident.methods.METHODS`` alone is a choice of ``bikeid
    identify --method`` and ``bikeid accuracy --methods``, a row of the accuracy study
    (scored against the truth: it returns the exact model, so its eigenvalues pass with
    zero error) and an estimator of the consistency study, with no other edit."""
    from bikeid.experiments.cli import build_parser
    from bikeid.experiments.testbed import accuracy as acc
    from bikeid.ident import methods
    from bikeid.ident.canonical import theta_from_matrices
    from bikeid.ident.pem import CanonicalModel
    from bikeid.sim.linear import canonical_matrices
    from bikeid.sim.parameters import benchmark

    def toy_fit(runs, settings=None, *, reference=None, **kw):
        p = reference or benchmark()
        at = {}
        for r in runs:
            v = round(r.speed, 6)
            th = theta_from_matrices(canonical_matrices(p), v)
            at[v] = CanonicalModel(theta=th, covariance=np.eye(10) * 1e-6, K=np.zeros((4, 4)),
                                   dt=r.dt, speed=v, noise_covariance=np.eye(4),
                                   outputs=("phi", "delta", "phidot", "deltadot"))  # fmt: skip
        return methods.Identified("toy", settings, tuple(at.values()), tuple(at), ("phi",), at)

    toy = methods.Method(
        "toy", "the truth, for a test", toy_fit, methods.PemSettings, (CanonicalModel,),
        ("toy",), fixed_entries=False, free_entries=False,
    )  # fmt: skip
    monkeypatch.setitem(methods.METHODS, "toy", toy)
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    assert sub.choices["identify"].parse_args(["x.h5", "--method", "toy"]).method == "toy"
    assert sub.choices["accuracy"].parse_args(["--methods", "toy,pem"]).methods == "toy,pem"
    assert "toy" in acc.METHODS
    sc = Scenario(speeds=(5.0,), durations=(2.0, 4.0, 8.0), seeds=2)
    runs = sc.runs(2.0, 0)
    row = acc.identify_controller(runs, benchmark(), methods=["toy"])["methods"]["toy"]
    assert all(m["error"] < 1e-9 for m in row["rows"][0]["modes"].values())
    res = run_consistency(["toy"], sc, efficiency=False)["methods"]["toy"]
    assert res["rmse"] == pytest.approx([0, 0, 0], abs=1e-9)
    assert res["verdict"] == "inconclusive"  # 2 seeds
