"""Grey-box prediction-error identification of the Whipple matrices (MATLAB ``idgrey`` idea).

Model (Moore & Hubbard eq. 1, Meijaard notation, q = [phi, delta])::

    M q'' + v C1 q' + (g K0 + v^2 K2) q = [0, T_delta] + H F

The parameters are entries of M, C1, K0, K2 (and H), named as in :mod:`ident.direct` (``Mpd`` =
M[phi, delta], ``K2dd``, ...); any subset is free, the others stay at a bicycle's Whipple
values (default free set: Moore & Hubbard's, :data:`ident.direct.MOORE_ROLL` +
:data:`ident.direct.MOORE_STEER`, HdF only when a run has a lateral force).  With
``symmetric=True`` (default) ``Mpd`` stands for M[phi, delta] = M[delta, phi] and ``K0pd``
for K0[phi, delta] = K0[delta, phi].
The matrices do not depend on speed, so one parameter vector fits runs at any number of
speeds jointly; runs at one speed give a per-speed fit (where, e.g., K0dd and K2dd are not
separable).

Predictor: the same as the canonical PEM (:mod:`ident.predictor`, whose kernel, sampling,
Levenberg-Marquardt solver and start gains are reused): at each run's nominal speed the
entries give the canonical parameters theta(v) = [a1..a8, b1, b2] of
:func:`ident.canonical.theta_from_matrices`, the model is sampled with a zero-order hold and
the one-step prediction error comes from the innovations predictor
xhat[k+1] = Ad xhat[k] + Bd u[k] + K (y[k] - C xhat[k]).  ``noise_model="free"`` (default)
estimates one innovation gain K per speed with the matrices (which makes the estimate
consistent in closed loop, as the canonical PEM); the initial state of every run is
projected out.  The Jacobian is exact: d theta / d entry is analytic
(d M^-1 = -M^-1 dM M^-1), chained with the kernel's sensitivities d e / d theta.

Conditioning: the Fisher information of the free entries is the Schur complement of the
information matrix J'J on the innovation gains (the gains and initial states are nuisance
parameters); its condition number after scaling to unit diagonal, square-rooted, is the
condition number of the column-scaled Jacobian (:attr:`GreyboxModel.condition`), and
each entry's ``inflation`` is the factor by which the other free entries inflate its
standard error (sqrt of its variance inflation factor).  A free set whose condition
number exceeds ``max_condition`` (default :data:`MAX_CONDITION`) at the start model or at
the optimum is refused (:class:`bikeid.sim.errors.UntrustworthyResult`, naming the
number and the entries of the weakest direction); with ``drop_unidentifiable=True`` the
entry with the largest share of the weakest direction is fixed instead, one at a time,
until the number is below the threshold (the result's ``dropped`` names them).

Lateral force ``F``: when a run logs one, the predictor gets a second input column
M^-1 H (H = [HpF, HdF], the torque per newton of F on the roll and steer equations) and the
entries HpF, HdF may be free (the default set then includes HdF, as Moore & Hubbard's).  The
two inputs are handled by superposition: the innovations predictor is linear in (T_delta, F,
y), so the prediction error is the sum of the kernel's pass over (T_delta, y) and a pass over
(F, 0) from a zero state, and so are their sensitivities.  Runs with a nonzero roll torque
``T_phi`` are refused (not supported).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import expm, expm_frechet

from bikeid.dataset.run import Run
from bikeid.ident.canonical import (
    A_POS,
    B_POS,
    canonical_ab,
    speed_map,
    speed_params_from_matrices,
    theta_from_matrices,
)
from bikeid.ident.direct import ALL_ENTRIES, MOORE_ROLL, MOORE_STEER, parse_entry
from bikeid.ident.informativity import guard
from bikeid.ident.linear_model import SpeedDependentModel
from bikeid.ident.pem import CanonicalModel, SpeedCanonicalModel
from bikeid.ident.predictor import (
    DEFAULT_OUTPUTS,
    PredictionProblem,
    discretize,
    discretize_with_derivatives,
    eliminate_initial_state,
    initial_gain,
    levenberg_marquardt,
    output_matrix,
    prediction_kernel,
    run_data,
    single_threaded_blas,
)
from bikeid.ident.signals import check_sampling
from bikeid.sim.errors import InputError, UntrustworthyResult
from bikeid.sim.linear import (
    CanonicalMatrices,
    canonical_matrices,
    lateral_force_vector,
    state_matrices,
)
from bikeid.sim.parameters import BicycleParameters, from_mapping

__all__ = [
    "DEFAULT_FREE",
    "MAX_CONDITION",
    "GreyboxModel",
    "fit",
    "theta_jacobian",
]

#: Moore & Hubbard's free sets (roll row, then steer row) without HdF (added by ``fit`` when a
#: run has a lateral force).
DEFAULT_FREE = MOORE_ROLL + tuple(n for n in MOORE_STEER if n != "HdF")
#: Largest accepted condition number of the column-scaled Jacobian of the free entries.
#: A direction that badly determined has a standard error 1e4 times the best-determined
#: one's (relative units): with the per-entry errors of ~0.1-1 % typical of the testbed's
#: 50 s runs it is undetermined.  Measured: Moore & Hubbard's set over 2-8 m/s 10
#: (tests/ident/test_greybox.py), with K0pp over the 29 speeds of ``bikeid accuracy`` 475-518;
#: K0dd and K2dd both free at one speed 7.7e7 (exactly collinear, the number is round-off).
MAX_CONDITION = 1e4
_MATS = ("M", "C1", "K0", "K2")
_SYM = {"Mdp": "Mpd", "K0dp": "K0pd"}
_FORCE = ("HpF", "HdF")


def _h(vals: Mapping[str, float]) -> np.ndarray:
    return np.array([vals.get("HpF", 0.0), vals.get("HdF", 0.0)])


def _matrices(vals: Mapping[str, float], g: float) -> CanonicalMatrices:
    mats = {m: np.array([[vals[f"{m}{r}{c}"] for c in "pd"] for r in "pd"]) for m in _MATS}
    return CanonicalMatrices(M=mats["M"], C1=mats["C1"], K0=mats["K0"], K2=mats["K2"], g=g)


def _unit(name: str, symmetric: bool) -> dict[str, np.ndarray]:
    """Derivative of each matrix with respect to the entry ``name`` (both symmetric cells)."""
    m, r, c = parse_entry(name)
    d = {k: np.zeros((2, 2)) for k in _MATS}
    d["H"] = np.zeros(2)
    if m == "H":
        d["H"][r] = 1.0
        return d
    d[m][r, c] = 1.0
    if symmetric and name in _SYM.values():
        d[m][c, r] = 1.0
    return d


def theta_jacobian(
    cm: CanonicalMatrices,
    v: float,
    free: Sequence[str],
    symmetric: bool = True,
    H: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Canonical parameters theta(v) of the matrices and their derivatives by the free entries.

    Parameters
    ----------
    cm : CanonicalMatrices
        M [kg m^2], C1 [kg m], K0 [kg m], K2 [kg] and g [m/s^2].
    v : float
        Forward speed [m/s].
    free : sequence of str
        Entry names (:mod:`ident.direct` naming, e.g. ``"Mpd"``, ``"K2dd"``).
    symmetric : bool, optional
        ``Mpd`` and ``K0pd`` move both off-diagonal cells of their matrix.
    H : (2,) array_like, optional
        Lateral-force column [HpF, HdF] [m]; when given, theta is extended by the lateral-force
        input column M^-1 H (``HpF``/``HdF`` may then be free).

    Returns
    -------
    theta : (10,) or (12,) ndarray
        [a1, ..., a8, b1, b2] (:func:`ident.canonical.theta_from_matrices`): odd a's
        [1/s^2], even a's [1/s], b [1/(kg m^2)]; with ``H`` also [f1, f2] = M^-1 H
        [m/(kg m^2)] (the F column of the acceleration rows).
    jac : (10, len(free)) or (12, len(free)) ndarray
        d theta / d entry, in theta's units per unit of the entry's matrix
        (d M^-1 = -M^-1 dM M^-1; odd a's -M^-1 (g K0 + v^2 K2), even a's -v M^-1 C1).

    Raises
    ------
    ValueError
        If a name is not a matrix entry, or is HpF/HdF without ``H``.
    """
    Minv = np.linalg.inv(cm.M)
    S, D = cm.stiffness(v), cm.damping(v)
    n = 10 if H is None else 12
    jac = np.empty((n, len(free)))
    for j, name in enumerate(free):
        d = _unit(name, symmetric)
        if H is None and np.any(d["H"]):
            raise ValueError(f"{name}: pass H= (the lateral-force column) to differentiate by it")
        dMinv = -Minv @ d["M"] @ Minv
        dAl = -dMinv @ S - Minv @ (cm.g * d["K0"] + v**2 * d["K2"])
        dAr = -dMinv @ D - v * Minv @ d["C1"]
        jac[:10, j] = [dAl[0, 0], dAr[0, 0], dAl[0, 1], dAr[0, 1], dAl[1, 0], dAr[1, 0],
                       dAl[1, 1], dAr[1, 1], dMinv[0, 1], dMinv[1, 1]]  # fmt: skip
        if H is not None:
            jac[10:, j] = dMinv @ H + Minv @ d["H"]
    theta = theta_from_matrices(cm, v)
    if H is not None:
        theta = np.concatenate([theta, Minv @ np.asarray(H, float)])
    return theta, jac


