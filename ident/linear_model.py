"""One base for every identified linear model: state space, eigenvalues, and over speed.

Every linear model class of :mod:`bikeid.ident` (:class:`~bikeid.ident.pem.CanonicalModel`,
:class:`~bikeid.ident.pem.SpeedCanonicalModel`, :class:`~bikeid.ident.greybox.GreyboxModel`,
:class:`~bikeid.ident.direct.DirectResult`) derives from :class:`LinearModel`, and those
defined over speed from :class:`SpeedDependentModel`, so they share one API:

- ``state_space(speed=None, dt=None, *, inputs=None, order="bikeid")``: a python-control
  ``StateSpace`` whose states are bikeid's [phi, delta, phidot, deltadot]
  (:data:`bikeid.sim.conventions.LINEAR_STATE`) and whose outputs are the model's measured
  states in the same order; inputs named (``T_delta``, and ``T_phi``, ``F`` where the model
  has them).  Chen & Dao's order [phi, phidot, delta, deltadot] only by name,
  ``order="chen_dao"`` (states and outputs both).  ``dt`` [s] samples it exactly with a
  zero-order hold (:func:`bikeid.sim.sampling.zoh`).
- ``eigenvalues(speed=None)``: an :class:`Eigenvalues` array in the one order used
  everywhere in bikeid (:data:`EIGENVALUE_ORDER`: ascending real part, then imaginary part,
  as ``numpy.sort_complex``), each with its mode name (``weave``, ``capsize``, ``caster``;
  ``weave (real)`` for the two real roots that merge into the weave pair at v_d) where it
  has one (:func:`mode_names`), in ``.modes``.
- Speed-dependent models add ``eigenvalues_vs_speed(speeds)`` (tracked, labelled branches,
  :func:`bikeid.sim.linear.eigenvalues_vs_speed`) and ``critical_speeds(vmax=30.0)``
  (:func:`bikeid.sim.linear.critical_speeds`).  Critical speeds belong to models over speed:
  a fixed-speed model (one speed's fit) refuses both with an
  :class:`~bikeid.sim.errors.InputError` that names the models which have them.

``speed`` is in m/s.  A model defined over speed needs it; a fixed-speed model takes
``None`` or its own speed (anything else is refused: it says nothing about other speeds).

A subclass provides ``_matrices_at(speed) -> (A, columns)`` (A in bikeid's state order,
``columns`` the input columns by name) and, if defined over speed, ``_speed_matrices()``
(canonical matrices whose A(v) is the model's, for the sweeps); its class attribute
``INPUTS`` names the default inputs of ``state_space`` and ``measured`` (or its
``outputs`` attribute) the measured states.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from bikeid.sim.conventions import CANONICAL_STATE, LINEAR_STATE
from bikeid.sim.errors import InputError
from bikeid.sim.linear import (
    WEAVE_REAL,
    CanonicalMatrices,
    EigenSweep,
    critical_speeds,
    eigenvalues_vs_speed,
    match_eigenvalues,
    mode_names_at,
)
from bikeid.sim.sampling import zoh

if TYPE_CHECKING:  # python-control is loaded where a StateSpace is made (it imports
    import control  # matplotlib: ~0.8 s that the commands without one need not pay)

__all__ = [
    "EIGENVALUE_ORDER",
    "MODE_NAMES",
    "WEAVE_REAL",
    "Eigenvalues",
    "LinearModel",
    "SpeedDependentModel",
    "mode_names",
    "sort_eigenvalues",
]

#: The one order of eigenvalues in bikeid's identification API (model ``eigenvalues``,
#: :func:`bikeid.ident.uncertainty.eigenvalue_intervals`, ``bikeid identify``).
EIGENVALUE_ORDER = "ascending real part, then ascending imaginary part (numpy.sort_complex)"
#: Mode names of the Whipple bicycle's eigenvalues; "" where an eigenvalue has none.
MODE_NAMES = ("weave", "capsize", "caster")
#: Highest speed [m/s] of the branch tracking that names four real eigenvalues of a model
#: defined over speed (the weave pair is complex well below it on every bicycle modelled).
_TRACK_TO = 10.0


class Eigenvalues(np.ndarray):
    """Eigenvalues [1/s] in :data:`EIGENVALUE_ORDER`, with their mode names.

    A complex ``numpy.ndarray`` (everything numpy does works on it) with one extra attribute.

    Parameters
    ----------
    values : array_like of complex
        The eigenvalues [1/s], already in :data:`EIGENVALUE_ORDER`.
    modes : sequence of str
        One name per eigenvalue: ``"weave"``, ``"weave (real)"``, ``"capsize"``,
        ``"caster"`` or ``""`` (:func:`mode_names`).

    Attributes
    ----------
    modes : tuple of str
        The mode name of each eigenvalue, ``""`` where it has none (lost by slicing).
    """

    modes: tuple[str, ...]

    def __new__(cls, values: Any, modes: Sequence[str]) -> Eigenvalues:
        obj = np.asarray(values, dtype=complex).ravel().view(cls)
        if len(modes) != obj.size:
            raise ValueError(f"{len(modes)} mode names for {obj.size} eigenvalues")
        obj.modes = tuple(str(m) for m in modes)
        return obj

    def __array_finalize__(self, obj: Any) -> None:
        modes = getattr(obj, "modes", None)
        self.modes = modes if modes is not None and len(modes) == self.size else ("",) * self.size

    def __reduce__(self):
        return (Eigenvalues, (np.asarray(self), self.modes))

    def by_mode(self) -> dict[str, list[complex]]:
        """The named eigenvalues grouped by mode.

        Returns
        -------
        dict of str to list of complex
            ``{"weave": [...], "capsize": [...], "caster": [...]}`` for the names present
            (``"weave (real)"`` below v_d instead of ``"weave"``) [1/s], in
            :data:`EIGENVALUE_ORDER` within each.
        """
        out: dict[str, list[complex]] = {}
        for lam, mode in zip(np.asarray(self), self.modes, strict=True):
            if mode:
                out.setdefault(mode, []).append(complex(lam))
        return out


def sort_eigenvalues(values: Any) -> np.ndarray:
    """Eigenvalues in :data:`EIGENVALUE_ORDER`.

    Parameters
    ----------
    values : array_like of complex
        Eigenvalues [1/s], any order.

    Returns
    -------
    (n,) complex ndarray
        The same values sorted by real part, then imaginary part.
    """
    return np.sort_complex(np.asarray(values, dtype=complex).ravel())


def mode_names(
    values: Any, matrices: CanonicalMatrices | None = None, speed: float | None = None
) -> tuple[str, ...]:
    """The mode name of each eigenvalue of a bicycle model at one speed.

    From the values alone by the rule of :func:`bikeid.sim.linear.mode_names_at`, which
    follows the Whipple bicycle's root loci (Meijaard et al. 2007, Table 2 and Fig. 3): the
    complex pair above v_d is the weave, the more negative real root the caster, the other
    the capsize; below v_d the four real roots are, in ascending order, the caster, the
    capsize and the weave's two real roots, ``"weave (real)"``
    (:data:`bikeid.sim.linear.WEAVE_REAL`); a complex pair of the caster and capsize roots
    merged (Browser, Pista, Fisher at low speed) stays unnamed.  A model over speed
    (``matrices`` and ``speed`` given) names four real roots by its own branches instead:
    tracked from ``speed`` up to 10 m/s, the labels of
    :func:`bikeid.sim.linear.eigenvalues_vs_speed` carried back (the weave's as
    ``"weave (real)"``), unless its tracking finds no weave pair.  On the benchmark the two
    agree at every speed below v_d.

    Parameters
    ----------
    values : (4,) array_like of complex
        Eigenvalues [1/s] of the model at ``speed``, in the order the names are wanted.
    matrices : CanonicalMatrices, optional
        Matrices whose A(v) is the model's (models defined over speed).
    speed : float, optional
        Forward speed [m/s] of ``values``; needed with ``matrices``.

    Returns
    -------
    tuple of str
        One of ``"weave"``, ``"weave (real)"``, ``"capsize"``, ``"caster"`` or ``""`` per
        eigenvalue.
    """
    lam = np.asarray(values, dtype=complex).ravel()
    names = mode_names_at(lam)
    if names.count(WEAVE_REAL) == 2 and "" not in names:  # four real roots
        return _tracked_names(lam, matrices, speed) or names
    return names


def _tracked_names(
    lam: np.ndarray, matrices: CanonicalMatrices | None, speed: float | None
) -> tuple[str, ...] | None:
    """Names of four real roots from the model's own branches over speed; None when the
    model is not defined over speed or its tracking finds no weave pair."""
    if matrices is None or speed is None or not 0 <= speed < 1000:
        return None
    sweep = eigenvalues_vs_speed(matrices, [float(speed), max(float(speed), _TRACK_TO)])
    if "weave" not in sweep.labels:
        return None
    names = [""] * 4
    _, col = match_eigenvalues(lam, sweep.values[0], return_index=True)
    for j, i in enumerate(col):  # lam[col[j]] pairs with branch j
        label = sweep.labels[j]
        names[i] = WEAVE_REAL if label == "weave" else label
    return tuple(names)


def _resolve_speed(model: Any, speed: float | None) -> float:
    if isinstance(model, SpeedDependentModel):
        if speed is None:
            raise InputError(
                f"a {type(model).__name__} is defined over speed: pass the speed [m/s]"
            )
        return float(speed)
    own = float(model.speed)
    if speed is not None and abs(float(speed) - own) > 1e-6 * max(1.0, abs(own)):
        raise InputError(
            f"speed={speed} m/s: this fixed-speed {type(model).__name__} was fitted at {own:g} "
            "m/s and says nothing about other speeds; use a model over speed "
            "(pem fit_speed_model, greybox, direct)"
        )
    return own


#: The permutation between the two state orders: x_bikeid = PERM x_chen_dao (symmetric).
_PERM = np.array([[1.0, 0, 0, 0], [0, 0, 1, 0], [0, 1, 0, 0], [0, 0, 0, 1]])


class LinearModel:
    """Base of every identified linear model: named state space and ordered eigenvalues.

    Attributes
    ----------
    INPUTS : tuple of str
        Class attribute: default inputs of :meth:`state_space`.
    measured_states : tuple of str
        The measured states the model outputs, in bikeid's state order.
    """

    INPUTS: ClassVar[tuple[str, ...]] = ("T_delta",)

    def _matrices_at(self, speed: float) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        raise NotImplementedError

    def _speed_matrices(self) -> CanonicalMatrices | None:
        return None

    @property
    def measured_states(self) -> tuple[str, ...]:
        """tuple of str: the measured states the model outputs, in bikeid's state order."""
        outs = getattr(self, "outputs", LINEAR_STATE)
        return tuple(s for s in LINEAR_STATE if s in outs)

    def state_space(
        self,
        speed: float | None = None,
        dt: float | None = None,
        *,
        inputs: Sequence[str] | None = None,
        order: str = "bikeid",
    ) -> control.StateSpace:
        """The model as a python-control ``StateSpace`` with named states, inputs, outputs.

        Parameters
        ----------
        speed : float, optional
            Forward speed [m/s]; required for a model defined over speed, ``None`` or the
            fitted speed for a fixed-speed model.
        dt : float, optional
            Sample period [s]: the model sampled exactly with a zero-order hold; default
            continuous time.
        inputs : sequence of str, optional
            Input columns in this order, from the model's inputs (``T_delta`` [N m]; a
            matrix model also ``T_phi`` [N m] and ``F`` [N], positive to the right);
            default the class's :attr:`INPUTS`.
        order : {"bikeid", "chen_dao"}, optional
            State (and output) order: bikeid's [phi, delta, phidot, deltadot] (default) or
            Chen & Dao's [phi, phidot, delta, deltadot].

        Returns
        -------
        control.StateSpace
            States and outputs named and in the chosen order (the outputs are the measured
            states, C rows of the identity, D = 0; rad and rad/s), inputs named; A [1/s].

        Raises
        ------
        InputError
            If the speed is missing or not the fitted one, ``dt`` is not positive, an
            input is unknown or ``order`` is neither choice.
        """
        v = _resolve_speed(self, speed)
        if order not in ("bikeid", "chen_dao"):
            raise InputError(f"order={order!r}: use 'bikeid' or 'chen_dao'")
        A, cols = self._matrices_at(v)
        names = tuple(self.INPUTS if inputs is None else inputs)
        bad = [u for u in names if u not in cols]
        if bad or not names:
            raise InputError(f"inputs {list(names)}: choose from {list(cols)}")
        B = np.column_stack([cols[u] for u in names])
        states = LINEAR_STATE
        if order == "chen_dao":
            A, B, states = _PERM @ A @ _PERM, _PERM @ B, CANONICAL_STATE
        outs = [s for s in states if s in self.measured_states]
        C = np.eye(4)[[states.index(o) for o in outs]]
        D = np.zeros((len(outs), len(names)))
        import control

        if dt is None:
            return control.ss(A, B, C, D, inputs=list(names), outputs=outs, states=list(states))
        if not (np.isfinite(dt) and dt > 0):
            raise InputError(f"dt={dt}: give a positive sample period [s] or None")
        Ad, Bd = zoh(A, B, float(dt))
        return control.ss(Ad, Bd, C, D, float(dt), inputs=list(names), outputs=outs,
                          states=list(states))  # fmt: skip

    def eigenvalues(self, speed: float | None = None) -> Eigenvalues:
        """Eigenvalues of the continuous-time state matrix, ordered and named.

        Parameters
        ----------
        speed : float, optional
            Forward speed [m/s]; required for a model defined over speed.

        Returns
        -------
        Eigenvalues
            The four eigenvalues [1/s] in :data:`EIGENVALUE_ORDER` (ascending real part,
            then imaginary part), with ``.modes`` naming each (:func:`mode_names`).

        Raises
        ------
        InputError
            If the speed is missing or not the fitted one.
        """
        v = _resolve_speed(self, speed)
        lam = sort_eigenvalues(np.linalg.eigvals(self._matrices_at(v)[0]))
        return Eigenvalues(lam, mode_names(lam, self._speed_matrices(), v))

    def eigenvalues_vs_speed(self, speeds: Any) -> EigenSweep:
        """Refused: a fixed-speed model says nothing about other speeds.

        Parameters
        ----------
        speeds : (K,) array_like
            Forward speeds [m/s] (not used).

        Returns
        -------
        EigenSweep
            Never: the call raises.

        Raises
        ------
        InputError
            Always, naming the models defined over speed.
        """
        raise InputError(_fixed_speed_refusal(self, "eigenvalues_vs_speed"))

    def critical_speeds(self, vmax: float = 30.0) -> dict:
        """Refused: weave and capsize speeds belong to a model over speed.

        Parameters
        ----------
        vmax : float, optional
            Upper end of the speed range [m/s] (not used).

        Returns
        -------
        dict
            Never: the call raises.

        Raises
        ------
        InputError
            Always, naming the models defined over speed.
        """
        raise InputError(_fixed_speed_refusal(self, "critical_speeds"))


