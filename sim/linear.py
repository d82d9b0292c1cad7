"""Linearized Whipple bicycle (Meijaard et al. 2007, Appendix A).

Equations of motion about upright straight-ahead running at speed v:

    M q'' + v C1 q' + (g K0 + v^2 K2) q = [T_phi, T_delta] + H F

with q = [phi, delta] (roll positive to the right, steer positive to the right,
z down), T_phi a roll torque on the rear frame [N m], T_delta the steer torque of
rear frame on front frame [N m] and F a lateral force [N], positive to the right,
on the rear frame at (x_F, z_F) (benchmark axes), entering through H.

State order used everywhere in bikeid: x = [phi, delta, phidot, deltadot]
(:data:`STATE_NAMES`); Chen & Dao's order [phi, phidot, delta, deltadot] is
handled in :mod:`ident`.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.polynomial import polynomial as P

from .parameters import BicycleParameters

if TYPE_CHECKING:  # python-control and scipy.optimize load on first use (start-up time)
    import control

__all__ = [
    "INPUT_NAMES",
    "STATE_NAMES",
    "WEAVE_REAL",
    "CanonicalMatrices",
    "EigenSweep",
    "canonical_matrices",
    "constant_term",
    "critical_speeds",
    "eigenvalues",
    "eigenvalues_vs_speed",
    "hurwitz3",
    "lateral_force_vector",
    "match_eigenvalues",
    "mode_names_at",
    "quartic_coefficients",
    "state_matrices",
    "state_space",
    "transfer_function",
    "yaw_rate",
]

STATE_NAMES = ("phi", "delta", "phidot", "deltadot")
INPUT_NAMES = ("T_phi", "T_delta", "F")


@dataclass(frozen=True)
class CanonicalMatrices:
    """Canonical matrices of the linearized Whipple bicycle (Meijaard 2007, eq. A1).

    The equations of motion about upright straight-ahead running at speed v are
    ``M q'' + v C1 q' + (g K0 + v^2 K2) q = [T_phi, T_delta]`` with q = [phi, delta].
    Rows are the roll and steer equations, columns the coordinates phi and delta.

    Attributes
    ----------
    M : (2, 2) ndarray
        Mass matrix [kg m^2] (symmetric, positive definite).
    C1 : (2, 2) ndarray
        Velocity-dependent damping-like matrix [kg m]; ``v C1`` is in N m s/rad.
    K0 : (2, 2) ndarray
        Gravity-dependent stiffness matrix [kg m]; ``g K0`` is in N m/rad.
    K2 : (2, 2) ndarray
        Velocity-dependent stiffness matrix [kg]; ``v^2 K2`` is in N m/rad.
    g : float
        Gravitational acceleration [m/s^2].
    """

    M: np.ndarray
    C1: np.ndarray
    K0: np.ndarray
    K2: np.ndarray
    g: float

    def stiffness(self, v: float) -> np.ndarray:
        """Stiffness matrix g K0 + v^2 K2 at speed ``v``.

        Parameters
        ----------
        v : float
            Forward speed [m/s].

        Returns
        -------
        (2, 2) ndarray
            g K0 + v^2 K2 [N m/rad], rows/columns [phi, delta].
        """
        return self.g * self.K0 + v**2 * self.K2

    def damping(self, v: float) -> np.ndarray:
        """Damping matrix v C1 at speed ``v``.

        Parameters
        ----------
        v : float
            Forward speed [m/s].

        Returns
        -------
        (2, 2) ndarray
            v C1 [N m s/rad], rows/columns [phi, delta].
        """
        return v * self.C1

    def char_poly(self, v: float) -> np.ndarray:
        """Characteristic polynomial det(M s^2 + v C1 s + g K0 + v^2 K2) at speed ``v``.

        Parameters
        ----------
        v : float
            Forward speed [m/s].

        Returns
        -------
        (5,) ndarray
            Coefficients in *ascending* powers of s (``numpy.polynomial`` order):
            ``[e, d, c, b, a]`` for ``a s^4 + b s^3 + c s^2 + d s + e``.  Its roots are
            the eigenvalues of :func:`state_matrices` ``(cm, v)[0]`` [1/s].
        """
        return _det_poly(self._poly_matrix(v))

    def _poly_matrix(self, v: float) -> list[list[np.ndarray]]:
        K = self.stiffness(v)
        C = self.damping(v)
        return [[np.array([K[i, j], C[i, j], self.M[i, j]]) for j in range(2)] for i in range(2)]


def _det_poly(Pm: list[list[np.ndarray]]) -> np.ndarray:
    return P.polysub(P.polymul(Pm[0][0], Pm[1][1]), P.polymul(Pm[0][1], Pm[1][0]))


def canonical_matrices(p: BicycleParameters) -> CanonicalMatrices:
    """Canonical matrices M, C1, K0, K2 from the benchmark parameters (Meijaard 2007, App. A).

    Parameters
    ----------
    p : BicycleParameters
        Bicycle in Meijaard (2007) notation, SI units.  The wheels are axisymmetric
        (IRzz = IRxx, IFzz = IFxx).

    Returns
    -------
    CanonicalMatrices
        M [kg m^2], C1 [kg m], K0 [kg m], K2 [kg] (rows/columns [phi, delta]) and
        g = ``p.g`` [m/s^2].
    """
    sl, cl = math.sin(p.lam), math.cos(p.lam)
    IRzz, IFzz = p.IRxx, p.IFxx
    mT = p.mR + p.mB + p.mH + p.mF
    xT = (p.xB * p.mB + p.xH * p.mH + p.w * p.mF) / mT
    zT = (-p.rR * p.mR + p.zB * p.mB + p.zH * p.mH - p.rF * p.mF) / mT
    ITxx = (
        p.IRxx + p.IBxx + p.IHxx + p.IFxx
        + p.mR * p.rR**2 + p.mB * p.zB**2 + p.mH * p.zH**2 + p.mF * p.rF**2
    )  # fmt: skip
    ITxz = p.IBxz + p.IHxz - p.mB * p.xB * p.zB - p.mH * p.xH * p.zH + p.mF * p.w * p.rF
    ITzz = IRzz + p.IBzz + p.IHzz + IFzz + p.mB * p.xB**2 + p.mH * p.xH**2 + p.mF * p.w**2
    mA = p.mH + p.mF
    xA = (p.xH * p.mH + p.w * p.mF) / mA
    zA = (p.zH * p.mH - p.rF * p.mF) / mA
    IAxx = p.IHxx + p.IFxx + p.mH * (p.zH - zA) ** 2 + p.mF * (p.rF + zA) ** 2
    IAxz = p.IHxz - p.mH * (p.xH - xA) * (p.zH - zA) + p.mF * (p.w - xA) * (p.rF + zA)
    IAzz = p.IHzz + IFzz + p.mH * (p.xH - xA) ** 2 + p.mF * (p.w - xA) ** 2
    uA = (xA - p.w - p.c) * cl - zA * sl
    IAll = mA * uA**2 + IAxx * sl**2 + 2 * IAxz * sl * cl + IAzz * cl**2
    IAlx = -mA * uA * zA + IAxx * sl + IAxz * cl
    IAlz = mA * uA * xA + IAxz * sl + IAzz * cl
    mu = p.c / p.w * cl
    SR = p.IRyy / p.rR
    SF = p.IFyy / p.rF
    ST = SR + SF
    SA = mA * uA + mu * mT * xT
    Mpd = IAlx + mu * ITxz
    M = np.array([[ITxx, Mpd], [Mpd, IAll + 2 * mu * IAlz + mu**2 * ITzz]])
    K0 = np.array([[mT * zT, -SA], [-SA, -SA * sl]])
    K2 = np.array([[0.0, (ST - mT * zT) * cl / p.w], [0.0, (SA + SF * sl) * cl / p.w]])
    C1 = np.array(
        [
            [0.0, mu * ST + SF * cl + ITxz * cl / p.w - mu * mT * zT],
            [-(mu * ST + SF * cl), IAlz * cl / p.w + mu * (SA + ITzz * cl / p.w)],
        ]
    )
    return CanonicalMatrices(M=M, C1=C1, K0=K0, K2=K2, g=p.g)


def lateral_force_vector(p: BicycleParameters, x_F: float, z_F: float) -> np.ndarray:
    """Input vector H of a lateral force F on the rear frame at (x_F, z_F).

    The generalized force is F times the partial velocity of the application point:
    roll lever -z_F (height above ground) and, through the yaw rate
    psi' = (v delta + c delta') cos(lam) / w, a steer lever x_F c cos(lam) / w.
    F enters the equations of motion as ``H F`` on the right-hand side.

    Parameters
    ----------
    p : BicycleParameters
        Bicycle parameters (uses c, w and lam).
    x_F : float
        Application point, benchmark x (forward of the rear contact) [m].
    z_F : float
        Application point, benchmark z (down; negative above the ground) [m].

    Returns
    -------
    (2,) ndarray
        H = [-z_F, x_F c cos(lam) / w] [m] (N m of generalized force per N of F), rows
        [phi, delta].  F [N] is positive to the right (+y).
    """
    return np.array([-z_F, x_F * p.c * math.cos(p.lam) / p.w])


def yaw_rate(p: BicycleParameters, v: float, delta: np.ndarray, deltadot: np.ndarray) -> np.ndarray:
    """Linearized rear-frame yaw rate psi' = (v delta + c delta') cos(lam) / w.

    Parameters
    ----------
    p : BicycleParameters
        Bicycle parameters (uses c, w and lam).
    v : float
        Forward speed [m/s].
    delta : array_like
        Steer angle [rad], positive to the right.
    deltadot : array_like
        Steer rate [rad/s], same shape as ``delta`` (or broadcastable).

    Returns
    -------
    ndarray
        Yaw rate psi' [rad/s] (positive turning to the right), broadcast shape of
        ``delta`` and ``deltadot``.
    """
    return (v * np.asarray(delta) + p.c * np.asarray(deltadot)) * math.cos(p.lam) / p.w


def state_matrices(
    p: BicycleParameters | CanonicalMatrices,
    v: float,
    lateral_force_point: tuple[float, float] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """State matrices A and B of the linear model at speed ``v``.

    x' = A x + B u with x = [phi, delta, phidot, deltadot] (:data:`STATE_NAMES`)
    and u = [T_phi, T_delta] or, with ``lateral_force_point``, [T_phi, T_delta, F].

    Parameters
    ----------
    p : BicycleParameters or CanonicalMatrices
        Bicycle parameters or precomputed canonical matrices.
    v : float
        Forward speed [m/s].
    lateral_force_point : (float, float), optional
        (x_F, z_F) [m], benchmark axes, where a lateral force F acts on the rear
        frame (:func:`lateral_force_vector`).  If given, B gets a third column for F.

    Returns
    -------
    A : (4, 4) ndarray
        State matrix: ``[[0, I], [-M^-1 (g K0 + v^2 K2), -M^-1 v C1]]``.
    B : (4, 2) or (4, 3) ndarray
        Input matrix, columns [T_phi, T_delta] (per N m) and optionally F (per N);
        the first two rows are zero.

    Raises
    ------
    ValueError
        If ``lateral_force_point`` is given with ``p`` a :class:`CanonicalMatrices`
        (the force lever needs the geometry).
    """
    cm = p if isinstance(p, CanonicalMatrices) else canonical_matrices(p)
    Minv = np.linalg.inv(cm.M)
    A = np.zeros((4, 4))
    A[0:2, 2:4] = np.eye(2)
    A[2:4, 0:2] = -Minv @ cm.stiffness(v)
    A[2:4, 2:4] = -Minv @ cm.damping(v)
    cols = [Minv]
    if lateral_force_point is not None:
        if isinstance(p, CanonicalMatrices):
            raise ValueError("lateral_force_point needs BicycleParameters, not matrices")
        H = lateral_force_vector(p, *lateral_force_point)
        cols.append((Minv @ H)[:, None])
    B = np.vstack([np.zeros((2, sum(c.shape[1] for c in cols))), np.hstack(cols)])
    return A, B


def state_space(
    p: BicycleParameters | CanonicalMatrices,
    v: float,
    inputs: tuple[str, ...] = ("T_phi", "T_delta"),
    lateral_force_point: tuple[float, float] | None = None,
) -> control.StateSpace:
    """Linear model as a python-control ``StateSpace`` at speed ``v``.

    Parameters
    ----------
    p : BicycleParameters or CanonicalMatrices
        Bicycle parameters or precomputed canonical matrices.
    v : float
        Forward speed [m/s].
    inputs : tuple of str, optional
        Inputs, in the order wanted, chosen from :data:`INPUT_NAMES`
        ``("T_phi", "T_delta", "F")``: roll torque [N m], steer torque [N m] and
        lateral force [N], all positive to the right.  Default ``("T_phi", "T_delta")``.
    lateral_force_point : (float, float), optional
        (x_F, z_F) [m], benchmark axes, of the lateral force; required for "F".

    Returns
    -------
    control.StateSpace
        Continuous-time system with states and outputs x = [phi, delta, phidot,
        deltadot] [rad, rad, rad/s, rad/s] (C = I, D = 0), labelled with
        :data:`STATE_NAMES`; inputs labelled as in ``inputs``.

    Raises
    ------
    ValueError
        If ``inputs`` names an unknown input, if "F" is requested without
        ``lateral_force_point``, or (from :func:`state_matrices`) if
        ``lateral_force_point`` is given with ``p`` a :class:`CanonicalMatrices`.
    """
    unknown = [u for u in inputs if u not in INPUT_NAMES]
    if unknown:
        raise ValueError(f"unknown inputs {unknown}; choose from {list(INPUT_NAMES)}")
    if "F" in inputs and lateral_force_point is None:
        raise ValueError("input 'F' needs lateral_force_point=(x_F, z_F) in metres")
    A, B = state_matrices(p, v, lateral_force_point)
    idx = [INPUT_NAMES.index(u) for u in inputs]
    import control

    return control.ss(
        A, B[:, idx], np.eye(4), np.zeros((4, len(idx))),
        inputs=list(inputs), outputs=list(STATE_NAMES), states=list(STATE_NAMES),
    )  # fmt: skip


def transfer_function(
    p: BicycleParameters | CanonicalMatrices, v: float, output: str = "phi", input: str = "T_delta"
) -> control.TransferFunction:
    """Exact SISO transfer function from a torque ``input`` to an angle ``output``.

    Built from the adjugate of P(s) = M s^2 + v C1 s + g K0 + v^2 K2, so there are
    no round-off coefficients: e.g. phi/T_delta = -P_phidelta(s) / det P(s).
    Multiply by s for the rates.

    Parameters
    ----------
    p : BicycleParameters or CanonicalMatrices
        Bicycle parameters or precomputed canonical matrices.
    v : float
        Forward speed [m/s].
    output : {"phi", "delta"}, optional
        Roll or steer angle [rad]. Default "phi".
    input : {"T_phi", "T_delta"}, optional
        Roll or steer torque [N m]. Default "T_delta".

    Returns
    -------
    control.TransferFunction
        Continuous-time transfer function [rad/(N m)]; denominator the quartic
        det P(s) (:meth:`CanonicalMatrices.char_poly`), leading zero coefficients of
        the numerator removed.

    Raises
    ------
    ValueError
        If ``output`` or ``input`` is not one of the names above.
    """
    cm = p if isinstance(p, CanonicalMatrices) else canonical_matrices(p)
    outs, ins = ("phi", "delta"), ("T_phi", "T_delta")
    if output not in outs or input not in ins:
        raise ValueError(f"output must be one of {outs} and input one of {ins}")
    i, j = outs.index(output), ins.index(input)
    Pm = cm._poly_matrix(v)
    adj = [[Pm[1][1], -Pm[0][1]], [-Pm[1][0], Pm[0][0]]]
    num = np.trim_zeros(adj[i][j][::-1], "f")
    den = cm.char_poly(v)[::-1]
    import control

    return control.tf(num if num.size else [0.0], den)


# -- eigenvalues ---------------------------------------------------------------------------
def eigenvalues(p: BicycleParameters | CanonicalMatrices, v: float) -> np.ndarray:
    """Eigenvalues of the linear model at speed ``v``.

    Parameters
    ----------
    p : BicycleParameters or CanonicalMatrices
        Bicycle parameters or precomputed canonical matrices.
    v : float
        Forward speed [m/s].

    Returns
    -------
    (4,) ndarray of complex
        The four eigenvalues of A(v) (:func:`state_matrices`) [1/s], unsorted
        (``numpy.linalg.eigvals`` order).
    """
    return np.linalg.eigvals(state_matrices(p, v)[0])


@dataclass(frozen=True)
class EigenSweep:
    """Eigenvalues against speed, tracked along continuous branches.

    Returned by :func:`eigenvalues_vs_speed`.

    Attributes
    ----------
    speeds : (K,) ndarray
        Forward speeds [m/s], as given to :func:`eigenvalues_vs_speed`.
    values : (K, 4) ndarray of complex
        ``values[k, j]`` is branch j at ``speeds[k]`` [1/s].
    labels : tuple of str
        ``labels[j]`` is one of ``weave``, ``capsize``, ``caster`` (the two weave
        branches are the pair that is complex above v_d) or ``mode<j>`` where no such
        structure exists.
    """

    speeds: np.ndarray
    values: np.ndarray
    labels: tuple[str, ...]

    def mode(self, label: str) -> np.ndarray:
        """Eigenvalue branches with a given label.

        Parameters
        ----------
        label : str
            One of the labels in :attr:`labels` (``weave``, ``capsize``, ``caster`` or
            ``mode<j>``).

        Returns
        -------
        (K, n) ndarray of complex
            The columns of :attr:`values` with this label [1/s]; n = 2 for ``weave``,
            1 otherwise.

        Raises
        ------
        ValueError
            If no branch has this label.
        """
        idx = [j for j, lab in enumerate(self.labels) if lab == label]
        if not idx:
            raise ValueError(f"no mode {label!r}; modes are {sorted(set(self.labels))}")
        return self.values[:, idx]


#: Every permutation of 4 columns (the 4x4 assignments of :func:`_assignment`), in
#: lexicographic order.
_PERMUTATIONS_4 = np.array(list(itertools.permutations(range(4))))


def _assignment(cost: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows and columns of the minimum-total-cost assignment of a square cost matrix.

    Up to 4x4 (every eigenvalue problem of the bicycle) all at most 24 assignments are
    summed and the smallest total taken: exact, and it keeps ``bikeid eig`` and
    ``critical-speeds`` free of the ~0.4 s ``scipy.optimize`` import (start-up time).
    Exact ties go to the lexicographically first permutation (the identity first).  Ties
    happen where a complex pair splits into two real roots (the two assignments are mirror
    images, so the data do not say which real root continues which branch);
    ``scipy.optimize.linear_sum_assignment``, used for larger problems, breaks them by its
    own rule.  For one shipped bicycle ('Browser', whose caster and capsize roots pass
    through a complex pair near 1-1.5 m/s) the two rules label those two roots oppositely
    below that speed; the values at every speed are the same either way.
    """
    n = cost.shape[0]
    if cost.shape == (n, n) and n <= 4:
        perms = _PERMUTATIONS_4 if n == 4 else np.array(list(itertools.permutations(range(n))))
        totals = cost[np.arange(n), perms].sum(axis=1)
        return np.arange(n), perms[int(np.argmin(totals))]
    from scipy.optimize import linear_sum_assignment

    return linear_sum_assignment(cost)


