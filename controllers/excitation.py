"""Roll references, steer-torque dither and lateral-force pulses.

Everything here is a deterministic function of time (and of a seed, for the random
signals): ``signal(t)`` for one time [s] in pure Python (microseconds, for the
simulation loop) and ``signal.sample(t_array)`` vectorized, with identical values.

- References [rad]: :class:`ZeroReference`, :class:`StepReference` (piecewise
  constant), :class:`ChirpReference` (Chen & Dao 2010's "sinusoidal roll-angle with
  increasing frequency").  References also give their exact ``rate(t)`` [rad/s], so
  a controller can use the error derivative without differentiating steps.
- :class:`UniformDither` [N m]: uniform pseudo-random in [-a, a] held for ``hold``
  seconds (Chen & Dao: "uniformly distributed pseudo-random number signals with
  amplitude smaller than 1 Nm ... added to the input steering torque").
- :class:`LateralForcePulses` [N, positive to the right]: half-sine pushes at random
  times with random directions, like Moore & Hubbard's manual lateral perturbations.

Random streams use ``numpy.random.default_rng(seed)`` and are extended in fixed-size
blocks drawn in sequence, so the value at a given time never depends on the order in
which times are queried.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

__all__ = [
    "ChirpReference",
    "LateralForcePulses",
    "StepReference",
    "UniformDither",
    "ZeroReference",
]

_BLOCK = 4096


def _finite(name: str, value: float) -> float:
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"{name} must be finite, got {value}")
    return value


def _positive(name: str, value: float) -> float:
    value = _finite(name, value)
    if value <= 0:
        raise ValueError(f"{name} must be positive, got {value}")
    return value


def _seed(seed: int) -> int:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    return int(seed)


# -- references ----------------------------------------------------------------------------
class ZeroReference:
    """phi_ref = 0 (pure balancing).

    ``ZeroReference()(t)`` returns 0.0 rad for every time t [s].

    Attributes
    ----------
    None
        The reference has no parameters or state.
    """

    def __call__(self, t: float) -> float:
        return 0.0

    def rate(self, t: float) -> float:
        """Reference rate at ``t``: zero.

        Parameters
        ----------
        t : float
            Time [s].

        Returns
        -------
        float
            d phi_ref / dt [rad/s].
        """
        return 0.0

    def sample(self, t) -> np.ndarray:
        """The reference at the times ``t``: zeros.

        Parameters
        ----------
        t : array_like
            Times [s], any shape.

        Returns
        -------
        ndarray
            Values [rad], the shape of ``t``, equal to calling the object at each time.
        """
        return np.zeros_like(np.asarray(t, dtype=float))

    def describe(self) -> dict[str, Any]:
        """JSON-serializable description (goes into run metadata).

        Returns
        -------
        dict
            ``{"name": "zero"}``.
        """
        return {"name": "zero"}


class StepReference:
    """Piecewise-constant roll reference: ``values[k]`` [rad] from ``times[k]`` [s] on,
    zero before ``times[0]``.  ``rate`` is zero (the steps are not differentiated).

    Parameters
    ----------
    times : sequence of float
        Step times [s], finite, strictly increasing, at least one.
    values : sequence of float
        Roll reference [rad] (positive leaning right) from each step time on, one per
        time.

    Attributes
    ----------
    times : list of float
        Step times [s].
    values : list of float
        Step values [rad].

    Raises
    ------
    ValueError
        If a time or value is not finite, the lengths differ or are zero, or the times
        are not strictly increasing.
    """

    def __init__(self, times: Sequence[float], values: Sequence[float]):
        tt = [_finite("step time", x) for x in times]
        vv = [_finite("step value", x) for x in values]
        if not tt or len(tt) != len(vv):
            raise ValueError(f"need one value per step time, got {len(tt)} times, {len(vv)} values")
        if any(b <= a for a, b in zip(tt, tt[1:], strict=False)):
            raise ValueError("step times must be strictly increasing")
        self.times, self.values = tt, vv

    def __call__(self, t: float) -> float:
        k = bisect.bisect_right(self.times, t)
        return self.values[k - 1] if k else 0.0

    def rate(self, t: float) -> float:
        """Reference rate at ``t``: zero (the steps are not differentiated).

        Parameters
        ----------
        t : float
            Time [s].

        Returns
        -------
        float
            d phi_ref / dt [rad/s].
        """
        return 0.0

    def sample(self, t) -> np.ndarray:
        """The reference at the times ``t`` (0 before the first step).

        Parameters
        ----------
        t : array_like
            Times [s], any shape.

        Returns
        -------
        ndarray
            Values [rad], the shape of ``t``, equal to calling the object at each time.
        """
        t = np.asarray(t, dtype=float)
        k = np.searchsorted(np.asarray(self.times), t, side="right")
        vals = np.concatenate([[0.0], self.values])
        return vals[k]

    def describe(self) -> dict[str, Any]:
        """JSON-serializable description (goes into run metadata).

        Returns
        -------
        dict
            ``name`` ("step"), ``times`` [s] and ``values`` [rad].
        """
        return {"name": "step", "times": self.times, "values": self.values}


class ChirpReference:
    """Sinusoid of increasing frequency (Chen & Dao 2010, Fig. 7), zero outside
    [start, start + duration]:

        phi_ref(t) = A sin(2 pi (f0 tau + (f1 - f0) tau^2 / (2 D))),  tau = t - start,

    a linear sweep from ``f0`` to ``f1`` [Hz] over ``duration`` D [s] with amplitude
    ``amplitude`` A [rad].  It starts at sin(0) = 0, so there is no step at ``start``;
    it ends wherever the phase is (a jump of at most A at the end).

    Parameters
    ----------
    amplitude : float, optional
        A [rad] (default 5 deg = 0.0873 rad), finite.
    f0 : float, optional
        Start frequency [Hz] (default 0.05), >= 0.
    f1 : float, optional
        End frequency [Hz] (default 0.5), >= 0.
    duration : float, optional
        Sweep length D [s] (default 50), positive.
    start : float, optional
        Sweep start time [s] (default 0).

    Attributes
    ----------
    amplitude, f0, f1, duration, start : float
        As the parameters [rad, Hz, Hz, s, s].

    Raises
    ------
    ValueError
        If a parameter is not finite, a frequency is negative or ``duration`` is not
        positive.
    """

    def __init__(
        self,
        amplitude: float = math.radians(5.0),
        f0: float = 0.05,
        f1: float = 0.5,
        duration: float = 50.0,
        start: float = 0.0,
    ):
        self.amplitude = _finite("amplitude", amplitude)
        self.f0 = _finite("f0", f0)
        self.f1 = _finite("f1", f1)
        if self.f0 < 0 or self.f1 < 0:
            raise ValueError(f"chirp frequencies must be >= 0 Hz, got f0={f0}, f1={f1}")
        self.duration = _positive("duration", duration)
        self.start = _finite("start", start)
        self._k = (self.f1 - self.f0) / self.duration

    def __call__(self, t: float) -> float:
        tau = t - self.start
        if tau < 0 or tau > self.duration:
            return 0.0
        return self.amplitude * math.sin(2 * math.pi * (self.f0 * tau + 0.5 * self._k * tau * tau))

    def rate(self, t: float) -> float:
        """Exact reference rate at ``t`` (0 outside the sweep).

        Parameters
        ----------
        t : float
            Time [s].

        Returns
        -------
        float
            d phi_ref / dt [rad/s].
        """
        tau = t - self.start
        if tau < 0 or tau > self.duration:
            return 0.0
        ph = 2 * math.pi * (self.f0 * tau + 0.5 * self._k * tau * tau)
        return self.amplitude * 2 * math.pi * (self.f0 + self._k * tau) * math.cos(ph)

    def frequency(self, t: float) -> float:
        """Instantaneous frequency [Hz] at time t (inside the sweep).

        Parameters
        ----------
        t : float
            Time [s]; outside [start, start + duration] the linear law is extrapolated.

        Returns
        -------
        float
            f0 + (f1 - f0) (t - start) / D [Hz].
        """
        return self.f0 + self._k * (t - self.start)

    def sample(self, t) -> np.ndarray:
        """The reference at the times ``t`` (0 outside the sweep).

        Parameters
        ----------
        t : array_like
            Times [s], any shape.

        Returns
        -------
        ndarray
            Values [rad], the shape of ``t``, equal to calling the object at each time.
        """
        tau = np.asarray(t, dtype=float) - self.start
        inside = (tau >= 0) & (tau <= self.duration)
        ph = 2 * np.pi * (self.f0 * tau + 0.5 * self._k * tau * tau)
        return np.where(inside, self.amplitude * np.sin(ph), 0.0)

    def describe(self) -> dict[str, Any]:
        """JSON-serializable description (goes into run metadata).

        Returns
        -------
        dict
            ``name`` ("chirp"), ``amplitude`` [rad], ``f0``, ``f1`` [Hz], ``duration``
            and ``start`` [s].
        """
        return {
            "name": "chirp", "amplitude": self.amplitude, "f0": self.f0, "f1": self.f1,
            "duration": self.duration, "start": self.start,
        }  # fmt: skip


# -- dither --------------------------------------------------------------------------------
class UniformDither:
    """Zero-order-held uniform noise in [-amplitude, amplitude] [N m].

    Sample k (held on [k hold, (k+1) hold)) is the k-th draw of
    ``default_rng(seed).uniform(-a, a)``; negative times give 0.  Uniform on [-a, a]
    has mean 0 and variance a^2 / 3.  ``amplitude`` above ``max_amplitude`` (1 N m,
    Chen & Dao's bound) raises unless ``max_amplitude`` is raised explicitly.

    Parameters
    ----------
    amplitude : float, optional
        a [N m] (default 1.0), >= 0 and <= ``max_amplitude``.
    hold : float, optional
        Hold time of each value [s] (default 0.01, the default logging period), positive.
    seed : int, optional
        Seed of the stream, a non-negative integer (default 0).
    max_amplitude : float, optional
        Largest allowed ``amplitude`` [N m] (default 1.0).

    Attributes
    ----------
    amplitude : float
        a [N m].
    hold : float
        Hold time [s].
    seed : int
        Seed.

    Raises
    ------
    ValueError
        If ``amplitude`` is negative, not finite or above ``max_amplitude``, ``hold`` is
        not positive and finite, or ``seed`` is not a non-negative integer.
    """

    def __init__(
        self,
        amplitude: float = 1.0,
        hold: float = 0.01,
        seed: int = 0,
        max_amplitude: float = 1.0,
    ):
        self.amplitude = _finite("dither amplitude", amplitude)
        if self.amplitude < 0:
            raise ValueError(f"dither amplitude must be >= 0 N m, got {amplitude}")
        if self.amplitude > max_amplitude:
            raise ValueError(
                f"dither amplitude {amplitude} N m exceeds max_amplitude={max_amplitude} N m "
                "(Chen & Dao use < 1 N m); pass a larger max_amplitude to allow it"
            )
        self.hold = _positive("dither hold time", hold)
        self.seed = _seed(seed)
        self._rng = np.random.default_rng(self.seed)
        self._values: list[float] = []

    def _extend(self, n: int) -> None:
        while len(self._values) < n:
            a = self.amplitude
            self._values.extend(self._rng.uniform(-a, a, _BLOCK).tolist())

    def values(self, n: int) -> np.ndarray:
        """The first ``n`` held values.

        Parameters
        ----------
        n : int
            Number of values.

        Returns
        -------
        (n,) ndarray
            Values [N m]; value k is held on [k hold, (k+1) hold).
        """
        self._extend(n)
        return np.array(self._values[:n])

    def __call__(self, t: float) -> float:
        if t < 0:
            return 0.0
        # small tolerance so that t = k * hold computed in floating point lands in bin k
        k = int(t / self.hold + 1e-9)
        vals = self._values
        if k >= len(vals):
            self._extend(k + 1)
        return vals[k]

    def sample(self, t) -> np.ndarray:
        """The dither at the times ``t`` (0 at negative times).

        Parameters
        ----------
        t : array_like
            Times [s], any shape.

        Returns
        -------
        ndarray
            Values [N m], the shape of ``t``, equal to calling the object at each time.
        """
        t = np.asarray(t, dtype=float)
        k = np.floor(t / self.hold + 1e-9).astype(np.int64)
        n = int(k.max()) + 1 if k.size else 0
        vals = self.values(max(n, 1))
        return np.where(t < 0, 0.0, vals[np.clip(k, 0, None)])

    def describe(self) -> dict[str, Any]:
        """JSON-serializable description (goes into run metadata).

        Returns
        -------
        dict
            ``name`` ("uniform"), ``amplitude`` [N m], ``hold`` [s] and ``seed``.
        """
        return {"name": "uniform", "amplitude": self.amplitude, "hold": self.hold,
                "seed": self.seed}  # fmt: skip


# -- lateral force pulses ------------------------------------------------------------------
class LateralForcePulses:
    """Half-sine lateral pushes [N, positive to the right] at random times.

    Pulse j starts at ``times[j]``, lasts ``duration`` [s] and has the shape
    ``direction_j * peak * sin(pi (t - t_j) / duration)``, direction +-1 with equal
    probability.  Gaps between pulse *ends* and the next start are
    ``min_gap + Exponential(mean_gap - min_gap)`` [s]; the first pulse starts after
    ``first`` + one such gap.  Moore & Hubbard perturbed the bicycle by hand with
    lateral pushes at irregular intervals; peak and duration are the user's choice.

    Parameters
    ----------
    peak : float, optional
        Peak force [N] (default 50), >= 0.
    duration : float, optional
        Pulse length [s] (default 0.2), positive.
    mean_gap : float, optional
        Mean gap between a pulse's end and the next start [s] (default 3), > ``min_gap``.
    min_gap : float, optional
        Least gap [s] (default 1), >= 0.
    seed : int, optional
        Seed of the stream, a non-negative integer (default 0).
    first : float, optional
        Time [s] after which the first gap starts (default 0).

    Attributes
    ----------
    peak, duration, mean_gap, min_gap, first : float
        As the parameters [N, s, s, s, s].
    seed : int
        Seed.
    times : list of float
        Start times [s] of the pulses drawn so far (extended on demand).
    directions : list of float
        Their directions, +1 (right) or -1 (left).

    Raises
    ------
    ValueError
        If a parameter is not finite, ``peak`` is negative, ``duration`` is not
        positive, not 0 <= ``min_gap`` < ``mean_gap``, or ``seed`` is not a non-negative
        integer.
    """

    def __init__(
        self,
        peak: float = 50.0,
        duration: float = 0.2,
        mean_gap: float = 3.0,
        min_gap: float = 1.0,
        seed: int = 0,
        first: float = 0.0,
    ):
        self.peak = _finite("pulse peak", peak)
        if self.peak < 0:
            raise ValueError(f"pulse peak must be >= 0 N, got {peak}")
        self.duration = _positive("pulse duration", duration)
        self.min_gap = _finite("min_gap", min_gap)
        self.mean_gap = _finite("mean_gap", mean_gap)
        if self.min_gap < 0 or self.mean_gap <= self.min_gap:
            raise ValueError(
                f"need 0 <= min_gap < mean_gap, got min_gap={min_gap}, mean_gap={mean_gap}"
            )
        self.first = _finite("first", first)
        self.seed = _seed(seed)
        self._rng = np.random.default_rng(self.seed)
        self.times: list[float] = []
        self.directions: list[float] = []
        self._next_start = self.first

    def _extend_to(self, t: float) -> None:
        while not self.times or self.times[-1] <= t:
            gaps = self.min_gap + self._rng.exponential(self.mean_gap - self.min_gap, 64)
            signs = np.where(self._rng.random(64) < 0.5, -1.0, 1.0)
            for g, s in zip(gaps.tolist(), signs.tolist(), strict=True):
                start = self._next_start + g
                self.times.append(start)
                self.directions.append(s)
                self._next_start = start + self.duration

    def pulses_until(self, t_end: float) -> list[tuple[float, float]]:
        """(start time [s], direction) of every pulse that starts before ``t_end``.

        Parameters
        ----------
        t_end : float
            End time [s] (exclusive).

        Returns
        -------
        list of (float, float)
            (start time [s], direction +1 or -1) per pulse, in time order.
        """
        self._extend_to(t_end)
        k = bisect.bisect_left(self.times, t_end)
        return list(zip(self.times[:k], self.directions[:k], strict=True))

    def __call__(self, t: float) -> float:
        self._extend_to(t)
        k = bisect.bisect_right(self.times, t) - 1
        if k < 0:
            return 0.0
        tau = t - self.times[k]
        if tau >= self.duration:
            return 0.0
        return self.directions[k] * self.peak * math.sin(math.pi * tau / self.duration)

    def sample(self, t) -> np.ndarray:
        """The lateral force at the times ``t`` (positive to the right).

        Parameters
        ----------
        t : array_like
            Times [s], any shape.

        Returns
        -------
        ndarray
            Values [N], the shape of ``t``, equal to calling the object at each time.
        """
        t = np.asarray(t, dtype=float)
        if t.size == 0:
            return np.zeros_like(t)
        self._extend_to(float(t.max()))
        times = np.asarray(self.times)
        k = np.searchsorted(times, t, side="right") - 1
        kk = np.clip(k, 0, None)
        tau = t - times[kk]
        on = (k >= 0) & (tau < self.duration)
        return np.where(
            on, np.asarray(self.directions)[kk] * self.peak * np.sin(np.pi * tau / self.duration), 0
        )

    def describe(self) -> dict[str, Any]:
        """JSON-serializable description (goes into run metadata).

        Returns
        -------
        dict
            ``name`` ("half-sine pulses"), ``peak`` [N], ``duration``, ``mean_gap``,
            ``min_gap`` [s], ``seed`` and ``first`` [s].
        """
        return {
            "name": "half-sine pulses", "peak": self.peak, "duration": self.duration,
            "mean_gap": self.mean_gap, "min_gap": self.min_gap, "seed": self.seed,
            "first": self.first,
        }  # fmt: skip
