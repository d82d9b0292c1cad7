"""Dictionary terms injected into the independent linear plant of the blind trials.

A blind trial (:mod:`bikeid.experiments.measured.blind_trials`) may carry, besides its hidden
library effect, any term of the discovery's dictionary
(:func:`bikeid.ident.effects.discovery.dictionary`) with a coefficient, e.g.
``{"roll: phidot": -3.0}`` or ``{"steer: v*deltadot": -0.1}``.  The term is named and parsed
by the dictionary itself (:func:`~bikeid.ident.effects.discovery.term_by_name`) and evaluated
by the law language's reference evaluation (:meth:`bikeid.sim.effect_law.Law.force`), so the
generator and the discovery share one grammar and one meaning of a coefficient: the
generalized torque [N m] the term adds to its equation is ``coefficient * term``, positive
adding torque in bikeid's sign convention (roll, steer and torques positive to the right),
the discovery's ``coefficient``.

- 1/v is 1/max(v, :data:`bikeid.sim.effect_registry.V_FLOOR`), as the kernels evaluate it.
- ``sign(rate)`` is smoothed as tanh(rate / 0.01 rad/s), the smoothing of the library's
  Coulomb friction (the plant integrates it with RK4).
- ``T`` is the steer torque the actuator applies (after the hidden gain, lag and delay).
- An acceleration term (``phiddot``, ``deltaddot``) enters the mass matrix: the equations
  ``M qdd + v C1 qd + (g K0 + v^2 K2) q = tq + c * e_i * qdd_j`` are solved with
  ``M - c e_i e_j^T`` (:meth:`InjectedTerms.mass_matrix`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from bikeid.sim.effect_law import Law
from bikeid.sim.effect_registry import V_FLOOR

__all__ = ["SIGN_SMOOTHING", "InjectedTerms", "normalized_terms"]

#: tanh smoothing [rad/s] of a sign term (that of the library's Coulomb friction).
SIGN_SMOOTHING = 0.01
_ACC = {"phiddot": 0, "deltaddot": 1}


def normalized_terms(terms: Mapping[str, float] | None) -> dict[str, float]:
    """Injected terms keyed by their dictionary label, coefficients as floats.

    Parameters
    ----------
    terms : mapping of str to float, optional
        Coefficient [the term's SI unit] by term, written ``"equation: term"`` (``"roll:
        v*phidot"``) or as a law (:func:`bikeid.ident.effects.discovery.term_by_name`).

    Returns
    -------
    dict of str to float
        ``{label: coefficient}`` with the dictionary's labels (``"roll: phidot"``).

    Raises
    ------
    ValueError
        One line naming an unknown term, a term given twice or a coefficient that is not a
        finite number.
    """
    from bikeid.ident.effects.discovery import dictionary, term_by_name

    out: dict[str, float] = {}
    if not terms:
        return out
    known = dictionary()
    for text, c in terms.items():
        label = term_by_name(text, known).label
        try:
            x = float(c)
        except (TypeError, ValueError):
            x = math.nan
        if not math.isfinite(x):
            raise ValueError(f"injected term {text!r}: coefficient {c!r} must be a finite "
                             "number (SI, positive adds torque)")  # fmt: skip
        if label in out:
            raise ValueError(f"injected term {label!r} given twice; give each term once")
        out[label] = x
    return out


@dataclass(frozen=True)
class InjectedTerms:
    """Parsed injected terms: torque terms evaluated per state, acceleration terms in M.

    Attributes
    ----------
    laws : tuple of (Law, float)
        Each non-acceleration term as a law of sign +1 with its coefficient [SI].
    accelerations : tuple of (int, int, float)
        (equation index, acceleration index, coefficient [kg m^2]) of each acceleration
        term (0 roll, 1 steer).
    """

    laws: tuple[tuple[Law, float], ...] = ()
    accelerations: tuple[tuple[int, int, float], ...] = ()

    @classmethod
    def from_mapping(cls, terms: Mapping[str, float] | None) -> InjectedTerms:
        """Parse ``{"equation: term": coefficient}`` (:func:`normalized_terms`).

        Parameters
        ----------
        terms : mapping of str to float, optional
            The injected terms (none: an empty set).

        Returns
        -------
        InjectedTerms
        """
        from bikeid.ident.effects.discovery import term_by_name

        laws, acc = [], []
        for label, c in normalized_terms(terms).items():
            law = term_by_name(label).law
            if law.kind == "acceleration":
                acc.append((law.index, _ACC[law.signal], c))
            else:
                laws.append((Law(law.equation, law.signal, law.speed_power, +1), c))
        return cls(tuple(laws), tuple(acc))

    def __bool__(self) -> bool:
        return bool(self.laws or self.accelerations)

    def mass_matrix(self, M: np.ndarray) -> np.ndarray:
        """The mass matrix with the acceleration terms moved to the left-hand side.

        Parameters
        ----------
        M : (2, 2) ndarray
            The plant's mass matrix [kg m^2] (roll, steer).

        Returns
        -------
        (2, 2) ndarray
            ``M - sum c e_i e_j^T`` over the acceleration terms (a copy).

        Raises
        ------
        ValueError
            If the result is not positive definite (the term makes the plant unphysical).
        """
        out = np.array(M, dtype=float)
        for i, j, c in self.accelerations:
            out[i, j] -= c
        sym = 0.5 * (out + out.T)
        if np.any(np.linalg.eigvalsh(sym) <= 0.0) or np.linalg.det(out) <= 0.0:
            raise ValueError("injected acceleration terms leave the mass matrix not positive "
                             "definite; give a smaller coefficient")  # fmt: skip
        return out

    def torques(self, v: float, q: np.ndarray, qd: np.ndarray, T: float) -> np.ndarray:
        """The generalized torques [N m] of the non-acceleration terms (roll, steer).

        Parameters
        ----------
        v : float
            Forward speed [m/s].
        q, qd : (2,) ndarray
            Roll and steer angles [rad] and rates [rad/s].
        T : float
            Steer torque the actuator applies [N m].

        Returns
        -------
        (2,) ndarray
            ``sum coefficient * term`` per equation.
        """
        tq = np.zeros(2)
        if not self.laws:
            return tq
        sig = {"phi": q[0], "delta": q[1], "phidot": qd[0], "deltadot": qd[1], "T": T}
        for law, c in self.laws:
            tq[law.index] += law.force(c, v, sig, V_FLOOR, SIGN_SMOOTHING)
        return tq