def _discretize_force(theta: np.ndarray, dt: float, derivatives: bool):
    """ZOH of the two-input model (T_delta, F) of the extended theta (12,): Ad, Bd, Bfd and,
    with ``derivatives``, their derivatives by the 12 parameters (``expm_frechet``)."""
    A, B = canonical_ab(theta[:10])
    Z = np.zeros((6, 6))
    Z[:4, :4], Z[:4, 4] = A * dt, B[:, 0] * dt
    Z[B_POS[0], 5], Z[B_POS[1], 5] = theta[10] * dt, theta[11] * dt
    if not derivatives:
        E = expm(Z)
        return E[:4, :4], E[:4, 4], E[:4, 5], None, None, None
    dAd, dBd, dBfd = np.empty((12, 4, 4)), np.empty((12, 4)), np.empty((12, 4))
    E = None
    for i in range(12):
        dZ = np.zeros((6, 6))
        if i < 8:
            dZ[A_POS[i]] = dt
        elif i < 10:
            dZ[B_POS[i - 8], 4] = dt
        else:
            dZ[B_POS[i - 10], 5] = dt
        E, dE = expm_frechet(Z, dZ)
        dAd[i], dBd[i], dBfd[i] = dE[:4, :4], dE[:4, 4], dE[:4, 5]
    return E[:4, :4], E[:4, 4], E[:4, 5], dAd, dBd, dBfd