def _track(values: np.ndarray) -> np.ndarray:
    out = values.copy()
    for k in range(1, len(out)):
        cost = np.abs(out[k - 1][:, None] - values[k][None, :])
        _, col = _assignment(cost)
        out[k] = values[k][col]
    return out


def match_eigenvalues(found, truth, *, return_index: bool = False):
    """``found`` reordered to pair with ``truth`` (minimum total distance |found - truth|).

    Parameters
    ----------
    found : (n,) array_like of complex
        Eigenvalues to reorder (identified, say) [1/s].
    truth : (n,) array_like of complex
        Reference eigenvalues [1/s], in the order wanted.
    return_index : bool, optional
        Also return the permutation, to reorder quantities attached to ``found`` (their
        standard errors, say) the same way.

    Returns
    -------
    (n,) ndarray of complex
        ``found[col]`` with ``col`` the optimal assignment (Hungarian algorithm,
        ``scipy.optimize.linear_sum_assignment``), so element i pairs with ``truth[i]``.
        Both inputs are flattened.
    col : (n,) ndarray of int
        Only with ``return_index=True``: the permutation ``col``.

    Raises
    ------
    ValueError
        If ``found`` and ``truth`` have different numbers of elements.
    """
    found = np.asarray(found, dtype=complex).ravel()
    truth = np.asarray(truth, dtype=complex).ravel()
    if found.size != truth.size:
        raise ValueError(f"cannot pair {found.size} eigenvalues with {truth.size}")
    _, col = _assignment(np.abs(truth[:, None] - found[None, :]))
    return (found[col], col) if return_index else found[col]


