"""The damped-oscillation fit of a decay (``weave.decay_eigenvalue``) with its compiled
forward-difference Jacobian against scipy's own finite differences (a second
implementation): the same Jacobian and the same fit, bit for bit."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.optimize import least_squares

from bikeid.ident.effects import weave
from bikeid.ident.effects.experiment_model import ExperimentModel
from bikeid.ident.effects.synthetic_decays import synthetic_windows


def _decays():
    """Decays of a stable and an unstable speed, with noise, and one that is mostly not an
    oscillation (two exponentials under a small 40 rad/s ripple)."""
    ws = synthetic_windows(ExperimentModel(), [1.5, 4.5], 2, seed=3)
    t = np.arange(ws[0].n) * 0.01
    flat = replace(ws[0], delta=np.exp(-3.0 * t) + 1e-3 * np.sin(40 * t),
                   phidot=np.exp(-2.0 * t) - 0.5)  # fmt: skip
    return [w for w in ws if w.kind == "decay"] + [flat]


def _scaled(w):
    t = np.arange(w.n) * float(w.meta.get("dt", 0.01))
    return t, np.column_stack([w.delta / np.std(w.delta), w.phidot / np.std(w.phidot)])


def _jacobian(th, t, ys):
    return weave._projected_jacobian(th, t, ys, weave._projected_residuals(th, t, ys))


@pytest.mark.parametrize(
    "th", [(-2.0, 7.5, 1.0), (-3.1, 0.5e1, 0.0), (9.999999999, 39.9999999999, 59.99999999)]
)
def test_compiled_jacobian_is_scipys_forward_difference(th):
    """At interior points and at points within one step of a bound (where scipy turns the
    step back), the compiled Jacobian equals the one ``least_squares(jac='2-point')``
    computes, exactly (both are read from a one-evaluation solve)."""
    lo, hi = weave._LOWER, weave._UPPER
    for w in _decays():
        t, ys = _scaled(w)
        ref = least_squares(weave._projected_residuals, th, bounds=(lo, hi), args=(t, ys),
                            max_nfev=1)  # fmt: skip
        got = least_squares(weave._projected_residuals, th, jac=_jacobian, bounds=(lo, hi),
                            args=(t, ys), max_nfev=1)  # fmt: skip
        np.testing.assert_array_equal(got.jac, ref.jac)


def test_decay_fit_is_bit_identical_to_scipys_finite_differences():
    """decay_eigenvalue's four starts with the compiled Jacobian (taking the residuals scipy
    has just evaluated at the same point instead of evaluating them again) land on the same
    eigenvalue as with scipy's '2-point' Jacobian, to the last bit (tolerance 0: the iterates
    are the same arithmetic), on decays with and without an oscillation."""
    for w in _decays():
        t, ys = _scaled(w)
        best = None
        for om0 in (5.0, 7.5, 10.0, 12.5):
            sol = least_squares(weave._projected_residuals, [-2.0, om0, 1.0],
                                bounds=(weave._LOWER, weave._UPPER), args=(t, ys))  # fmt: skip
            if best is None or sol.cost < best.cost:
                best = sol
        assert weave.decay_eigenvalue(w) == complex(best.x[0], best.x[1])
