"""Every layer applies the effect registry (sim.effect_registry) and none re-spells it.

Checked: the identification library is exactly the registry's ``in_library`` set with the
registry's units and absent values; every registry entry changes the linear experiment model;
every entry with a ``plant_term`` changes the nonlinear plant's compiled effects; the
trials' effects take their facts from the registry; the sensor layer sets the channel
fields the registry names (against a hand computation).
"""

from __future__ import annotations

import numpy as np
import pytest

from bikeid.sim.effect_registry import EFFECTS, library_names
from bikeid.sim.effects import nonlinear_effects


def _inside(name: str, frac: float = 0.2) -> float:
    """A value a fraction ``frac`` of the way from absent to the far end of the plausible
    range (so never absent, always plausible)."""
    e = EFFECTS[name]
    lo, hi = e.plausible
    end = hi if hi - e.absent >= e.absent - lo else lo
    return e.absent + frac * (end - e.absent)


def test_library_is_the_registry_in_library_set():
    from bikeid.ident.effects.library import LIBRARY

    assert set(LIBRARY) == set(library_names())
    for name, cand in LIBRARY.items():
        e = EFFECTS[name]
        assert (cand.unit, cand.absent, cand.doc) == (e.unit, e.absent, e.doc)
        assert cand.kind in ("additive", "structural")
        assert cand.lower <= e.absent <= cand.upper  # the fit may start at absent


@pytest.mark.parametrize("name", list(EFFECTS))
def test_every_registry_effect_changes_the_experiment_model(name):
    """A non-absent value inside the plausible range changes the simulated decay of one
    synthetic window (linear model, 3 m/s) by more than round-off (1e-9)."""
    from bikeid.ident.effects.experiment_model import ExperimentModel
    from bikeid.ident.effects.synthetic_decays import synthetic_windows

    w = synthetic_windows(ExperimentModel(), [3.0], 1, noise=0.0)[0]
    nominal = ExperimentModel().simulate([w])[0]
    value = _inside(name)
    assert value != EFFECTS[name].absent
    sim = ExperimentModel(effects={name: value}).simulate([w])[0]
    diff = max(np.max(np.abs(sim[c] - nominal[c])) for c in ("phi", "delta", "phidot", "T"))
    assert diff > 1e-9, name


@pytest.mark.parametrize("name", [n for n, e in EFFECTS.items() if e.plant_term])
def test_every_plant_term_changes_the_nonlinear_plant(name):
    """An entry the nonlinear plant carries changes its compiled plant vector or input chain,
    and the object built is that of its ``plant_term``."""
    from bikeid.sim import effects as fx

    objects, eq = nonlinear_effects({name: _inside(name)}, 3.0, 0.01)
    assert set(eq) == {EFFECTS[name].plant_term}
    changed_plant = not np.array_equal(fx.plant_vector(objects), fx.plant_vector([]))
    changed_input = fx.input_chain(objects, 0.01) != fx.input_chain([], 0.01)
    assert changed_plant or changed_input, name


def test_trial_effects_take_their_facts_from_the_registry():
    from bikeid.experiments.measured.effect_trials import EFFECTS as TRIALS
    from bikeid.sim import effects as fx

    for name, spec in TRIALS.items():
        e = EFFECTS[name]
        assert (spec.unit, spec.absent, spec.in_library) == (e.unit, e.absent, e.in_library)
    (coulomb,) = TRIALS["steer_coulomb_friction"].sim_effects(0.2)
    assert coulomb == fx.SteerCoulomb(0.2, smoothing=0.01)  # the trials' smoothing


def test_sensors_apply_the_sensor_layer_by_hand():
    """roll_rate_scale s and roll_rate_bias b give phidot_m = s phidot + b, steer_angle_bias
    delta_m = delta + b; the channel's noise and quantization are kept; effects of other
    layers are skipped; an unknown name is refused; the original is unchanged."""
    from bikeid.dataset.sensors import Channel, Sensors

    base = Sensors({"phidot": Channel(std=0.0, step=0.001)})
    s = base.with_effects({"roll_rate_scale": 1.1, "roll_rate_bias": 0.02,
                           "steer_angle_bias": -0.01, "steer_viscous_damping": 0.3})  # fmt: skip
    x = np.array([0.0, 0.5, -1.234])
    np.testing.assert_allclose(s.channel("phidot").apply(x),
                               0.001 * np.round((1.1 * x + 0.02) / 0.001))  # fmt: skip
    np.testing.assert_allclose(s.channel("delta").apply(x), x - 0.01)
    assert s.channel("phi").ideal and base.channel("phidot").scale == 1.0
    assert s.channel("phidot").step == 0.001
    assert set(s.channels) == {"phidot", "delta"}
    with pytest.raises(ValueError, match="unknown effect"):
        base.with_effects({"gyro_drift": 1.0})