#: Name of a real root on one of the weave's two branches: below v_d the weave is two real
#: roots that merge at v_d into the weave's complex pair (:func:`mode_names_at`).
WEAVE_REAL = "weave (real)"
#: |imaginary part| [1/s] above which an eigenvalue counts as complex in :func:`mode_names_at`.
_COMPLEX = 1e-9


def mode_names_at(values) -> tuple[str, ...]:
    """Mode names of a bicycle's four eigenvalues at one speed, from the values alone.

    The rule follows the Whipple bicycle's root loci (Meijaard et al. 2007, Table 2 and
    Fig. 3: each column of Table 2 is one continuous branch; at zero speed the benchmark's
    roots are +-3.13 and +-5.53 1/s, the two positive ones merge at v_d = 0.684 m/s into
    the weave pair, -3.13 continues as the capsize root and -5.53 as the caster root):

    - One complex pair and two real roots, the pair right of the more negative real root
      (the Whipple bicycle above v_d): the pair is the weave, the more negative real root
      the caster and the other the capsize.
    - Four real roots (below v_d), by their order along the real axis as on the Whipple
      bicycle below v_d: the most negative the caster, the next the capsize, the two
      largest the weave's real roots, :data:`WEAVE_REAL` (``"weave (real)"``).
    - A complex pair left of both real roots, or the left one of two complex pairs: the
      caster and capsize roots merged into an oscillation (the Browser, Pista and Fisher
      bicycles of ``bicycleparameters`` between about 0.2 and 2 m/s).  That pair is neither
      mode alone and stays unnamed (``""``); the roots right of it are the weave (its
      pair, or its two real roots).
    - Anything else (not four finite eigenvalues) is unnamed.

    Parameters
    ----------
    values : (4,) array_like of complex
        Eigenvalues [1/s] at one speed, in the order the names are wanted.

    Returns
    -------
    tuple of str
        One of ``"weave"``, ``"weave (real)"``, ``"capsize"``, ``"caster"`` or ``""`` per
        eigenvalue.
    """
    lam = np.asarray(values, dtype=complex).ravel()
    names = [""] * lam.size
    if lam.size != 4 or not np.all(np.isfinite(lam)):
        return tuple(names)
    cplx = sorted((i for i in range(4) if abs(lam[i].imag) > _COMPLEX),
                  key=lambda i: lam[i].real)  # fmt: skip
    real = sorted((i for i in range(4) if i not in cplx), key=lambda i: lam[i].real)
    if len(cplx) == 4:  # two pairs: the left one is the caster and capsize merged
        for i in cplx[2:]:
            names[i] = "weave"
    elif len(cplx) == 2 and lam[cplx[0]].real < lam[real[0]].real:  # caster-capsize pair
        for i in real:
            names[i] = WEAVE_REAL
    elif len(cplx) == 2:
        for i in cplx:
            names[i] = "weave"
        names[real[0]], names[real[1]] = "caster", "capsize"
    elif not cplx:
        for i, name in zip(real, ("caster", "capsize", WEAVE_REAL, WEAVE_REAL), strict=True):
            names[i] = name
    return tuple(names)


