"""The nonlinear Carvallo-Whipple bicycle (Moore 2012 coordinates).

Equations derived by ``scripts/derive_whipple.py`` (sympy ``KanesMethod``,
``constraint_solver="CRAMER"``) and emitted as numba code in
:mod:`sim._whipple_generated`; no computer algebra at run time.

Coordinates (Moore 2012; frames N inertial with x forward, y right, z down):
q1, q2 rear contact position in N [m]; q3 yaw, q4 roll, q5 rear-frame pitch
(q5 = lam when upright), q6 rear wheel angle (relative to the rear frame),
q7 steer (about the steer axis), q8 front wheel angle [rad]; speeds u_i = q_i'.
Independent speeds u4, u6, u7; u3, u5, u8 follow from the nonholonomic
constraints, q5 from the holonomic one (Newton, warm-started, to round-off).

**Integration state** (:data:`STATE`): ``y = [q1, q2, q3, q4, q6, q7, q8, u4, u6, u7]``.

**Mapping to the benchmark** (Meijaard 2007 signs, checked against
:mod:`sim.linear` by the linearization tests): roll phi = q4, steer delta = q7,
yaw psi = q3 (all positive to the right), phidot = u4, deltadot = u7,
psidot = u3, rear wheel rate thetaRdot = u6 and forward speed v = -rR * u6
(Meijaard's v = -rR thetaR').  The rear contact moves along the heading at
-rR (u5 + u6), which differs from v by the pitch-rate term rR * u5 (zero when
upright).  Pitch output theta = q5 - lam: rear-frame pitch from the upright
reference configuration, positive nose up (about the roll frame's y axis).

**Inputs** ``r = [T_delta, T_phi, F, T_R]`` (:data:`INPUTS`): steer torque of the
rear frame on the front frame about the steer axis [N m]; roll torque on the
rear frame about the yaw frame's x axis (the generalized force of roll) [N m];
lateral force, horizontal and perpendicular to the rear frame's heading,
positive right, applied at the rear-frame point (x_F, z_F) of benchmark axes [N];
rear-wheel drive torque of the rear frame on the rear wheel about its axle
(positive accelerates the wheel about +y, i.e. *brakes* forward motion) [N m].

**Speed modes**: ``"coast"`` (rear wheel free; speed is a state; energy is
conserved without inputs) and ``"held"`` (an ideal drive torque T_R makes
u6' = 0 at every instant, solved together with the other accelerations from the
same linear system; returned as the drive torque; any given T_R is ignored).

Extra generalized forces (:mod:`sim.effects`) add to the dynamic rows of
(u4, u6, u7).

**Normal contact forces** (:meth:`WhippleBicycle.contact_forces`, :func:`rhs_contact`):
the ground's upward force on each wheel [N], from the equations of motion.  The
model's wheel-ground contact is bilateral: it stays valid only while both are > 0.
"""

from __future__ import annotations

import hashlib
import math
from pathlib import Path

import numpy as np
from numba import njit

from . import _whipple_generated as gen
from .conventions import MEASURED
from .effects import plant_forces, plant_vector
from .parameters import BicycleParameters

__all__ = [
    "INPUTS",
    "STATE",
    "WhippleBicycle",
    "parameter_vector",
]

#: Integration state order.
STATE = ("q1", "q2", "q3", "q4", "q6", "q7", "q8", "u4", "u6", "u7")
#: Input vector order.
INPUTS = ("T_delta", "T_phi", "F", "T_R")
#: Speed order of the generated mass matrix: independent, then dependent.
SPEEDS = ("u4", "u6", "u7", "u3", "u5", "u8")
MODES = ("coast", "held")

_NEWTON_MAXIT = 40


