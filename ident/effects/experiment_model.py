"""Nominal (and augmented) model of the steer-by-wire treadmill experiment.

Plant: the linear Carvallo-Whipple model of the steer-by-wire bicycle (Meijaard 2007,
``sim.linear``) about upright running at the treadmill speed v.  The free decays are
small (|phi| < 0.15 rad, |delta| < 0.3 rad), so the linear model is used; the
nonlinear plant (``sim/integrate.py``) had not landed when this was written.

Controller: the logged steer-into-lean law ``T_cmd = K (V - v_s) phidot_m + T_ext``
(K = 2 N s^2/rad, V = 6.5 m/s), evaluated once per 10 ms loop on the *sensor* speed
v_s and the measured roll rate and held over the loop (zero-order hold, exactly as the
firmware does).  ``T_ext`` is the relayed handlebar torque of the Bode runs (zero in the
free decays).  Sign: with roll/steer positive to the right, +K stabilizes (see
``bikeid.dataset.sbw_logs``).

Effects: every name, unit, absent value, plausible range and one-line term is declared once
in :mod:`bikeid.sim.effect_registry` (``EFFECTS``); all default to absent.  This model
applies every entry to the linear model: the entries with a law from the table (each law's
term to M, C or K, or, for a constant or the sign of a rate, to the forcing of the sampled
loop: :meth:`ExperimentModel.law_matrix`, :meth:`ExperimentModel.forcing_rows`), input terms
to the command, sensor terms to the outputs, parameter corrections through
:meth:`plant_params`; a sign term (the steer Coulomb friction) is smoothed as
tanh(rate / 0.1 rad/s) here.

``tire_twist_stiffness`` (a contact-patch twist torque that falls with speed) can be fitted
by name but is kept out of the identification library: the per-file fits contradict its 1/v
law (docs/measured.md).

The four *parameter* corrections trail_correction, front_inertia_scale, front_mass_shift and
rear_inertia_scale are corrections of the values the data
README flags as uncertain (borrowed frame/fork inertias, estimated mass split); they change
the bicycle itself, so the linear matrices and the nonlinear plant both see them
(:meth:`ExperimentModel.plant_params`).  ``front_mass_shift`` dm moves mass from the rear
frame (at its mass centre) to the front frame (at its mass centre) keeping the total mass
and the combined B+H mass centre (the well-measured quantities): the rear-frame centre
moves to compensate; the moved mass carries no inertia of its own (point mass).

``tire_relaxation`` sigma [m] replaces the front wheel's lateral non-slip constraint
(contact path heading = wheel-plane heading psi + delta cos(lam)) by a first-order lag in
travelled distance: the front contact Q moves along a heading psi_c whose angle to the rear
frame relaxes towards the steered wheel plane's with time constant sigma / v,

    y_Q' = v psi_c,    (sigma / v) (psi_c - psi)' + (psi_c - psi) = delta cos(lam),

with y_Q = y_P + w psi - c cos(lam) delta.  The rear constraint y_P' = v psi and the
longitudinal rolling are kept, so the front lateral contact force is still a constraint force.
With the kinematic steer delta_k = (psi_c - psi) / cos(lam) (= delta in the Whipple model):

    psi'      = (v delta_k + c delta') cos(lam) / w
    delta_k'  = (v / sigma) (delta - delta_k).

The front slip angle is alpha = (delta - delta_k) cos(lam).  The lag acts on the heading
relative to the rear frame so that a steady turn is the Whipple one (delta_k = delta, no
slip); lagging the absolute heading instead, sigma psi_c' = v (psi + delta cos(lam) - psi_c),
adds a steady slip sigma psi' / v = sigma / R in a turn of radius R (tried on the real data
too, docs/measured.md).  This is a kinematic one-parameter lag, not a force-based tyre model
(cornering stiffness and a lateral degree of freedom would add parameters).

The Meijaard (2007, App. A) roll/steer equations depend on the front constraint only through
the rear-frame yaw: they are  M q'' + v C1d q' + g K0 q + a psi'' + v b psi' = f  with
a = [ITxz, IAlz + mu ITzz] (yaw-acceleration inertia, incl. the front-force moment mu w F_f),
b = [ST - mT zT, SA + SF sin(lam)] (wheel gyroscopics and centrifugal terms) and C1d the rest.
Eliminating psi with the relaxed kinematics gives (e_d the steer column)

    M q'' + v (C1 - nu a e_d^T) q' + g K0 q + v nu a delta_k' + v^2 K2[:, d] delta_k = f,
    nu = cos(lam) / w,   b nu = K2[:, d],

one extra state delta_k; delta_k = delta recovers  M q'' + v C1 q' + (g K0 + v^2 K2) q = f
exactly (tests/ident/effects/test_pipeline.py).  Linear model only: the nonlinear defect correction
is taken
without the relaxation (like steer_inertia), so the model is first order in sigma around it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numba
import numpy as np

from bikeid.dataset.sbw_logs import SPEED_CALIBRATION
from bikeid.dataset.windows import Window
from bikeid.sim.effect_registry import EFFECTS, V_FLOOR, Effect, effect
from bikeid.sim.effects import nonlinear_effects
from bikeid.sim.linear import CanonicalMatrices, canonical_matrices
from bikeid.sim.parameters import BicycleParameters, steer_by_wire
from bikeid.sim.sampling import zoh

__all__ = [
    "COULOMB_EPS",
    "DT",
    "ExperimentModel",
    "SimulationFailed",
    "nonlinear_correction",
    "with_nonlinear_correction",
    "window_errors",
    "yaw_coupling",
]

DT = 0.01  # s, one control loop of the steer-by-wire logs (the default sample period)
COULOMB_EPS = 0.1  # rad/s, smoothing of the Coulomb friction


class SimulationFailed(ValueError):
    """The nonlinear plant could not simulate a window (it fell, or a wheel lifted).

    A ValueError naming the window and the simulation's stop reason, so a caller can drop
    that window and go on.

    Parameters
    ----------
    file : str
        The window's log file.
    start : int
        The window's first row (file row index).
    reason : str
        Why the simulation stopped (e.g. the rear wheel's normal force reached 0 N).
    """

    def __init__(self, file: str, start: int, reason: str) -> None:
        super().__init__(f"{file}@{start}: nonlinear simulation failed: {reason}")
        self.file, self.start, self.reason = file, start, reason


@dataclass(frozen=True)
class ExperimentModel:
    """The treadmill experiment: Whipple plant + steer-into-lean loop + effects.

    Parameters
    ----------
    p : BicycleParameters, optional
        The bicycle (Meijaard 2007 benchmark parameter set); default the steer-by-wire
        bicycle (:func:`bikeid.sim.parameters.steer_by_wire`).
    effects : dict of str to float, optional
        Effect values by registry name (:data:`bikeid.sim.effect_registry.EFFECTS`), in
        each effect's registry unit; unset effects are absent.
    K : float, optional
        Steer-into-lean gain [N s^2/rad]: T_cmd = K (V - v_s) phidot_m (positive
        stabilizes, roll and steer positive to the right).
    V : float, optional
        Speed [m/s] at which the controller's gain vanishes.
    dt : float, optional
        Sample period of the logs and of the sampled loop [s] (default :data:`DT`, the
        steer-by-wire logs' 10 ms); a log of another period needs its own.
    speed_calibration : tuple of float, optional
        (a, b) of the logged speed: sensor = a * true + b [m/s]; default the steer-by-wire
        treadmill's (:data:`bikeid.dataset.sbw_logs.SPEED_CALIBRATION`); (1, 0) for a log
        whose speed column is the true speed.

    Raises
    ------
    ValueError
        If an effect name is unknown, a value is not a finite number, ``input_delay`` or
        ``actuator_lag`` is negative [s], or ``tire_relaxation`` is negative [m].
    """

    p: BicycleParameters = field(default_factory=steer_by_wire)
    effects: dict = field(default_factory=dict)
    K: float = 2.0
    V: float = 6.5
    dt: float = DT
    speed_calibration: tuple[float, float] = SPEED_CALIBRATION

    def __post_init__(self) -> None:
        if not (math.isfinite(self.dt) and self.dt > 0):
            raise ValueError(f"sample period dt must be a finite number > 0 s, got {self.dt!r}")
        a, b = self.speed_calibration
        if not (math.isfinite(a) and a > 0 and math.isfinite(b)):
            raise ValueError(f"speed_calibration (a, b) needs a finite a > 0 and a finite b, "
                             f"got {self.speed_calibration!r}")  # fmt: skip
        for k, v in self.effects.items():
            unit = effect(k).unit  # ValueError naming the known effects
            try:
                ok = math.isfinite(float(v))
            except (TypeError, ValueError):
                ok = False
            if not ok:
                raise ValueError(f"effect {k!r} must be a finite number [{unit}], got {v!r}")
        if self.e("input_delay") < 0 or self.e("actuator_lag") < 0:
            raise ValueError("input_delay and actuator_lag must be >= 0 s")
        if self.e("tire_relaxation") < 0:
            raise ValueError("tire_relaxation (relaxation length sigma) must be >= 0 m")

    def e(self, name: str) -> float:
        """Value of effect ``name`` [its registry unit]; its absent value when not set.

        Parameters
        ----------
        name : str
            Registry name (ValueError for an unknown one).

        Returns
        -------
        float
            The value in the effect's registry unit
            (:data:`bikeid.sim.effect_registry.EFFECTS`).

        Raises
        ------
        ValueError
            If ``name`` is not a registered effect.
        """
        v = self.effects.get(name)
        return float(effect(name).absent if v is None else v)

    def _cached(self, key: str, make):
        """``make()``, computed once per model: a model is a value (frozen, its effects never
        changed in place; :meth:`with_effects` makes a new one), so what depends only on it
        is kept on the instance (not a field: equality, ``replace`` and ``repr`` ignore it)."""
        d = self.__dict__
        if key not in d:
            object.__setattr__(self, key, make())
        return d[key]

    def with_effects(self, **values: float) -> ExperimentModel:
        """A copy with the effects ``values`` (registry names) set or replaced.

        Parameters
        ----------
        **values : float
            Effect values by registry name, each in its registry unit.

        Returns
        -------
        ExperimentModel
            The new model (this one is unchanged).

        Raises
        ------
        ValueError
            If a name is unknown or a value invalid (as the constructor).
        """
        return replace(self, effects={**self.effects, **values})

    # -- matrices ---------------------------------------------------------------------
    def plant_params(self) -> BicycleParameters:
        """``p`` with the parameter corrections applied (module docstring).

        Raises ValueError (from the parameter validation) if a correction makes the
        bicycle unphysical, e.g. a negative rear-frame mass.

        Returns
        -------
        BicycleParameters
            ``p`` with trail_correction [m] added to c, front_inertia_scale and
            rear_inertia_scale applied to the H and B inertia tensors [kg m^2] and
            front_mass_shift [kg] moved from B to H; ``p`` itself when none is set.

        Raises
        ------
        ValueError
            If ``front_mass_shift`` leaves a frame without mass, or the corrected
            parameters fail validation.
        """
        return self._cached("_plant_params", self._plant_params)

    def _plant_params(self) -> BicycleParameters:
        p = self.p
        ch: dict[str, float] = {}
        if self.e("trail_correction"):
            ch["c"] = p.c + self.e("trail_correction")
        sf = self.e("front_inertia_scale")
        if sf != 1.0:
            ch.update(IHxx=sf * p.IHxx, IHyy=sf * p.IHyy, IHzz=sf * p.IHzz, IHxz=sf * p.IHxz)
        sr = self.e("rear_inertia_scale")
        if sr != 1.0:
            ch.update(IBxx=sr * p.IBxx, IByy=sr * p.IByy, IBzz=sr * p.IBzz, IBxz=sr * p.IBxz)
        dm = self.e("front_mass_shift")
        if dm:
            mB, mH = p.mB - dm, p.mH + dm
            if mB <= 0 or mH <= 0:
                raise ValueError(
                    f"front_mass_shift {dm} kg leaves a frame without mass "
                    f"(mB {p.mB}, mH {p.mH} kg); keep it within (-mH, mB)"
                )
            xs = (p.mB * p.xB + p.mH * p.xH - mH * p.xH) / mB
            zs = (p.mB * p.zB + p.mH * p.zH - mH * p.zH) / mB
            ch.update(mB=mB, mH=mH, xB=xs, zB=zs)
        return p.replace(**ch) if ch else p

    def canonical(self) -> CanonicalMatrices:
        """Canonical matrices M, C1, K0, K2 of :meth:`plant_params`, steer_inertia added to
        M[delta, delta] [kg m^2].

        Returns
        -------
        CanonicalMatrices
            M [kg m^2], C1 [kg m], K0 [kg m], K2 [kg], rows/columns [phi, delta], and g.

        Raises
        ------
        ValueError
            If the parameter corrections are invalid (:meth:`plant_params`).
        """
        return self._cached("_canonical", self._canonical)

    def _canonical(self) -> CanonicalMatrices:
        cm = canonical_matrices(self.plant_params())
        M = cm.M + self.law_matrix("acceleration", 0.0)
        return CanonicalMatrices(M=M, C1=cm.C1, K0=cm.K0, K2=cm.K2, g=cm.g)

    def law_effects(self) -> list[tuple[Effect, float]]:
        """The set effects that carry a law, with their values, in registry order.

        Returns
        -------
        list of (Effect, float)
            Entries of :data:`bikeid.sim.effect_registry.EFFECTS` with a law and their
            values [the entry's unit].
        """
        return list(self._law_effects())

    def _law_effects(self) -> tuple[tuple[Effect, float], ...]:
        """:meth:`law_effects`, computed once (the matrices' hot loops read this tuple)."""
        return self._cached("_law_effects_t", lambda: tuple(
            (e, float(self.effects[n])) for n, e in EFFECTS.items()
            if e.law is not None and n in self.effects))  # fmt: skip

    def law_matrix(self, kind: str, v: float) -> np.ndarray:
        """The 2 x 2 addition of the laws of one kind to the left side M, C or K at speed v.

        A law's force ``coef * x`` on the right side (coef = sign * value * v^p,
        :meth:`bikeid.sim.effect_law.Law.coefficient`) is ``-coef`` in the matrix row of
        its equation and the column of its state.

        Parameters
        ----------
        kind : {"acceleration", "rate", "angle"}
            Which matrix: M [kg m^2], C [N m s/rad] or K [N m/rad].
        v : float
            True speed [m/s].

        Returns
        -------
        (2, 2) ndarray
            Rows and columns [phi, delta].
        """
        D = np.zeros((2, 2))
        for e, value in self._law_effects():
            law = e.law
            if law.kind == kind:
                col = 1 if "delta" in law.signal else 0
                D[law.index, col] -= law.coefficient(value, v, V_FLOOR)
        return D

    def forcing_rows(self, speeds) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The constant and sign laws as rows of the sampled loop's forcing.

        Parameters
        ----------
        speeds : array_like
            True speed of each window [m/s].

        Returns
        -------
        eq : (nr,) ndarray of int
            Equation of each row (0 roll, 1 steer).
        code : (nr,) ndarray of int
            Signal code (:data:`bikeid.sim.effect_law.KERNEL_SIGNALS`: 0 constant, 3 and 4
            the signs of the roll and steer rates, as tanh(rate / COULOMB_EPS)).
        coef : (len(speeds), nr) ndarray
            Signed coefficients [N m] at each window's speed; rows in the kernels' order
            (constants before signs).
        """
        rows = [(e.law, value) for e, value in self._law_effects()
                if e.law.kind in ("constant", "sign")]  # fmt: skip
        rows.sort(key=lambda r: r[0].kernel_code)  # stable: registry order within a code
        vs = np.atleast_1d(np.asarray(speeds, dtype=float))
        eq = np.array([law.index for law, _ in rows], dtype=np.int64)
        code = np.array([law.kernel_code for law, _ in rows], dtype=np.int64)
        coef = np.zeros((vs.size, len(rows)))
        for j, (law, value) in enumerate(rows):
            coef[:, j] = [law.coefficient(value, v, V_FLOOR) for v in vs]
        return eq, code, coef

    def continuous(self, v: float, cm: CanonicalMatrices | None = None):
        """(A, B) of [phi, delta, phidot, deltadot(, Ta)(, delta_k)] with inputs [u, w, T_phi].

        u: commanded torque into the actuator (lag); w: torque straight on the steer
        (friction, bias); T_phi: roll torque.  Ta (applied torque) only with an actuator
        lag, delta_k (kinematic steer) only with a tyre relaxation length (module docstring).

        Parameters
        ----------
        v : float
            True speed [m/s].
        cm : CanonicalMatrices, optional
            :meth:`canonical` (computed when not given).

        Returns
        -------
        A : (n, n) ndarray
            [1/s, 1/s^2 blocks].
        B : (n, 3) ndarray
            Inputs in N m.
        """
        E, A, B = self.descriptor(v, cm)
        if E is None:
            return A, B
        return np.linalg.solve(E, A), np.linalg.solve(E, B)

    def descriptor(self, v: float, cm: CanonicalMatrices | None = None, relax: bool = False):
        """(E, A, B) with E x' = A x + B u; E is None when it would be the identity.

        With ``tire_relaxation`` sigma the delta_k row is  sigma delta_k' = v (delta -
        delta_k)  and the steer/roll rows carry
        v nu a delta_k' (module docstring); E is singular at sigma = 0, where the finite
        generalized eigenvalues are exactly those of the Whipple model (``relax=True``
        keeps the delta_k state at sigma = 0 for that check).

        Parameters
        ----------
        v : float
            True speed [m/s].
        cm : CanonicalMatrices, optional
            :meth:`canonical` (computed when not given).
        relax : bool, optional
            Keep the delta_k state when sigma = 0.

        Returns
        -------
        E : (n, n) ndarray or None
            Descriptor matrix (None: identity; with delta_k its last diagonal entry is
            sigma [m] and the acceleration rows couple to delta_k').
        A : (n, n) ndarray
            State matrix for [phi, delta, phidot, deltadot(, Ta)(, delta_k)] (the delta_k
            row in m/s units: v (delta - delta_k)).
        B : (n, 3) ndarray
            Input matrix for [u, w, T_phi] [N m] (as :meth:`continuous`).
        """
        cm = cm or self.canonical()
        Minv = self._cached("_minv", lambda: np.linalg.inv(self.canonical().M))
        if cm is not self.canonical():  # matrices given from elsewhere
            Minv = np.linalg.inv(cm.M)
        C = v * cm.C1 + self.law_matrix("rate", v)
        Kq = cm.stiffness(v) + self.law_matrix("angle", v)
        lag = self.e("actuator_lag")
        sigma = self.e("tire_relaxation")
        relax = relax or sigma > 0
        nx = 4 + (lag > 0) + relax
        A = np.zeros((nx, nx))
        A[0:2, 2:4] = np.eye(2)
        B = np.zeros((nx, 3))
        B[2:4, 1] = Minv[:, 1]
        B[2:4, 2] = Minv[:, 0]
        if lag > 0:
            A[2:4, 4] = Minv[:, 1]
            A[4, 4] = -1.0 / lag
            B[4, 0] = 1.0 / lag
        else:
            B[2:4, 0] = Minv[:, 1]
        E = None
        if relax:
            p = self.plant_params()
            a, nu = yaw_coupling(p)
            k = nx - 1
            # psi enters the roll/steer rows as a psi'' + v b psi', b nu = K2[:, delta]:
            C[:, 1] -= v * nu * a
            Kq[:, 1] -= v**2 * cm.K2[:, 1]
            Kd = v**2 * cm.K2[:, 1]  # on delta_k
            E = np.eye(nx)
            E[2:4, k] = Minv @ (v * nu * a)  # v nu a delta_k' moved to the left side
            E[k, k] = sigma
            A[k, 1] = v
            A[k, k] = -v
            A[2:4, k] = -Minv @ Kd
        A[2:4, 0:2] = -Minv @ Kq
        A[2:4, 2:4] = -Minv @ C
        return E, A, B

    def discrete(self, v: float, h: float | None = None, cm: CanonicalMatrices | None = None):
        """ZOH discretization over step h [s]: (Ad, Bd) (:func:`bikeid.sim.sampling.zoh`).

        Parameters
        ----------
        v : float
            True speed [m/s].
        h : float, optional
            Step [s] (default the model's sample period ``dt``).
        cm : CanonicalMatrices, optional
            :meth:`canonical` (computed when not given).

        Returns
        -------
        Ad : (n, n) ndarray
            Sampled state matrix, states as :meth:`continuous`.
        Bd : (n, 3) ndarray
            Sampled input matrix for [u, w, T_phi] held over h [state units per N m].
        """
        A, B = self.continuous(v, cm)
        return zoh(A, B, self.dt if h is None else h, small=True)

    def true_speed(self, v_sensor: float) -> float:
        """True speed [m/s] from the sensor speed [m/s]: calibration, then speed_scale.

        Parameters
        ----------
        v_sensor : float
            Speed reported by the treadmill sensor [m/s].

        Returns
        -------
        float
            speed_scale * (v_sensor - b) / a [m/s], (a, b) the model's ``speed_calibration``.
        """
        a, b = self.speed_calibration
        return float(self.e("speed_scale") * (v_sensor - b) / a)

    def _delay(self) -> tuple[int, float]:
        d = self.e("input_delay") / self.dt
        m = int(math.floor(d + 1e-12))
        return m, d - m

    def closed_loop(self, v_sensor: float):
        """Augmented discrete closed loop z+ = Phi z + G_ext T_ext + c (no Coulomb term).

        z = [x(4), (Ta), command buffer (m+1)].  Returns (Phi, G_ext, c, n_plant).

        Parameters
        ----------
        v_sensor : float
            Sensor speed [m/s] (the loop gain uses it; the plant runs at :meth:`true_speed`).

        Returns
        -------
        Phi : (nz, nz) ndarray
            One-loop (10 ms) transition matrix of z.
        G : (nz,) ndarray
            Per N m of T_ext.
        c : (nz,) ndarray
            Constant terms (biases).
        n_plant : int
            Number of plant states at the head of z (4, plus Ta and delta_k when present).
        """
        v = self.true_speed(v_sensor)
        Ad, Bd = self.discrete(v)
        npl = Ad.shape[0]
        m, f = self._delay()
        L = m + 1
        nz = npl + L
        s, brr = self.e("roll_rate_scale"), self.e("roll_rate_bias")
        Kc = self.K * (self.V - v_sensor)
        h = np.zeros(nz)
        h[2] = Kc * s  # Tc = h z + c0 + T_ext
        c0 = Kc * brr

        def sel(j):  # row vector giving Tc_{k-j} in terms of z (and whether c0/T_ext enter)
            r = np.zeros(nz)
            if j == 0:
                return h.copy(), 1.0
            r[npl + j - 1] = 1.0
            return r, 0.0

        r1, a1 = sel(m)
        r2, a2 = sel(m + 1)
        g = self.e("command_gain")
        urow = g * ((1 - f) * r1 + f * r2)
        uext = g * ((1 - f) * a1 + f * a2)
        Phi = np.zeros((nz, nz))
        Phi[:npl, :npl] = Ad
        Phi[:npl, :] += np.outer(Bd[:, 0], urow)
        Phi[npl, :] = h
        for j in range(1, L):
            Phi[npl + j, npl + j - 1] = 1.0
        G = np.zeros(nz)
        G[:npl] = Bd[:, 0] * uext
        G[npl] = 1.0
        c = np.zeros(nz)
        feq, fcode, fcoef = self.forcing_rows([v])
        const = [0.0, 0.0]  # roll, steer constant torques [N m] (the sign terms are dropped)
        for j in np.flatnonzero(fcode == 0):
            const[feq[j]] += fcoef[0, j]
        c[:npl] = Bd[:, 0] * uext * c0 + Bd[:, 1] * const[1]
        if const[0] != 0.0:
            c[:npl] += Bd[:, 2] * const[0]
        c[npl] = c0
        return Phi, G, c, npl

    # -- analyses ---------------------------------------------------------------------
    def eigenvalues(self, v_sensor: float) -> np.ndarray:
        """Closed-loop eigenvalues [1/s] at a sensor speed: log(z)/dt of the sampled loop.

        Includes the zero-order hold and any delay; delay-buffer roots near z = 0 are
        dropped.  Sorted by decreasing real part.

        Parameters
        ----------
        v_sensor : float
            Sensor speed [m/s].

        Returns
        -------
        ndarray of complex
            Closed-loop eigenvalues [1/s], decreasing real part.
        """
        Phi = self.closed_loop(v_sensor)[0]
        z = np.linalg.eigvals(Phi)
        z = z[np.abs(z) > 1e-6]
        lam = np.log(z.astype(complex)) / self.dt
        return lam[np.argsort(-lam.real)]

    def oscillatory_roots(self, v_sensor: float) -> np.ndarray:
        """Closed-loop roots with 0 < Im < 0.8 Nyquist (one of each complex pair) [1/s].

        Parameters
        ----------
        v_sensor : float
            Sensor speed [m/s].

        Returns
        -------
        ndarray of complex
            Roots [1/s] with positive imaginary part below 0.8 pi / DT rad/s, decreasing
            real part.
        """
        lam = self.eigenvalues(v_sensor)
        return lam[(lam.imag > 1e-6) & (lam.imag < 0.8 * math.pi / self.dt)]

    def weave(self, v_sensor: float, near: complex | None = None) -> complex:
        """An oscillatory closed-loop root (:meth:`oscillatory_roots`).

        Without ``near``: the least damped one; with ``near``: the one closest to it
        (mode matching against a root fitted to data; below ~1.8 m/s the loop has two
        oscillatory pairs).

        Parameters
        ----------
        v_sensor : float
            Sensor speed [m/s].
        near : complex, optional
            A root to match [1/s].

        Returns
        -------
        complex
            [1/s]; nan + nan i when the loop has no oscillatory root.
        """
        osc = self.oscillatory_roots(v_sensor)
        if osc.size == 0:
            return complex(np.nan, np.nan)
        if near is not None:
            return complex(osc[np.argmin(np.abs(osc - near))])
        return complex(osc[np.argmax(osc.real)])

    def frequency_response(self, v_sensor: float, freqs) -> np.ndarray:
        """Complex response (len(freqs), 2) from T_ext to [phidot_m, delta_m].

        Parameters
        ----------
        v_sensor : float
            Sensor speed [m/s].
        freqs : array_like
            Frequencies [Hz].

        Returns
        -------
        (len(freqs), 2) ndarray of complex
            [rad/s per N m, rad per N m].
        """
        Phi, G, _, _ = self.closed_loop(v_sensor)
        s = self.e("roll_rate_scale")
        out = []
        for fr in np.atleast_1d(freqs):
            z = np.exp(2j * math.pi * fr * self.dt)
            X = np.linalg.solve(z * np.eye(Phi.shape[0]) - Phi, G)
            out.append([s * X[2], X[1]])
        return np.array(out)

    # -- simulation -------------------------------------------------------------------
    def simulate(self, windows: list[Window], nsub: int = 1) -> list[dict[str, np.ndarray]]:
        """Simulate each window from its measured initial state (vectorized over windows).

        Returns per window the *measured-equivalent* outputs phi, delta, phidot,
        deltadot (sensor biases/scale applied), and the applied command T.  A window with
        ``drive == "logged"`` is driven open loop by its logged command ``T_logged`` (the
        input-path effects, delay, gain and lag, still act on it; an unstable model simply
        grows over the window); a window with ``drive == "kstep"`` is predicted k samples
        ahead through the model's steady-state Kalman filter on its logged command
        (:func:`bikeid.ident.effects.kstep.kstep_outputs`; ``nsub`` does not apply); the
        others by the steer-into-lean law.  ``nsub`` substeps per 10 ms loop re-evaluate the
        Coulomb friction (the controller is still sampled every 10 ms).

        Parameters
        ----------
        windows : list of Window
            Measured windows (initial state, sensor speed, external torque T_ext).
        nsub : int, optional
            Substeps per loop.

        Returns
        -------
        list of dict of str to ndarray
            ``phi``, ``delta`` [rad], ``phidot``, ``deltadot`` [rad/s], ``T`` [N m] per window
            (each window's defect correction added, when one is attached).
        """
        if not windows:
            return []
        ks = [i for i, w in enumerate(windows) if w.drive == "kstep"]
        if ks:  # k-step windows: predicted through the model's Kalman filter
            from bikeid.ident.effects.kstep import kstep_outputs

            kw = [windows[i] for i in ks]
            out_k = dict(zip(ks, kstep_outputs(self, kw, initial_states(kw), COULOMB_EPS),
                             strict=True))  # fmt: skip
            rest = [i for i in range(len(windows)) if i not in out_k]
            out_r = dict(zip(rest, self.simulate([windows[i] for i in rest], nsub), strict=True))
            return [out_k[i] if i in out_k else out_r[i] for i in range(len(windows))]
        nw = len(windows)
        nmax = max(w.n for w in windows)
        cms = self.canonical()
        vs = np.array([np.mean(w.v_sensor) for w in windows])
        mats = [self.discrete(self.true_speed(v), self.dt / nsub, cms) for v in vs]
        Ad = np.stack([m[0] for m in mats])
        Bd = np.stack([m[1] for m in mats])
        npl = Ad.shape[1]
        m, f = self._delay()
        g, s = self.e("command_gain"), self.e("roll_rate_scale")
        brr, bphi, bdel = (
            self.e("roll_rate_bias"),
            self.e("roll_angle_bias"),
            self.e("steer_angle_bias"),
        )
        feq, fcode, fcoef = self.forcing_rows([self.true_speed(v) for v in vs])
        Kc = self.K * (self.V - vs)
        H = max(m + 2, 2)
        hist = np.stack([w.command_history(H) for w in windows])  # oldest first
        x = np.zeros((nw, npl))
        x0 = initial_states(windows)
        x[:, 0] = x0[:, 0] - bphi
        x[:, 1] = x0[:, 1] - bdel
        x[:, 2] = (x0[:, 2] - brr) / s
        x[:, 3] = x0[:, 3]
        if self.e("actuator_lag") > 0:
            x[:, 4] = g * hist[:, -1]
        if self.e("tire_relaxation") > 0:  # delta_k on the slow manifold, first order in sigma
            vt = np.array([self.true_speed(v) for v in vs])
            x[:, -1] = x[:, 1] - self.e("tire_relaxation") / vt * x[:, 3]
        text = np.zeros((nw, nmax))
        tphi = np.zeros((nw, nmax))
        tlog = np.zeros((nw, nmax))
        logged = np.array([w.drive == "logged" for w in windows])
        for i, w in enumerate(windows):
            if w.drive not in ("loop", "logged"):
                raise ValueError(f"{w.file}@{w.start}: drive must be 'loop', 'logged' or "
                                 f"'kstep', got {w.drive!r}")  # fmt: skip
            if logged[i]:
                if w.T_logged is None or np.size(w.T_logged) != w.n:
                    raise ValueError(f"{w.file}@{w.start}: drive 'logged' needs the logged "
                                     "steer command over the window (T_logged)")  # fmt: skip
                tlog[i, : w.n] = w.T_logged
            text[i, : w.n] = w.T_ext
            if w.T_phi is not None:
                tphi[i, : w.n] = w.T_phi
        cmd = np.zeros((nw, H + nmax))  # Tc_{k-H} .. Tc_{-1} (history), then Tc_0, Tc_1, ...
        cmd[:, :H] = hist
        X, U = _sampled_loop(
            np.ascontiguousarray(Ad), np.ascontiguousarray(Bd), x, cmd, H, logged, tlog, text,
            tphi, Kc, s, brr, g, f, m, nsub, feq, fcode, fcoef, COULOMB_EPS,
        )  # fmt: skip
        out = []
        for i, w in enumerate(windows):
            n = w.n
            o = {
                "phi": X[i, :n, 0] + bphi,
                "delta": X[i, :n, 1] + bdel,
                "phidot": s * X[i, :n, 2] + brr,
                "deltadot": X[i, :n, 3],
                "T": U[i, :n],
            }
            if w.correction is not None:
                for c, d in w.correction.items():
                    o[c] = o[c] + d
            out.append(o)
        return out


def nonlinear_correction(window: Window, model: ExperimentModel | None = None) -> dict:
    """The defect correction of one window at ``model``: y_nl(m') - y_lin(m').

    m' is the part of ``model`` (default: the nominal) that the nonlinear plant can carry
    (:func:`bikeid.sim.effects.nonlinear_effects`, Coulomb smoothing COULOMB_EPS).
    The nonlinear Whipple plant (:func:`sim.integrate.simulate`, RK4, 4 substeps per 10 ms,
    speed held at the true speed) and the linear model are both run with m' from the
    window's measured initial state, zero command history, and the same sampled loop
    ``T = K (V - v_s) phidot`` (v_s the window's mean sensor speed), or, for a window with
    ``drive == "logged"``, the same logged command replayed open loop.  A window with
    ``drive == "kstep"`` is cut into segments of its horizon k (one weave period at most,
    :func:`bikeid.ident.effects.kstep.horizon`), each replayed from its own measured start,
    so that the open-loop plant does not run long enough to fall.

    Parameters
    ----------
    window : Window
        The window (its own correction, if any, is ignored).
    model : ExperimentModel, optional
        The linearization point (default: the nominal model).

    Returns
    -------
    dict of str to ndarray
        ``phi``, ``delta`` [rad], ``phidot``, ``deltadot`` [rad/s]: nonlinear minus linear.

    Raises
    ------
    SimulationFailed
        A ValueError, if the nonlinear simulation stops before the window's end (naming
        the window and why).
    """
    from bikeid.controllers.steer_into_lean import SteerIntoLean
    from bikeid.sim.integrate import simulate
    from bikeid.sim.nonlinear import WhippleBicycle

    model = model or ExperimentModel()
    if window.drive == "kstep":  # replayed over segments of one horizon (ident.effects.kstep)
        from bikeid.ident.effects.kstep import horizon

        w = window
        k = int(w.meta.get("kstep_horizon") or horizon(model, float(np.mean(w.v_sensor))))
        parts = [nonlinear_correction(_segment(w, a, min(a + k, w.n)), model)
                 for a in range(0, w.n, k) if min(a + k, w.n) - a >= 2]  # fmt: skip
        out = {c: np.concatenate([p[c] for p in parts]) for c in parts[0]}
        if out["phi"].size < w.n:  # a last segment of one sample: no correction there
            out = {c: np.pad(y, (0, w.n - y.size), mode="edge") for c, y in out.items()}
        return out
    bike = WhippleBicycle(model.plant_params())
    w = window
    vs = float(np.mean(w.v_sensor))
    v = model.true_speed(vs)
    dt = model.dt
    fx, eq = nonlinear_effects(model.effects, v, dt, COULOMB_EPS)
    keep = {k: model.e(k) for k in model.effects if EFFECTS[k].layer == "parameter"}
    lin_m = replace(model, effects={**eq, **keep})
    w0 = replace(w, hist=np.zeros_like(w.hist), correction=None)
    sl = lin_m.simulate([w0])[0]
    if w.drive == "logged":  # replay the logged command, sample by sample
        cmd = np.asarray(w.T_logged, dtype=float)

        def ctrl(t, y, cmd=cmd):
            return cmd[min(int(round(t / dt)), cmd.size - 1)]
    else:
        ctrl = SteerIntoLean(model.K, model.V, design_speed=vs)
    tr = simulate(
        bike, bike.state(v, *map(float, w.state0())), (w.n - 1) * dt, controller=ctrl,
        mode="held", substeps=4, effects=fx or None, dt=dt,
    )  # fmt: skip
    if tr.stop_reason is not None or tr.t.size != w.n:
        raise SimulationFailed(w.file, w.start, str(tr.stop_reason or "ended early"))
    return {c: tr.signal(c) - sl[c] for c in ("phi", "delta", "phidot", "deltadot")}


def _segment(w: Window, a: int, b: int) -> Window:
    """Rows a..b-1 of a k-step window as a window replaying its logged command."""
    arr = ("phi", "delta", "phidot", "deltadot", "v_sensor", "T_ext", "T_phi", "T_logged")
    cut = {c: getattr(w, c)[a:b] for c in arr if getattr(w, c) is not None}
    hist = np.concatenate([w.hist, w.T_logged[:a]])[-max(w.hist.size, 1) :]
    return replace(w, **cut, start=w.start + a, hist=hist, drive="logged", correction=None)


def with_nonlinear_correction(
    windows: list[Window], model: ExperimentModel | None = None
) -> list[Window]:
    """Make the model nonlinear: new windows carrying the defect correction at ``model``.

    Each returned window is its input with ``correction`` = :func:`nonlinear_correction` at
    ``model`` (the inputs are values and stay as they are).  The correction is added to
    every later :meth:`ExperimentModel.simulate` of the window, so a model m simulates as
    y_lin(m) + y_nl(m') - y_lin(m'): exactly the nonlinear plant at m = m', and to first
    order in (m - m') near it (defect correction;
    :func:`bikeid.ident.effects.selection.select_effects` takes it again at the current
    model after each accepted effect).  Needed because the logs' decays reach steer angles of
    0.3-0.6 rad at 1.5 m/s, where the linear and the nonlinear plant differ by 0.1-0.45 in
    NRMSE (0.02-0.1 at 2.5-4.5 m/s).

    Parameters
    ----------
    windows : list of Window
        The windows.
    model : ExperimentModel, optional
        The linearization point (default: the nominal model).

    Returns
    -------
    list of Window
        New windows, in order, each with its correction at ``model``.
    """
    return [replace(w, correction=nonlinear_correction(w, model)) for w in windows]


@numba.njit(cache=True)
def _sampled_loop(Ad, Bd, x, cmd, H, logged, tlog, text, tphi, Kc, s, brr, g, f, m, nsub,
                  feq, fcode, fcoef, eps):  # fmt: skip
    """The sampled loop of :meth:`ExperimentModel.simulate`, compiled (same arithmetic).

    Per window i and loop k: the command Tc_k (logged, or the law on the measured-equivalent
    roll rate plus T_ext) goes into ``cmd[i, H + k]``; the plant input is the delayed,
    interpolated command times the gain; ``nsub`` ZOH substeps with the forcing rows
    (:meth:`ExperimentModel.forcing_rows`: constants, and signs of rates as
    tanh(rate / eps)) re-evaluated into the steer torque w and the roll torque.  Returns
    the states X (nw, nmax, npl) at each loop start and the inputs U.
    """
    nr = feq.shape[0]
    nw, npl = x.shape
    nmax = tlog.shape[1]
    X = np.zeros((nw, nmax, npl))
    U = np.zeros((nw, nmax))
    xn = np.zeros(npl)
    for i in range(nw):
        for k in range(nmax):
            for j in range(npl):
                X[i, k, j] = x[i, j]
            if logged[i]:
                tck = tlog[i, k]
            else:
                tck = Kc[i] * (s * x[i, 2] + brr) + text[i, k]
            cmd[i, H + k] = tck
            u = g * ((1 - f) * cmd[i, H + k - m] + f * cmd[i, H + k - m - 1])
            U[i, k] = u
            for _ in range(nsub):
                wtq = 0.0
                wroll = tphi[i, k]
                for j in range(nr):
                    if fcode[j] == 0:
                        term = fcoef[i, j]
                    elif fcode[j] == 3:
                        term = fcoef[i, j] * np.tanh(x[i, 2] / eps)
                    else:
                        term = fcoef[i, j] * np.tanh(x[i, 3] / eps)
                    if feq[j] == 1:
                        wtq += term
                    else:
                        wroll += term
                for r in range(npl):
                    acc = 0.0
                    for c in range(npl):
                        acc += Ad[i, r, c] * x[i, c]
                    xn[r] = acc + Bd[i, r, 0] * u + Bd[i, r, 1] * wtq + Bd[i, r, 2] * wroll
                for r in range(npl):
                    x[i, r] = xn[r]
    return X, U


#: Weights of the first 5 samples giving a quadratic least-squares fit's value at the first:
#: :meth:`bikeid.dataset.windows.Window.state0` as one dot product (the fit is linear in the
#: samples and does not depend on the sample period).
_STATE0_WEIGHTS = np.linalg.pinv(np.vander(np.arange(5.0), 3))[-1]
_WINDOW_STATE0 = Window.state0  # the quadratic fit the weights reproduce


def initial_states(windows: list[Window]) -> np.ndarray:
    """The measured start state of each window, as :meth:`Window.state0` (vectorized).

    Parameters
    ----------
    windows : list of Window
        The windows.

    Returns
    -------
    (len(windows), 4) ndarray
        phi [rad], delta [rad], phidot [rad/s], deltadot [rad/s] at each first sample: the
        quadratic least-squares fit over the first 5 samples, equal to ``state0`` to
        round-off (windows shorter than 5 samples, or whose ``state0`` is not
        :meth:`Window.state0`'s fit, e.g. a subclass giving the exact state, use ``state0``
        itself).
    """
    if not windows:
        return np.zeros((0, 4))
    if min(w.n for w in windows) < 5 or any(type(w).state0 is not _WINDOW_STATE0
                                            for w in windows):  # fmt: skip
        return np.stack([w.state0() for w in windows])
    first = np.array([[w.phi[:5], w.delta[:5], w.phidot[:5], w.deltadot[:5]] for w in windows])
    return first @ _STATE0_WEIGHTS


def yaw_coupling(p: BicycleParameters) -> tuple[np.ndarray, float]:
    """(a, nu) of the rear-frame yaw in the roll/steer equations (Meijaard 2007, App. A).

    a = [ITxz, IAlz + mu ITzz] [kg m^2] multiplies psi'' (roll row: total-bicycle product of
    inertia; steer row: front-assembly yaw coupling plus the moment mu w F_f of the front
    contact force needed to yaw the whole bicycle); nu = cos(lam) / w [1/m], with
    psi' = nu (v delta + c delta') in the Whipple model.

    Parameters
    ----------
    p : BicycleParameters
        The bicycle (Meijaard 2007 parameters: lam [rad], c, w [m], masses [kg],
        inertias [kg m^2]).

    Returns
    -------
    a : (2,) ndarray
        [kg m^2].
    nu : float
        [1/m].
    """
    sl, cl = math.sin(p.lam), math.cos(p.lam)
    ITxz = p.IBxz + p.IHxz - p.mB * p.xB * p.zB - p.mH * p.xH * p.zH + p.mF * p.w * p.rF
    ITzz = p.IRxx + p.IBzz + p.IHzz + p.IFxx + p.mB * p.xB**2 + p.mH * p.xH**2 + p.mF * p.w**2
    mA = p.mH + p.mF
    xA = (p.xH * p.mH + p.w * p.mF) / mA
    zA = (p.zH * p.mH - p.rF * p.mF) / mA
    IAxz = p.IHxz - p.mH * (p.xH - xA) * (p.zH - zA) + p.mF * (p.w - xA) * (p.rF + zA)
    IAzz = p.IHzz + p.IFxx + p.mH * (p.xH - xA) ** 2 + p.mF * (p.w - xA) ** 2
    uA = (xA - p.w - p.c) * cl - zA * sl
    IAlz = mA * uA * xA + IAxz * sl + IAzz * cl
    mu = p.c / p.w * cl
    return np.array([ITxz, IAlz + mu * ITzz]), cl / p.w


def window_errors(windows: list[Window], sims, channels=("phidot", "delta")) -> np.ndarray:
    """NRMSE per window and channel: ||y_sim - y|| / ||y - mean(y)|| (0 = perfect).

    This is 1 - fit of MATLAB ``compare`` (identification.md 1.2), computed by
    :func:`bikeid.ident.validate.goodness_of_fit` (``"nrmse"``), the fit of ``bikeid
    validate``; NaN for a window whose signal is constant.

    Parameters
    ----------
    windows : list of Window
        Measured windows.
    sims : list of dict
        :meth:`ExperimentModel.simulate` of each window.
    channels : tuple of str, optional
        Window signals compared (default roll rate [rad/s] and steer angle [rad]).

    Returns
    -------
    (len(windows), len(channels)) ndarray
        Dimensionless.
    """
    from bikeid.ident.validate import goodness_of_fit

    out = np.zeros((len(windows), len(channels)))
    for i, (w, s) in enumerate(zip(windows, sims, strict=True)):
        for j, c in enumerate(channels):
            out[i, j] = goodness_of_fit(getattr(w, c), s[c])["nrmse"]
    return out