def eigenvalues_vs_speed(p: BicycleParameters | CanonicalMatrices, speeds) -> EigenSweep:
    """Eigenvalues over a range of speeds, branches tracked and labelled.

    Tracking uses a fine internal grid (step <= 0.01 m/s) so that labels follow
    continuous branches through the real-to-complex transition at v_d.
    Labelling: at the highest speed with a complex pair, that pair is the weave,
    the most negative real root the caster and the other real root the capsize.

    Parameters
    ----------
    p : BicycleParameters or CanonicalMatrices
        Bicycle parameters or precomputed canonical matrices.
    speeds : (K,) array_like
        Forward speeds [m/s], finite, any order; their span must be below 1000 m/s.

    Returns
    -------
    EigenSweep
        ``values`` (K, 4) [1/s] at ``speeds`` (in the given order), with the branch
        labels.

    Raises
    ------
    ValueError
        If ``speeds`` is empty, not 1-D or not finite, or spans 1000 m/s or more.
    """
    speeds = np.asarray(speeds, dtype=float)
    if speeds.ndim != 1 or speeds.size == 0 or not np.all(np.isfinite(speeds)):
        raise ValueError("speeds must be a non-empty 1-D array of finite values")
    cm = p if isinstance(p, CanonicalMatrices) else canonical_matrices(p)
    lo, hi = float(speeds.min()), float(speeds.max())
    if hi - lo > 1000.0:
        raise ValueError(
            f"speeds span {lo:g}..{hi:g} m/s; branch tracking uses a 0.01 m/s grid, so keep the "
            "span below 1000 m/s"
        )
    fine = np.union1d(np.linspace(lo, hi, max(2, int(math.ceil((hi - lo) / 0.01)) + 1)), speeds)
    vals = np.array([np.sort_complex(eigenvalues(cm, v)) for v in fine])
    tracked = _track(vals)
    labels = ["mode0", "mode1", "mode2", "mode3"]
    cplx = np.where(np.abs(tracked.imag).max(axis=1) > 1e-9)[0]
    if cplx.size:
        k = cplx[-1]
        row = tracked[k]
        pair = [j for j in range(4) if abs(row[j].imag) > 1e-9]
        real = [j for j in range(4) if j not in pair]
        if len(pair) == 2 and len(real) == 2:
            caster = min(real, key=lambda j: row[j].real)
            capsize = max(real, key=lambda j: row[j].real)
            labels[pair[0]] = labels[pair[1]] = "weave"
            labels[caster] = "caster"
            labels[capsize] = "capsize"
    pick = np.searchsorted(fine, speeds)
    return EigenSweep(speeds=speeds, values=tracked[pick], labels=tuple(labels))