class _GreyProblem(PredictionProblem):
    """Prediction errors of runs at several speeds, parameters [free entries, K per speed].

    Reuses :class:`ident.predictor.PredictionProblem`'s residual (x0 projected out); with
    ``forces`` (one F array per run) the error is the superposition of the kernel's passes
    over (T_delta, y) and (F, 0), the latter added by ``_extra_error``.  The Jacobian is
    never stored whole: per run its columns are accumulated into J'J and J'r (x0
    eliminated), whose innovation-gain blocks are per speed group.
    """

    def __init__(self, data, groups, Ks, vals, free, symmetric, g, free_k, weights, outputs,
                 forces=None):  # fmt: skip
        super().__init__(data, None, Ks, free_k, weights, outputs)
        self.groups, self.vals, self.free = groups, dict(vals), tuple(free)
        self.symmetric, self.g, self.forces = symmetric, g, forces
        self.n_groups = max(groups) + 1
        self._H = self._gvec = None

    @property
    def n_params(self) -> int:
        return len(self.free) + (4 * self.L * self.n_groups if self.free_k else 0)

    def values(self, p) -> dict[str, float]:
        vals = dict(self.vals)
        for n, val in zip(self.free, p, strict=True):
            vals[n] = float(val)
            if self.symmetric and n in _SYM.values():
                vals[next(k for k, s in _SYM.items() if s == n)] = float(val)
        return vals

    def matrices(self, p) -> CanonicalMatrices:
        return _matrices(self.values(p), self.g)

    def split(self, x):
        P, nk = len(self.free), 4 * self.L
        if not self.free_k:
            return x[:P], None
        return x[:P], [x[P + i * nk : P + (i + 1) * nk].reshape(4, self.L)
                       for i in range(self.n_groups)]  # fmt: skip

    def _models(self, x, derivatives: bool):
        """Per run (Ad, Bd, dAd, dBd, K, S), plus (Bfd, dBfd) with forces; None if unstable."""
        p, Kfree = self.split(x)
        vals = self.values(p)
        cm = _matrices(vals, self.g)
        H = _h(vals) if self.forces is not None else None
        out, cache = [], {}
        for i, d in enumerate(self.data):
            key = (d.dt, d.v)
            if key not in cache:
                try:
                    if derivatives:
                        theta, S = theta_jacobian(cm, d.v, self.free, self.symmetric, H)
                    else:
                        theta, S = theta_from_matrices(cm, d.v), None
                        if H is not None:
                            theta = np.concatenate([theta, np.linalg.solve(cm.M, H)])
                except np.linalg.LinAlgError:  # a trial step made M singular
                    return None
                if not np.all(np.isfinite(theta)):
                    return None
                if H is not None:
                    Ad, Bd, Bfd, dAd, dBd, dBfd = _discretize_force(theta, d.dt, derivatives)
                    cache[key] = (Ad, Bd, dAd, dBd, S, Bfd, dBfd)
                elif derivatives:
                    cache[key] = (*discretize_with_derivatives(theta, d.dt), S)
                else:
                    cache[key] = (*discretize(theta, d.dt), None, None, S)
            Ad, Bd, dAd, dBd, S, *force = cache[key]
            K = Kfree[self.groups[i]] if self.free_k else self.Ks[i]
            if not np.max(np.abs(np.linalg.eigvals(Ad - K @ self.C))) < 1.0:
                return None
            out.append((Ad, Bd, dAd, dBd, K, S, *force))
        return out

    def _extra_error(self, i: int, model) -> np.ndarray | float:
        """The lateral force's share of run ``i``'s errors: the kernel's pass over (F, 0)."""
        if self.forces is None:
            return 0.0
        Ad, K, Bfd = model[0], model[4], model[6]
        Ef, _ = prediction_kernel(Ad, Bfd, K, np.zeros((0, 4, 4)), np.zeros((0, 4)),
                                  np.zeros((0, 4, self.L)), self.forces[i],
                                  np.zeros_like(self.data[i].y), self.idx, np.zeros(4),
                                  False, self.w)  # fmt: skip
        return Ef

    def normal_equations(self, x):
        """(residual, J'J, J'r) at x with the x0 columns projected out, or (None, None, None)."""
        r = self.residual(x)
        if r is None:
            return None, None, None
        models = self._models(x, derivatives=True)
        P, nk = len(self.free), 4 * self.L
        n = self.n_params
        H, gv = np.zeros((n, n)), np.zeros(n)
        start = 0
        for i, (d, x0, model) in enumerate(zip(self.data, self.x0s, models, strict=True)):
            Ad, Bd, dAd, dBd, K, S = model[:6]
            no_dk = np.zeros((0, 4, self.L))
            _, J = prediction_kernel(Ad, Bd, K, dAd, dBd, no_dk, d.u, d.y, self.idx, x0,
                                     self.free_k, self.w)  # fmt: skip
            if self.forces is not None:  # superposition: + the pass over (F, 0) from x = 0
                Bfd, dBfd = model[6:]
                _, Jf = prediction_kernel(Ad, Bfd, K, dAd, dBfd, no_dk, self.forces[i],
                                          np.zeros_like(d.y), self.idx, np.zeros(4),
                                          self.free_k, self.w)  # fmt: skip
                J[:, :, :-4] += Jf[:, :, :-4]
            J = J.reshape(-1, J.shape[2])  # weighted by the kernel
            ri = r[start : start + J.shape[0]]
            start += J.shape[0]
            # Gram of [d e/d theta, d e/d K, d e/d x0], chained to the entries; the x0 columns
            # are eliminated by the Schur complement, which equals J'J of the Kaufman-projected
            # Jacobian (ident.pem), without forming it
            nt = S.shape[0]
            rest = J.shape[1] - nt  # K columns and the 4 x0 columns
            T = np.zeros((J.shape[1], P + rest))
            T[:nt, :P] = S
            T[nt:, P:] = np.eye(rest)
            G_proj, g_proj = eliminate_initial_state(T.T @ (J.T @ J) @ T, T.T @ (J.T @ ri))
            cols = np.arange(P)
            if self.free_k:
                k0 = P + self.groups[i] * nk
                cols = np.concatenate([cols, np.arange(k0, k0 + nk)])
            H[np.ix_(cols, cols)] += G_proj
            gv[cols] += g_proj
        self._x, self._r, self._H, self._gvec = x.copy(), r, H, gv
        return r, H, gv

    def jacobian(self, x):
        raise NotImplementedError("the grey-box problem provides normal_equations only")


