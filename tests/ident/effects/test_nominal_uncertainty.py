"""The nominal bicycle's uncertainty: the box the stated parameters move in, what a parameter
correction must reach beyond it, and the calibration that keeps a nominal off by its
uncertainty from being reported as an effect (known both ways on blind-generator decays)."""

import numpy as np
import pytest

from bikeid.ident.effects.acceptance import AcceptanceRule
from bikeid.ident.effects.nominal_uncertainty import (
    BODY_INERTIAS,
    DEFAULT_TEXT,
    Calibration,
    NominalUncertainty,
)
from bikeid.sim.parameters import steer_by_wire


def test_apply_moves_each_body_and_the_trail():
    """Offset x moves every entry of a body's tensor by the factor 1 + 0.05 x (exactly: one
    factor per body) and the trail by 0.002 x m; the other parameters stay as stated."""
    p = steer_by_wire()
    u = NominalUncertainty()
    x = np.array([1.0, -1.0, 0.5, 0.0, -0.25])
    q = u.apply(p, x)
    for keys, xi in zip(BODY_INERTIAS.values(), x[:4], strict=True):
        for k in keys:
            assert getattr(q, k) == pytest.approx((1 + 0.05 * xi) * getattr(p, k), rel=1e-15)
    assert q.c == pytest.approx(p.c - 0.0005, abs=1e-15)
    assert (q.mB, q.w, q.lam) == (p.mB, p.w, p.lam)
    assert u.values(x) == pytest.approx(
        {
            "inertia_R": 0.05,
            "inertia_B": -0.05,
            "inertia_H": 0.025,
            "inertia_F": 0.0,
            "trail": -0.0005,
        }  # fmt: skip
    )
    assert NominalUncertainty(inertia=0.0).names == ("trail",)


@pytest.mark.parametrize(
    "effect, value, offsets, expected",
    [("trail_correction", 0.001, 0.0, 0.0),  # within +-2 mm: no evidence
     ("trail_correction", 0.005, 0.0, 0.003),  # 5 mm: 3 mm beyond the band
     ("trail_correction", -0.003, 1.0, 0.0),  # offset +2 mm, total -1 mm: inside
     ("trail_correction", 0.003, 1.0, 0.003),  # total 5 mm
     ("rear_inertia_scale", 1.04, 0.0, 0.0),  # 4 % within 5 %
     ("rear_inertia_scale", 1.2, -1.0, 0.14 - 0.05),  # 0.95 x 1.2 = 1.14
     ("front_inertia_scale", 0.9, 0.0, 0.05),
     ("roll_rate_bias", -0.007, 0.0, 0.0),  # a gyro offset within +-0.01 rad/s
     ("roll_rate_bias", -0.025, 0.0, 0.015),
     ("steer_angle_bias", 0.024, 0.0, 0.022),  # the real encoder zero: beyond +-2 mrad
     ("steer_stiffness", 1.0, 0.0, None)],  # no band
)  # fmt: skip
def test_excess_beyond_the_band(effect, value, offsets, expected):
    """What a parameter correction reaches beyond the band, hand-computed: the total
    deviation (calibrated offset and correction stacked) less the half-width; an instrument
    offset's value less its band."""
    u = NominalUncertainty()
    x = np.zeros(5)
    x[{"trail_correction": 4, "rear_inertia_scale": 1, "front_inertia_scale": 2}.get(effect, 0)] = (
        offsets
    )
    got = u.excess(effect, value, x)
    assert got == (None if expected is None else pytest.approx(expected, abs=1e-12))


def test_parse_and_errors():
    """The command-line forms, and clear errors naming the accepted forms."""
    assert NominalUncertainty.parse("none") is None
    assert NominalUncertainty.parse("default") == NominalUncertainty.parse(DEFAULT_TEXT)
    assert NominalUncertainty.parse("default") == NominalUncertainty()
    assert NominalUncertainty.parse("trail=0.003") == NominalUncertainty(0.0, 0.003, {})
    assert NominalUncertainty.parse("roll_rate_bias=0.02").sensor == {"roll_rate_bias": 0.02}
    with pytest.raises(ValueError, match="not an instrument offset"):
        NominalUncertainty(sensor={"speed_scale": 0.1})
    for bad in ("inertia", "inertia=x", "mass=0.1", "inertia=0.1,inertia=0.2", ""):
        with pytest.raises(ValueError, match="use none, default or inertia=F,trail=M"):
            NominalUncertainty.parse(bad)
    for bad in (-0.1, 0.5, float("nan")):
        with pytest.raises(ValueError, match="half-width"):
            NominalUncertainty(inertia=bad)
    with pytest.raises(ValueError, match="trail"):
        NominalUncertainty(trail=0.05)


