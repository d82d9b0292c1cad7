"""Chen & Dao's canonical state-space form of the Whipple bicycle (C&D eqs. 2-4).

State x = [phi, phidot, delta, deltadot] (``sim.conventions.CANONICAL_STATE``), one
input T_delta [N m], outputs y = [phi, delta] [rad]::

        [ 0   1   0   0 ]        [ 0  ]
    A = [ a1  a2  a3  a4 ],  B = [ b1 ],  C = [[1, 0, 0, 0],
        [ 0   0   0   1 ]        [ 0  ]        [0, 0, 1, 0]]
        [ a5  a6  a7  a8 ]       [ b2 ]

From M q'' + v C1 q' + (g K0 + v^2 K2) q = [0, T_delta] (reference §1.4):
A_l = [[a1, a3], [a5, a7]] = -M^-1 (g K0 + v^2 K2), A_r = [[a2, a4], [a6, a8]] =
-v M^-1 C1, [b1, b2] = second column of M^-1.  Hence (C&D eq. 4) the odd a's are
alpha + beta v^2, the even a's gamma v, and b1, b2 do not depend on speed: the
speed-parameterized vector is [alpha1, alpha3, alpha5, alpha7, beta1, beta3, beta5,
beta7, gamma2, gamma4, gamma6, gamma8, b1, b2] with alpha = -g M^-1 K0 (entries),
beta = -M^-1 K2, gamma = -M^-1 C1.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from bikeid.sim.conventions import LINEAR_STATE
from bikeid.sim.errors import UntrustworthyResult
from bikeid.sim.linear import CanonicalMatrices

if TYPE_CHECKING:
    import control

__all__ = [
    "C_OUT",
    "SPEED_NAMES",
    "THETA_NAMES",
    "canonical_ab",
    "matrices_from_speed_params",
    "speed_map",
    "speed_params_from_matrices",
    "steer_zeros",
    "theta_from_matrices",
    "to_bikeid_order",
    "to_canonical_form",
]

THETA_NAMES = ("a1", "a2", "a3", "a4", "a5", "a6", "a7", "a8", "b1", "b2")
SPEED_NAMES = (
    "alpha1", "alpha3", "alpha5", "alpha7", "beta1", "beta3", "beta5", "beta7",
    "gamma2", "gamma4", "gamma6", "gamma8", "b1", "b2",
)  # fmt: skip
C_OUT = np.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0]])
#: (row, column) of a1..a8 in A; b1, b2 sit in rows 1 and 3 of B.
A_POS = ((1, 0), (1, 1), (1, 2), (1, 3), (3, 0), (3, 1), (3, 2), (3, 3))
B_POS = (1, 3)
#: x_bikeid = PERM @ x_canonical
PERM = np.array([[1.0, 0, 0, 0], [0, 0, 1, 0], [0, 1, 0, 0], [0, 0, 0, 1]])


def canonical_ab(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Canonical-form A and B from the parameter vector theta.

    Parameters
    ----------
    theta : (10,) array_like
        [a1, ..., a8, b1, b2] (:data:`THETA_NAMES`).

    Returns
    -------
    A : (4, 4) ndarray
        State matrix for x = [phi, phidot, delta, deltadot] (Chen & Dao's order,
        :data:`sim.conventions.CANONICAL_STATE`): rows 0 and 2 are [0, 1, 0, 0] and
        [0, 0, 0, 1], rows 1 and 3 hold a1..a4 and a5..a8 [1/s^2 or 1/s].
    B : (4, 1) ndarray
        Input matrix for T_delta: b1 in row 1, b2 in row 3 [1/(kg m^2)], zeros
        elsewhere.

    Raises
    ------
    ValueError
        If ``theta`` does not hold exactly 10 values.
    """
    theta = np.asarray(theta, dtype=float)
    if theta.shape != (10,):
        raise ValueError(f"theta must hold 10 values a1..a8, b1, b2; got shape {theta.shape}")
    A = np.zeros((4, 4))
    A[0, 1] = A[2, 3] = 1.0
    for (r, c), a in zip(A_POS, theta[:8], strict=True):
        A[r, c] = a
    B = np.zeros((4, 1))
    B[1, 0], B[3, 0] = theta[8], theta[9]
    return A, B


