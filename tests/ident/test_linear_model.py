"""Every eigenvalue named: the mode-name rule of ident.linear_model against the benchmark.

Published values: Meijaard, Papadopoulos, Ruina & Schwab (2007), "Linearized dynamics
equations for the balance and steer of a bicycle: a benchmark and review", Proc. R. Soc. A
463:1955-1982, Table 2 (eigenvalues against speed; each column one continuous root locus)
and Table 2(a) (v_d = 0.68428307889246 m/s, where the weave pair turns real, a double root
at 3.78290405129320 1/s), as transcribed in whipple-benchmarks.md
section 1.5.  The branch identities between the published rows come from an independent
method: sim.linear's branch tracking on a 0.01 m/s grid (eigenvalues_vs_speed).
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bikeid.dataset.linear_loop import simulate
from bikeid.ident import pem
from bikeid.ident.canonical import theta_from_matrices
from bikeid.ident.linear_model import WEAVE_REAL, mode_names
from bikeid.ident.pem import CanonicalModel
from bikeid.ident.uncertainty import eigenvalue_intervals
from bikeid.sim.linear import canonical_matrices, eigenvalues, eigenvalues_vs_speed
from bikeid.sim.parameters import benchmark, by_name

P = benchmark()
CM = canonical_matrices(P)
V_D = 0.68428307889246  # Meijaard 2007 Table 2(a)
DOUBLE_ROOT = 3.78290405129320  # the weave pair at v_d, Table 2(a)

#: Meijaard 2007 Table 2: v -> (weave pair Re, |Im|, capsize, castering) [1/s].
TABLE2 = {
    1.0: (3.52696170990070, 0.80774027519931, -3.13423125066578, -7.11008014637442),
    2.0: (2.68234517512745, 1.68066296590675, -3.07158645641514, -8.67387984831735),
    3.0: (1.70675605663975, 2.31582447384325, -2.63366137253667, -10.35101467245920),
    4.0: (0.41325331521125, 3.07910818603206, -1.42944427361326, -12.15861426576450),
    5.0: (-0.77534188219585, 4.46486771378823, -0.32286642900409, -14.07838969279820),
    6.0: (-1.52644486584142, 5.87673060598709, -0.00406690076970, -16.08537123098030),
    10.0: (-3.72016840437287, 10.90681139476287, 0.16105338653172, -24.62459635017404),
}
#: Meijaard 2007 Table 2, v = 0: all real, +-3.13164324790656 and +-5.53094371765393.
ZERO_SPEED = (-5.53094371765393, -3.13164324790656, 3.13164324790656, 5.53094371765393)


def _fixed_speed_model(v: float) -> CanonicalModel:
    """A fixed-speed model (it cannot track branches) holding the benchmark at v."""
    return CanonicalModel(theta=theta_from_matrices(CM, v), covariance=1e-6 * np.eye(10),
                          K=np.zeros((4, 4)), dt=0.01, speed=v, noise_covariance=np.eye(4),
                          outputs=("phi", "phidot", "delta", "deltadot"))  # fmt: skip


def _branch(name: str) -> str:
    """The branch a name lies on: the weave's real roots are on the weave branches."""
    return "weave" if name == WEAVE_REAL else name


def test_published_zero_speed_roots_are_named():
    """Table 2, v = 0: the four published roots named from the numbers alone.  Which is
    which is the root loci of Table 2: -3.13 continues to the capsize column (-3.134 at
    1 m/s), -5.53 to the castering column (-7.110), the two positive roots merge at v_d into
    the weave pair (checked against the tracked branches in the next tests).  The model's
    own eigenvalues at v = 0 are the published ones (round-off of the benchmark's matrices
    through the canonical parameters: 1e-9 relative)."""
    names = mode_names(np.array(ZERO_SPEED, dtype=complex))
    assert names == ("caster", "capsize", WEAVE_REAL, WEAVE_REAL)
    ev = _fixed_speed_model(0.0).eigenvalues()
    np.testing.assert_allclose(np.asarray(ev), ZERO_SPEED, rtol=1e-9)
    assert ev.modes == names