def _conditioning(H: np.ndarray, P: int) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """Condition number of the column-scaled Jacobian of the first P parameters (nuisance
    parameters eliminated), per-parameter SE inflation, weakest direction, marginal info."""
    A = H[:P, :P]
    if H.shape[0] > P:
        B, D = H[:P, P:], H[P:, P:]
        A = A - B @ np.linalg.lstsq(D, B.T, rcond=None)[0]
    A = 0.5 * (A + A.T)
    s = np.sqrt(np.clip(np.diag(A), 0.0, None))
    if np.any(s == 0):
        weak = (s == 0).astype(float)
        return float("inf"), np.full(P, np.inf), weak / np.linalg.norm(weak), A
    F = A / np.outer(s, s)
    lam, V = np.linalg.eigh(F)
    cond = float(np.sqrt(lam[-1] / lam[0])) if lam[0] > 0 else float("inf")
    try:
        infl = np.sqrt(np.clip(np.diag(np.linalg.inv(F)), 0.0, None))
    except np.linalg.LinAlgError:
        infl = np.full(P, np.inf)
    return cond, infl, V[:, 0], A


@dataclass(frozen=True)
class GreyboxModel(SpeedDependentModel):
    """Grey-box estimate of the Whipple matrices (free entries estimated, others fixed).

    Attributes
    ----------
    M : (2, 2) ndarray
        Mass matrix [kg m^2], rows/columns [phi, delta].
    C1 : (2, 2) ndarray
        Velocity-dependent damping-like matrix [kg m]; ``v C1`` is in N m s/rad.
    K0 : (2, 2) ndarray
        Gravity-dependent stiffness matrix [kg m]; ``g K0`` is in N m/rad.
    K2 : (2, 2) ndarray
        Velocity-dependent stiffness matrix [kg]; ``v^2 K2`` is in N m/rad.
    g : float
        Gravitational acceleration [m/s^2] of K0.
    H : (2,) ndarray
        Lateral-force column [HpF, HdF] [m] (N m per N of F on the roll and steer
        equations); zeros when no run had a lateral force.
    free : dict of str to float
        Estimated entries and their values (matrix units); ``Mpd``/``K0pd`` stand for both
        off-diagonal cells when ``symmetric``.
    stderr : dict of str to float
        Standard error of each estimated entry (same units), from sigma^2 (J'J)^-1 of the
        whitened residuals with the innovation gains and initial states as nuisance
        parameters.
    covariance : (P, P) ndarray
        Covariance of the free entries in the order of ``free``.
    condition : float
        Condition number of the column-scaled Jacobian of the free entries at the optimum
        (dimensionless; see the module docstring).
    inflation : dict of str to float
        Per free entry: factor by which correlation with the other free entries inflates
        its standard error (sqrt of the variance inflation factor, >= 1).
    weakest : dict of str to float
        The weakest scaled direction (unit vector over the free entries).
    dropped : tuple of str
        Entries fixed by ``drop_unidentifiable`` (at their reference/start values).
    fixed : dict of str to float
        Every entry not estimated, at its fixed value (the symmetric copy of a free entry,
        Mdp or K0dp, is not listed).
    symmetric : bool
        Whether ``Mpd``/``K0pd`` tie both off-diagonal cells.
    K : dict of float to (4, L) ndarray
        Discrete innovation gain per speed [m/s] (canonical state order
        [phi, phidot, delta, deltadot]); zeros for ``noise_model="none"``.
    dt : float
        Sample period [s].
    outputs : tuple of str
        Measured states fitted.
    speeds : tuple of float
        Nominal speeds [m/s] of the runs (sorted, distinct).
    noise_covariance : (L, L) ndarray
        Sample covariance of the one-step prediction errors (outputs' units squared).
    cost : float
        Sum of squared weighted prediction errors at the optimum (dimensionless).
    nfev : int
        Residual evaluations over all passes.
    notes : tuple of str
        Remarks (dropped entries, minimizer messages).
    """

    M: np.ndarray
    C1: np.ndarray
    K0: np.ndarray
    K2: np.ndarray
    g: float
    H: np.ndarray
    free: dict[str, float]
    stderr: dict[str, float]
    covariance: np.ndarray
    condition: float
    inflation: dict[str, float]
    weakest: dict[str, float]
    dropped: tuple[str, ...]
    fixed: dict[str, float]
    symmetric: bool
    K: dict[float, np.ndarray]
    dt: float
    outputs: tuple[str, ...]
    speeds: tuple[float, ...]
    noise_covariance: np.ndarray
    cost: float = float("nan")
    nfev: int = 0
    notes: tuple[str, ...] = field(default_factory=tuple)

    @property
    def least_determined(self) -> tuple[str, ...]:
        """tuple of str: free entries with more than 20 % share (|component| > 0.2) of the
        weakest scaled direction, largest first (the ones ``drop_unidentifiable`` would fix
        first; poorly determined only if :attr:`condition` is large)."""
        order = sorted(self.weakest, key=lambda n: -abs(self.weakest[n]))
        return tuple(n for n in order if abs(self.weakest[n]) > 0.2)

    def canonical(self) -> CanonicalMatrices:
        """The estimated matrices as :class:`bikeid.sim.linear.CanonicalMatrices`.

        Returns
        -------
        CanonicalMatrices
            ``M, C1, K0, K2, g`` of this result.
        """
        return CanonicalMatrices(M=self.M, C1=self.C1, K0=self.K0, K2=self.K2, g=self.g)

    def entry(self, name: str) -> float:
        """Value of one matrix entry by name (``"Mpd"``, ``"K2dd"``, ...).

        Parameters
        ----------
        name : str
            Entry name (:mod:`ident.direct` naming) of M, C1, K0, K2 or H.

        Returns
        -------
        float
            The entry in its matrix's units (M kg m^2, C1 kg m, K0 kg m, K2 kg, H m).

        Raises
        ------
        ValueError
            If ``name`` is not an entry name.
        """
        m, r, c = parse_entry(name)
        return float(self.H[r] if m == "H" else getattr(self, m)[r, c])

    def theta(self, v: float) -> np.ndarray:
        """Canonical parameters at speed ``v`` (:func:`ident.canonical.theta_from_matrices`).

        Parameters
        ----------
        v : float
            Forward speed [m/s].

        Returns
        -------
        (10,) ndarray
            [a1, ..., a8, b1, b2] (odd a's [1/s^2], even a's [1/s], b [1/(kg m^2)]).
        """
        return theta_from_matrices(self.canonical(), v)

    def theta_covariance(self, v: float) -> np.ndarray:
        """Covariance of :meth:`theta` at ``v``, propagated linearly from the free entries.

        Parameters
        ----------
        v : float
            Forward speed [m/s].

        Returns
        -------
        (10, 10) ndarray
            J cov J' with J = d theta / d entry (:func:`theta_jacobian`), squared units of
            theta.
        """
        J = self._theta_jacobian(v)
        return J @ self.covariance @ J.T

    def _theta_jacobian(self, v: float) -> np.ndarray:
        """d theta(v) / d free entries (10, P); H entries (free when a run had F) enter
        theta only through the F column, so their columns here are zero."""
        forced = any(n in _FORCE for n in self.free)
        H = self.H if forced else None
        return theta_jacobian(self.canonical(), v, tuple(self.free), self.symmetric, H)[1][:10]

    def speed_model(self):
        """The estimate as a speed-parameterized canonical model (what v_w, v_c intervals use).

        The matrices give the 14 speed parameters p = [alpha, beta, gamma, b]
        (:func:`ident.canonical.speed_params_from_matrices`; theta(v) = S(v) p); their
        covariance is dp/de cov dp/de' with dp/de solved exactly from d theta / d e at
        v = 0, 1, 2 m/s (theta is linear in p: S(0), S(1), S(2) stacked have full column
        rank).

        Returns
        -------
        ident.pem.SpeedCanonicalModel
            ``params`` (14,), ``covariance`` (14, 14), ``per_speed`` = :meth:`at` of each
            fitted speed, ``dt``, ``g``, ``outputs``, ``cost``, ``nfev`` of this fit.
        """
        grid = (0.0, 1.0, 2.0)
        S = np.vstack([speed_map(v) for v in grid])
        J = np.vstack([self._theta_jacobian(v) for v in grid])
        dp = np.linalg.lstsq(S, J, rcond=None)[0]
        return SpeedCanonicalModel(
            params=speed_params_from_matrices(self.canonical()),
            covariance=dp @ self.covariance @ dp.T, per_speed={v: self.at(v) for v in self.K},
            dt=self.dt, g=self.g, outputs=self.outputs, cost=self.cost, nfev=self.nfev,
        )  # fmt: skip

    def at(self, v: float):
        """The canonical model at speed ``v``: what saving, validation and intervals use.

        Parameters
        ----------
        v : float
            Forward speed [m/s]; need not be one of the fitted speeds.

        Returns
        -------
        ident.pem.CanonicalModel
            theta = :meth:`theta` (v), covariance :meth:`theta_covariance` (v) (delta method
            from the free entries), innovation gain ``K`` and ``noise_covariance`` of the
            fitted speed nearest to ``v``, input T_delta only (a lateral-force column H is
            not part of it), as :meth:`ident.pem.SpeedCanonicalModel.at`.
        """
        near = min(self.K, key=lambda s: abs(s - v))
        return CanonicalModel(
            theta=self.theta(v), covariance=self.theta_covariance(v), K=self.K[near],
            dt=self.dt, speed=float(v), noise_covariance=self.noise_covariance,
            outputs=self.outputs,
        )  # fmt: skip

    def _matrices_at(self, speed: float) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        A, B = state_matrices(self.canonical(), speed)
        Bf = np.concatenate([np.zeros(2), np.linalg.solve(self.M, self.H)])
        return A, {"T_phi": B[:, 0], "T_delta": B[:, 1], "F": Bf}

    def _speed_matrices(self) -> CanonicalMatrices:
        return self.canonical()

    def steer_zeros(self) -> np.ndarray:
        """Zeros of delta/T_delta: roots of Mpp s^2 + v C1pp s + g K0pp + v^2 K2pp at v = 0.

        Returns
        -------
        (2,) complex ndarray
            +-sqrt(-g K0pp / Mpp) [1/s] (speed-independent when C1pp = K2pp = 0, as in the
            Whipple model; the speed terms are ignored here).
        """
        z = np.sqrt(complex(-self.g * self.K0[0, 0] / self.M[0, 0]))
        return np.array([z, -z])


