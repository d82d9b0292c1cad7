"""Dictionary terms injected into the blind trials' independent linear plant: the torque each
adds, by hand from the canonical matrices, and the decays against the pipeline's experiment
model carrying the same term through an effects file (a second implementation)."""

import math
import tempfile
from pathlib import Path

import numpy as np
import pytest

from bikeid.dataset.windows import Window
from bikeid.experiments.measured.blind_trials import (
    BlindTrial,
    Nuisance,
    _LinearPlant,
    draw_term_trials,
    generate_windows,
    linear_plant_matrices,
    log_signals,
    with_terms,
)
from bikeid.ident.effects.discovery import injection_file
from bikeid.ident.effects.experiment_model import ExperimentModel
from bikeid.sim.effect_files import load_effects_file
from bikeid.sim.effect_registry import unregister_effects
from bikeid.sim.parameters import steer_by_wire

X = np.array([0.03, -0.02, 0.4, -0.7, 0.0])  # phi, delta [rad], phidot, deltadot [rad/s], Ta
V, T_CMD, T_PHI = 3.2, 0.8, 1.5  # m/s, N m, N m
NAN = float("nan")


def _hand_qdd(extra: np.ndarray, M=None) -> np.ndarray:
    """Meijaard's M qdd + v C1 qd + (g K0 + v^2 K2) q = T solved by hand, T = [T_phi, T_cmd]
    plus ``extra``, from bicycleparameters' matrices (not the plant's attributes)."""
    p = steer_by_wire()
    M0, C1, K0, K2 = linear_plant_matrices(p)
    M = M0 if M is None else M
    q, qd = X[:2], X[2:4]
    rhs = np.array([T_PHI, T_CMD]) + extra - V * C1 @ qd - (p.g * K0 + V * V * K2) @ q
    return np.linalg.solve(M, rhs)


@pytest.mark.parametrize(
    "term, c, eq, value",
    [
        ("roll: phidot", -3.0, 0, X[2]),
        ("roll: phi/v", 40.0, 0, X[0] / V),
        ("steer: v*deltadot", -0.15, 1, V * X[3]),
        ("steer: sign(deltadot)", -0.2, 1, math.tanh(X[3] / 0.01)),
        ("steer: T", 0.25, 1, T_CMD),
        ("roll: 1", 0.5, 0, 1.0),
    ],
)  # fmt: skip
def test_injected_term_adds_coefficient_times_term(term, c, eq, value):
    """The plant's accelerations with ``term`` equal the hand solution with c * term added to
    its equation's torque (sign smoothed as tanh(rate / 0.01), the library Coulomb's; T the
    applied torque, here the command): 1e-12 relative is round-off of a 2x2 solve.  The same
    plant without the term gives the hand solution without it, and the two differ by more
    than 1e-3 relative, so a plant ignoring the term (or adding it to the other equation)
    fails."""
    p = steer_by_wire()
    extra = np.zeros(2)
    extra[eq] = c * value
    with_term = np.asarray(_LinearPlant(p, "none", NAN, {term: c}).rhs(X, V, T_CMD, T_PHI)[2:4])
    without = np.asarray(_LinearPlant(p, "none", NAN, {}).rhs(X, V, T_CMD, T_PHI)[2:4])
    np.testing.assert_allclose(with_term, _hand_qdd(extra), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(without, _hand_qdd(np.zeros(2)), rtol=1e-12, atol=1e-12)
    assert np.max(np.abs(with_term - without)) > 1e-3 * np.max(np.abs(without))


def test_acceleration_term_enters_the_mass_matrix():
    """``steer: deltaddot`` c moves c * deltaddot to the left: (M - c e_s e_s^T) qdd = rhs,
    solved by hand (1e-12 relative); the unchanged M gives another answer."""
    p = steer_by_wire()
    c = 0.02
    M = linear_plant_matrices(p)[0].copy()
    M[1, 1] -= c
    plant = _LinearPlant(p, "none", NAN, {"steer: deltaddot": c})
    got = np.asarray(plant.rhs(X, V, T_CMD, T_PHI)[2:4])
    np.testing.assert_allclose(got, _hand_qdd(np.zeros(2), M), rtol=1e-12, atol=1e-12)
    assert np.max(np.abs(got - _hand_qdd(np.zeros(2)))) > 1e-3 * np.max(np.abs(got))


def test_bad_terms_are_refused():
    """An unknown term, a non-finite coefficient, an unphysical mass, and a term asked of
    the nonlinear plant each give one ValueError naming the problem."""
    p = steer_by_wire()
    with pytest.raises(ValueError, match="no term of the dictionary"):
        _LinearPlant(p, "none", NAN, {"roll: psi": 1.0})
    with pytest.raises(ValueError, match="finite number"):
        _LinearPlant(p, "none", NAN, {"roll: phidot": float("inf")})
    with pytest.raises(ValueError, match="positive definite"):
        _LinearPlant(p, "none", NAN, {"steer: deltaddot": 1.0})  # M_ss is 0.14 kg m^2
    tr = draw_term_trials(1, 5, {"roll: phidot": -3.0})[0]
    assert tr.terms == {"roll: phidot": -3.0} and tr.nuisance.plant == "independent_linear"
    with pytest.raises(ValueError, match="independent linear plant"):
        log_signals(tr, 3.0, 1, plant="bikeid_nonlinear", pushes=1)


QUIET = Nuisance(
    plant="independent_linear", push="state", pulse_duration=0.2, pulse_torque=0.0, noise=0.0,
    colour=0.0, steer_noise=0.0, encoder_counts=2**40, gyro_bias=0.0, gyro_walk=0.0,
    steer_rate="gyro", speed_wander=0.0, wander_freq=0.5,
)  # fmt: skip


@pytest.mark.parametrize("term, c", [("roll: phi", -30.0), ("steer: v*deltadot", -0.15)])
def test_generator_term_agrees_with_experiment_model(term, c, monkeypatch):
    """With every nuisance off, the decays of the generator with an injected term (its own
    RK4, 10 substeps of 1 ms) equal the experiment model's with the same term injected
    through ``discovery.injection_file`` (exact zero-order hold): the two share the term's
    meaning and sign.  Tolerance 1e-6 of the signal, as the library effects' agreement test
    (RK4 error < 1e-8 over the window); the nominal model misses by more than 1e-2, so the
    term is seen."""
    monkeypatch.setattr(
        Window, "state0", lambda w: np.array([w.phi[0], w.delta[0], w.phidot[0], w.deltadot[0]])
    )
    tr = with_terms(BlindTrial(0, 1, "none", NAN, (2.5, 4.0), (3.0, 3.5), QUIET), {term: c})
    ws = generate_windows(tr, (2.5, 4.0), 1, seed=3, label="q")
    with tempfile.TemporaryDirectory() as tmp:
        f = load_effects_file(injection_file(Path(tmp) / "i.yaml", {term: c}))
    try:
        sims = ExperimentModel(effects=dict(f.values)).simulate(ws)
    finally:
        unregister_effects(f.names)
    nominal = ExperimentModel().simulate(ws)
    for w, s, s0 in zip(ws, sims, nominal, strict=True):
        scale = np.max(np.abs(w.phidot))
        np.testing.assert_allclose(s["phidot"], w.phidot, atol=1e-6 * scale)
        assert np.max(np.abs(s0["phidot"] - w.phidot)) > 1e-2 * scale
