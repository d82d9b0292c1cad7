"""The default path's eigenvalue intervals: refused where they cannot cover, kept where they do.

The default path (README): the nonlinear benchmark bicycle under the roll PID at 5 m/s with a
1 N m dither, ``pem.fit``, ``ident.uncertainty.eigenvalue_intervals``.  On 30 s records a
fit with a free innovation gain (``noise_model="gain"``, the former default) ends on the
stability boundary of its one-step predictor (spectral radius of Ad - K C within 1e-8 of 1)
in 19 of 20 seeds, and those intervals miss the linearized truth far more often than 5 %
(``benchmarks/bench_default_path_coverage.py``, docs/uncertainty.md); the default fit's
predictor is stable by construction (``benchmarks/bench_predictor.py``).  Independent
sources: the linearized truth (``sim.linear``), the
plant poles exp(lambda dt) for the predictor radius at zero gain, and the exact binomial
bound for the verdicts.
"""

from __future__ import annotations

import numpy as np
import pytest

from bikeid.controllers import UniformDither, make
from bikeid.dataset.closed_loop import simulate_run
from bikeid.experiments.cli import main
from bikeid.experiments.testbed.coverage import DEFAULT_PATH_PARTS, default_path_summary
from bikeid.ident import pem
from bikeid.ident.uncertainty import (
    PREDICTOR_BOUNDARY_TOL,
    check_predictor_interior,
    eigenvalue_intervals,
    predictor_radius,
)
from bikeid.sim import linear
from bikeid.sim.errors import UntrustworthyResult
from bikeid.sim.parameters import benchmark


@pytest.fixture(scope="module")
def short_run():
    """Seed 0 of the default path, 30 s (one of the 19 of 20 boundary fits)."""
    p = benchmark()
    run = simulate_run(p, make("pid", p), speed=5.0, duration=30.0,
                       dither=UniformDither(1.0, seed=0), seed=0)  # fmt: skip
    return p, run


def _contains(ei, p) -> dict[str, bool]:
    """Whether each real-part interval holds the linearized truth (modes paired)."""
    truth = np.sort_complex(linear.eigenvalues(p, 5.0))
    weave = truth[np.argmax(truth.imag)]
    real = sorted(truth[truth.imag == 0].real)  # caster, capsize
    targets = [weave, np.conj(weave), complex(real[1]), complex(real[0])]
    _, col = linear.match_eigenvalues(ei.values, targets, return_index=True)
    out = {}
    for name, i in zip(DEFAULT_PATH_PARTS, (3, 0, 2), strict=True):
        j = col[i]
        out[name] = bool(ei.real_lower[j] <= targets[i].real <= ei.real_upper[j])
    return out


def test_boundary_fit_is_refused_and_would_have_missed(short_run):
    p, run = short_run
    model = pem.fit(run, noise_model="gain")
    # on the boundary: 1 - radius measured 4.6e-9, four orders of magnitude inside the
    # tolerance (the study's boundary fits have 1 - radius <= 8.3e-7, its interior ones
    # >= 6.6e-4)
    assert 1.0 - predictor_radius(model) < 1e-2 * PREDICTOR_BOUNDARY_TOL
    ei = eigenvalue_intervals(model, refuse_boundary=False, refuse_structure=False)
    assert ei.at_predictor_boundary
    # what the refusal protects against: none of the three intervals holds the truth
    assert _contains(ei, p) == dict.fromkeys(DEFAULT_PATH_PARTS, False)
    with pytest.raises(UntrustworthyResult, match="stability boundary.*noise_model='kalman'"):
        eigenvalue_intervals(model)
    with pytest.raises(UntrustworthyResult, match="stable by construction"):
        check_predictor_interior(model)


def test_the_boundary_remedy_followed_covers(short_run):
    """The refusal's remedy (refit with the default noise model) on the same record: the
    Kalman-gain predictor is inside its boundary by construction, and the three intervals
    the boundary fit missed hold the truth (benchmarks/bench_predictor.py counts it over
    all refused records)."""
    p, run = short_run
    model = pem.fit(run, noise_model="kalman")
    assert model.noise_model == "kalman"
    Ad, _, C, K = model.predictor()
    assert np.max(np.abs(np.linalg.eigvals(Ad - K @ C))) < 1.0 - PREDICTOR_BOUNDARY_TOL
    assert _contains(eigenvalue_intervals(model), p) == dict.fromkeys(DEFAULT_PATH_PARTS, True)