def parameter_vector(
    p: BicycleParameters, lateral_force_point: tuple[float, float] | None = None
) -> np.ndarray:
    """Numerical parameter vector of the generated equations.

    Parameters
    ----------
    p : BicycleParameters
        Bicycle in Meijaard notation.
    lateral_force_point : (float, float), optional
        (x_F, z_F) in benchmark axes [m] (x forward, z down, origin at the rear
        contact) where the lateral force F acts on the rear frame; default: the rear
        body mass centre (xB, zB).

    Returns
    -------
    (28,) ndarray
        The Moore (2012) parameters of :meth:`BicycleParameters.to_moore` plus the
        force point ``lf1``, ``lf3`` (relative to the rear wheel centre in rear-frame
        axes) [m], in ``sim._whipple_generated.PARAMETERS`` order; SI units.

    Raises
    ------
    ValueError
        If ``lateral_force_point`` is not finite.
    """
    x_F, z_F = (p.xB, p.zB) if lateral_force_point is None else lateral_force_point
    if not (math.isfinite(x_F) and math.isfinite(z_F)):
        raise ValueError(f"lateral_force_point {lateral_force_point!r} must be finite (x_F, z_F)")
    mo = p.to_moore()
    cl, sl = math.cos(p.lam), math.sin(p.lam)
    # point relative to the rear wheel centre, in rear-frame axes C1 (forward-up), C3
    mo["lf1"] = x_F * cl - (z_F + p.rR) * sl
    mo["lf3"] = x_F * sl + (z_F + p.rR) * cl
    return np.array([float(mo[name]) for name in gen.PARAMETERS])


# -- compiled kernels ------------------------------------------------------------------------
@njit(cache=True)
def _solve(A, b):
    """Solve A x = b in place (Gaussian elimination, partial pivoting); x in b."""
    n = b.shape[0]
    for k in range(n):
        piv = k
        amax = abs(A[k, k])
        for i in range(k + 1, n):
            if abs(A[i, k]) > amax:
                amax = abs(A[i, k])
                piv = i
        if piv != k:
            for j in range(n):
                tmp = A[k, j]
                A[k, j] = A[piv, j]
                A[piv, j] = tmp
            tmp = b[k]
            b[k] = b[piv]
            b[piv] = tmp
        akk = A[k, k]
        for i in range(k + 1, n):
            m = A[i, k] / akk
            if m != 0.0:
                for j in range(k + 1, n):
                    A[i, j] -= m * A[k, j]
                b[i] -= m * b[k]
    for i in range(n - 1, -1, -1):
        s = b[i]
        for j in range(i + 1, n):
            s -= A[i, j] * b[j]
        b[i] = s / A[i, i]


@njit(cache=True)
def pitch(q4, q7, guess, p):
    """Pitch q5 solving the holonomic constraint by Newton from ``guess``; NaN if it fails."""
    q5 = guess
    for _ in range(_NEWTON_MAXIT):
        h, dh = gen.holonomic(q4, q5, q7, p)
        step = h / dh
        q5 -= step
        if abs(step) < 1e-11:
            h, dh = gen.holonomic(q4, q5, q7, p)
            return q5 - h / dh
    return np.nan


@njit(cache=True)
def speeds(q4, q5, q7, u4, u6, u7, p, u):
    """Fill ``u`` with all speeds [u4, u6, u7, u3, u5, u8] from the independent ones."""
    Ad = np.empty((3, 3))
    Ai = np.empty((3, 3))
    gen.velocity_constraint(q4, q5, q7, p, Ad, Ai)
    b = np.empty(3)
    for i in range(3):
        b[i] = -(Ai[i, 0] * u4 + Ai[i, 1] * u6 + Ai[i, 2] * u7)
    _solve(Ad, b)
    u[0] = u4
    u[1] = u6
    u[2] = u7
    u[3] = b[0]
    u[4] = b[1]
    u[5] = b[2]


@njit(cache=True)
def accelerations(q4, q5, q7, u, p, r, extra, held, udot):
    """Fill ``udot`` (order of ``u``) and return the rear-wheel torque T_R [N m].

    ``extra`` is added to the dynamic rows of (u4, u6, u7).  With ``held`` the
    drive torque making u6' = 0 is an unknown in place of u6'; r[3] is ignored.
    """
    M = np.empty((6, 6))
    f = np.empty(6)
    if held:
        rr = np.empty(4)
        rr[0] = r[0]
        rr[1] = r[1]
        rr[2] = r[2]
        rr[3] = 0.0
        gen.mass_forcing(q4, q5, q7, u, p, rr, M, f)
    else:
        gen.mass_forcing(q4, q5, q7, u, p, r, M, f)
    f[0] += extra[0]
    f[1] += extra[1]
    f[2] += extra[2]
    if held:
        G = np.empty((6, 4))
        gen.input_matrix(q4, q5, q7, p, G)
        for i in range(6):
            M[i, 1] = -G[i, 3]
    _solve(M, f)
    for i in range(6):
        udot[i] = f[i]
    if held:
        udot[1] = 0.0
        return f[1]
    return r[3]