# -- critical speeds -----------------------------------------------------------------------
def quartic_coefficients(cm: CanonicalMatrices, v: np.ndarray) -> tuple[np.ndarray, ...]:
    """Coefficients of the characteristic quartic at every speed of ``v`` at once.

    The determinant det(M s^2 + v C1 s + g K0 + v^2 K2) = a s^4 + b s^3 + c s^2 + d s + e
    is expanded by hand; the grid scan and the bisection of :func:`_roots` (and the
    implicit derivatives of ``ident.uncertainty``) all use it, so they see one function.

    Parameters
    ----------
    cm : CanonicalMatrices
        The bicycle (M, C1, K0, K2, g; complex entries allowed, for complex-step
        derivatives).
    v : (n,) array_like
        Speeds [m/s].

    Returns
    -------
    a, b, c, d, e : (n,) ndarray
        The quartic's coefficients at each speed (units of M^2 [kg^2 m^4] times 1/s^k).
    """
    v = np.asarray(v, dtype=float)[:, None, None]
    K = cm.g * cm.K0 + v**2 * cm.K2
    C = v * cm.C1
    M = np.broadcast_to(cm.M, K.shape)

    def cross(X, Y):  # coefficient contribution X00 Y11 - X01 Y10
        return X[:, 0, 0] * Y[:, 1, 1] - X[:, 0, 1] * Y[:, 1, 0]

    e = cross(K, K)
    d = cross(K, C) + cross(C, K)
    c = cross(K, M) + cross(C, C) + cross(M, K)
    b = cross(C, M) + cross(M, C)
    a = cross(M, M)
    return a, b, c, d, e