def _meta_bicycle(runs) -> BicycleParameters | None:
    """The simulated bicycle of the runs' metadata (linear loop or sweep), else None."""
    meta = runs[0].meta
    values = meta.get("parameters") or (meta.get("bicycle") or {}).get("parameters")
    return from_mapping(values, name="run meta") if values else None


def _reference(reference, runs) -> CanonicalMatrices:
    if reference is None:
        reference = _meta_bicycle(runs)
        if reference is None:
            raise InputError(
                "no values for the fixed entries: pass reference=BicycleParameters (or use "
                "runs whose meta holds the simulated bicycle's parameters)"
            )
    if isinstance(reference, BicycleParameters):
        return canonical_matrices(reference)
    if isinstance(reference, CanonicalMatrices):
        return reference
    raise InputError("reference must be BicycleParameters or CanonicalMatrices")


def _free_set(free, symmetric, forced: bool) -> tuple[str, ...]:
    if free is None:
        free = DEFAULT_FREE + (("HdF",) if forced else ())
    free = tuple(free)
    if not free or len(set(free)) != len(free):
        raise InputError(f"free set {free} must be non-empty without repeats")
    for n in free:
        if n not in ALL_ENTRIES:
            raise InputError(f"unknown matrix entry {n!r}; valid names are {list(ALL_ENTRIES)}")
        if n in _FORCE and not forced:
            raise InputError(
                f"{n} is free but F is zero in every run, so the lateral-force column is not "
                "identifiable; drop it from the free set"
            )
    clash = [n for n in _SYM if n in free] if symmetric else []
    if clash:
        raise InputError(
            f"{clash} are tied to {[_SYM[n] for n in clash]} by symmetry: free the latter or "
            "pass symmetric=False"
        )
    return free