@njit(cache=True)
def rhs(y, q5g, p, r, ev, held, ydot):
    """State derivative of ``y`` (STATE order) into ``ydot``; returns T_R.

    ``q5g[0]`` is the pitch warm start, updated in place.  Returns NaN (and a NaN
    ``ydot``) if the pitch Newton iteration fails.
    """
    return _derivative(y, q5g, p, r, ev, held, ydot, ydot[:0])  # no forces: empty view


@njit(cache=True)
def rhs_contact(y, q5g, p, r, ev, held, ydot, nf):
    """:func:`rhs` that also fills ``nf`` with the normal contact forces [N_R, N_F] [N].

    Same accelerations; see :func:`normal_forces` for the forces (NaN if the pitch
    Newton iteration fails).
    """
    return _derivative(y, q5g, p, r, ev, held, ydot, nf)


@njit(cache=True)
def normal_forces(q4, q5, q7, u, udot, p, r, extra, T_R, nf):
    """Normal contact forces [N_R, N_F] [N] into ``nf`` (positive: the ground pushes up).

    ``u``, ``udot`` in :data:`SPEEDS` order, ``r`` the inputs, ``extra`` the plant-effect
    generalized forces on (u4, u6, u7) and ``T_R`` the drive torque acting.  The roll
    effect (extra[0]) is a torque about the yaw frame's x axis on the rear frame, as
    T_phi; the steer effect (extra[2]) acts between the frames, as T_delta.
    """
    re = np.empty(4)
    re[0] = r[0] + extra[2]
    re[1] = r[1] + extra[0]
    re[2] = r[2]
    re[3] = T_R
    n_rear, n_front = gen.contact_forces(q4, q5, q7, u, udot, p, re)
    nf[0] = n_rear
    nf[1] = n_front


@njit(cache=True)
def _derivative(y, q5g, p, r, ev, held, ydot, nf):
    """:func:`rhs`; with a 2-element ``nf`` also the normal forces (:func:`normal_forces`)."""
    q4 = y[3]
    q7 = y[5]
    q5 = pitch(q4, q7, q5g[0], p)
    if not math.isfinite(q5):
        for i in range(10):
            ydot[i] = np.nan
        for i in range(nf.shape[0]):
            nf[i] = np.nan
        return np.nan
    q5g[0] = q5
    u = np.empty(6)
    speeds(q4, q5, q7, y[7], y[8], y[9], p, u)
    extra = np.empty(3)
    plant_forces(ev, q4, q7, u[0], u[1], u[2], extra)
    udot = np.empty(6)
    T_R = accelerations(q4, q5, q7, u, p, r, extra, held, udot)
    if nf.shape[0] == 2:
        normal_forces(q4, q5, q7, u, udot, p, r, extra, T_R, nf)
    c = np.empty(4)
    gen.contact(y[2], q4, q5, q7, u, p, c)
    ydot[0] = c[0]
    ydot[1] = c[1]
    ydot[2] = u[3]
    ydot[3] = u[0]
    ydot[4] = u[1]
    ydot[5] = u[2]
    ydot[6] = u[5]
    ydot[7] = udot[0]
    ydot[8] = udot[1]
    ydot[9] = udot[2]
    return T_R