@pytest.mark.parametrize("v", sorted(TABLE2))
def test_published_rows_above_v_d_are_named_as_their_columns(v):
    """Table 2, v = 1-10: the published numbers named as the columns they are printed in
    (weave pair, capsize, castering), whatever their order along the real axis; the fixed-
    speed model's eigenvalues equal them (1e-9 relative) and carry the same names."""
    re, im, capsize, caster = TABLE2[v]
    lam = np.sort_complex(np.array([complex(re, -im), complex(re, im), capsize, caster]))
    names = mode_names(lam)
    expected = {complex(re, -im): "weave", complex(re, im): "weave",
                complex(capsize): "capsize", complex(caster): "caster"}  # fmt: skip
    assert names == tuple(expected[z] for z in lam)
    ev = _fixed_speed_model(v).eigenvalues()
    np.testing.assert_allclose(np.asarray(ev), lam, rtol=1e-9)
    assert ev.modes == names


def test_names_follow_the_branches_through_v_d():
    """From 0 to 2 m/s (0.3 and 0.6 m/s included, and v_d +- 1e-3): each tracked branch
    keeps its name at every speed, the weave branches being named weave (real) exactly
    below v_d and weave above it.  At v = 1 the branches are Table 2's columns (1e-9), so
    the names below v_d are the continuations of the published columns.  Just below v_d the
    two weave (real) roots straddle the published double root 3.7829 (their split grows as
    sqrt(v_d - v): 0.05 1/s at 1e-3 m/s, tolerance 0.1); just above it the weave pair's real
    part is within 0.01 of it (it moves by -0.8 1/s per m/s)."""
    speeds = np.union1d(np.round(np.arange(0.0, 2.0001, 0.02), 10),
                        [0.3, 0.6, V_D - 1e-3, V_D + 1e-3, 1.0])  # fmt: skip
    sweep = eigenvalues_vs_speed(P, speeds)
    assert sorted(sweep.labels) == ["capsize", "caster", "weave", "weave"]
    k1 = int(np.flatnonzero(speeds == 1.0)[0])
    re, im, capsize, caster = TABLE2[1.0]
    for j, lab in enumerate(sweep.labels):
        published = {"weave": re, "capsize": capsize, "caster": caster}[lab]
        assert abs(sweep.values[k1, j].real - published) < 1e-9 * abs(published)
        if lab == "weave":
            assert abs(abs(sweep.values[k1, j].imag) - im) < 1e-9
    for k, v in enumerate(speeds):
        ev = _fixed_speed_model(float(v)).eigenvalues()
        for lam, name in zip(np.asarray(ev), ev.modes, strict=True):
            j = int(np.argmin(np.abs(sweep.values[k] - lam)))
            assert abs(sweep.values[k, j] - lam) < 1e-8 * max(1.0, abs(lam))
            assert _branch(name) == sweep.labels[j], (v, lam, name)
            if sweep.labels[j] == "weave":
                assert name == (WEAVE_REAL if v < V_D else "weave"), (v, lam, name)
    below = _fixed_speed_model(V_D - 1e-3).eigenvalues().by_mode()[WEAVE_REAL]
    assert len(below) == 2 and all(abs(z - DOUBLE_ROOT) < 0.1 for z in below)
    assert below[0].real < DOUBLE_ROOT < below[1].real
    above = _fixed_speed_model(V_D + 1e-3).eigenvalues().by_mode()["weave"]
    assert len(above) == 2 and all(abs(z.real - DOUBLE_ROOT) < 0.01 for z in above)


