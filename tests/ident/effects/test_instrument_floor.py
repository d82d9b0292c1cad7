"""The instruments' noise floor (ident.effects.instrument_floor), both ways.

Known answers: decays of a known model with the logs' nuisances (AR(1)-coloured sensor
noise, a gyro drift, the steer encoder's quantization, treadmill speed wander) scored by the
right model leave a cost the instruments explain (cost / floor below the ``instruments``
rule's INSTRUMENT_MAX), although the second-difference floor calls it structure; a roll
viscous damping the library lacks (sim.effect_registry, in_library False) leaves the nominal
a cost well above the floor.
"""

from dataclasses import replace

import numpy as np

from bikeid.dataset.windows import Window
from bikeid.ident.effects.acceptance import INSTRUMENT_MAX
from bikeid.ident.effects.experiment_model import ExperimentModel
from bikeid.ident.effects.fit import noise_floor, output_residuals
from bikeid.ident.effects.instrument_floor import instrument_floor, quiet_noise
from bikeid.ident.effects.kstep import with_horizon
from bikeid.ident.effects.library import LIBRARY


def _ar1(rng, n, sd, a):
    x = np.zeros(n)
    x[0] = rng.normal(0, sd)
    for k in range(1, n):
        x[k] = a * x[k - 1] + rng.normal(0, sd * np.sqrt(1 - a * a))
    return x


SD = {"phi": 0.003, "delta": 0.002, "phidot": 0.02, "deltadot": 0.05}  # rad, rad/s


def _nuisance_decays(truth, v, seed, n=200, per=6):
    """Closed-loop decays of ``truth`` at v with the logs' nuisances on what is logged, and
    the log's quiet stretch (2 s of upright running: the same nuisances on a zero signal)."""
    rng = np.random.default_rng(seed)
    q = 0.000767  # rad, the steer encoder
    m = 200
    quiet = {c: _ar1(rng, m, sd, 0.8) for c, sd in SD.items()}
    quiet["delta"] = np.round(quiet["delta"] / q) * q
    quiet["phidot"] += rng.normal(0, 0.01) + rng.normal(0, 0.01) * np.arange(m) * 0.01
    meta = {"instrument_noise": quiet_noise(quiet, 0.01)}
    out = []
    for j in range(per):
        sg = (-1.0) ** j
        vs = (1.066 * v - 0.128) + 0.03 * np.sin(2 * np.pi * rng.uniform(0.2, 0.5)
                                                  * np.arange(n) * 0.01)  # fmt: skip
        z = np.zeros(n)
        x0 = [rng.normal(0, 0.01), sg * rng.uniform(0, 0.08), sg * rng.uniform(0.3, 0.6),
              sg * rng.uniform(0.5, 1.5)]  # fmt: skip
        w = Window("syn", v, 0, z + x0[0], z + x0[1], z + x0[2], z + x0[3], vs, z.copy(),
                   np.zeros(20))  # fmt: skip
        s = truth.simulate([w], nsub=10)[0]
        drift = rng.normal(0, 0.01) + rng.normal(0, 0.01) * np.arange(n) * 0.01  # rad/s
        out.append(replace(
            w, phi=s["phi"] + _ar1(rng, n, SD["phi"], 0.8),
            delta=np.round((s["delta"] + _ar1(rng, n, SD["delta"], 0.8)) / q) * q,
            phidot=s["phidot"] + _ar1(rng, n, SD["phidot"], 0.8) + drift,
            deltadot=s["deltadot"] + _ar1(rng, n, SD["deltadot"], 0.8), T_logged=s["T"],
            meta=meta))  # fmt: skip
    return with_horizon(out, ExperimentModel())


def test_right_model_with_the_logs_nuisances_is_within_the_instrument_floor():
    """No effect, k-step error at an unstable (1.5 m/s) and a stable loop speed (4 m/s):
    the right model's cost over the instruments' floor is below INSTRUMENT_MAX (1.3), while
    over the second-difference floor it is above 2 (AR(1) noise of coefficient 0.8 puts only
    (1 - a)(3 - a)/3 = 0.15 of its variance into second differences)."""
    m = ExperimentModel()
    ws = _nuisance_decays(m, 1.5, 0) + _nuisance_decays(m, 4.0, 1)
    r = output_residuals(m, ws)
    cost = float(r @ r)
    fl = instrument_floor(m, ws)
    assert cost / fl["floor"] < INSTRUMENT_MAX
    assert cost / fl["floor"] > 0.5  # the floor is not inflated past the cost
    assert cost / noise_floor(ws) > 2.0
    assert fl["speed_wander"] > 0


def test_an_outside_library_effect_stays_above_the_instrument_floor():
    """Truth with a roll viscous damping of 3 N m s/rad (not in the library): the nominal's
    cost is more than INSTRUMENT_MAX times the floor; the truth's own is not (both ways on
    the same decays)."""
    assert "roll_viscous_damping" not in LIBRARY
    truth = ExperimentModel(effects={"roll_viscous_damping": 3.0})
    ws = _nuisance_decays(truth, 1.5, 2) + _nuisance_decays(truth, 4.0, 3)
    nom = ExperimentModel()
    r = output_residuals(nom, ws)
    assert float(r @ r) > INSTRUMENT_MAX * instrument_floor(nom, ws)["floor"]
    rt = output_residuals(truth, ws)
    assert float(rt @ rt) < INSTRUMENT_MAX * instrument_floor(truth, ws)["floor"]