def test_calibration_record():
    """The record names the offsets in physical units and which sit on the edge."""
    c = Calibration(NominalUncertainty(), steer_by_wire(), np.array([1.0, 0.2, -1.0, 0, 0.5]))
    d = c.as_dict()
    assert d["at_edge"] == ["inertia_R", "inertia_H"]
    assert d["offsets"]["trail"] == pytest.approx(0.001)
    assert c.params().c == pytest.approx(steer_by_wire().c + 0.001)
    assert Calibration(NominalUncertainty(), steer_by_wire()).offsets.tolist() == [0.0] * 5
    with pytest.raises(ValueError, match="2 given"):
        Calibration(NominalUncertainty(), steer_by_wire(), np.zeros(2))


@pytest.mark.slow
def test_nominal_off_by_its_uncertainty_is_not_an_effect():
    """Known both ways on decays of the independent linear plant (blind generator: white
    roll-rate noise 8 mrad/s, 8192-count encoder, no other nuisance) whose bicycle is the
    stated one with every body's inertia 5 % off (alternating signs) and the trail 2 mm
    long, the edges of the default band.  No effect: fitted as stated with each effect tested
    at 5 % alone, the selection accepts spurious effects (measured: a steer inertia and a
    gyro scale); calibrated within the band it accepts none.  With a
    steer damping of 0.5 N m s/rad the calibrated selection still names it first, within
    2 % (measured 0.4987: the damping is far outside what the band can mimic)."""
    from bikeid.experiments.measured.blind_trials import (
        BlindTrial,
        band_edge_nuisance,
        generate_windows,
    )
    from bikeid.ident.effects.experiment_model import ExperimentModel
    from bikeid.ident.effects.selection import select_effects

    nz = band_edge_nuisance()

    def select(effect, value, uncertainty, correction="bonferroni"):
        tr = BlindTrial(0, 11, effect, value, (2.0, 3.5), (2.7, 4.2), nz)
        ws = generate_windows(tr, tr.fit_speeds, 4, tr.seed, "fit")
        rule = AcceptanceRule(nominal_uncertainty=uncertainty, correction=correction)
        return select_effects(ExperimentModel(), ws, max_effects=2, nonlinear=False, rule=rule)

    # each test at 5 % alone (no multiple-comparison correction), as the per-test t > 3 rule
    # before it: the stated nominal's mismatch is read as effects, the calibrated is not
    stated = select("none", float("nan"), None, "none")
    assert stated.effects, "the stated nominal should leave a mismatch read as an effect"
    calibrated = select("none", float("nan"), NominalUncertainty(), "none")
    assert calibrated.effects == [], calibrated.evidence
    # with the default Bonferroni correction over 37 tests (19 + 18; 3 degrees of freedom: 4
    # fit-half clusters) the stated nominal's best mismatch candidate (trail, t 6.6, p 0.007)
    # is not accepted either (measured; the calibrated one, tested at 5 % alone above, is a
    # fortiori not)
    assert select("none", float("nan"), None).effects == []
    cal = calibrated.evidence["nominal_calibration"]
    assert cal["cost_calibrated"] < cal["cost_stated"]
    damped = select("steer_viscous_damping", 0.5, NominalUncertainty())
    assert damped.effects[0].name == "steer_viscous_damping"
    assert damped.effects[0].value == pytest.approx(0.5, rel=0.02)


def test_model_object_keeps_the_calibrated_bicycle(tmp_path):
    """A measured-fit model object with calibrated parameters is saved and read back with
    those parameters (not the stated bicycle), and the held-out evaluation's model is built
    on them; a model object with broken parameters is refused, naming the field."""
    from bikeid.ident.effects.pipeline import _experiment_model, model_from_json, save_fit
    from bikeid.sim.errors import InputError

    p = NominalUncertainty().apply(steer_by_wire(), np.array([1.0, -1.0, 0.3, 0.0, 1.0]))
    obj = {"effects": {"steer_viscous_damping": 0.3}, "parameters": p.as_dict(),
           "plant": "linear", "fit_speeds": [2.5]}  # fmt: skip
    save_fit(obj, tmp_path / "m.json")
    model, back = model_from_json(tmp_path / "m.json")
    assert model.p.as_dict() == pytest.approx(p.as_dict(), rel=1e-15)
    assert model.e("steer_viscous_damping") == 0.3
    assert _experiment_model(back).p.IRyy == pytest.approx(p.IRyy, rel=1e-15)
    assert _experiment_model({"effects": {}}).p == steer_by_wire()
    with pytest.raises(InputError, match="'parameters'"):
        _experiment_model({"effects": {}, "parameters": {**p.as_dict(), "mB": -1.0}})