def _force_column(H, reference, runs) -> tuple[float, float]:
    if H is not None:
        h = np.asarray(H, float)
        if h.shape != (2,) or not np.all(np.isfinite(h)):
            raise InputError(f"H={H!r}: give two finite numbers (HpF, HdF) [m]")
        return float(h[0]), float(h[1])
    point = runs[0].meta.get("lateral_force_point")
    ref = _meta_bicycle(runs) if reference is None else reference
    if point is None or not isinstance(ref, BicycleParameters):
        raise InputError(
            "a run has a lateral force F but no H is known: pass H=(HpF, HdF) [m], or use runs "
            "with meta['lateral_force_point'] and a BicycleParameters reference"
        )
    h = lateral_force_vector(ref, *point)
    return float(h[0]), float(h[1])


def _refuse(cond, weak, names, max_condition, where) -> UntrustworthyResult:
    order = np.argsort(-np.abs(weak))
    involved = [names[i] for i in order if abs(weak[i]) > 0.2] or [names[order[0]]]
    return UntrustworthyResult(
        f"free set unidentifiable from these data {where}: condition number {cond:.3g} of the "
        f"column-scaled Jacobian exceeds {max_condition:g}; {involved} are (nearly) "
        "collinear. Fix one of them (free=...), add runs at other speeds, or pass "
        "drop_unidentifiable=True (CLI: --drop-unidentifiable)."
    )