def _discriminant(a, b, c, d, e):
    """Discriminant of a s^4 + b s^3 + c s^2 + d s + e (elementwise on arrays)."""
    return (
        256 * a**3 * e**3 - 192 * a**2 * b * d * e**2 - 128 * a**2 * c**2 * e**2
        + 144 * a**2 * c * d**2 * e - 27 * a**2 * d**4 + 144 * a * b**2 * c * e**2
        - 6 * a * b**2 * d**2 * e - 80 * a * b * c**2 * d * e + 18 * a * b * c * d**3
        + 16 * a * c**4 * e - 4 * a * c**3 * d**2 - 27 * b**4 * e**2 + 18 * b**3 * c * d * e
        - 4 * b**3 * d**3 - 4 * b**2 * c**3 * e + b**2 * c**2 * d**2
    )  # fmt: skip


def hurwitz3(a, b, c, d, e):
    """Third Hurwitz determinant of the quartic (its zero defines v_w).

    Parameters
    ----------
    a, b, c, d, e : ndarray
        Quartic coefficients (:func:`quartic_coefficients`).

    Returns
    -------
    ndarray
        b c d - a d^2 - b^2 e: zero exactly when a pair of roots is +-i w.
    """
    return b * c * d - a * d**2 - b**2 * e


def constant_term(a, b, c, d, e):
    """The quartic's constant term (its zero defines v_c: a root crosses s = 0).

    Parameters
    ----------
    a, b, c, d, e : ndarray
        Quartic coefficients (:func:`quartic_coefficients`).

    Returns
    -------
    ndarray
        e = det(g K0 + v^2 K2).
    """
    return e


