"""Regenerate the Whipple equations in-process and compare with the committed code.

``scripts/derive_whipple.py`` derives Kane's equations with sympy; ``sim/_whipple_generated.py``
is its committed, numba-compiled output.  Here the symbolic result is evaluated
independently through ``sympy.lambdify`` (numpy) at random states, so a stale or
hand-edited generated file fails.  Tolerance: both evaluate the same expressions in
double precision with different common-subexpression orders, so they differ by
round-off amplified by the conditioning of the terms, ~1e-13 relative; we allow 1e-9.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from bikeid.sim import _whipple_generated as gen
from bikeid.sim.nonlinear import parameter_vector
from bikeid.sim.parameters import benchmark, steer_by_wire

pytestmark = pytest.mark.slow

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "derive_whipple.py"


@pytest.fixture(scope="module")
def fresh():
    spec = importlib.util.spec_from_file_location("derive_whipple", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    assert tuple(mod.PARAMETERS) == tuple(gen.PARAMETERS)
    assert tuple(mod.INPUTS) == tuple(gen.INPUTS)
    return mod.lambdified(mod.derive())


def _close(a, b):
    a, b = np.asarray(a, float), np.asarray(b, float)
    scale = max(1.0, float(np.max(np.abs(b))))
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-9 * scale)


def test_generated_code_matches_fresh_derivation(fresh):
    rng = np.random.default_rng(20070401)
    for params in (benchmark(), steer_by_wire()):
        p = parameter_vector(params, (0.4, -0.8))
        for _ in range(10):
            q4, q7 = rng.uniform(-0.8, 0.8, size=2)
            q5 = params.lam + rng.uniform(-0.1, 0.1)
            u = rng.normal(scale=3.0, size=6)
            r = rng.normal(size=4)
            _close(gen.holonomic(q4, q5, q7, p), fresh["holonomic"](q4, q5, q7, p))
            Ad, Ai = np.empty((3, 3)), np.empty((3, 3))
            gen.velocity_constraint(q4, q5, q7, p, Ad, Ai)
            Ad0, Ai0 = fresh["velocity_constraint"](q4, q5, q7, p)
            _close(Ad, Ad0)
            _close(Ai, Ai0)
            M, f = np.empty((6, 6)), np.empty(6)
            gen.mass_forcing(q4, q5, q7, u, p, r, M, f)
            M0, f0 = fresh["mass_forcing"](q4, q5, q7, u, p, r)
            _close(M, M0)
            _close(f, np.ravel(f0))
            _close(gen.energy(q4, q5, q7, u, p), fresh["energy"](q4, q5, q7, u, p))
            ud = rng.normal(scale=10.0, size=6)
            _close(
                gen.contact_forces(q4, q5, q7, u, ud, p, r),
                fresh["contact_forces"](q4, q5, q7, u, ud, p, r),
            )
            q3 = rng.uniform(-3.0, 3.0)
            mom = np.empty(12)
            gen.momentum(q3, q4, q5, q7, u, p, mom)
            _close(mom, fresh["momentum"](q3, q4, q5, q7, u, p))