@njit(cache=True)
def outputs(y, q5g, p, out):
    """Fill ``out`` with [MEASURED..., theta+lam (=q5), xR, yR, xF, yF]; returns q5."""
    q4 = y[3]
    q7 = y[5]
    q5 = pitch(q4, q7, q5g[0], p)
    q5g[0] = q5
    u = np.empty(6)
    speeds(q4, q5, q7, y[7], y[8], y[9], p, u)
    c = np.empty(4)
    gen.contact(y[2], q4, q5, q7, u, p, c)
    out[0] = -p[1] * y[8]
    out[1] = q4
    out[2] = q7
    out[3] = y[2]
    out[4] = u[0]
    out[5] = u[2]
    out[6] = u[3]
    out[7] = u[1]
    out[8] = q5
    out[9] = y[0]
    out[10] = y[1]
    out[11] = y[0] + c[2]
    out[12] = y[1] + c[3]
    return q5


# -- numba cache hygiene ---------------------------------------------------------------------
_PLANT_SOURCES = ("_whipple_generated.py", "effects.py", "nonlinear.py", "integrate.py")


def invalidate_stale_caches(dispatchers, tag: str) -> None:
    """Flush numba caches of ``dispatchers`` when any plant source file changed.

    numba's ``cache=True`` only watches the file of the cached function, not the
    functions it calls in other modules: after regenerating the equations or adding
    an effect, a cached kernel would silently run the old code.  We keep a digest
    of all plant sources next to the cache and flush when it changes.
    """
    try:
        here = Path(__file__).parent
        digest = hashlib.sha256(b"".join((here / n).read_bytes() for n in _PLANT_SOURCES))
        stamp = Path(dispatchers[0]._cache.cache_path) / f"bikeid_{tag}.sources.sha256"
        if stamp.exists() and stamp.read_text() == digest.hexdigest():
            return
        for d in dispatchers:
            d._cache.flush()
        tmp = stamp.with_suffix(f".{id(stamp)}.tmp")
        tmp.write_text(digest.hexdigest())
        tmp.replace(stamp)
    except (OSError, AttributeError):  # read-only or unusual cache: numba's own checks only
        pass


invalidate_stale_caches(
    [pitch, speeds, accelerations, rhs, rhs_contact, normal_forces, _derivative, outputs],
    "nonlinear",
)