def _roots(f, cm: CanonicalMatrices, vmax: float, step: float = 0.01) -> list[float]:
    """Zeros of f(quartic coefficients at v) for v in (0, vmax]: sign changes on the grid,
    each refined by bisection until its bracket is two adjacent doubles.

    All brackets are halved together (vectorized, at most ~60 halvings for a 0.01 m/s
    bracket), so the root is the sign change of the computed function to the last bit,
    without ``scipy.optimize`` (its import is ~0.4 s of ``bikeid critical-speeds``).
    """
    grid = np.arange(step, vmax + step / 2, step)
    vals = f(*quartic_coefficients(cm, grid))
    exact = [float(v) for v, fv in zip(grid[:-1], vals[:-1], strict=True) if fv == 0.0]
    k = np.nonzero(vals[:-1] * vals[1:] < 0)[0]
    lo, hi, flo = grid[k], grid[k + 1], vals[k]
    for _ in range(200):  # each pass halves every bracket; 200 is far beyond 64-bit floats
        mid = 0.5 * (lo + hi)
        open_ = (mid > lo) & (mid < hi)
        if not open_.any():
            break
        fmid = f(*quartic_coefficients(cm, mid))
        hit = open_ & (fmid == 0.0)
        lo, hi = np.where(hit, mid, lo), np.where(hit, mid, hi)
        right = open_ & ~hit & (np.sign(fmid) == np.sign(flo))  # the zero is in (mid, hi)
        left = open_ & ~hit & ~right
        lo, flo = np.where(right, mid, lo), np.where(right, fmid, flo)
        hi = np.where(left, mid, hi)
    fhi = f(*quartic_coefficients(cm, hi)) if hi.size else hi
    best = np.where(np.abs(flo) <= np.abs(fhi), lo, hi)
    return sorted(exact + [float(v) for v in best])


