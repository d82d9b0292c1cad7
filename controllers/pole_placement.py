"""Roll tracking by pole placement with integral action (Chen & Dao 2010, eqs. 7-17).

Two laws, both on the measured x = [phi, delta, phidot, deltadot] (y[1], y[2], y[4],
y[5]) and the integral xi' = phi_ref - phi (eq. 8, C* = [1 0 0 0]):

- ``law="chen_dao"``, the paper's eq. 7 (default when ``poles`` are given):
  T = -K x + kI xi.  The reference enters only through the integrator.
- ``law="servo"``, our extension (default with the default poles):
  T = -K (x - x_ref) + kI xi with x_ref = [phi_ref, 0, phidot_ref, 0], i.e. the paper's
  law plus the feedforward K_phi phi_ref + K_phidot phidot_ref (exact ``reference.rate``
  when the reference has one, else a backward difference).  Same gains, same poles.

The gains come from ``control.place`` on the fifth-order error system (eqs. 14-15)

    Aa = [[A, 0], [-C*, 0]],   Ba = [[B], [0]],   Ka = [K, -kI],

so eig(Aa - Ba Ka) are the requested poles.  After placing, the achieved eigenvalues
are checked: ``place`` returns gains of ~1e12 without a warning where the plant is
uncontrollable (the benchmark at v = 1.4110 m/s, controllers.md §3.3), and that
raises :class:`ValueError` with the PBH measure

    min over eigenvalues lambda of A of  sigma_min([A - lambda I, B]) / ||[A, B]||_2.

Default poles (``poles=None``, :func:`tracking_poles`), speed dependent: two poles on the
zeros of phi/T_delta at the design speed (left half plane for v > 0.577 m/s on the
benchmark: -1.71 and -12.9 at 1 m/s, -13.7 and -59.3 at 5 m/s) and three fixed poles
``free_poles`` = (-6, -8, -10) s^-1.  Zeros faster than ``zero_cap`` (30 s^-1) or slower
than 0.5 s^-1 are not cancelled (poles -1.2 cap, -1.4 cap, resp. the mirrored zero); a
zero within 2 % of a free pole is moved 2 % away from it.

Why: placing poles on both roll zeros is the same as choosing the steer gains so that
steer no longer enters the roll acceleration, K_delta = a_delta / b_phi and
K_deltadot = a_deltadot / b_phi, where phidot' = a . x + b_phi T is the roll row of the
model.  Roll then obeys a third-order ODE with the characteristic polynomial
Delta3(s) = s^3 + d2 s^2 + d1 s + d0 = prod(s - p) over the free poles, d0 = b_phi kI,
d1 = b_phi K_phi - a_phi, d2 = b_phi K_phidot - a_phidot, so

    chen_dao:  phi/phi_ref = d0 / Delta3(s)
    servo:     phi/phi_ref = 1 - (s^3 - a_phidot s^2 - a_phi s) / Delta3(s)

at every speed where both zeros are cancelled (a_phi = +9.5 s^-2 is the gravity term of
the benchmark, a_phidot = -0.1 s^-1 at 1 m/s).  On the benchmark that is v < 2.5 m/s; above,
the fast zero (beyond 30 s^-1) is left alone and the relations hold approximately.  The
cancelled modes are invisible in roll and show only in steer.  The paper's law lags like a
third-order low-pass (its Fig. 7 "delay time", here sum(1/|p|) = 0.39 s); the servo error
is 2-10 % of the reference over 0.16-0.5 Hz.  ``poles=[...]`` (five values) gives a fixed-pole
design (e.g. :data:`SLOW_POLES`, the earlier default -2..-6).

Model: by default the true linearization ``sim.linear.state_space(p, v)``
(T_delta column).  Alternatively a user model: a ``control.StateSpace`` with 4 states
(one input T_delta, or an input labelled "T_delta"), or a callable ``v -> StateSpace``
for scheduling.  State order: bikeid's [phi, delta, phidot, deltadot] is used as is.
A Chen & Dao-ordered model [phi, phidot, delta, deltadot] (``ident``'s canonical form,
state order ``sim.conventions.CANONICAL_STATE``) is recognized from its state labels or
declared with ``state_order="chen_dao"``; it is permuted to bikeid order by
x_b = P x_cd (A_b = P A P^T, B_b = P B) before placing, so the gains always act on
the measured [phi, delta, phidot, deltadot].

Scheduling: with ``design_speed`` the gains are placed once at that speed.  Without
it (default), gains are placed on ``speed_grid`` and interpolated linearly at the
measured speed; grid points where placement is inaccurate (near an uncontrollable
speed) are dropped and listed in ``skipped_speeds``.  The default grid (0.8-16 m/s,
step 0.2, none closer than 0.7 % to 1.411 m/s) keeps interpolated loops stable over
1-15 m/s in the linear benchmark model (checked in the tests).

The design is continuous-time; run at ``sample_time`` dt, the zero-order hold adds about
dt/2 of delay: with the default poles |p| dt <= 0.42 at 100 Hz.  Poles must be distinct
(``place`` refuses a pole repeated more than rank(B) = 1 times).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import control
import numpy as np

from bikeid.sim.conventions import CANONICAL_STATE, LINEAR_STATE
from bikeid.sim.linear import state_matrices
from bikeid.sim.parameters import BicycleParameters, benchmark

from .base import (
    DEFAULT_SAMPLE_TIME,
    I_DELTA,
    I_DELTADOT,
    I_PHI,
    I_PHIDOT,
    Controller,
    GainSchedule,
    LinearLaw,
)

__all__ = [
    "DEFAULT_POLES",
    "LAWS",
    "SLOW_POLES",
    "TRACKING_POLES",
    "ZERO_CAP",
    "PolePlacement",
    "augmented_system",
    "pbh_measure",
    "place_with_integral",
    "roll_zeros",
    "to_bikeid_order",
    "tracking_poles",
]

#: The earlier default (fixed poles -2..-6 s^-1; controllers.md §4.4 lists their gains).
SLOW_POLES = (-2.0, -3.0, -4.0, -5.0, -6.0)
#: Kept for imports written before the tracking default; same as :data:`SLOW_POLES`.
DEFAULT_POLES = SLOW_POLES
#: The three poles of the default design that are not placed on the roll zeros [1/s].
TRACKING_POLES = (-6.0, -8.0, -10.0)
#: Roll zeros faster than this [1/s] are not cancelled (kept slow against the sample rate).
ZERO_CAP = 30.0
#: Slowest roll zero [1/s] that is cancelled (slower or right-half-plane zeros are mirrored).
_MIN_ZERO_RATE = 0.5
#: Relative distance below which a cancelling pole is moved off a tracking pole.
_SEPARATION = 0.02
LAWS = ("servo", "chen_dao")
#: Permutation from Chen & Dao order [phi, phidot, delta, deltadot] to bikeid order.
_CD_TO_BIKEID = [CANONICAL_STATE.index(s) for s in LINEAR_STATE]  # [0, 2, 1, 3]


def _default_grid() -> list[float]:
    grid = [round(0.8 + 0.2 * k, 10) for k in range(77)]  # 0.8 ... 16.0
    return grid


def to_bikeid_order(
    A: np.ndarray, B: np.ndarray, state_order: str = "bikeid"
) -> tuple[np.ndarray, np.ndarray]:
    """(A, B) in bikeid state order from a model in ``state_order`` ("bikeid"|"chen_dao").

    Parameters
    ----------
    A : (4, 4) array_like
        State matrix in ``state_order``.
    B : array_like, 4 x m
        Input matrix in ``state_order`` (reshaped to (4, m)).
    state_order : {"bikeid", "chen_dao"}, optional
        ``"bikeid"`` (default): [phi, delta, phidot, deltadot], returned as is;
        ``"chen_dao"``: [phi, phidot, delta, deltadot] (``sim.conventions.CANONICAL_STATE``),
        permuted by x_b = P x_cd (A_b = P A P^T, B_b = P B).

    Returns
    -------
    A : (4, 4) ndarray
        State matrix in bikeid order.
    B : (4, m) ndarray
        Input matrix in bikeid order.

    Raises
    ------
    ValueError
        For an unknown ``state_order``.
    """
    A = np.asarray(A, dtype=float)
    B = np.asarray(B, dtype=float).reshape(A.shape[0], -1)
    if state_order == "bikeid":
        return A, B
    if state_order == "chen_dao":
        p = _CD_TO_BIKEID
        return A[np.ix_(p, p)], B[p, :]
    raise ValueError(f"state_order must be 'bikeid' or 'chen_dao', got {state_order!r}")


def _model_matrices(sys: control.StateSpace, state_order: str | None) -> tuple[np.ndarray, ...]:
    if not isinstance(sys, control.StateSpace):
        raise ValueError(f"model must be a control.StateSpace, got {type(sys).__name__}")
    if sys.isdtime(strict=True):
        raise ValueError("model must be continuous-time (dt=0); convert a discrete model first")
    if sys.nstates != 4:
        raise ValueError(f"model must have 4 states (phi, delta and rates), got {sys.nstates}")
    labels = tuple(getattr(sys, "state_labels", ()))
    if state_order is None:
        if labels == LINEAR_STATE:
            state_order = "bikeid"
        elif labels == CANONICAL_STATE:
            state_order = "chen_dao"
        else:
            raise ValueError(
                f"cannot tell the state order from labels {labels}; pass "
                f"state_order='bikeid' {LINEAR_STATE} or 'chen_dao' {CANONICAL_STATE}"
            )
    inputs = tuple(getattr(sys, "input_labels", ()))
    if sys.ninputs == 1:
        B = sys.B
    elif "T_delta" in inputs:
        B = sys.B[:, [inputs.index("T_delta")]]
    else:
        raise ValueError(
            f"model has {sys.ninputs} inputs {inputs}; give one input or label one 'T_delta'"
        )
    return to_bikeid_order(sys.A, B, state_order)


def augmented_system(A: np.ndarray, B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Chen & Dao eq. (15): Aa = [[A, 0], [-C*, 0]], Ba = [B; 0] with C* = [1, 0, 0, 0].

    The fifth state is the integral xi of phi_ref - phi [rad s] (eq. 8).

    Parameters
    ----------
    A : (4, 4) array_like
        State matrix in bikeid order x = [phi, delta, phidot, deltadot] (kinematic
        rows [0 I]; acceleration rows in 1/s^2 on the angles, 1/s on the rates).
    B : (4,) or (4, 1) array_like
        T_delta input column [rad/(N m s^2) in the acceleration rows, 0 above].

    Returns
    -------
    Aa : (5, 5) ndarray
        Augmented state matrix of [x, xi].
    Ba : (5, 1) ndarray
        Augmented T_delta column (zero in the xi row).
    """
    Aa = np.zeros((5, 5))
    Aa[:4, :4] = A
    Aa[4, 0] = -1.0
    Ba = np.zeros((5, 1))
    Ba[:4] = np.asarray(B, dtype=float).reshape(4, 1)
    return Aa, Ba


