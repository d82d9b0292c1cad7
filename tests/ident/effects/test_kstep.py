"""The k-step prediction error (ident.effects.kstep): bounded where the open-loop replay grows.

Known answers: at 1.5 m/s the steer-by-wire bicycle without its controller is unstable
(weave growth rate 3.02 1/s, sim.linear), so replaying the logged torque from a noisy start
state gives an error growing like exp(3.02 t); the k-step error of the true model stays at
the measurement noise (its second-difference floor), and a library effect in the truth still
makes the nominal model's k-step error larger than the truth's.
"""

from dataclasses import replace

import numpy as np
import pytest

from bikeid.dataset.windows import Window
from bikeid.ident.effects.experiment_model import ExperimentModel
from bikeid.ident.effects.fit import noise_floor, output_residuals
from bikeid.ident.effects.kstep import horizon, kstep_error, with_horizon
from bikeid.sim.linear import eigenvalues

V = 1.5  # m/s, unstable without the controller


def _decays(truth, n=300, seed=0, noise=0.01, v=V):
    """Closed-loop decays of ``truth`` (the steer-into-lean loop, 10 substeps), the command
    the loop applied logged; white noise as synthetic_windows."""
    rng = np.random.default_rng(seed)
    vs = 1.066 * v - 0.128
    z = np.zeros(n)
    out = []
    for j in range(4):
        sg = (-1.0) ** j
        x0 = [rng.normal(0, 0.01), sg * rng.uniform(0, 0.08), sg * rng.uniform(0.3, 0.6),
              sg * rng.uniform(0.5, 1.5)]  # fmt: skip
        w = Window("syn", v, 0, z + x0[0], z + x0[1], z + x0[2], z + x0[3], z + vs, z.copy(),
                   np.zeros(20))  # fmt: skip
        s = truth.simulate([w], nsub=10)[0]
        out.append(replace(
            w, phi=s["phi"] + rng.normal(0, noise / 5, n),
            delta=s["delta"] + rng.normal(0, noise / 5, n),
            phidot=s["phidot"] + rng.normal(0, noise, n),
            deltadot=s["deltadot"] + rng.normal(0, 3 * noise, n), T_logged=s["T"]))  # fmt: skip
    return out


def test_kstep_error_stays_at_the_noise_while_the_replay_grows():
    """3 s decays at 1.5 m/s.  Replay: its error over 2.5-3 s over that of 0.5-1 s is
    exp(rate x 2 s) with rate the plant's largest growth rate (3.02 1/s): log ratio within
    +-1.5 of 6.04 (the other modes decay; +-1.5 covers the start error's projection).  The
    true model's k-step cost is at most 4 times the second-difference floor of each window
    (measured 2.1-3.2 here: the filter's estimation error, propagated k steps, adds to the
    noise), while the replay's is thousands of times it; with k beyond the window the k-step
    error is the replay's (the same recursion, to 1e-9)."""
    truth = ExperimentModel()
    ws = _decays(truth)
    rate = max(eigenvalues(truth.plant_params(), truth.true_speed(1.066 * V - 0.128)).real)
    assert rate == pytest.approx(3.02, abs=0.01)
    rep = truth.simulate([replace(w, drive="logged") for w in ws])
    late = np.sqrt(np.mean([np.mean((s["phidot"][250:] - w.phidot[250:]) ** 2)
                            for w, s in zip(ws, rep, strict=True)]))  # fmt: skip
    early = np.sqrt(np.mean([np.mean((s["phidot"][50:100] - w.phidot[50:100]) ** 2)
                             for w, s in zip(ws, rep, strict=True)]))  # fmt: skip
    assert np.log(late / early) == pytest.approx(rate * 2.0, abs=1.5)
    ke = kstep_error(truth, with_horizon(ws, truth))
    floor = np.array([noise_floor([w]) for w in ws])
    assert np.all(ke.per_window < 4 * floor)
    replay = output_residuals(truth, [replace(w, drive="logged") for w in ws])
    assert kstep_error(truth, ws, k=10**6).cost == pytest.approx(replay @ replay, rel=1e-9)
    assert ke.cost < 1e-3 * (replay @ replay)
    assert np.all(ke.per_window > 0.5 * floor)  # not below the noise it cannot remove
    assert ke.horizons == [horizon(truth, 1.066 * V - 0.128)] * 4
    assert ke.horizons[0] == round(1 / rate / 0.01)  # one e-fold of the unstable weave


def test_the_kstep_horizon_is_one_weave_period_where_the_bicycle_is_stable():
    """At 6 m/s the steer-by-wire bicycle is self-stable (sim.linear): k = its weave period."""
    m = ExperimentModel()
    v = 6.0
    lam = eigenvalues(m.plant_params(), v)
    assert max(lam.real) < 0
    w = max(lam[lam.imag > 0], key=lambda z: z.real)
    assert horizon(m, 1.066 * v - 0.128) == round(2 * np.pi / w.imag / 0.01)


@pytest.mark.parametrize("v", [V, 4.0])
def test_a_library_effect_still_reduces_the_kstep_error(v):
    """Truth with a viscous steer damping of 0.4 N m s/rad (inside the library's range):
    the truth's k-step cost is under half the nominal's, at an unstable (1.5 m/s) and at a
    stable closed-loop speed (4 m/s)."""
    truth = ExperimentModel(effects={"steer_viscous_damping": 0.4})
    ws = with_horizon(_decays(truth, n=200, seed=3, v=v), ExperimentModel())
    c_true = kstep_error(truth, ws).cost
    c_nom = kstep_error(ExperimentModel(), ws).cost
    assert c_true < 0.5 * c_nom