def theta_from_matrices(cm: CanonicalMatrices, v: float) -> np.ndarray:
    """The exact canonical parameters of a linear model at one speed.

    Parameters
    ----------
    cm : CanonicalMatrices
        Linear model (:func:`sim.linear.canonical_matrices`).
    v : float
        Forward speed [m/s].

    Returns
    -------
    (10,) ndarray
        theta = [a1, ..., a8, b1, b2] (:data:`THETA_NAMES`): odd a's from
        -M^-1 (g K0 + v^2 K2) [1/s^2], even a's from -v M^-1 C1 [1/s], [b1, b2] the
        second column of M^-1 [1/(kg m^2)].
    """
    Minv = np.linalg.inv(cm.M)
    Al = -Minv @ cm.stiffness(v)
    Ar = -Minv @ cm.damping(v)
    return np.array([Al[0, 0], Ar[0, 0], Al[0, 1], Ar[0, 1],
                     Al[1, 0], Ar[1, 0], Al[1, 1], Ar[1, 1], Minv[0, 1], Minv[1, 1]])  # fmt: skip


def speed_params_from_matrices(cm: CanonicalMatrices) -> np.ndarray:
    """The exact speed-parameterized vector of a linear model.

    Parameters
    ----------
    cm : CanonicalMatrices
        Linear model (:func:`sim.linear.canonical_matrices`).

    Returns
    -------
    (14,) ndarray
        [alpha1, alpha3, alpha5, alpha7, beta1, beta3, beta5, beta7, gamma2, gamma4,
        gamma6, gamma8, b1, b2] (:data:`SPEED_NAMES`) with alpha = -g M^-1 K0
        [1/s^2], beta = -M^-1 K2 [1/m^2], gamma = -M^-1 C1 [1/m] (row-major entries)
        and [b1, b2] the second column of M^-1 [1/(kg m^2)].
    """
    Minv = np.linalg.inv(cm.M)
    al, be, ga = -cm.g * Minv @ cm.K0, -Minv @ cm.K2, -Minv @ cm.C1
    order = ((0, 0), (0, 1), (1, 0), (1, 1))
    return np.array(
        [al[i] for i in order] + [be[i] for i in order] + [ga[i] for i in order]
        + [Minv[0, 1], Minv[1, 1]]
    )  # fmt: skip


def speed_map(v: float) -> np.ndarray:
    """Linear map from the speed parameters to theta at speed ``v``.

    Parameters
    ----------
    v : float
        Forward speed [m/s].

    Returns
    -------
    (10, 14) ndarray
        S(v) with theta(v) = S(v) @ speed_params: a_odd = alpha + beta v^2,
        a_even = gamma v, b1 and b2 copied.
    """
    S = np.zeros((10, 14))
    for k, odd in enumerate((0, 2, 4, 6)):  # a1, a3, a5, a7
        S[odd, k] = 1.0
        S[odd, 4 + k] = v**2
    for k, even in enumerate((1, 3, 5, 7)):  # a2, a4, a6, a8
        S[even, 8 + k] = v
    S[8, 12] = S[9, 13] = 1.0
    return S


def matrices_from_speed_params(params: np.ndarray, g: float = 9.81) -> CanonicalMatrices:
    """M^-1-scaled canonical matrices: M = I, K0 = -alpha / g, K2 = -beta, C1 = -gamma.

    These give the same A(v) and eigenvalues as the true M, C1, K0, K2 (M itself is
    not identifiable from T_delta alone; only its second column of M^-1, [b1, b2]),
    so ``sim.linear.eigenvalues_vs_speed`` and ``critical_speeds`` apply directly.
    The B matrix of ``sim.linear.state_matrices`` on the result is *not* the true
    one (it is [0; I]): take b1, b2 from ``params`` instead.

    Parameters
    ----------
    params : (14,) array_like
        Speed parameters in :data:`SPEED_NAMES` order (b1, b2 are not used).
    g : float, optional
        Gravitational acceleration [m/s^2] to divide alpha by. Default 9.81.

    Returns
    -------
    CanonicalMatrices
        M = I, C1 = -gamma, K0 = -alpha / g, K2 = -beta (rows/columns [phi, delta],
        units of the true matrices divided by kg m^2), and ``g``.

    Raises
    ------
    ValueError
        If ``params`` does not hold exactly 14 values.
    """
    p = np.asarray(params, dtype=float)
    if p.shape != (14,):
        raise ValueError(f"need 14 speed parameters {SPEED_NAMES}, got shape {p.shape}")
    al, be, ga = (p[i : i + 4].reshape(2, 2) for i in (0, 4, 8))
    return CanonicalMatrices(M=np.eye(2), C1=-ga, K0=-al / g, K2=-be, g=g)


