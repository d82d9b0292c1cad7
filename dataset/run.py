"""One experiment run: time series of the Moore & Hubbard Table 1 signals + metadata.

Simulated and measured data both become a :class:`Run`, so identification never
knows where the data came from.  Signal names, units and signs are those of
:mod:`sim.conventions`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bikeid.sim.conventions import INPUTS, MEASURED

__all__ = ["Run", "run_stop"]

REQUIRED = ("phi", "delta", "phidot", "deltadot", "v", "T_delta")


@dataclass
class Run:
    """A run sampled on a uniform time base.

    Every array is converted to ``float`` and checked on construction.  Units and
    signs are those of :mod:`sim.conventions` (:data:`~sim.conventions.UNITS`):
    angles rad, rates rad/s, v m/s, torques N m, force N, positive to the right.

    Attributes
    ----------
    t : (N,) ndarray
        Time [s], uniform, strictly increasing, N >= 2.  Uniformity is assumed,
        not checked (:attr:`dt` is the median spacing).
    signals : dict of str to (N,) ndarray
        Measured signals by name (see ``sim.conventions.MEASURED`` and ``INPUTS``);
        at least phi, delta, phidot, deltadot, v and T_delta.  Optional extras (pitch
        ``theta``, contact positions ``x``, ``y``, ...) are allowed.  For measured data
        these are what the sensors reported.
    truth : dict of str to (N,) ndarray or None
        The same signals without sensor effects (simulated runs only).
    dither : (N,) ndarray or None
        Steer-torque dither [N m] (part of T_delta), or None.
    reference : (N,) ndarray or None
        Roll-angle reference [rad], or None.
    meta : dict
        JSON-serializable metadata: bicycle parameters, controller and gains,
        effects, noise, seed, speed, source ("simulated" or "measured"),
        ``fell_at`` [s] if the bicycle fell, ``stop`` (why a simulated run ended
        early, see :func:`run_stop`), package version, ...

    Raises
    ------
    ValueError
        On construction, if ``t`` is not 1-D with at least 2 finite, strictly
        increasing samples, a required signal is missing, an array does not have
        shape (N,) or holds non-finite samples, or ``meta`` is not JSON-serializable.
    """

    t: np.ndarray
    signals: dict[str, np.ndarray]
    truth: dict[str, np.ndarray] | None = None
    dither: np.ndarray | None = None
    reference: np.ndarray | None = None
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.t = np.asarray(self.t, dtype=float)
        n = self.t.size
        if self.t.ndim != 1 or n < 2:
            raise ValueError(f"run time base must be 1-D with at least 2 samples, got {n}")
        if not np.all(np.isfinite(self.t)) or np.any(np.diff(self.t) <= 0):
            raise ValueError("run time base must be finite and strictly increasing")
        missing = [k for k in REQUIRED if k not in self.signals]
        if missing:
            raise ValueError(f"run is missing signals {missing}; required are {list(REQUIRED)}")
        self.signals = {k: self._check(k, v, n) for k, v in self.signals.items()}
        if self.truth is not None:
            self.truth = {k: self._check(f"truth/{k}", v, n) for k, v in self.truth.items()}
        for name in ("dither", "reference"):
            arr = getattr(self, name)
            if arr is not None:
                setattr(self, name, self._check(name, arr, n))
        try:
            json.dumps(self.meta)
        except TypeError as exc:
            raise ValueError(f"run metadata must be JSON-serializable: {exc}") from None

    @staticmethod
    def _check(name: str, arr, n: int) -> np.ndarray:
        arr = np.asarray(arr, dtype=float)
        if arr.shape != (n,):
            raise ValueError(f"signal {name!r} has shape {arr.shape}, expected ({n},)")
        bad = ~np.isfinite(arr)
        if bad.any():
            first = int(np.argmax(bad))
            raise ValueError(
                f"signal {name!r} has {int(bad.sum())} non-finite samples (first at index "
                f"{first}); clean or cut the data before building a Run"
            )
        return arr

    # -- convenience ---------------------------------------------------------------
    @property
    def n(self) -> int:
        """Number of samples N."""
        return self.t.size

    @property
    def dt(self) -> float:
        """Sample period [s] (median spacing)."""
        return float(np.median(np.diff(self.t)))

    @property
    def speed(self) -> float:
        """Nominal speed [m/s]: ``meta['speed']`` if set, else the mean of v."""
        return float(self.meta.get("speed", np.mean(self.signals["v"])))

    def __getitem__(self, name: str) -> np.ndarray:
        """A measured signal by name: ``run["phi"]``.

        Parameters
        ----------
        name : str
            Signal name (a key of :attr:`signals`, or an input of
            ``sim.conventions.INPUTS``).

        Returns
        -------
        (N,) ndarray
            The signal; T_phi and F default to zeros when not recorded.

        Raises
        ------
        KeyError
            If the run has no such signal and it is not an input.
        """
        if name in self.signals:
            return self.signals[name]
        if name in INPUTS:
            return np.zeros(self.n)
        raise KeyError(
            f"run has no signal {name!r}; it has {sorted(self.signals)} "
            f"(known names: {list(MEASURED) + list(INPUTS)})"
        )

    def true(self, name: str) -> np.ndarray:
        """A noise-free signal (simulated runs only).

        Parameters
        ----------
        name : str
            Signal name (a key of :attr:`truth`, or an input of
            ``sim.conventions.INPUTS``).

        Returns
        -------
        (N,) ndarray
            The true signal; an input not stored in :attr:`truth` is zeros.

        Raises
        ------
        ValueError
            If the run has no noise-free signals (measured data).
        KeyError
            If :attr:`truth` has no such signal and it is not an input.
        """
        if self.truth is None:
            raise ValueError("this run has no noise-free signals (measured data)")
        if name not in self.truth:
            if name in INPUTS:
                return np.zeros(self.n)
            raise KeyError(f"run has no true signal {name!r}; it has {sorted(self.truth)}")
        return self.truth[name]

    def window(self, t0: float, t1: float) -> Run:
        """The samples with t0 <= t < t1, as a new run (metadata copied).

        Parameters
        ----------
        t0, t1 : float
            Start (included) and end (excluded) of the window [s], on the run's own
            time base (not shifted to zero).

        Returns
        -------
        Run
            Signals, truth, dither and reference cut to the window; a shallow copy of
            ``meta``.

        Raises
        ------
        ValueError
            If the window holds fewer than 2 samples.
        """
        sel = (self.t >= t0) & (self.t < t1)
        if sel.sum() < 2:
            raise ValueError(f"window [{t0}, {t1}) s holds fewer than 2 samples")

        def cut(d):
            return None if d is None else {k: v[sel] for k, v in d.items()}

        return Run(
            t=self.t[sel],
            signals=cut(self.signals),
            truth=cut(self.truth),
            dither=None if self.dither is None else self.dither[sel],
            reference=None if self.reference is None else self.reference[sel],
            meta=dict(self.meta),
        )


def run_stop(run: Run) -> dict[str, Any] | None:
    """Why a run ended early, from its metadata, or None if it is complete.

    Parameters
    ----------
    run : Run
        Any run.  Simulated runs record ``meta["stop"]`` (``dataset.closed_loop``);
        runs written before that field existed record only ``meta["fell_at"]``, read
        here as a ``roll_limit`` stop.

    Returns
    -------
    dict or None
        ``{"cause", "time" [s], "message", "physical"}`` (``sim.integrate.STOP_CAUSES``),
        or None for a complete run (and for measured data).
    """
    stop = run.meta.get("stop")
    if stop:
        return dict(stop)
    fell = run.meta.get("fell_at")
    if fell is not None:
        return {
            "cause": "roll_limit",
            "time": float(fell),
            "message": f"fell at t={float(fell):.3f} s",
            "physical": True,
        }
    return None