def pbh_measure(A: np.ndarray, B: np.ndarray) -> tuple[float, complex]:
    """Relative PBH controllability measure and the eigenvalue where it is smallest.

    min over eigenvalues lambda of A of sigma_min([A - lambda I, B]) / ||[A, B]||_2;
    zero exactly when the mode lambda is uncontrollable.

    Parameters
    ----------
    A : (n, n) ndarray
        State matrix.
    B : (n, m) ndarray
        Input matrix.

    Returns
    -------
    measure : float
        The relative PBH measure [-], >= 0.
    mode : complex
        The eigenvalue of A [1/s] where it is attained.
    """
    n = A.shape[0]
    scale = np.linalg.norm(np.hstack([A, B]), 2)
    best, where = math.inf, 0j
    for lam in np.linalg.eigvals(A):
        s = np.linalg.svd(np.hstack([A - lam * np.eye(n), B]), compute_uv=False)[-1] / scale
        if s < best:
            best, where = float(s), complex(lam)
    return best, where


def place_with_integral(
    A: np.ndarray,
    B: np.ndarray,
    poles: Sequence[complex] = SLOW_POLES,
    rtol: float = 1e-4,
    pbh_tol: float = 1e-6,
) -> tuple[np.ndarray, float]:
    """(K (4,), kI) placing eig(Aa - Ba [K, -kI]) at ``poles``; law T = -K x + kI xi.

    Raises ``ValueError`` when the achieved poles miss the requested ones by more than
    ``rtol`` relative (|p| + 1) scale, which is what happens at an uncontrollable speed,
    or when the relative PBH measure of the augmented system is below ``pbh_tol`` (gains
    that place the poles but are hypersensitive: the benchmark gives PBH 4e-8 and a sign
    flip of the roll-rate gain at 1.411 m/s, and PBH >= 1.7e-6 at 1.410 and 1.412 m/s).

    Parameters
    ----------
    A : (4, 4) array_like
        State matrix in bikeid order x = [phi, delta, phidot, deltadot] (kinematic
        rows [0 I]; acceleration rows in 1/s^2 on the angles, 1/s on the rates).
    B : (4,) or (4, 1) array_like
        T_delta input column [rad/(N m s^2) in the acceleration rows, 0 above].
    poles : sequence of complex, length 5, optional
        Requested closed-loop poles [1/s], distinct, in the open left half plane
        (default :data:`SLOW_POLES`).
    rtol : float, optional
        Largest accepted |achieved - requested| / (|requested| + 1) (default 1e-4).
    pbh_tol : float, optional
        Smallest accepted relative PBH measure of (Aa, Ba) (default 1e-6).

    Returns
    -------
    K : (4,) ndarray
        State gains [K_phi, K_delta, K_phidot, K_deltadot] [N m/rad, N m/rad, N m s/rad,
        N m s/rad].
    kI : float
        Integral gain [N m/(rad s)].

    Raises
    ------
    ValueError
        If ``poles`` are not 5 distinct left-half-plane values, ``control.place`` fails,
        or the placement is inaccurate (pole error above ``rtol``, non-finite gains or
        PBH measure below ``pbh_tol``; the message gives the measure and the mode).
    """
    poles = np.asarray(poles, dtype=complex)
    if poles.shape != (5,):
        raise ValueError(f"need 5 closed-loop poles for the augmented system, got {poles.size}")
    if np.any(poles.real >= 0):
        raise ValueError(f"closed-loop poles must be in the open left half plane, got {poles}")
    if len(set(np.round(poles, 12).tolist())) != 5:
        raise ValueError("poles must be distinct (place refuses repeated poles); space them by 1 %")
    Aa, Ba = augmented_system(A, B)
    try:
        Ka = np.asarray(control.place(Aa, Ba, poles), dtype=float).reshape(5)
    except ValueError as exc:
        raise ValueError(f"pole placement failed: {exc}") from None
    achieved = np.linalg.eigvals(Aa - Ba @ Ka[None, :])
    err = _pole_mismatch(achieved, poles)
    pbh, lam = pbh_measure(Aa, Ba)
    if not np.all(np.isfinite(Ka)) or err > rtol or pbh < pbh_tol:
        raise ValueError(
            f"pole placement is inaccurate (relative pole error {err:.1e}, |K| = "
            f"{np.abs(Ka).max():.1e}): the plant is (nearly) uncontrollable, PBH measure "
            f"{pbh:.1e} at mode {lam.real:.4g}{lam.imag:+.4g}j; choose another speed or model"
        )
    return Ka[:4].copy(), float(-Ka[4])