def _fixed_speed_refusal(model: Any, what: str) -> str:
    """Why a fixed-speed model has no ``what`` and which models do."""
    return (
        f"{what}: this {type(model).__name__} was fitted at one speed "
        f"({float(model.speed):g} m/s) and says nothing about other speeds; {what} belongs "
        "to a model over speed (pem.fit_speed_model, greybox, direct; bikeid identify "
        "--speed-parameterized)"
    )


class SpeedDependentModel(LinearModel):
    """Base of a linear model defined over speed: adds the eigenvalue sweep and critical speeds.

    Attributes
    ----------
    INPUTS : tuple of str
        Class attribute: default inputs of :meth:`state_space`.
    """

    def _speed_matrices(self) -> CanonicalMatrices:
        raise NotImplementedError

    def eigenvalues_vs_speed(self, speeds: Any) -> EigenSweep:
        """Eigenvalues over a speed grid, tracked along branches and labelled by mode.

        Parameters
        ----------
        speeds : (K,) array_like
            Forward speeds [m/s].

        Returns
        -------
        EigenSweep
            :func:`bikeid.sim.linear.eigenvalues_vs_speed` of the model (eigenvalues
            [1/s]; labels weave, capsize, caster).
        """
        return eigenvalues_vs_speed(self._speed_matrices(), speeds)

    def critical_speeds(self, vmax: float = 30.0) -> dict:
        """Weave and capsize speeds (and the others) of the model.

        Parameters
        ----------
        vmax : float, optional
            Upper end [m/s] of the speed range searched.

        Returns
        -------
        dict
            :func:`bikeid.sim.linear.critical_speeds` of the model (``v_d``, ``v_w``,
            ``v_c`` [m/s] or None, ``weave_frequency`` [rad/s], ``all``).
        """
        return critical_speeds(self._speed_matrices(), vmax)
