"""The arm model: the linearized Whipple bicycle plus the rider's arms (Moore & Hubbard).

Moore's dissertation ("Extensions", "Rider Arms") and Moore & Hubbard's "arm model": four
arm segments (right/left upper arm, right/left lower arm with the hand) added to the Whipple
bicycle.  The shoulders are fixed in the rear frame (the rider's torso belongs to it), the
hands hold grip points fixed in the front frame, the elbows are hinges whose axes stay
perpendicular to the roll frame's ground normal (the arms hang down).  These constraints
remove the arms' freedoms: the model keeps q = [phi, delta] and the steer torque as input,
so it has the Meijaard form ``M q'' + v C1 q' + (g K0 + v^2 K2) q = [T_phi, T_delta]``
(:class:`~bikeid.sim.linear.CanonicalMatrices`, rows/columns [phi, delta]).

The equations are derived by ``scripts/derive_arms.py`` (sympy; committed output
``sim/_arms_generated.py``): closed-form arm kinematics as functions of steer and pitch,
and the linear contribution of each segment to M, C1, K0, K2 from the Whipple model's own
kinematics (see the script's docstring).  By default the arms are *part of* the rear body
of the given bicycle (as in every bicycle-with-rider parameter set, the benchmark's 85 kg
rear body included): :func:`remove_arms` takes their nominal mass and inertia out of the
rear body and the segments are added back as moving bodies, so the same bicycle with the
arms locked to the rear frame is the Whipple model again.

Default arms (:class:`ArmParameters`): a 72 kg rider (the benchmark's nominal rider of the
Moore & Hubbard reproduction) with de Leva's (1996, J. Biomech. 29, 1223-1230, adjusted
Zatsiorsky-Seluyanov male table) segment mass fractions, lengths, mass-centre positions and
radii of gyration: upper arm 2.71 %, 281.7 mm, 57.72 % from the shoulder; forearm 1.62 %,
268.9 mm, 45.74 %; hand 0.61 %, 86.2 mm, 79.0 %; the lower arm is forearm and hand lumped
(Yeadon's A2/B2 segment, as Moore used), ending at the grip 70 mm beyond the wrist.  The
shoulder and grip positions are an assumption (the benchmark does not give them), an upright
city-bicycle posture consistent with the benchmark's rear-body mass centre (0.3, -0.9) m and
front frame: shoulders at x = 0.35 m, 1.40 m above the ground, 0.19 m either side; grips at
x = 0.75 m, 1.00 m above the ground, 0.25 m either side.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

import numpy as np

from . import _arms_generated as gen
from .errors import InputError
from .linear import CanonicalMatrices, canonical_matrices, eigenvalues
from .parameters import BicycleParameters

__all__ = [
    "ArmParameters",
    "arm_model_matrices",
    "body_contribution",
    "geometry_vector",
    "remove_arms",
    "segment_bodies",
    "stability_summary",
]

_RIDER = 72.0  # kg
_UP_M, _UP_L, _UP_C, _UP_RT, _UP_RA = 0.0271, 0.2817, 0.5772, 0.277, 0.158
_FO_M, _FO_L, _FO_C, _FO_RT, _FO_RA = 0.0162, 0.2689, 0.4574, 0.2705, 0.121
_HA_M, _HA_L, _HA_C, _HA_RT, _HA_RA = 0.0061, 0.0862, 0.790, 0.570, 0.401
_GRIP = 0.070  # m, wrist to grip centre


def _lower_arm(mass: float) -> tuple[float, float, float, float, float]:
    """Forearm + hand lumped: (mass, length, com from elbow, transverse, axial inertia)."""
    mf, mh = _FO_M * mass, _HA_M * mass
    cf, ch = _FO_C * _FO_L, _FO_L + _HA_C * _HA_L
    m = mf + mh
    com = (mf * cf + mh * ch) / m
    it = (
        mf * (_FO_RT * _FO_L) ** 2 + mh * (_HA_RT * _HA_L) ** 2
        + mf * (cf - com) ** 2 + mh * (ch - com) ** 2
    )  # fmt: skip
    ia = mf * (_FO_RA * _FO_L) ** 2 + mh * (_HA_RA * _HA_L) ** 2
    return m, _FO_L + _GRIP, com, it, ia


_LO = _lower_arm(_RIDER)


@dataclass(frozen=True)
class ArmParameters:
    """The rider's arms: geometry at the upright and segment inertia (both arms alike).

    Positions are benchmark axes at the upright configuration (x forward of the rear
    contact, y right, z down; a point above the ground has a negative z) [m]; the left
    arm is the mirror image (y negated) of the right one.  Segment inertias are about the
    segment's mass centre, axisymmetric about the segment's long axis.  Defaults: the
    module docstring (de Leva 1996 for a 72 kg rider; assumed shoulder and grip positions).

    Attributes
    ----------
    shoulder_x, shoulder_y, shoulder_z : float
        Right shoulder joint centre [m] (fixed in the rear frame); shoulder_y > 0.
    grip_x, grip_y, grip_z : float
        Right grip (hand) point [m] (fixed in the front frame); grip_y > 0.
    upper_length : float
        Shoulder to elbow [m], > 0.
    upper_com : float
        Upper arm mass centre from the shoulder [m], in [0, upper_length].
    upper_mass : float
        Upper arm mass [kg], >= 0 (0: massless).
    upper_transverse, upper_axial : float
        Upper arm inertia about transverse axes and its long axis [kg m^2], >= 0.
    lower_length : float
        Elbow to grip [m], > 0.
    lower_com : float
        Lower arm (forearm + hand) mass centre from the elbow [m], in [0, lower_length].
    lower_mass : float
        Lower arm mass [kg], >= 0.
    lower_transverse, lower_axial : float
        Lower arm inertia about transverse axes and its long axis [kg m^2], >= 0.
    """

    shoulder_x: float = 0.35
    shoulder_y: float = 0.19
    shoulder_z: float = -1.40
    grip_x: float = 0.75
    grip_y: float = 0.25
    grip_z: float = -1.00
    upper_length: float = _UP_L
    upper_com: float = _UP_C * _UP_L
    upper_mass: float = _UP_M * _RIDER
    upper_transverse: float = _UP_M * _RIDER * (_UP_RT * _UP_L) ** 2
    upper_axial: float = _UP_M * _RIDER * (_UP_RA * _UP_L) ** 2
    lower_length: float = _LO[1]
    lower_com: float = _LO[2]
    lower_mass: float = _LO[0]
    lower_transverse: float = _LO[3]
    lower_axial: float = _LO[4]

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            real = (int, float, np.integer, np.floating)
            if isinstance(value, bool) or not isinstance(value, real):
                raise InputError(f"arm parameter {f.name!r} must be a real number, got {value!r}")
            if not math.isfinite(float(value)):
                raise InputError(f"arm parameter {f.name!r} is {value}: it must be finite")
            object.__setattr__(self, f.name, float(value))
        for name in ("shoulder_y", "grip_y", "upper_length", "lower_length"):
            if getattr(self, name) <= 0:
                raise InputError(f"arm parameter {name!r} must be > 0 [m]")
        for name in ("upper_mass", "lower_mass", "upper_transverse", "upper_axial",
                     "lower_transverse", "lower_axial"):  # fmt: skip
            if getattr(self, name) < 0:
                raise InputError(f"arm parameter {name!r} must be >= 0")
        if not 0 <= self.upper_com <= self.upper_length:
            raise InputError("arm parameter 'upper_com' must lie in [0, upper_length] [m]")
        if not 0 <= self.lower_com <= self.lower_length:
            raise InputError("arm parameter 'lower_com' must lie in [0, lower_length] [m]")
        reach = math.dist(
            (self.shoulder_x, self.shoulder_y, self.shoulder_z),
            (self.grip_x, self.grip_y, self.grip_z),
        )
        a, b = self.upper_length, self.lower_length
        if not abs(a - b) < reach < a + b:
            raise InputError(
                f"the grip is {reach:.3f} m from the shoulder, out of the arm's reach "
                f"({abs(a - b):.3f}, {a + b:.3f}) m: move the grip or change the arm lengths"
            )

    def arm_vector(self) -> np.ndarray:
        """The right arm as ``scripts/derive_arms.py``'s arm vector.

        Returns
        -------
        (10,) ndarray
            [xs, ys, zs, xg, yg, zg, a, b, l5, l6] [m] (``_arms_generated.ARM``).
        """
        return np.array(
            [
                self.shoulder_x, self.shoulder_y, self.shoulder_z,
                self.grip_x, self.grip_y, self.grip_z,
                self.upper_length, self.lower_length, self.upper_com, self.lower_com,
            ]
        )  # fmt: skip

    def scaled(self, factor: float) -> ArmParameters:
        """The same geometry with masses and inertias times ``factor``.

        Parameters
        ----------
        factor : float
            Scale of every segment mass and inertia (dimensionless), >= 0.

        Returns
        -------
        ArmParameters
            Lengths and positions unchanged.
        """
        names = ("upper_mass", "upper_transverse", "upper_axial",
                 "lower_mass", "lower_transverse", "lower_axial")  # fmt: skip
        return replace(self, **{n: getattr(self, n) * factor for n in names})

    @property
    def mass(self) -> float:
        """Mass of both arms [kg]."""
        return 2.0 * (self.upper_mass + self.lower_mass)


def geometry_vector(p: BicycleParameters) -> np.ndarray:
    """The geometry vector of the generated code.

    Parameters
    ----------
    p : BicycleParameters
        Bicycle.

    Returns
    -------
    (6,) ndarray
        [w, c, lam, rR, rF, g] [m, m, rad, m, m, m/s^2] (``_arms_generated.GEOMETRY``).
    """
    return np.array([p.w, p.c, p.lam, p.rR, p.rF, p.g])


def segment_bodies(p: BicycleParameters, arms: ArmParameters) -> list[np.ndarray]:
    """The four segments as body vectors of ``body_matrices`` (right/left upper, lower).

    Parameters
    ----------
    p : BicycleParameters
        Bicycle (its geometry places the steer axis).
    arms : ArmParameters
        The arms.

    Returns
    -------
    list of (22,) ndarray
        Per segment [m, Ixx, Iyy, Izz, Ixy, Iyz, Ixz, p0, dp/ddelta, d2p/ddelta^2,
        dp/dpitch, w] in rear-frame (Moore C) axes about the rear wheel centre: mass [kg],
        nominal inertia about the mass centre [kg m^2], mass-centre position [m] and its
        derivatives [m/rad, m/rad^2], angular velocity relative to the rear frame per unit
        steer rate (dimensionless).  Order: right upper, right lower, left upper, left lower.
    """
    geo = geometry_vector(p)
    out = []
    for side in (1.0, -1.0):
        vec = arms.arm_vector()
        vec[1] *= side
        vec[4] *= side
        segs = gen.arm_segments(geo, vec)
        for seg, m, it, ia in (
            (segs[0], arms.upper_mass, arms.upper_transverse, arms.upper_axial),
            (segs[1], arms.lower_mass, arms.lower_transverse, arms.lower_axial),
        ):
            seg = np.asarray(seg, float)
            ax = seg[12:15]
            inertia = it * (np.eye(3) - np.outer(ax, ax)) + ia * np.outer(ax, ax)
            out.append(
                np.concatenate(
                    [
                        [m, inertia[0, 0], inertia[1, 1], inertia[2, 2]],
                        [inertia[0, 1], inertia[1, 2], inertia[0, 2]],
                        seg[0:12],
                        seg[15:18],
                    ]
                )
            )
    return out


def body_contribution(p: BicycleParameters, body: np.ndarray) -> CanonicalMatrices:
    """Linear contribution of one extra body to M, C1, K0, K2.

    Parameters
    ----------
    p : BicycleParameters
        Bicycle (geometry only).
    body : (22,) array_like
        Body vector (:func:`segment_bodies`; rear-frame axes about the rear wheel centre).

    Returns
    -------
    CanonicalMatrices
        The increments of M [kg m^2], C1 [kg m], K0 [kg m], K2 [kg] (rows/columns
        [phi, delta]) the body adds to the Whipple model; g = ``p.g``.
    """
    M, C1, K0, K2, _ = gen.body_matrices(geometry_vector(p), np.asarray(body, float))
    return CanonicalMatrices(
        M=np.array(M, float), C1=np.array(C1, float), K0=np.array(K0, float),
        K2=np.array(K2, float), g=p.g,
    )  # fmt: skip


def _arm_bodies_benchmark(p: BicycleParameters, arms: ArmParameters):
    """(mass, position, inertia) of each segment at the upright, benchmark axes."""
    R = p.moore_rotation()  # benchmark -> rear-frame (Moore C) axes
    out = []
    for b in segment_bodies(p, arms):
        ic = np.array([[b[1], b[4], b[6]], [b[4], b[2], b[5]], [b[6], b[5], b[3]]])
        pos = R.T @ b[7:10] - np.array([0.0, 0.0, p.rR])
        out.append((b[0], pos, R.T @ ic @ R))
    return out


def _about_origin(m: float, r: np.ndarray, inertia: np.ndarray) -> np.ndarray:
    return inertia + m * (r @ r * np.eye(3) - np.outer(r, r))


def remove_arms(p: BicycleParameters, arms: ArmParameters) -> BicycleParameters:
    """The bicycle with the arms' nominal mass and inertia taken out of the rear body.

    Parameters
    ----------
    p : BicycleParameters
        Bicycle whose rear body (mB, xB, zB, IB..) includes the rider's arms at the upright.
    arms : ArmParameters
        The arms.

    Returns
    -------
    BicycleParameters
        Rear body without the four segments (mass, mass centre and inertia by the parallel
        axis theorem, benchmark axes); all else unchanged.

    Raises
    ------
    InputError
        If the arms weigh as much as the rear body or leave it an impossible inertia.
    """
    mB = p.mB - arms.mass
    if mB <= 0:
        raise InputError(
            f"the arms ({arms.mass:.2f} kg) weigh as much as the rear body ({p.mB:.2f} kg): "
            "give lighter arms or a bicycle with a rider"
        )
    rB = np.array([p.xB, 0.0, p.zB])
    J = _about_origin(p.mB, rB, p.inertia_B())
    first = p.mB * rB
    for m, r, inertia in _arm_bodies_benchmark(p, arms):
        J = J - _about_origin(m, r, inertia)
        first = first - m * r
    r_new = first / mB
    inertia = J - mB * (r_new @ r_new * np.eye(3) - np.outer(r_new, r_new))
    try:
        return p.replace(
            mB=mB, xB=float(r_new[0]), zB=float(r_new[2]), IBxx=float(inertia[0, 0]),
            IByy=float(inertia[1, 1]), IBzz=float(inertia[2, 2]), IBxz=float(inertia[0, 2]),
        )  # fmt: skip
    except ValueError as exc:
        raise InputError(
            f"removing the arms leaves an impossible rear body ({exc}): the arms are too "
            "heavy for this bicycle's rider"
        ) from exc


def arm_model_matrices(
    p: BicycleParameters, arms: ArmParameters | None = None, arms_in_rear_body: bool = True
) -> CanonicalMatrices:
    """Canonical matrices M, C1, K0, K2 of the arm model.

    Parameters
    ----------
    p : BicycleParameters
        Bicycle with rider.
    arms : ArmParameters, optional
        The rider's arms; default :class:`ArmParameters` () (72 kg rider).
    arms_in_rear_body : bool, optional
        True (default): ``p``'s rear body includes the arms, which are taken out
        (:func:`remove_arms`) and added back as moving segments.  False: ``p``'s rear body
        excludes them and the segments are added.

    Returns
    -------
    CanonicalMatrices
        M [kg m^2], C1 [kg m], K0 [kg m], K2 [kg] in Meijaard's form, rows/columns
        [phi, delta] (roll and steer positive to the right), inputs [T_phi, T_delta].
    """
    arms = ArmParameters() if arms is None else arms
    base = remove_arms(p, arms) if arms_in_rear_body else p
    cm = canonical_matrices(base)
    M, C1, K0, K2 = cm.M.copy(), cm.C1.copy(), cm.K0.copy(), cm.K2.copy()
    for b in segment_bodies(p, arms):
        d = body_contribution(p, b)
        M += d.M
        C1 += d.C1
        K0 += d.K0
        K2 += d.K2
    return CanonicalMatrices(M=M, C1=C1, K0=K0, K2=K2, g=cm.g)


def stability_summary(
    cm: CanonicalMatrices, vmax: float = 10.0, step: float = 0.01
) -> dict[str, object]:
    """Stable speed ranges and the character of the unstable modes.

    Eigenvalues on a speed grid from ``step`` to ``vmax``; each change of stability is
    refined by bisection to 1e-6 m/s.

    Parameters
    ----------
    cm : CanonicalMatrices
        The model.
    vmax : float, optional
        Highest speed [m/s]. Default 10.
    step : float, optional
        Grid step [m/s]. Default 0.01.

    Returns
    -------
    dict
        ``stable_ranges``: list of [low, high] [m/s] where every eigenvalue has a negative
        real part (empty: no stable speed range); ``real_unstable_everywhere``: True if at
        every grid speed a real eigenvalue (|imag| < 1e-9 1/s) is positive;
        ``oscillatory_stable_everywhere``: True if every complex eigenvalue at every grid
        speed has a negative real part; ``max_real``: the largest real part at each grid
        speed [1/s]; ``speeds`` [m/s].

    Raises
    ------
    InputError
        If not 0 < ``step`` < ``vmax``.
    """
    if not (vmax > step > 0):
        raise InputError("stability_summary needs 0 < step < vmax [m/s]")
    v = np.arange(step, vmax + step / 2, step)
    ev = [eigenvalues(cm, float(s)) for s in v]
    mr = np.array([float(np.max(e.real)) for e in ev])
    real_unst = all(bool(np.any((np.abs(e.imag) < 1e-9) & (e.real > 0))) for e in ev)
    osc_stable = all(bool(np.all(e.real[np.abs(e.imag) >= 1e-9] < 0)) for e in ev)

    def stable(s: float) -> bool:
        return bool(np.max(eigenvalues(cm, s).real) < 0)

    def edge(a: float, b: float) -> float:
        sa = stable(a)
        while b - a > 1e-6:
            mid = 0.5 * (a + b)
            if stable(mid) == sa:
                a = mid
            else:
                b = mid
        return 0.5 * (a + b)

    ranges = []
    flag = mr < 0
    start = float(v[0]) if flag[0] else None
    for k in range(1, len(v)):
        if flag[k] != flag[k - 1]:
            e = edge(float(v[k - 1]), float(v[k]))
            if flag[k]:
                start = e
            else:
                ranges.append([start, e])
                start = None
    if start is not None:
        ranges.append([start, float(v[-1])])
    return {
        "stable_ranges": ranges,
        "real_unstable_everywhere": real_unst,
        "oscillatory_stable_everywhere": osc_stable,
        "max_real": mr,
        "speeds": v,
    }