def to_bikeid_order(sys: control.StateSpace) -> control.StateSpace:
    """Permute a canonical-order model to bikeid's state order.

    Parameters
    ----------
    sys : control.StateSpace
        4-state model with x = [phi, phidot, delta, deltadot] (Chen & Dao's order).

    Returns
    -------
    control.StateSpace
        The same system with x = [phi, delta, phidot, deltadot]
        (:data:`sim.conventions.LINEAR_STATE`): A' = P A P^T, B' = P B, C' = C P^T,
        D unchanged, with P = :data:`PERM`; same sample time and input/output labels.

    Raises
    ------
    ValueError
        If ``sys`` does not have 4 states.
    """
    A, B, C, D = (np.asarray(m) for m in (sys.A, sys.B, sys.C, sys.D))
    if A.shape != (4, 4):
        raise ValueError("to_bikeid_order expects a 4-state canonical model")
    import control

    return control.ss(PERM @ A @ PERM.T, PERM @ B, C @ PERM.T, D, sys.dt,
                      inputs=sys.input_labels, outputs=sys.output_labels,
                      states=list(LINEAR_STATE))  # fmt: skip


def to_canonical_form(A: np.ndarray, B: np.ndarray, C: np.ndarray) -> np.ndarray:
    """theta of the canonical form similar to (A, B, C) (continuous time, 2 outputs).

    The transformation z = T x with T = [c1; c1 A; c2; c2 A] makes z = [y1, y1', y2,
    y2']; rows 1 and 3 of T B (which are zero for a true mechanical system) are dropped.
    With outputs y = [phi, delta] the result is in Chen & Dao's state order
    [phi, phidot, delta, deltadot].

    Parameters
    ----------
    A : (4, 4) ndarray
        State matrix, any state basis.
    B : (4,) or (4, m) ndarray
        Input matrix; only the first column (T_delta) is used.
    C : (2, 4) ndarray
        Output matrix; rows c1, c2 give y1 (phi) and y2 (delta).

    Returns
    -------
    (10,) ndarray
        theta = [a1, ..., a8, b1, b2] (:data:`THETA_NAMES`).

    Raises
    ------
    ValueError
        When T is singular (condition number above 1e12: the pair (A, C) has other
        observability indices than (2, 2)).
    """
    c1, c2 = C[0], C[1]
    T = np.vstack([c1, c1 @ A, c2, c2 @ A])
    if np.linalg.cond(T) > 1e12:
        raise UntrustworthyResult(
            "the model is not observable with indices (2, 2); cannot form the canonical form"
        )
    Ti = np.linalg.inv(T)
    Ac = T @ A @ Ti
    Bc = T @ B.reshape(4, -1)[:, :1]
    return np.array([Ac[r, c] for r, c in A_POS] + [Bc[1, 0], Bc[3, 0]])


def steer_zeros(theta: np.ndarray) -> np.ndarray:
    """Zeros [1/s] of delta/T_delta of the canonical model ``theta`` (finite ones, sorted).

    Transmission zeros of (A, B, c_delta, 0): the finite generalized eigenvalues of the
    Rosenbrock pencil [[A, B], [c_delta, 0]] - s [[I, 0], [0, 0]].  In Meijaard notation
    they are the roots of M_pp s^2 + v C1_pp s + g K0_pp + v^2 K2_pp (the roll row with
    delta held), +-sqrt(-g K0_pp / M_pp) = +-3.1347 rad/s for the benchmark at any speed
    (C1_pp = K2_pp = 0 in the Whipple model).

    Parameters
    ----------
    theta : (10,) array_like
        Canonical parameters [a1, ..., a8, b1, b2] (:data:`THETA_NAMES`).

    Returns
    -------
    (k,) ndarray of complex
        The finite zeros (|z| < 1e8) [1/s], sorted by real then imaginary part
        (``numpy.sort_complex``); k = 2 for a mechanical model with b2 != 0.

    Raises
    ------
    ValueError
        If ``theta`` does not hold exactly 10 values.
    """
    from scipy.linalg import eigvals

    A, B = canonical_ab(theta)
    P = np.zeros((5, 5))
    P[:4, :4], P[:4, 4:], P[4, 2] = A, B, 1.0
    E = np.zeros((5, 5))
    E[:4, :4] = np.eye(4)
    z = eigvals(P, E)
    z = z[np.isfinite(z) & (np.abs(z) < 1e8)]
    return np.sort_complex(np.real_if_close(z, tol=1e6).astype(complex))