@settings(max_examples=30, deadline=None)
@given(v=st.floats(0.0, 0.684))
def test_fixed_speed_rule_agrees_with_tracking_below_v_d(v):
    """Property: below v_d (four real roots) the order rule of a fixed-speed model and the
    branch tracking of a model over speed (mode_names with the matrices) name every root
    alike on the benchmark."""
    lam = np.sort_complex(eigenvalues(P, v))
    assert not np.any(lam.imag)
    assert mode_names(lam) == mode_names(lam, CM, v)
    assert sorted(mode_names(lam)) == ["capsize", "caster", WEAVE_REAL, WEAVE_REAL]


def test_caster_capsize_pair_is_not_called_the_weave():
    """bicycleparameters' Browser at 0.8 m/s: its caster and capsize roots have merged into
    a complex pair (Re -3.76 1/s) while its weave is still two real roots; the tracked
    branches (sim.linear) say so.  The pair is neither mode alone and stays unnamed, the real
    roots are the weave (real); the pair is never named the weave."""
    with warnings.catch_warnings():  # Browser's IByy is clipped to the triangle inequality
        warnings.simplefilter("ignore", UserWarning)
        p = by_name("Browser")
    sweep = eigenvalues_vs_speed(p, [0.8, 10.0])
    lam = np.sort_complex(eigenvalues(p, 0.8))
    names = mode_names(lam)
    for z, name in zip(lam, names, strict=True):
        label = sweep.labels[int(np.argmin(np.abs(sweep.values[0] - z)))]
        if abs(z.imag) > 0:
            assert label in ("caster", "capsize") and name == ""
        else:
            assert label == "weave" and name == WEAVE_REAL
    assert names == ("", "", WEAVE_REAL, WEAVE_REAL)
    assert mode_names(lam, canonical_matrices(p), 0.8) == names


def test_identified_model_with_four_real_eigenvalues_is_named():
    """A PEM model identified at 0.5 m/s (below v_d: four real roots) from a 30 s dithered
    run of the linear benchmark under a pole-placement loop (poles -2..-6 placed at 0.5 m/s;
    the default PID does not stabilize the loop there): each identified root carries the name
    of the true root it estimates (the true names from the tracked branches, not from the
    rule under test), and its intervals carry the same names.  Observed largest error of the
    identified roots 0.055 1/s; tolerance 0.2 1/s, below half the smallest gap between true
    roots (3.0 1/s)."""
    from bikeid.controllers.pole_placement import PolePlacement

    v = 0.5
    ctrl = PolePlacement(poles=[-2, -3, -4, -5, -6], design_speed=v, p=P)
    run = simulate(P, v, duration=30, seed=1, controller=ctrl, rate_noise=1e-3,
                   angle_noise=1e-4)  # fmt: skip
    model = pem.fit([run])
    ev = model.eigenvalues()
    assert isinstance(model, CanonicalModel) and not np.any(np.asarray(ev).imag)
    sweep = eigenvalues_vs_speed(P, [v, 10.0])
    for lam, name in zip(np.asarray(ev), ev.modes, strict=True):
        j = int(np.argmin(np.abs(sweep.values[0] - lam)))
        assert abs(sweep.values[0, j] - lam) < 0.2
        assert _branch(name) == sweep.labels[j] and name != "weave", (lam, name)
    assert ev.modes == ("caster", "capsize", WEAVE_REAL, WEAVE_REAL)
    assert eigenvalue_intervals(model, method="delta").modes == ev.modes


def test_fixed_speed_model_refuses_critical_speeds_and_names_the_models_that_have_them():
    """Critical speeds belong to a model over speed: one speed's fit refuses them (and the
    sweep over speed) with a message, never a meaningless number or an AttributeError."""
    from bikeid.sim.errors import InputError

    m = _fixed_speed_model(5.0)
    for call in (m.critical_speeds, lambda: m.eigenvalues_vs_speed([4.0, 5.0])):
        with pytest.raises(InputError, match=r"fitted at one speed \(5 m/s\).*model over speed"):
            call()