def _pole_mismatch(achieved: np.ndarray, requested: np.ndarray) -> float:
    """Largest relative distance after matching each requested pole to an achieved one."""
    left = list(achieved)
    worst = 0.0
    for p in requested:
        k = int(np.argmin([abs(a - p) for a in left]))
        worst = max(worst, abs(left.pop(k) - p) / (abs(p) + 1.0))
    return worst


def roll_zeros(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Finite zeros of phi/T_delta [1/s] for the model (A, B) in bikeid order.

    They are the eigenvalues of the roll zero dynamics (the motions with phi = 0 held by
    the torque): with B = [0, 0, b_phi, b_delta]^T, eliminating T from the phidot and
    deltadot rows gives b_delta phi'' - b_phi delta'' = c x, c = b_delta A[2] - b_phi A[3],
    which at phi = 0 is the second-order ODE  -b_phi delta'' = c_delta delta + c_deltadot
    delta'  in delta.  Needs b_phi != 0 (relative degree 2, as for every Whipple model).

    Parameters
    ----------
    A : (4, 4) array_like
        State matrix in bikeid order x = [phi, delta, phidot, deltadot] (kinematic
        rows [0 I]; acceleration rows in 1/s^2 on the angles, 1/s on the rates).
    B : (4,) or (4, 1) array_like
        T_delta input column [rad/(N m s^2) in the acceleration rows, 0 above].

    Returns
    -------
    (2,) complex ndarray
        The two zeros [1/s].

    Raises
    ------
    ValueError
        If b_phi = B[2] is zero (relative to max |B|).
    """
    A = np.asarray(A, dtype=float)
    b = np.asarray(B, dtype=float).reshape(4)
    if abs(b[2]) <= 1e-12 * max(abs(b).max(), 1e-300):
        raise ValueError(
            "the model has no direct steer-torque effect on roll acceleration (B[phidot] = 0); "
            "roll zeros need relative degree 2: pass explicit poles="
        )
    c = b[3] * A[2] - b[2] * A[3]
    # delta'' = -(c_delta delta + c_deltadot delta') / b_phi
    return np.roots([1.0, c[3] / b[2], c[1] / b[2]]).astype(complex)


def tracking_poles(
    A: np.ndarray,
    B: np.ndarray,
    free: Sequence[complex] = TRACKING_POLES,
    cap: float = ZERO_CAP,
) -> np.ndarray:
    """The default five poles at one speed: the roll zeros of (A, B) plus ``free`` (3).

    A zero z of phi/T with 0.5 <= -Re z and |z| <= ``cap`` [1/s] becomes a pole (it then
    cancels from phi/phi_ref and from phi/T); a faster zero gets the pole -cap (1.2 + 0.2 k),
    k = 0, 1 counting such zeros (20 % beyond any cancelled zero); a slower or
    right-half-plane zero gets its mirror image -max(|Re z|, 0.5) + j Im z.  A cancelling
    pole within 2 % of a free pole is moved to 2 % from it (on its own side), so ``place``
    never sees repeated poles.

    Parameters
    ----------
    A : (4, 4) array_like
        State matrix in bikeid order x = [phi, delta, phidot, deltadot] (kinematic
        rows [0 I]; acceleration rows in 1/s^2 on the angles, 1/s on the rates).
    B : (4,) or (4, 1) array_like
        T_delta input column [rad/(N m s^2) in the acceleration rows, 0 above].
    free : sequence of complex, length 3, optional
        The poles not placed on the zeros [1/s] (default :data:`TRACKING_POLES`).
    cap : float, optional
        Fastest cancelled zero [1/s] (default :data:`ZERO_CAP` = 30), positive.

    Returns
    -------
    (5,) complex ndarray
        The two poles derived from the roll zeros (in order of increasing |zero|), then
        ``free`` [1/s].

    Raises
    ------
    ValueError
        If ``free`` does not have 3 entries, ``cap`` is not positive and finite, or the
        roll zeros are undefined (:func:`roll_zeros`).
    """
    free = [complex(p) for p in free]
    if len(free) != 3:
        raise ValueError(f"free poles: need 3 (the other 2 sit on the roll zeros), got {free}")
    cap = float(cap)
    if not (math.isfinite(cap) and cap > 0):
        raise ValueError(f"zero cap must be a positive rate [1/s], got {cap}")
    out: list[complex] = []
    n_fast = 0
    for z in sorted(roll_zeros(A, B), key=abs):
        if abs(z) > cap:
            p = complex(-cap * (1.2 + 0.2 * n_fast))
            n_fast += 1
        elif z.real > -_MIN_ZERO_RATE:
            p = complex(-max(abs(z.real), _MIN_ZERO_RATE), z.imag)
        else:
            p = complex(z)
        for f in free:
            if abs(p - f) < _SEPARATION * abs(f):
                p = f * (1 + _SEPARATION) if abs(p) >= abs(f) else f * (1 - _SEPARATION)
        out.append(p)
    return np.array(out + free, dtype=complex)


class PolePlacement(Controller):
    """State feedback with integral action; see the module docstring.

    poles: five closed-loop poles [1/s] (fixed at every speed), or None (default) for
    :func:`tracking_poles` at each design speed with ``free_poles`` and ``zero_cap``.
    law: ``"servo"`` (reference feedforward) or ``"chen_dao"`` (the paper's eq. 7); None
    (default) picks ``"servo"`` with the default poles and ``"chen_dao"`` with explicit
    ``poles`` (the feedforward x_ref = [phi_ref, 0, phidot_ref, 0] assumes the steer modes
    are cancelled from roll; with slow fixed poles it hurts: -2..-6 at 15 m/s falls).

    Parameters
    ----------
    poles : sequence of complex, length 5, optional
        Fixed closed-loop poles [1/s]; None (default) for :func:`tracking_poles`.
    p : BicycleParameters, optional
        Bicycle (Meijaard 2007 notation) of the design model when ``model`` is None
        (default: the benchmark bicycle).
    model : control.StateSpace or callable, optional
        User design model: a continuous-time 4-state ``StateSpace`` (needs
        ``design_speed``) or a callable v [m/s] -> ``StateSpace``; one input, or one
        labelled ``"T_delta"``.  None (default): ``sim.linear`` at ``p``.
    state_order : {"bikeid", "chen_dao"} or None, optional
        State order of ``model``; None (default) infers it from the state labels.
    design_speed : float, optional
        Speed [m/s] at which the gains are placed once; None (default) schedules them
        over ``speed_grid`` on the measured speed.
    speed_grid : sequence of float, optional
        Scheduling speeds [m/s] (default 0.8-16 m/s in steps of 0.2).
    sample_time, saturation, reference
        As in :class:`~controllers.base.Controller` ([s], [N m], [rad] of t [s]).
    law : {"servo", "chen_dao"} or None, optional
        Control law (module docstring); None picks as described above.
    free_poles : sequence of complex, length 3, optional
        Free poles of :func:`tracking_poles` [1/s] (default (-6, -8, -10)).
    zero_cap : float, optional
        ``cap`` of :func:`tracking_poles` [1/s] (default 30).

    Attributes
    ----------
    law : str
        ``"servo"`` or ``"chen_dao"``.
    poles : list of complex or None
        The fixed poles [1/s], or None for the tracking design.
    free_poles : list of complex
        Free poles [1/s].
    zero_cap : float
        Zero cap [1/s].
    p : BicycleParameters
        The design bicycle.
    state_order : str or None
        State order of the user model.
    schedule : GainSchedule or None
        Rows (K_phi, K_delta, K_phidot, K_deltadot, kI) over speed; None with
        ``design_speed``.
    skipped_speeds : list of float
        Grid speeds [m/s] where placement was inaccurate and which were left out.
    xi : float
        Integral of phi_ref - phi [rad s] (reset to 0 by ``reset()``).

    Raises
    ------
    ValueError
        For an unknown ``law``, invalid ``free_poles``/``zero_cap``, a ``StateSpace``
        model without ``design_speed``, a model that is neither, a bad model
        (:func:`to_bikeid_order`, 4 states, continuous time, T_delta input), an
        inaccurate placement at ``design_speed``, or placement failing at every grid speed.
    """

    name = "pole_placement"

    def __init__(
        self,
        poles: Sequence[complex] | None = None,
        *,
        p: BicycleParameters | None = None,
        model: control.StateSpace | Callable[[float], control.StateSpace] | None = None,
        state_order: str | None = None,
        design_speed: float | None = None,
        speed_grid: Sequence[float] | None = None,
        sample_time: float = DEFAULT_SAMPLE_TIME,
        saturation: float = math.inf,
        reference: Callable[[float], float] | None = None,
        law: str | None = None,
        free_poles: Sequence[complex] = TRACKING_POLES,
        zero_cap: float = ZERO_CAP,
    ):
        if law is None:
            law = "servo" if poles is None else "chen_dao"
        if law not in LAWS:
            raise ValueError(
                f"law must be 'servo' (reference feedforward) or 'chen_dao' (paper eq. 7), "
                f"got {law!r}"
            )
        self.law = law
        self.poles = None if poles is None else [complex(p) for p in poles]
        self.free_poles = [complex(p) for p in free_poles]
        self.zero_cap = float(zero_cap)
        if poles is None:
            tracking_poles(np.zeros((4, 4)), np.r_[0, 0, 1.0, 1.0], self.free_poles, zero_cap)
        self.p = p if p is not None else benchmark()
        self._user_model = model
        if isinstance(model, control.StateSpace):
            if design_speed is None:
                raise ValueError(
                    "a fixed StateSpace model holds at one speed: pass design_speed= (m/s), "
                    "or pass a callable v -> StateSpace to schedule"
                )
        elif model is not None and not callable(model):
            raise ValueError("model must be a control.StateSpace or a callable v -> StateSpace")
        self.state_order = state_order
        self.skipped_speeds: list[float] = []
        # validate the basics before the (possibly long) placement
        super().__init__(sample_time, saturation, reference, design_speed)
        if design_speed is not None:
            K, kI = self.design(self.design_speed)
            self._fixed = (*K.tolist(), kI)
            self.schedule = None
        else:
            grid = _default_grid() if speed_grid is None else [float(s) for s in speed_grid]
            rows, speeds = [], []
            for v in grid:
                try:
                    K, kI = self.design(v)
                except ValueError:
                    self.skipped_speeds.append(v)
                    continue
                speeds.append(v)
                rows.append((*K.tolist(), kI))
            if not speeds:
                raise ValueError(f"pole placement failed at every grid speed {grid}")
            self.schedule = GainSchedule(speeds, rows)
            self._fixed = None

    def linear_model(self, v: float) -> tuple[np.ndarray, np.ndarray]:
        """(A, B) in bikeid order with B the T_delta column, at speed v [m/s].

        Parameters
        ----------
        v : float
            Forward speed [m/s] (ignored by a fixed ``StateSpace`` model).

        Returns
        -------
        A : (4, 4) ndarray
            State matrix, x = [phi, delta, phidot, deltadot].
        B : (4, 1) ndarray
            T_delta column.

        Raises
        ------
        ValueError
            If a user model is not a usable 4-state continuous-time ``StateSpace``.
        """
        model = self._user_model
        if model is None:
            A, B = state_matrices(self.p, v)
            return A, B[:, 1:2]
        sys = model if isinstance(model, control.StateSpace) else model(v)
        return _model_matrices(sys, self.state_order)

    def poles_at(self, v: float) -> np.ndarray:
        """The five requested closed-loop poles [1/s] of the design at speed v [m/s].

        Parameters
        ----------
        v : float
            Forward speed [m/s].

        Returns
        -------
        (5,) complex ndarray
            ``poles``, or :func:`tracking_poles` of the design model at ``v`` [1/s].
        """
        if self.poles is not None:
            return np.array(self.poles, dtype=complex)
        return tracking_poles(*self.linear_model(v), self.free_poles, self.zero_cap)

    def design(self, v: float) -> tuple[np.ndarray, float]:
        """(K, kI) at speed v; raises ValueError where placement is inaccurate.

        Parameters
        ----------
        v : float
            Design speed [m/s].

        Returns
        -------
        K : (4,) ndarray
            [K_phi, K_delta, K_phidot, K_deltadot] [N m/rad, N m/rad, N m s/rad,
            N m s/rad].
        kI : float
            Integral gain [N m/(rad s)].

        Raises
        ------
        ValueError
            If placement fails or is inaccurate at ``v`` (:func:`place_with_integral`;
            the message names the speed).
        """
        A, B = self.linear_model(v)
        try:
            return place_with_integral(A, B, self.poles_at(v))
        except ValueError as exc:
            raise ValueError(f"at v = {v} m/s: {exc}") from None

    def current_gains(self, v: float) -> tuple[float, ...]:
        """(K_phi, K_delta, K_phidot, K_deltadot, kI) at speed v [m/s].

        Parameters
        ----------
        v : float
            Forward speed [m/s] at which the schedule is interpolated (ignored with
            ``design_speed``).

        Returns
        -------
        tuple of float
            [N m/rad, N m/rad, N m s/rad, N m s/rad, N m/(rad s)].
        """
        return self._fixed if self.schedule is None else self.schedule(v)

    @property
    def speed_scheduled(self) -> bool:
        """True if the gains are interpolated at the measured speed (no ``design_speed``)."""
        return self.schedule is not None

    def linear_law(self, v: float) -> LinearLaw | None:
        """T = -K x + kI xi (+ K_phi r + K_phidot r' for the servo law).

        Parameters
        ----------
        v : float
            Speed [m/s] of the scheduled gains (ignored with ``design_speed``).

        Returns
        -------
        LinearLaw or None
            L = -K, l_i = kI, l_r = K_phi and l_rd = K_phidot (servo) or 0 (chen_dao);
            None with a finite ``saturation``.
        """
        if math.isfinite(self.saturation):
            return None
        g = self.current_gains(v)
        servo = self.law == "servo"
        return LinearLaw(
            -np.array(g[:4], dtype=float), float(g[4]),
            float(g[0]) if servo else 0.0, float(g[2]) if servo else 0.0,
        )  # fmt: skip

    def _reset_state(self) -> None:
        super()._reset_state()
        self.xi = 0.0

    def _control(self, t: float, y: Sequence[float], dt: float) -> float:
        g = self._fixed if self.schedule is None else self.schedule(self.speed(y))
        phi = y[I_PHI]
        u = (
            -g[0] * phi - g[1] * y[I_DELTA] - g[2] * y[I_PHIDOT] - g[3] * y[I_DELTADOT]
            + g[4] * self.xi
        )  # fmt: skip
        if self.law == "servo":
            r, rd = self._reference_and_rate(t, dt)
            u += g[0] * r + g[2] * rd
        else:
            r = self.reference(t)
        s = self.saturation
        e = r - phi
        # conditional integration (anti-windup): freeze xi while saturated and winding up
        if not ((u > s and g[4] * e > 0) or (u < -s and g[4] * e < 0)):
            self.xi += e * dt
        return u

    def _gains_description(self) -> dict[str, Any]:
        law = {
            "servo": "T = -K ([phi, delta, phidot, deltadot] - [phi_ref, 0, phidot_ref, 0]) "
            "+ kI int(phi_ref - phi)",
            "chen_dao": "T = -K [phi, delta, phidot, deltadot] + kI int(phi_ref - phi)",
        }[self.law]
        out: dict[str, Any] = {
            "law": law,
            "law_name": self.law,
            "model": "true linearization" if self._user_model is None else "user model",
            "anti_windup": "clamp",
        }
        if self.poles is not None:
            out["poles"] = [[p.real, p.imag] for p in self.poles]
        else:
            out["poles"] = "roll zeros of the design model + free poles"
            out["free_poles"] = [[p.real, p.imag] for p in self.free_poles]
            out["zero_cap"] = self.zero_cap
        if self._user_model is None:
            out["parameters"] = getattr(self.p, "name", None) or "custom"
        if self.schedule is None:
            out["K"] = list(self._fixed[:4])
            out["kI"] = self._fixed[4]
            out["placed_poles"] = [[p.real, p.imag] for p in self.poles_at(self.design_speed)]
        else:
            out["schedule"] = self.schedule.as_dict()
            out["skipped_speeds"] = self.skipped_speeds
        return out
