"""Fuzzy controller: the fast paths against scikit-fuzzy's own Mamdani evaluation.

Independent source: scikit-fuzzy 0.5's ``ControlSystemSimulation`` on the same design
(MFs, rule table, min/max/centroid), with only its rule firing order cached.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bikeid.controllers.fuzzy import ControlSurface, FuzzyController, mamdani, skfuzzy_simulation

# scikit-fuzzy 0.5 calls np.maximum with a positional out argument (deprecated in numpy 2)
pytestmark = pytest.mark.filterwarnings("ignore:Passing more than 2 positional:DeprecationWarning")

N_TABLE = 301
H = 2.0 / (N_TABLE - 1)


@pytest.fixture(scope="module")
def skf():
    sim = skfuzzy_simulation(301)

    def run(e, ce):
        sim.input["E"] = e
        sim.input["CE"] = ce
        sim.compute()
        return sim.output["U"]

    return run


@pytest.fixture(scope="module")
def points():
    # 300 points, slightly beyond the universe to exercise clipping
    return np.random.default_rng(7).uniform(-1.05, 1.05, (300, 2))


def test_exact_mamdani_matches_skfuzzy_at_nodes(skf):
    """At inputs on the 301-point universe every kink of skfuzzy's sampled MFs is a sample,
    so skfuzzy's centroid is exact there; ours must agree to round-off (1e-12)."""
    g = np.linspace(-1, 1, 301)
    idx = np.random.default_rng(3).integers(0, 301, (100, 2))
    want = np.array([skf(g[i], g[j]) for i, j in idx])
    got = mamdani(g[idx[:, 0]], g[idx[:, 1]])
    assert np.abs(got - want).max() < 1e-12


def test_exact_mamdani_matches_skfuzzy_off_nodes(skf, points):
    """Off the nodes skfuzzy's output set misses kinks between samples (spacing
    h = 1/150): an O(h^2) area error, ~4e-5; we allow 1e-4 of full scale."""
    want = np.array([skf(e, c) for e, c in points])
    got = mamdani(points[:, 0], points[:, 1])
    assert np.abs(got - want).max() < 1e-4


def test_table_lookup_matches_skfuzzy(skf, points):
    """The in-loop bilinear table (301 x 301, h = 1/150) against skfuzzy on 300 points.
    Bilinear interpolation across a kink of the min/max surface errs by at most
    h * (slope jump) / 4; slopes of the normalized surface are within [-3, 3] (MF slope
    3 times an output shift <= 1), so <= h * 6 / 4 = 1e-2, and 5e-3 where (as here) the
    jumps are half of that; plus the 1e-4 off-node skfuzzy error."""
    surf = ControlSurface(N_TABLE)
    want = np.array([skf(e, c) for e, c in points])
    got = np.array([surf(e, c) for e, c in points])
    assert np.abs(got - want).max() < 5e-3 + 1e-4


def test_slope_at_origin_is_three_halves():
    """Analytic: for small x, ZE clipped at 1 - 3x and PS clipped at 3x give the centroid
    1.5 h (3x) / 1 = 1.5 x (h = 1/3); so dU/dE = dU/dCE = 3/2 at the origin."""
    for x in (1e-5, 1e-4):
        assert abs(mamdani(x, 0.0) / x - 1.5) < 10 * x
        assert abs(mamdani(0.0, x) / x - 1.5) < 10 * x


def test_saturation_value_is_eight_ninths():
    """At E = CE = 1 only PB fires fully: centroid of the rising half triangle on
    [2/3, 1] is 2/3 + (2/3)(1/3) = 8/9."""
    assert abs(mamdani(1.0, 1.0) - 8 / 9) < 1e-14
    assert abs(mamdani(5.0, 3.0) - 8 / 9) < 1e-14  # clipped inputs


@settings(max_examples=60, deadline=None)
@given(st.floats(-1, 1), st.floats(-1, 1))
def test_surface_symmetries(e, c):
    """The diagonal table with symmetric MFs gives U(-E,-CE) = -U(E,CE) and
    U(E,CE) = U(CE,E); round-off only."""
    u = mamdani(e, c)
    assert abs(mamdani(-e, -c) + u) < 1e-12
    assert abs(mamdani(c, e) - u) < 1e-12


def test_controller_sign_and_speed_adaptation():
    """Lean right (phi > 0, e < 0) must steer right (T > 0, into the lean); the torque
    scale falls as sqrt(v_a / v) above v_a = 3 m/s."""
    c = FuzzyController()
    y = [2.0, math.radians(1.0), 0, 0, 0.0, 0, 0, 0]
    t_low = c(0.0, y)
    assert t_low > 0
    c.reset()
    y12 = list(y)
    y12[0] = 12.0
    assert abs(c(0.0, y12) / t_low - math.sqrt(3.0 / 12.0)) < 1e-12


def test_exact_and_table_controllers_agree():
    """Same law through both paths: differ only by the table error (< 5e-3 of full scale)."""
    a, b = FuzzyController(), FuzzyController(exact=True)
    rng = np.random.default_rng(0)
    for k in range(50):
        y = [4.0, rng.normal(0, 0.1), 0, 0, rng.normal(0, 0.5), 0, 0, 0]
        ta, tb = a(k * 1e-3, y), b(k * 1e-3, y)
        assert abs(ta - tb) <= 5e-3 * abs(a.torque_scale)


def test_bad_surface_size():
    with pytest.raises(ValueError, match="multiple of 6|% 6"):
        ControlSurface(201)