@single_threaded_blas
def fit(
    runs: Run | Sequence[Run],
    free: Sequence[str] | None = None,
    reference: BicycleParameters | CanonicalMatrices | None = None,
    *,
    start: Mapping[str, float] | None = None,
    symmetric: bool = True,
    outputs: Sequence[str] = DEFAULT_OUTPUTS,
    noise_model: str = "free",
    max_nfev: int = 100,
    passes: int = 2,
    max_condition: float = MAX_CONDITION,
    drop_unidentifiable: bool = False,
    H: Sequence[float] | None = None,
    informativity: str = "refuse",
) -> GreyboxModel:
    """Grey-box PEM of the free entries of M, C1, K0, K2 over runs at one or many speeds.

    Parameters
    ----------
    runs : Run or sequence of Run
        Runs with one sample period, nonzero ``T_delta`` [N m, positive to the right],
        zero ``T_phi``, optionally a lateral force ``F`` [N, positive to the right], and the
        ``outputs`` signals (``phi``, ``delta`` [rad], ``phidot``, ``deltadot`` [rad/s]);
        each at its nominal ``run.speed`` [m/s] (per-sample speed variation is ignored).
    free : sequence of str, optional
        Entries to estimate (:mod:`ident.direct` names); default :data:`DEFAULT_FREE`
        (Moore & Hubbard's roll and steer sets), plus HdF when a run has a lateral force.
    reference : BicycleParameters or CanonicalMatrices, optional
        Values of the fixed entries and start of the free ones (default: the first run's
        ``meta['parameters']``).
    start : mapping of str to float, optional
        Start values overriding the reference for some free entries (matrix units).
    symmetric : bool, optional
        ``Mpd`` and ``K0pd`` stand for both off-diagonal cells (M and K0 symmetric).
    outputs : sequence of str, optional
        Measured states fitted; must include phi and delta.
    noise_model : {"free", "none"}, optional
        One innovation gain per speed estimated (closed-loop consistent), or K = 0
        (output error).
    max_nfev : int, optional
        Residual evaluations allowed per weighting pass.
    passes : int, optional
        Fits with re-estimated output weights (at least 1).
    max_condition : float, optional
        Largest accepted condition number of the column-scaled Jacobian of the free entries.
    drop_unidentifiable : bool, optional
        Instead of refusing, fix the worst-determined entries (largest share of the weakest
        direction) at their start values until the condition number is below
        ``max_condition``.
    H : (float, float), optional
        (HpF, HdF) [m], values (and starts) of the lateral-force column when a run has a
        lateral force; default from the runs' ``meta['lateral_force_point']``
        (:func:`bikeid.sim.linear.lateral_force_vector`) with a ``BicycleParameters``
        reference.  Not used when F is zero in every run.
    informativity : {"refuse", "report", "skip"}, optional
        Before the fit, whether the runs can determine the free entries, with excited runs
        at two or more speeds when they span two (:func:`bikeid.ident.informativity.guard`):
        refuse when they cannot (default), or fit and say so in ``notes``, or skip the
        check (``notes`` says so).

    Returns
    -------
    GreyboxModel
        Matrices, estimates, standard errors, conditioning, innovation gains.

    Raises
    ------
    InputError
        If no runs are given, a run breaks the sampling contract, runs differ in sample
        period, ``T_delta`` is zero or ``T_phi`` nonzero in a run, an option or entry name
        is invalid, HpF/HdF are free without a lateral force, or no fixed values (matrices,
        or H with a lateral force) are available.
    UntrustworthyResult
        If the free set's condition number exceeds ``max_condition`` (and
        ``drop_unidentifiable`` is False), no stable predictor exists at the start, or the
        runs cannot determine the model and ``informativity`` is ``"refuse"``.
    """
    runs = [runs] if isinstance(runs, Run) else list(runs)
    if not runs:
        raise InputError("no runs given")
    try:
        check_sampling(runs, "greybox.fit")
    except UntrustworthyResult:
        raise
    except ValueError as exc:
        raise InputError(str(exc)) from None
    if noise_model not in ("free", "none"):
        raise InputError(f"noise_model {noise_model!r}: choose 'free' or 'none'")
    outputs = tuple(outputs)
    try:
        C, _ = output_matrix(outputs)
        data = run_data(runs, outputs)
    except ValueError as exc:
        raise InputError(str(exc)) from None
    if any(np.any(np.asarray(r["T_phi"], float)) for r in runs):
        raise InputError(
            "T_phi is nonzero in a run: the grey-box predictor has the inputs T_delta and F "
            "only; use ident.direct for runs with a roll torque"
        )
    forces = [np.asarray(r["F"], float) for r in runs]
    forced = any(np.any(f) for f in forces)
    dts = {round(d.dt, 12) for d in data}
    if len(dts) > 1:
        raise InputError(f"runs have different sample periods {sorted(dts)}; resample first")
    free = _free_set(free, symmetric, forced)
    cm = _reference(reference, runs)
    _, told = guard(runs, len(free), what="the grey-box model", informativity=informativity,
                    min_speeds=2)  # fmt: skip
    vals = {n: float(getattr(cm, parse_entry(n)[0])[parse_entry(n)[1], parse_entry(n)[2]])
            for n in ALL_ENTRIES if n not in _FORCE}  # fmt: skip
    if forced:
        vals["HpF"], vals["HdF"] = _force_column(H, reference, runs)
    for n, val in (start or {}).items():
        if n not in free:
            raise InputError(f"start value for {n!r}, which is not free")
        vals[n] = float(val)
    if symmetric:
        for a, b in _SYM.items():
            vals[a] = vals[b]
    speeds = sorted({round(d.v, 6) for d in data})
    groups = [speeds.index(round(d.v, 6)) for d in data]
    free_k = noise_model == "free"
    yvar = np.mean([np.var(d.y, axis=0) for d in data], axis=0)
    w = 1.0 / np.sqrt(yvar)
    dt = data[0].dt

    def problem(names, Ks) -> _GreyProblem:
        return _GreyProblem(data, groups, Ks, vals, names, symmetric, cm.g, free_k, w, outputs,
                            forces if forced else None)  # fmt: skip

    p0 = np.array([vals[n] for n in free])
    base = problem(free, [None] * len(data)).matrices(p0)
    Kg = []
    for gi, v in enumerate(speeds):
        th = theta_from_matrices(base, v)
        grp = [d for d, k in zip(data, groups, strict=True) if k == gi]
        K = initial_gain(th, dt, C, grp, np.mean([np.var(d.y, axis=0) for d in grp], axis=0),
                       free_k)  # fmt: skip
        if K is None:
            raise UntrustworthyResult(
                f"no stable one-step predictor at {v:g} m/s from the start model; give start= "
                "values closer to the data"
            )
        Kg.append(K)
    Ks = [Kg[k] for k in groups]
    names = list(free)
    dropped: list[str] = []
    notes: list[str] = [told] if told else []
    # conditioning at the start: refuse (or drop) before spending a fit on garbage
    prob = problem(names, Ks)
    x = np.concatenate([p0] + ([K.ravel() for K in Kg] if free_k else []))
    r, H, _ = prob.normal_equations(x)
    if r is None:
        raise UntrustworthyResult("the start model gives an unstable predictor; give start=")
    while True:
        cond, _, weak, _ = _conditioning(H, len(names))
        if cond <= max_condition:
            break
        if not drop_unidentifiable or len(names) == 1:
            raise _refuse(cond, weak, names, max_condition, "at the start model")
        j = int(np.argmax(np.abs(weak)))
        dropped.append(names.pop(j))
        keep = np.delete(np.arange(H.shape[0]), j)
        H, x = H[np.ix_(keep, keep)], x[keep]
    if dropped:
        notes.append(f"fixed at start values (poorly determined, condition > {max_condition:g}): "
                     f"{dropped}")  # fmt: skip
    nfev = 0
    for _ in range(max(1, passes)):
        prob = problem(names, Ks)
        sol = levenberg_marquardt(prob, x, max_nfev)
        nfev += sol.nfev
        x = sol.x
        w = 1.0 / np.sqrt(np.mean(prob.residuals() ** 2, axis=0))
    if not sol.success:
        notes.append(f"Levenberg-Marquardt: {sol.message}")
    P = len(names)
    H, r = prob._H, prob._r
    cond, infl, weak, _ = _conditioning(H, P)
    if cond > max_condition:
        raise _refuse(cond, weak, names, max_condition, "at the optimum")
    dof = max(r.size - H.shape[0] - 4 * len(data), 1)
    cov = float(r @ r) / dof * np.linalg.pinv(H)[:P, :P]
    p, Kf = prob.split(x)
    est_vals = prob.values(p)
    est = _matrices(est_vals, cm.g)
    fixed = {n: vals[n] for n in vals if n not in names}
    for n in _SYM if symmetric else ():
        if _SYM[n] in names:  # the steer-row copy of a free entry is not fixed
            fixed.pop(n)
    se = np.sqrt(np.diag(cov))
    return GreyboxModel(
        M=est.M, C1=est.C1, K0=est.K0, K2=est.K2, g=cm.g, H=_h(est_vals),
        free={n: float(v) for n, v in zip(names, p, strict=True)},
        stderr={n: float(s) for n, s in zip(names, se, strict=True)},
        covariance=cov, condition=cond,
        inflation={n: float(f) for n, f in zip(names, infl, strict=True)},
        weakest={n: float(c) for n, c in zip(names, weak, strict=True)},
        dropped=tuple(dropped), fixed=fixed, symmetric=symmetric,
        K={v: (Kf[i] if free_k else Kg[i]).copy() for i, v in enumerate(speeds)},
        dt=dt, outputs=outputs, speeds=tuple(speeds),
        noise_covariance=np.atleast_2d(np.cov(prob.residuals().T)),
        cost=float(r @ r), nfev=nfev, notes=tuple(notes),
    )  # fmt: skip