def critical_speeds(p: BicycleParameters | CanonicalMatrices, vmax: float = 30.0) -> dict:
    """Critical speeds by root finding on the characteristic polynomial.

    The quartic a s^4 + b s^3 + c s^2 + d s + e = det(M s^2 + v C1 s + g K0 + v^2 K2)
    is scanned on a 0.01 m/s grid from 0.01 m/s to vmax and each sign change refined
    by bisection to adjacent doubles (the last bit of the computed coefficients).

    Parameters
    ----------
    p : BicycleParameters or CanonicalMatrices
        Bicycle parameters or precomputed canonical matrices.
    vmax : float, optional
        Highest speed searched [m/s]. Default 30.

    Returns
    -------
    dict
        ``"v_d"`` : float or None
            Speed [m/s] at which the weave pair turns from two real roots into a
            complex pair (a zero of the quartic's discriminant where the weave's roots
            merge, :func:`mode_names_at`; not where the caster and capsize roots do).
        ``"v_w"`` : float or None
            Weave speed [m/s]: the weave pair crosses the imaginary axis (zero of the
            third Hurwitz determinant b c d - a d^2 - b^2 e).
        ``"v_c"`` : float or None
            Capsize speed [m/s]: the capsize root crosses zero (zero of the constant
            term, det(g K0 + v^2 K2)).
        ``"weave_frequency"`` : float or None
            Imaginary part of the weave pair at ``v_w`` [rad/s].
        ``"all"`` : dict of str to list of float
            Every crossing found, keyed ``"v_d"``, ``"v_w"``, ``"v_c"`` [m/s].

        A speed that does not exist in (0, vmax] is ``None``.  If several crossings
        exist, the lowest is reported and all are listed under ``all``.
    """
    cm = p if isinstance(p, CanonicalMatrices) else canonical_matrices(p)
    d_roots = [  # the weave's real roots merge (not the caster and capsize roots: Browser)
        v for v in _roots(_discriminant, cm, vmax)
        if "weave" in mode_names_at(eigenvalues(cm, v + 1e-4))
        and "weave" not in mode_names_at(eigenvalues(cm, max(v - 1e-4, 0.0)))
    ]  # fmt: skip
    w_roots = []
    for v in _roots(hurwitz3, cm, vmax):
        ev = eigenvalues(cm, v)
        if np.min(np.abs(ev.real[np.abs(ev.imag) > 1e-9]), initial=np.inf) < 1e-6:
            w_roots.append(v)
    c_roots = _roots(constant_term, cm, vmax)
    out: dict = {
        "v_d": d_roots[0] if d_roots else None,
        "v_w": w_roots[0] if w_roots else None,
        "v_c": c_roots[0] if c_roots else None,
        "weave_frequency": None,
        "all": {"v_d": d_roots, "v_w": w_roots, "v_c": c_roots},
    }
    if w_roots:
        out["weave_frequency"] = float(np.max(np.abs(eigenvalues(cm, w_roots[0]).imag)))
    return out
