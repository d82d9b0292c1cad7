"""Start-up of the quick commands: what they import, and the numpy-only mechanisms that let
them skip ``scipy.optimize`` (~0.4 s to import on the 2-core VM, docs/performance.md).

No timing is asserted (timings are measured by ``benchmarks/bench_startup.py``); these
tests check structure (which modules a command loads) and that the replacements give the
answers of the methods they replace.
"""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.optimize import brentq, linear_sum_assignment

from bikeid.sim import linear

#: Modules the quick commands must not load: each costs 0.05-0.5 s of start-up.
HEAVY = (
    "scipy.optimize",
    "scipy.linalg",
    "control",
    "matplotlib",
    "numba",
    "h5py",
    "skfuzzy",
    "bicycleparameters",
    "importlib.metadata",
)

_PROBE = """
import contextlib, io, json, sys
from bikeid.experiments.cli import main
with contextlib.redirect_stdout(io.StringIO()):
    rc = main(json.loads(sys.argv[1]))
print(json.dumps([rc, sorted(m for m in json.loads(sys.argv[2]) if m in sys.modules)]))
"""


@pytest.mark.parametrize(
    "argv",
    [
        ["--help"],
        ["linearize", "--speed", "5"],
        ["critical-speeds"],
        ["eig", "--speeds", "0:10:0.5"],
    ],
)
def test_quick_commands_do_not_import_heavy_modules(argv):
    """A fresh interpreter runs the command; none of :data:`HEAVY` may be in
    ``sys.modules`` afterwards (structural: the imports that cost start-up time)."""
    out = subprocess.run(
        [sys.executable, "-c", _PROBE, json.dumps(argv), json.dumps(HEAVY)],
        capture_output=True,
        text=True,
        check=True,
        timeout=120,
    )
    rc, loaded = json.loads(out.stdout.strip().splitlines()[-1])
    assert rc == 0, out.stderr
    assert loaded == [], f"{' '.join(argv)} imports {loaded}"


@given(arrays(np.float64, (4, 4), elements=st.floats(0.0, 10.0)))
def test_assignment_cost_equals_scipy(cost):
    """The exhaustive 4x4 assignment reaches the optimum of scipy's Hungarian solver (a
    second method): equal total cost (1e-12: sums of 4 terms below 10, rounding ~1e-15),
    and a permutation."""
    rows, cols = linear._assignment(cost)
    r2, c2 = linear_sum_assignment(cost)
    assert sorted(cols.tolist()) == [0, 1, 2, 3]
    assert cost[rows, cols].sum() == pytest.approx(cost[r2, c2].sum(), abs=1e-12)


def test_critical_speeds_bisection_matches_brentq():
    """The bisection of the critical-speed scan agrees with ``scipy.optimize.brentq`` (the
    former refinement, xtol = rtol = 1e-15) on the same expansion, for every crossing of
    three bicycles; 1e-12 m/s: both stop within a few ulps of the computed sign change
    (observed differences up to 6e-14 m/s over ten shipped bicycles)."""
    from bikeid.sim.parameters import by_name

    for name in ("benchmark", "steer-by-wire", "Fisher"):
        cm = linear.canonical_matrices(by_name(name))
        for f in (linear._discriminant, linear.hurwitz3, linear.constant_term):
            got = linear._roots(f, cm, 30.0)
            grid = np.arange(0.01, 30.0 + 0.005, 0.01)
            vals = f(*linear.quartic_coefficients(cm, grid))
            ks = np.nonzero(vals[:-1] * vals[1:] < 0)[0]
            ref = [
                brentq(
                    lambda v, f=f, cm=cm: float(f(*linear.quartic_coefficients(cm, [v]))[0]),
                    grid[k],
                    grid[k + 1],
                    xtol=1e-15,
                    rtol=1e-15,
                )
                for k in ks
            ]
            assert len(got) == len(ref)
            np.testing.assert_allclose(got, ref, rtol=0, atol=1e-12)
