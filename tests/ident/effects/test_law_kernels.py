"""The experiment model applies the effect laws from the registry's table; these tests hold
it to the hand-written formulas it replaced (ident/effects/experiment_model.py at 90b6a67,
reproduced below), on random effect values and speeds (hypothesis).

Independent source: the old formulas, written out here: C = v C1 + diag(c_phi, c_delta +
c_scrub / v), K = g K0 + v^2 K2 + diag(k_phi, k_delta + k_twist / v), M[delta, delta] += I,
and the sampled loop's steer torque w = b - T_c tanh(deltadot / 0.1) (Meijaard 2007 eq.
A.21 with the registry's sign conventions).
"""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from bikeid.ident.effects.experiment_model import (
    COULOMB_EPS,
    ExperimentModel,
    initial_states,
)
from bikeid.sim.linear import canonical_matrices

_EFFECTS = {
    "steer_viscous_damping": st.floats(-1.0, 10.0),
    "tire_scrub_torque": st.floats(-5.0, 20.0),
    "steer_stiffness": st.floats(-10.0, 20.0),
    "tire_twist_stiffness": st.floats(-20.0, 50.0),
    "roll_viscous_damping": st.floats(0.0, 100.0),
    "roll_stiffness": st.floats(0.0, 1000.0),
    "steer_inertia": st.floats(-0.02, 1.0),
}


@settings(max_examples=25, deadline=None)
@given(values=st.fixed_dictionaries(_EFFECTS), v=st.floats(0.0, 8.0))
def test_matrices_equal_the_old_formulas(values, v):
    """(A, B) of the linear experiment model against the old hand-written terms: equal to
    1e-13 relative (the same operations in the same order; round-off at most)."""
    m = ExperimentModel(effects=values)
    A, B = m.continuous(v)
    cm = canonical_matrices(m.p)
    vf = max(v, 0.1)
    M = cm.M.copy()
    M[1, 1] += values["steer_inertia"]
    C = v * cm.C1 + np.diag([values["roll_viscous_damping"],
                             values["steer_viscous_damping"] + values["tire_scrub_torque"] / vf]
                            )  # fmt: skip
    K = cm.stiffness(v).copy()
    K[0, 0] += values["roll_stiffness"]
    K[1, 1] += values["steer_stiffness"] + values["tire_twist_stiffness"] / vf  # fmt: skip
    Minv = np.linalg.inv(M)
    A_ref = np.block([[np.zeros((2, 2)), np.eye(2)], [-Minv @ K, -Minv @ C]])
    scale = np.max(np.abs(A_ref))
    np.testing.assert_allclose(A, A_ref, rtol=1e-13, atol=1e-13 * scale)
    np.testing.assert_allclose(B[2:4, :], np.column_stack([Minv[:, 1], Minv[:, 1], Minv[:, 0]]),
                               rtol=1e-13, atol=1e-15)  # fmt: skip


@settings(max_examples=8, deadline=None)
@given(bias=st.floats(-2.0, 2.0), tc=st.floats(0.0, 5.0), seed=st.integers(0, 1000))
def test_sampled_loop_forcing_equals_the_old_formula(bias, tc, seed):
    """The sampled loop's forcing rows (a constant steer torque and a Coulomb friction) against
    the old loop written out in Python (one window, 2 substeps per loop): equal to 1e-12 of
    the signal's peak (the same arithmetic; round-off at most)."""
    from bikeid.ident.effects.synthetic_decays import synthetic_windows

    w = synthetic_windows(ExperimentModel(), [3.0], 1, noise=0.005, seed=seed)[0]
    m = ExperimentModel(effects={"steer_torque_bias": bias, "steer_coulomb_friction": tc})
    nsub = 2
    sim = m.simulate([w], nsub=nsub)[0]
    vs = float(np.mean(w.v_sensor))
    Ad, Bd = m.discrete(m.true_speed(vs), m.dt / nsub)
    x = initial_states([w])[0].copy()
    Kc = m.K * (m.V - vs)
    phidot = []
    for k in range(w.n):
        phidot.append(x[2])
        u = Kc * x[2] + w.T_ext[k]
        for _ in range(nsub):
            wtq = bias - tc * np.tanh(x[3] / COULOMB_EPS) if tc != 0.0 else bias
            x = Ad @ x + Bd[:, 0] * u + Bd[:, 1] * wtq
    ref = np.array(phidot)
    np.testing.assert_allclose(sim["phidot"], ref, rtol=0, atol=1e-12 * np.max(np.abs(ref)))
