"""The effect laws: the language, the registry's laws, duplicates refused, and the
table-driven plant kernel held to the formula it replaced.

Independent sources: the old hand-written kernel (reproduced below from the code before
the table, Meijaard 2007 sign convention), hand-derived units, and the registry's docs.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bikeid.sim import effects as fx
from bikeid.sim.effect_law import SIGNALS, Law, all_laws, parse_law, same_unit
from bikeid.sim.effect_registry import (
    EFFECTS,
    Effect,
    linear_entry,
    no_law_reason,
    register_effects,
    unregister_effects,
)
from bikeid.sim.effects import nonlinear_effects


def test_every_plant_entry_has_its_law_and_the_others_say_why():
    """Every plant entry carries a law whose unit is the entry's; every entry without a law
    says why in one line."""
    for name, e in EFFECTS.items():
        if e.layer == "plant":
            assert e.law is not None, name
        if e.law is None:
            assert no_law_reason(name), name
        else:
            assert same_unit(e.unit, e.law.unit), name


@pytest.mark.parametrize(
    ("name", "text", "unit", "entry"),
    [  # hand-written from each entry's doc line (registry) and M q'' + C q' + K q = f
        ("steer_viscous_damping", "steer: -c * deltadot", "N m s/rad", "C[steer, delta] += value"),
        ("steer_coulomb_friction", "steer: -c * sign(deltadot)", "N m",
         "f[steer] += -value * sign(deltadot)"),
        ("steer_stiffness", "steer: -c * delta", "N m/rad", "K[steer, delta] += value"),
        ("tire_twist_stiffness", "steer: -c / v * delta", "N m/rad * m/s",
         "K[steer, delta] += value / v"),
        ("tire_scrub_torque", "steer: -c / v * deltadot", "N m s/rad * m/s",
         "C[steer, delta] += value / v"),
        ("steer_torque_bias", "steer: +c", "N m", "f[steer] += +value"),
        ("steer_inertia", "steer: -c * deltaddot", "kg m^2", "M[steer, delta] += value"),
        ("roll_viscous_damping", "roll: -c * phidot", "N m s/rad", "C[roll, phi] += value"),
        ("roll_stiffness", "roll: -c * phi", "N m/rad", "K[roll, phi] += value"),
    ],
)  # fmt: skip
def test_the_registry_laws_by_hand(name, text, unit, entry):
    e = EFFECTS[name]
    assert e.law.text() == text
    assert same_unit(e.unit, unit)
    assert linear_entry(e) == entry


def test_the_language_round_trips_and_units_by_dimension():
    """Every term of the language parses back from its text; units by dimensional analysis:
    N m per unit of signal, times (m/s)^-p (e.g. c in -c v phidot is N m s^2/rad/m); the
    radian counts (a torque is not a stiffness per radian)."""
    laws = all_laws()
    assert len({law.key for law in laws}) == len(laws)
    # 2 equations x (7 signals with 4 speed powers + 3 without) = 62
    assert len(laws) == 2 * (7 * 4 + 3)
    for law in laws:
        assert parse_law(law.text("k")) == law
    assert same_unit(Law("roll", "phidot", 1).unit, "N m s^2/rad/m")
    assert same_unit(Law("steer", "delta", 2).unit, "kg/rad")  # N m s^2/m^2/rad = kg/rad
    assert not same_unit(Law("steer", "delta").unit, "N m")
    assert not same_unit(Law("steer", "deltadot").unit, "N m/rad")


@pytest.mark.parametrize(
    ("text", "problem"),
    [
        ("steer -c * deltadot", "no equation"),
        ("yaw: -c * phi", "unknown equation"),
        ("roll: c * phi", "start the term with its sign"),
        ("roll: -c * omega", "unknown term 'omega'"),
        ("roll: -c * phi * delta", "one term"),
        ("roll: -c * v * phiddot", "no speed factor"),
        ("roll: -c * v * v * phi", "one speed factor"),
    ],
)
def test_bad_laws_are_refused_in_one_line(text, problem):
    with pytest.raises(ValueError, match=problem) as exc:
        parse_law(text)
    assert "\n" not in str(exc.value)


def _decl(name, law, unit, **kw):
    return Effect(name, unit, 0.0, (-1.0, 10.0), True, "plant", "test", law=law,
                  origin="test.yaml", **kw)  # fmt: skip


def test_a_duplicate_law_is_refused_naming_both():
    """A steer-column spring under a new name is steer_stiffness: refused, both named; the
    sign does not make another term."""
    for law in ("steer: -k * delta", "steer: +k * delta"):
        with pytest.raises(ValueError, match="'column_spring'.*'steer_stiffness'"):
            register_effects([_decl("column_spring", law, "N m/rad")])
    assert "column_spring" not in EFFECTS
    with pytest.raises(ValueError, match="declared twice"):
        register_effects([_decl("steer_stiffness", "steer: -k * v * delta", "N m s/rad/m")])
    with pytest.raises(ValueError, match="same law"):  # two new ones with one law
        register_effects([_decl("a1", "roll: -c * v * phi", "N m s/rad/m"),
                          _decl("a2", "roll: -c * v * phi", "N m s/rad/m")])  # fmt: skip
    assert "a1" not in EFFECTS


def test_a_wrong_unit_is_refused():
    with pytest.raises(ValueError, match="not that of its law"):
        _decl("x", "roll: -c * phidot", "N m/rad")


def _old_plant_forces(cd, tc, s, cr, kr, kd, q4, q7, u4, u7):
    """The kernel before the table (sim/effects.py at 90b6a67), slots in its order."""
    return (-cr * u4 - kr * q4, 0.0, -cd * u7 - tc * math.tanh(u7 / s) - kd * q7)


_coef = st.floats(0.0, 50.0)
_state = st.floats(-3.0, 3.0)


@settings(max_examples=200, deadline=None)
@given(cd=_coef, tc=st.floats(0.0, 5.0), s=st.floats(0.005, 1.0), cr=_coef, kr=_coef,
       kd=st.floats(-10.0, 20.0), q4=_state, q7=_state, u4=_state, u7=_state)  # fmt: skip
def test_table_kernel_equals_the_old_formula(cd, tc, s, cr, kr, kd, q4, q7, u4, u7):
    """Same arithmetic in the same order: equal to 1e-15 relative (round-off; the rows are
    summed in the old formula's order, so it is exact in practice)."""
    objs = [fx.SteerDamping(cd), fx.RollStiffness(kr), fx.SteerCoulomb(tc, smoothing=s),
            fx.RollDamping(cr), fx.SteerStiffness(kd)]  # fmt: skip
    out = np.empty(3)
    fx.plant_forces(fx.plant_vector(objs), q4, q7, u4, 0.0, u7, out)
    ref = _old_plant_forces(cd, tc, s, cr, kr, kd, q4, q7, u4, u7)
    np.testing.assert_allclose(out, ref, rtol=1e-15, atol=1e-300)


@settings(max_examples=100, deadline=None)
@given(law=st.sampled_from([law for law in all_laws() if law.kernel_code is not None]),
       value=st.floats(-5.0, 5.0), v=st.floats(0.0, 8.0), q4=_state, q7=_state, u4=_state,
       u7=_state)  # fmt: skip
def test_any_kernel_law_gives_its_reference_force(law, value, v, q4, q7, u4, u7):
    """A PlantLaw row in the compiled kernel = the law's pure-Python force (sign as tanh with
    the same smoothing), on its equation only."""
    e = fx.PlantLaw(law, value, v, smoothing=0.05)
    out = np.empty(3)
    fx.plant_forces(fx.plant_vector([e]), q4, q7, u4, 0.0, u7, out)
    sig = {"phi": q4, "delta": q7, "phidot": u4, "deltadot": u7}
    ref = law.force(value, v, sig, 0.1, smoothing=0.05)
    expect = [0.0, 0.0, 0.0]
    expect[2 * law.index] = ref
    np.testing.assert_allclose(out, expect, rtol=1e-14, atol=1e-14)


def test_a_toy_builtin_effect_is_one_declaration(monkeypatch):
    """A new built-in plant effect added by one declaration (here patched into the table)
    reaches the nonlinear plant's table and the linear experiment model with no other
    edit: a roll damping growing with speed, c v phidot, at 3 m/s equals a plain roll
    damping of 3 c in both."""
    from bikeid.ident.effects.experiment_model import ExperimentModel
    from bikeid.ident.effects.synthetic_decays import synthetic_windows

    toy = Effect("roll_speed_damping", "N m s^2/rad/m", 0.0, (0.0, 10.0), False, "plant",
                 "roll torque -c * v * phidot (toy)", law="roll: -c * v * phidot")  # fmt: skip
    monkeypatch.setitem(EFFECTS, toy.name, toy)
    objs, eq = nonlinear_effects({toy.name: 0.5}, 3.0, 0.01)
    assert eq == {toy.name: 0.5}
    ref, _ = nonlinear_effects({"roll_viscous_damping": 1.5}, 3.0, 0.01)
    np.testing.assert_allclose(fx.plant_vector(objs), fx.plant_vector(ref), rtol=1e-15)
    w = synthetic_windows(ExperimentModel(), [3.0], 1, noise=0.0)[0]
    m = ExperimentModel(speed_calibration=(1.0, 0.0))  # true speed = the window's speed
    v = m.true_speed(float(np.mean(w.v_sensor)))
    a = m.with_effects(**{toy.name: 0.5}).simulate([w])[0]
    b = m.with_effects(roll_viscous_damping=0.5 * v).simulate([w])[0]
    for c in ("phi", "delta", "phidot"):
        np.testing.assert_allclose(a[c], b[c], rtol=1e-12, atol=1e-12)


def test_unregister_refuses_builtin_names():
    with pytest.raises(ValueError, match="built in"):
        unregister_effects(["steer_stiffness"])


def test_signals_cover_the_discovery_grammar():
    """States, accelerations, signs of both rates, the torque and a constant."""
    assert set(SIGNALS) == {"phi", "delta", "phidot", "deltadot", "phiddot", "deltaddot",
                            "sign(phidot)", "sign(deltadot)", "T", "1"}  # fmt: skip