def test_interior_fit_passes_and_covers(short_run):
    """The same 30 s record, fitted as output error (the loop has no process noise, so its
    optimal innovation gain is 0): inside the boundary, and every interval covers."""
    p, run = short_run
    model = pem.fit(run, noise_model="none")
    ei = eigenvalue_intervals(model)
    assert not ei.at_predictor_boundary
    assert 1.0 - ei.predictor_radius > 10 * PREDICTOR_BOUNDARY_TOL
    assert _contains(ei, p) == dict.fromkeys(DEFAULT_PATH_PARTS, True)


def test_predictor_radius_at_zero_gain_is_the_plant_pole(short_run):
    """With K = 0 the predictor is the sampled plant: radius = max |exp(lambda dt)| of the
    model's own continuous eigenvalues (a second computation; round-off tolerance)."""
    _, run = short_run
    model = pem.fit(run, noise_model="none")
    assert not np.any(model.K)
    lam = np.linalg.eigvals(model.A)
    expected = float(np.max(np.abs(np.exp(lam * model.dt))))
    assert predictor_radius(model) == pytest.approx(expected, rel=1e-12)


def _rows(n: int, covered: int, boundary: int) -> list[dict]:
    rows = []
    for k in range(n):
        row = {"boundary": k < boundary}
        for name in DEFAULT_PATH_PARTS:
            row.update({f"in_{name}": k >= n - covered, f"est_{name}": float(k),
                        f"se_{name}": 1.0})  # fmt: skip
        rows.append(row)
    return rows


@pytest.mark.parametrize(
    ("covered", "boundary", "verdict", "interior"),
    [
        # 20/20: the Clopper-Pearson interval [0.832, 1] holds 0.95
        (20, 0, "consistent", (20, 20)),
        # 10/20 with the 10 misses on the boundary: [0.272, 0.728] lies below 0.95, while
        # the 10 interior fits cover 10/10
        (10, 10, "too narrow", (10, 10)),
    ],
)
def test_summary_counts_and_verdicts_both_ways(covered, boundary, verdict, interior):
    s = default_path_summary(_rows(20, covered, boundary))
    for name in DEFAULT_PATH_PARTS:
        assert s[name]["all"]["covered"] == covered
        assert s[name]["all"]["verdict"] == verdict
        assert (s[name]["interior"]["covered"], s[name]["interior"]["n"]) == interior
        assert s[name]["interior"]["verdict"] == "consistent"
        # scatter of 0..19 (sd 5.92, closed form sqrt(n (n + 1) / 12)) over a median SE of 1
        assert s[name]["sd_ratio"] == pytest.approx(np.sqrt(20 * 21 / 12), rel=1e-12)
    assert s["boundary"] == boundary


def test_cli_default_path_runs_and_counts(capsys):
    rc = main(["coverage", "--plant", "linear", "--seeds", "2", "--duration", "10"])
    out = capsys.readouterr().out
    assert rc == 0
    assert "default path: benchmark, linear plant" in out
    assert "predictor's stability boundary" in out


def test_identify_withholds_intervals_of_a_boundary_fit(short_run, tmp_path, capsys):
    """``bikeid identify --noise-model gain`` on the 30 s default-path record: the estimate
    is printed, the eigenvalue intervals are withheld with the reason (the free gain ends on
    the predictor's stability boundary); the remedy printed, the Kalman gain
    (``--noise-model kalman``, the default), cannot end there, and its JSON carries the
    intervals."""
    import json

    from bikeid.dataset.store import write_runs

    _, run = short_run
    path = write_runs(tmp_path / "short.h5", [run])
    rc = main(["identify", str(path), "--method", "pem", "--noise-model", "gain", "--json"])
    doc = json.loads(capsys.readouterr().out)
    assert rc == 0
    assert doc["per_speed"][0]["eigenvalues"]  # the estimate stands
    assert doc["per_speed"][0].get("eigenvalue_intervals") is None
    assert any("stability boundary" in n and "--noise-model kalman" in n
               for n in doc["intervals"]["notes"])  # fmt: skip
    rc = main(["identify", str(path), "--method", "pem", "--noise-model", "kalman", "--json"])
    doc = json.loads(capsys.readouterr().out)
    assert rc == 0
    assert doc["per_speed"][0].get("eigenvalue_intervals") is not None