# -- Python object ---------------------------------------------------------------------------
class WhippleBicycle:
    """The nonlinear Whipple bicycle for one parameter set (see the module docstring).

    State order :data:`STATE` ``[q1, q2, q3, q4, q6, q7, q8, u4, u6, u7]``
    (x, y [m], yaw, roll, rear wheel angle, steer, front wheel angle [rad], roll
    rate, rear wheel rate, steer rate [rad/s]); inputs :data:`INPUTS`
    ``[T_delta, T_phi, F, T_R]`` [N m, N m, N, N m].

    Parameters
    ----------
    p : BicycleParameters
        Benchmark-notation parameters.
    lateral_force_point : (float, float), optional
        (x_F, z_F) [m], benchmark axes, where the lateral force F acts on the rear
        frame; default (xB, zB).

    Attributes
    ----------
    params : BicycleParameters
        The parameters ``p``.
    lateral_force_point : (float, float)
        (x_F, z_F) [m] in use.
    p : (28,) ndarray
        Numerical parameter vector (:func:`parameter_vector`).
    rR : float
        Rear wheel radius [m].
    lam : float
        Steer axis tilt [rad]; Moore's pitch q5 equals lam upright.

    Raises
    ------
    ValueError
        If ``p`` is not a :class:`BicycleParameters`, the force point is not finite,
        or the holonomic constraint has no upright solution.
    """

    def __init__(
        self, p: BicycleParameters, lateral_force_point: tuple[float, float] | None = None
    ) -> None:
        if not isinstance(p, BicycleParameters):
            raise ValueError(f"expected a sim.parameters.BicycleParameters, got {type(p).__name__}")
        self.params = p
        self.lateral_force_point = (
            (p.xB, p.zB) if lateral_force_point is None else tuple(map(float, lateral_force_point))
        )
        self.p = parameter_vector(p, self.lateral_force_point)
        self.rR = p.rR
        self.lam = p.lam
        self._q5 = np.array([self.upright_pitch()])

    # -- configuration --------------------------------------------------------------------
    def upright_pitch(self) -> float:
        """Moore pitch q5 of the upright configuration.

        Returns
        -------
        float
            q5 [rad] at phi = delta = 0 (equals lam for the Meijaard geometry).

        Raises
        ------
        ValueError
            If the Newton iteration on the holonomic constraint fails.
        """
        q5 = pitch(0.0, 0.0, self.lam, self.p)
        if not math.isfinite(q5):
            raise ValueError(f"bicycle {self.params.name!r}: no upright pitch solution")
        return float(q5)

    def pitch(self, phi: float, delta: float, guess: float | None = None) -> float:
        """Moore pitch q5 satisfying the holonomic constraint at (phi, delta).

        Parameters
        ----------
        phi : float
            Roll angle q4 [rad], positive to the right.
        delta : float
            Steer angle q7 [rad], positive to the right.
        guess : float, optional
            Newton starting value [rad]; default ``lam``.

        Returns
        -------
        float
            q5 [rad] (rear-frame pitch; pitch from upright is q5 - lam, positive nose
            up).

        Raises
        ------
        ValueError
            If the Newton iteration fails (configuration too far from upright).
        """
        q5 = pitch(float(phi), float(delta), self.lam if guess is None else float(guess), self.p)
        if not math.isfinite(q5):
            raise ValueError(
                f"no pitch satisfies the holonomic constraint at phi={phi}, delta={delta} rad "
                "(configuration too far from upright?)"
            )
        return float(q5)

    def state(
        self,
        v: float,
        phi: float = 0.0,
        delta: float = 0.0,
        phidot: float = 0.0,
        deltadot: float = 0.0,
        psi: float = 0.0,
        x: float = 0.0,
        y: float = 0.0,
    ) -> np.ndarray:
        """A consistent integration state from benchmark quantities (SI, radians).

        Pitch and the dependent speeds are implied (solved at every evaluation); the
        wheel angles q6, q8 start at 0.

        Parameters
        ----------
        v : float
            Forward speed -rR u6 [m/s].
        phi, delta : float, optional
            Roll and steer angles [rad], positive to the right. Default 0.
        phidot, deltadot : float, optional
            Roll and steer rates [rad/s]. Default 0.
        psi : float, optional
            Yaw (heading) [rad], positive to the right. Default 0.
        x, y : float, optional
            Rear contact position in N [m] (x forward, y right). Default 0.

        Returns
        -------
        (10,) ndarray
            ``[x, y, psi, phi, 0, delta, 0, phidot, -v / rR, deltadot]``
            (:data:`STATE` order).

        Raises
        ------
        ValueError
            If a value is not finite or no pitch satisfies the holonomic constraint at
            (phi, delta).
        """
        vals = dict(v=v, phi=phi, delta=delta, phidot=phidot, deltadot=deltadot, psi=psi, x=x, y=y)
        for k, val in vals.items():
            if not math.isfinite(float(val)):
                raise ValueError(f"initial {k}={val!r} must be finite")
        self.pitch(phi, delta)  # raises if inconsistent
        return np.array(
            [x, y, psi, phi, 0.0, delta, 0.0, phidot, -float(v) / self.rR, deltadot], dtype=float
        )

    # -- evaluation ----------------------------------------------------------------------
    def rhs(
        self,
        y: np.ndarray,
        inputs=(0.0, 0.0, 0.0, 0.0),
        mode: str = "coast",
        effects=None,
    ) -> tuple[np.ndarray, float]:
        """State derivative at ``y``.

        Parameters
        ----------
        y : (10,) array_like
            State in :data:`STATE` order.
        inputs : (4,) array_like, optional
            [T_delta, T_phi, F, T_R] [N m, N m, N, N m] (:data:`INPUTS`); default zero.
        mode : {"coast", "held"}, optional
            Speed mode; in "held" T_R is ignored and solved for. Default "coast".
        effects : sequence, optional
            Plant-side :mod:`sim.effects` objects.

        Returns
        -------
        ydot : (10,) ndarray
            dy/dt, :data:`STATE` order.
        T_R : float
            Rear-wheel drive torque [N m] (the input in "coast", the holding torque in
            "held").

        Raises
        ------
        ValueError
            If ``mode`` or ``inputs`` is invalid or the pitch Newton iteration fails.
        """
        return _checked_rhs(y, self._q5, self.p, _inputs(inputs), plant_vector(effects),
                            _mode(mode))  # fmt: skip

    def ode(self, inputs=(0.0, 0.0, 0.0, 0.0), mode: str = "coast", effects=None):
        """The right-hand side ``f(t, y) -> dy/dt`` for ``scipy.integrate.solve_ivp``, with
        constant inputs: :meth:`rhs`'s derivative with its checks done once (a Poincare
        map calls it ~10^5 times; the per-call checks cost three times the derivative).

        Parameters
        ----------
        inputs : (4,) array_like, optional
            [T_delta, T_phi, F, T_R] [N m, N m, N, N m], held; default zero.
        mode : {"coast", "held"}, optional
            Speed mode (:meth:`rhs`). Default "coast".
        effects : sequence, optional
            Plant-side :mod:`sim.effects` objects.

        Returns
        -------
        callable
            ``f(t, y)`` -> (10,) ndarray, dy/dt in :data:`STATE` order (t is unused); it
            raises ValueError where :meth:`rhs` does (pitch Newton iteration failed).
        """
        held, r, ev, q5, p = _mode(mode), _inputs(inputs), plant_vector(effects), self._q5, self.p

        def f(_t: float, y: np.ndarray) -> np.ndarray:
            return _checked_rhs(y, q5, p, r, ev, held)[0]

        return f

    def contact_forces(
        self,
        y: np.ndarray,
        inputs=(0.0, 0.0, 0.0, 0.0),
        mode: str = "coast",
        effects=None,
    ) -> tuple[float, float]:
        """Normal contact forces of the ground on the rear and front wheel at state ``y``.

        From the equations of motion (Newton-Euler for the whole bicycle with the
        accelerations of ``mass_forcing``; ``scripts/derive_whipple.py``), not a static
        estimate: they depend on the speeds, the inputs and the effects.  The Whipple
        model's contact is bilateral, so a force <= 0 means the wheel would lift off and
        the model no longer describes the bicycle (:mod:`sim.integrate` stops the run,
        cause ``wheel_unloaded``).

        Parameters
        ----------
        y : (10,) array_like
            State in :data:`STATE` order.
        inputs : (4,) array_like, optional
            [T_delta, T_phi, F, T_R] [N m, N m, N, N m] (:data:`INPUTS`); default zero.
        mode : {"coast", "held"}, optional
            Speed mode. Default "coast".
        effects : sequence, optional
            Plant-side :mod:`sim.effects` objects (they change the accelerations; the
            roll effect acts as a roll torque T_phi).

        Returns
        -------
        N_rear : float
            Normal force on the rear wheel [N], along the upward vertical (-A3, z is
            down): positive when the ground pushes the wheel up.
        N_front : float
            Normal force on the front wheel [N], same sign convention.  Upright at rest
            N_rear + N_front = m g; static split m g (w - x_cm) / w and m g x_cm / w.

        Raises
        ------
        ValueError
            If ``mode`` or ``inputs`` is invalid or the pitch Newton iteration fails.
        """
        held = _mode(mode)
        ydot = np.empty(10)
        nf = np.empty(2)
        ev = plant_vector(effects)
        _pitch_solved(rhs_contact(
            np.asarray(y, float), self._q5, self.p, _inputs(inputs), ev, held, ydot, nf
        ))  # fmt: skip
        return float(nf[0]), float(nf[1])

    def all_speeds(
        self, q4: float, q5: float, q7: float, u4: float, u6: float, u7: float
    ) -> np.ndarray:
        """All six generalized speeds from the independent ones.

        Parameters
        ----------
        q4, q5, q7 : float
            Roll, pitch and steer [rad] (q5 consistent with the holonomic constraint).
        u4, u6, u7 : float
            Roll rate, rear wheel rate and steer rate [rad/s].

        Returns
        -------
        (6,) ndarray
            [u4, u6, u7, u3, u5, u8] (:data:`SPEEDS` order) [rad/s], the dependent ones
            from the nonholonomic constraints.
        """
        u = np.empty(6)
        speeds(q4, q5, q7, u4, u6, u7, self.p, u)
        return u

    def all_accelerations(
        self,
        q4: float,
        q5: float,
        q7: float,
        u4: float,
        u6: float,
        u7: float,
        inputs=(0.0, 0.0, 0.0, 0.0),
        mode: str = "coast",
        extra=(0.0, 0.0, 0.0),
    ) -> tuple[np.ndarray, np.ndarray, float]:
        """Speeds, accelerations and drive torque at a given configuration.

        Parameters
        ----------
        q4, q5, q7 : float
            Roll, pitch and steer [rad].
        u4, u6, u7 : float
            Independent speeds [rad/s].
        inputs : (4,) array_like, optional
            [T_delta, T_phi, F, T_R] [N m, N m, N, N m]; default zero.
        mode : {"coast", "held"}, optional
            Speed mode. Default "coast".
        extra : (3,) array_like, optional
            Extra generalized forces added to the dynamic rows of (u4, u6, u7)
            [N m]; default zero.

        Returns
        -------
        u : (6,) ndarray
            Speeds in :data:`SPEEDS` order [rad/s].
        udot : (6,) ndarray
            Their time derivatives [rad/s^2] (u6' = 0 in "held").
        T_R : float
            Rear-wheel drive torque [N m].

        Raises
        ------
        ValueError
            If ``mode`` or ``inputs`` is invalid.
        """
        u = self.all_speeds(q4, q5, q7, u4, u6, u7)
        udot = np.empty(6)
        T_R = accelerations(
            q4, q5, q7, u, self.p, _inputs(inputs), np.asarray(extra, float), _mode(mode), udot
        )
        return u, udot, float(T_R)

    def measurements(self, y: np.ndarray) -> np.ndarray:
        """The measured signals at state ``y``.

        Parameters
        ----------
        y : (10,) array_like
            State in :data:`STATE` order.

        Returns
        -------
        (8,) ndarray
            [v, phi, delta, psi, phidot, deltadot, psidot, thetaRdot]
            (:data:`sim.conventions.MEASURED`) [m/s, rad, rad, rad, rad/s, rad/s,
            rad/s, rad/s].
        """
        return self.outputs(y)[: len(MEASURED)]

    def outputs(self, y: np.ndarray) -> np.ndarray:
        """Measured signals, pitch and contact points at state ``y``.

        Parameters
        ----------
        y : (10,) array_like
            State in :data:`STATE` order.

        Returns
        -------
        (13,) ndarray
            [v, phi, delta, psi, phidot, deltadot, psidot, thetaRdot, theta, xR, yR,
            xF, yF]: the MEASURED signals, theta = q5 - lam the pitch from upright
            [rad] (positive nose up), and (xR, yR), (xF, yF) the rear and front contact
            points in N [m].
        """
        out = np.empty(13)
        outputs(np.asarray(y, float), self._q5, self.p, out)
        out[8] -= self.lam
        return out

    def energy(self, y: np.ndarray) -> tuple[float, float]:
        """Kinetic and potential energy at state ``y``.

        Parameters
        ----------
        y : (10,) array_like
            State in :data:`STATE` order.

        Returns
        -------
        kinetic : float
            Kinetic energy [J].
        potential : float
            Gravitational potential energy [J], zero with mass centres at ground level.

        Raises
        ------
        ValueError
            If no pitch satisfies the holonomic constraint.
        """
        q5 = self.pitch(y[3], y[5], self._q5[0])
        u = self.all_speeds(y[3], q5, y[5], y[7], y[8], y[9])
        ke, pe = gen.energy(y[3], q5, y[5], u, self.p)
        return float(ke), float(pe)

    def constraint_residuals(self, y: np.ndarray) -> tuple[float, np.ndarray]:
        """Constraint residuals at state ``y`` (zero to round-off for a valid state).

        Parameters
        ----------
        y : (10,) array_like
            State in :data:`STATE` order.

        Returns
        -------
        holonomic : float
            Holonomic constraint residual [m].
        nonholonomic : (3,) ndarray
            Nonholonomic (velocity) constraint residuals [m/s].

        Raises
        ------
        ValueError
            If no pitch satisfies the holonomic constraint.
        """
        q5 = self.pitch(y[3], y[5], self._q5[0])
        h, _ = gen.holonomic(y[3], q5, y[5], self.p)
        u = self.all_speeds(y[3], q5, y[5], y[7], y[8], y[9])
        Ad = np.empty((3, 3))
        Ai = np.empty((3, 3))
        gen.velocity_constraint(y[3], q5, y[5], self.p, Ad, Ai)
        return float(h), Ad @ u[3:] + Ai @ u[:3]

    # -- linearization -------------------------------------------------------------------
    def linearize(
        self, v: float, step: float = 1e-3, lateral_force: bool = False, effects=None
    ) -> tuple[np.ndarray, np.ndarray]:
        """A, B about upright straight running at speed v, by finite differences.

        State [phi, delta, phidot, deltadot] (:data:`sim.linear.STATE_NAMES`),
        inputs [T_phi, T_delta] (+ F if ``lateral_force``), matching
        :func:`sim.linear.state_matrices`.  Fourth-order central differences with
        ``step`` (rad, rad/s); the model is exactly linear in the inputs.
        Plant-side ``effects`` (:mod:`sim.effects`) are included if given.  Coast
        mode (the rear wheel rate is not perturbed).

        Parameters
        ----------
        v : float
            Forward speed [m/s].
        step : float, optional
            Finite-difference step [rad or rad/s]. Default 1e-3.
        lateral_force : bool, optional
            Add a column for F at :attr:`lateral_force_point`. Default False.
        effects : sequence, optional
            Plant-side :mod:`sim.effects` objects.

        Returns
        -------
        A : (4, 4) ndarray
            State matrix.
        B : (4, 2) or (4, 3) ndarray
            Input matrix, columns [T_phi, T_delta] (per N m) and optionally F (per N).
        """
        y0 = self.state(v)
        idx = (3, 5, 7, 9)  # phi, delta, phidot, deltadot in STATE

        def f(y, r):
            yd, _ = self.rhs(y, r, effects=effects)
            return yd[[3, 5, 7, 9]]

        zero = np.zeros(4)
        A = np.empty((4, 4))
        for j, k in enumerate(idx):
            cols = []
            for m in (-2, -1, 1, 2):
                y = y0.copy()
                y[k] += m * step
                cols.append(f(y, zero))
            A[:, j] = (cols[0] - 8 * cols[1] + 8 * cols[2] - cols[3]) / (12 * step)
        base = f(y0, zero)
        inputs = [1, 0] + ([2] if lateral_force else [])  # T_phi, T_delta, F in r
        B = np.empty((4, len(inputs)))
        for j, k in enumerate(inputs):
            r = zero.copy()
            r[k] = 1.0
            B[:, j] = f(y0, r) - base
        return A, B


def _mode(mode: str) -> bool:
    if mode not in MODES:
        raise ValueError(f"speed mode {mode!r} unknown; use 'coast' or 'held'")
    return mode == "held"


def _pitch_solved(T_R: float) -> float:
    """``T_R`` from a compiled right-hand side, or ValueError where its pitch Newton
    iteration failed (NaN)."""
    if not math.isfinite(T_R):
        raise ValueError("pitch Newton iteration failed: state too far from upright")
    return float(T_R)


def _checked_rhs(y, q5, p, r, ev, held) -> tuple[np.ndarray, float]:
    """(dy/dt, T_R) of the compiled :func:`rhs` with checked arguments (``r`` from
    :func:`_inputs`, ``held`` from :func:`_mode`); ValueError where the pitch fails."""
    ydot = np.empty(10)
    return ydot, _pitch_solved(rhs(np.asarray(y, float), q5, p, r, ev, held, ydot))


def _inputs(inputs) -> np.ndarray:
    r = np.asarray(inputs, dtype=float).reshape(-1)
    if r.shape != (4,) or not np.all(np.isfinite(r)):
        raise ValueError(
            f"inputs must be 4 finite numbers [T_delta, T_phi, F, T_R], got {inputs!r}"
        )
    return r
