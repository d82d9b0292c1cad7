"""Sensor models: what an instrument reports given the true signal.

Each channel (a name from :data:`sim.conventions.MEASURED` or ``INPUTS``) has

    measured = Q( scale * LP(true) + bias + std * w ),     w ~ N(0, 1) white, per sample,

where ``LP`` is the optional anti-alias low-pass filter and ``Q`` rounds to the quantization
step (``Q(x) = step * round(x / step)``; no rounding when ``step == 0``).  Units are the
channel's (``sim.conventions.UNITS``): rad, rad/s, m/s, N m, N.  Signs are unchanged (a
negative ``scale`` would flip a sensor and is refused).

The anti-alias filter is a Butterworth low-pass of order 1 or 2 with cutoff ``cutoff`` [Hz],
discretized by the bilinear transform with pre-warping at the cutoff (so its gain is exactly
-3 dB at ``cutoff``) on the *fine* simulation grid and run there; the filtered signal is then
sampled at the sensor rate.  The filter starts in steady state at the first sample (no
start-up transient).  Its cutoff must lie below the Nyquist frequency ``rate / 2``.

Noise is deterministic: channel ``name`` of a run with seed ``seed`` draws from
``SeedSequence(seed, spawn_key=(crc32(name),))``, so a channel's noise does not depend on
which other channels exist, and sample k's noise does not depend on the run length.

Default figures (:meth:`Sensors.default`), stated rather than measured: white noise
1e-3 rad on angles (roll and steer potentiometers, yaw), 1e-2 rad/s on rates (rate gyros,
wheel generator), 1e-2 m/s on speed; no bias, unit scale, no quantization, no filter; input
channels (T_delta, T_phi, F) are logged exactly (the commanded value).  Moore & Hubbard
(2014) list their instruments (potentiometers, VectorNav VN-100 IMU, steer rate gyro, DC
generator, torque sensor, load cell) sampled at 200 Hz but give no noise figures; the
defaults are an order-of-magnitude choice, not a calibration.
"""

from __future__ import annotations

import math
import zlib
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from bikeid.sim.conventions import INPUTS, MEASURED
from bikeid.sim.effect_registry import effect

__all__ = ["AntiAlias", "Channel", "SensorChain", "Sensors", "channel_noise"]

#: Channels a sensor model knows, in the order used for vectors.
CHANNELS = MEASURED + INPUTS
ANGLES = ("phi", "delta", "psi")
RATES = ("phidot", "deltadot", "psidot", "thetaRdot")


def _finite(name: str, value: Any) -> float:
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"sensor {name} must be a number, got {value!r}") from None
    if not math.isfinite(value):
        raise ValueError(f"sensor {name} must be finite, got {value}")
    return value


@dataclass(frozen=True)
class Channel:
    """One channel's instrument model (all in the channel's units).

    std: white-noise standard deviation (>= 0); bias: constant offset; scale: gain (> 0,
    1 = exact); step: quantization step (>= 0, 0 = no quantization).

    measured = Q(scale * true + bias + std * w), w ~ N(0, 1) (module docstring).

    Parameters
    ----------
    std : float, optional
        White-noise standard deviation, >= 0 [channel unit, e.g. rad, rad/s, m/s, N m]
        (default 0).
    bias : float, optional
        Constant offset [channel unit] (default 0).
    scale : float, optional
        Gain, > 0 [-] (default 1, exact); a sign flip is refused.
    step : float, optional
        Quantization step, >= 0 [channel unit] (default 0, none).

    Raises
    ------
    ValueError
        If a field is not a finite number, ``std`` or ``step`` is negative, or ``scale``
        is not positive.
    """

    std: float = 0.0
    bias: float = 0.0
    scale: float = 1.0
    step: float = 0.0

    def __post_init__(self) -> None:
        for name in ("std", "bias", "scale", "step"):
            object.__setattr__(self, name, _finite(name, getattr(self, name)))
        if self.std < 0:
            raise ValueError(f"sensor noise std must be >= 0, got {self.std}")
        if self.step < 0:
            raise ValueError(f"sensor quantization step must be >= 0 (0 = none), got {self.step}")
        if self.scale <= 0:
            raise ValueError(
                f"sensor scale must be > 0, got {self.scale}; flip signs in the data instead"
            )

    @property
    def ideal(self) -> bool:
        """True if the channel reports the true value exactly (no noise, bias, gain, step)."""
        return self.std == 0 and self.bias == 0 and self.scale == 1 and self.step == 0

    def apply(self, x: np.ndarray, w: np.ndarray | float = 0.0) -> np.ndarray:
        """Measured value for true (filtered) value ``x`` and standard-normal draws ``w``.

        Parameters
        ----------
        x : ndarray or float
            True (anti-alias filtered) values [channel unit], any shape.
        w : ndarray or float, optional
            Standard-normal draws [-], broadcastable to ``x`` (default 0, no noise).

        Returns
        -------
        ndarray
            Q(scale * x + (w * std + bias)) [channel unit], the shape of ``x`` and ``w``
            broadcast.
        """
        # Same operation order as SensorChain, so both give bit-identical values.
        y = self.scale * np.asarray(x, dtype=float) + (np.asarray(w) * self.std + self.bias)
        if self.step > 0:
            y = self.step * np.round(y / self.step)
        return y


@dataclass(frozen=True)
class AntiAlias:
    """Butterworth low-pass of ``order`` 1 or 2 with -3 dB ``cutoff`` [Hz].

    Parameters
    ----------
    cutoff : float
        -3 dB frequency [Hz], positive and finite; must lie below the Nyquist frequency
        of the grid it runs on.
    order : {1, 2}, optional
        Filter order (default 2).

    Raises
    ------
    ValueError
        If ``cutoff`` is not a positive finite number or ``order`` is not 1 or 2.
    """

    cutoff: float
    order: int = 2

    def __post_init__(self) -> None:
        object.__setattr__(self, "cutoff", _finite("anti-alias cutoff", self.cutoff))
        if self.cutoff <= 0:
            raise ValueError(f"anti-alias cutoff must be > 0 Hz, got {self.cutoff}")
        if self.order not in (1, 2):
            raise ValueError(f"anti-alias order must be 1 or 2, got {self.order!r}")

    def sos(self, fs: float) -> np.ndarray:
        """Second-order sections for sample rate ``fs`` [Hz] (bilinear, pre-warped).

        Parameters
        ----------
        fs : float
            Sample rate of the grid the filter runs on [Hz].

        Returns
        -------
        (1, 6) ndarray
            ``scipy.signal`` second-order sections [b0, b1, b2, a0, a1, a2].

        Raises
        ------
        ValueError
            If ``cutoff`` is not below ``fs / 2``.
        """
        from scipy.signal import butter

        if self.cutoff >= fs / 2:
            raise ValueError(
                f"anti-alias cutoff {self.cutoff} Hz is not below the simulation grid's Nyquist "
                f"frequency {fs / 2} Hz; use a finer simulation step"
            )
        return butter(self.order, self.cutoff, btype="low", fs=fs, output="sos")

    def filter(self, x: np.ndarray, fs: float) -> np.ndarray:
        """Filter ``x`` sampled at ``fs`` [Hz], starting in steady state at ``x[0]``.

        Parameters
        ----------
        x : (n,) ndarray
            Uniformly sampled signal [any unit], n >= 1.
        fs : float
            Its sample rate [Hz].

        Returns
        -------
        (n,) ndarray
            The filtered signal [unit of ``x``].

        Raises
        ------
        ValueError
            If ``cutoff`` is not below ``fs / 2``.
        """
        from scipy.signal import sosfilt, sosfilt_zi

        sos = self.sos(fs)
        x = np.asarray(x, dtype=float)
        y, _ = sosfilt(sos, x, zi=sosfilt_zi(sos) * x[0])
        return y


def channel_noise(seed: int, name: str, n: int) -> np.ndarray:
    """``n`` standard-normal draws for channel ``name`` of a run seeded ``seed``.

    Drawn from ``SeedSequence(seed, spawn_key=(crc32(name),))``, so the draws of one
    channel do not depend on the other channels, and the first k draws not on ``n``.

    Parameters
    ----------
    seed : int
        Run seed, a non-negative integer.
    name : str
        Channel name (e.g. ``"phi"``, ``"T_delta"``).
    n : int
        Number of draws.

    Returns
    -------
    (n,) ndarray
        Standard-normal draws [-].

    Raises
    ------
    ValueError
        If ``seed`` is not a non-negative integer.
    """
    if int(seed) != seed or seed < 0:
        raise ValueError(f"sensor seed must be a non-negative integer, got {seed!r}")
    ss = np.random.SeedSequence(int(seed), spawn_key=(zlib.crc32(name.encode()),))
    return np.random.default_rng(ss).standard_normal(n)


@dataclass(frozen=True)
class Sensors:
    """The instruments of a run: per-channel models, sample rate [Hz], anti-alias filter.

    Channels not listed are ideal (reported exactly).

    Parameters
    ----------
    channels : mapping of str to Channel or dict, optional
        Instrument model per channel name (:data:`sim.conventions.MEASURED` or
        ``INPUTS`` names); a dict is converted with ``Channel(**d)``.
    rate : float, optional
        Sample rate [Hz], positive (default 100).
    antialias : AntiAlias or dict or None, optional
        Anti-alias filter applied to every channel before sampling, with cutoff below
        ``rate / 2``; None (default) for none.

    Raises
    ------
    ValueError
        If ``rate`` is not positive and finite, a channel name is empty, not a string or
        contains ``/``, a channel is not a Channel or dict, or the anti-alias cutoff is
        not below the sensor Nyquist frequency.
    """

    channels: Mapping[str, Channel] = field(default_factory=dict)
    rate: float = 100.0
    antialias: AntiAlias | None = None

    def __post_init__(self) -> None:
        rate = _finite("rate", self.rate)
        if rate <= 0:
            raise ValueError(f"sensor sample rate must be > 0 Hz, got {rate}")
        object.__setattr__(self, "rate", rate)
        chans = {}
        for name, ch in dict(self.channels).items():
            if not isinstance(name, str) or not name or "/" in name:
                raise ValueError(f"sensor channel name {name!r} is not a valid signal name")
            if isinstance(ch, Mapping):
                ch = Channel(**ch)
            if not isinstance(ch, Channel):
                raise ValueError(f"sensor channel {name!r} must be a Channel or a dict")
            chans[name] = ch
        object.__setattr__(self, "channels", chans)
        if self.antialias is not None:
            aa = self.antialias
            if isinstance(aa, Mapping):
                aa = AntiAlias(**aa)
                object.__setattr__(self, "antialias", aa)
            if aa.cutoff >= rate / 2:
                raise ValueError(
                    f"anti-alias cutoff {aa.cutoff} Hz must be below the sensor Nyquist "
                    f"frequency {rate / 2} Hz (rate {rate} Hz)"
                )

    # -- constructors ---------------------------------------------------------------
    @classmethod
    def ideal(cls, rate: float = 100.0) -> Sensors:
        """Exact instruments sampled at ``rate`` [Hz].

        Parameters
        ----------
        rate : float, optional
            Sample rate [Hz] (default 100).

        Returns
        -------
        Sensors
            No channel models (every channel ideal), no filter.
        """
        return cls({}, rate)

    @classmethod
    def default(cls, rate: float = 100.0, antialias: AntiAlias | None = None) -> Sensors:
        """The stated default noise levels (see the module docstring).

        Parameters
        ----------
        rate : float, optional
            Sample rate [Hz] (default 100).
        antialias : AntiAlias or None, optional
            Anti-alias filter (default none).

        Returns
        -------
        Sensors
            White noise of std 1e-3 rad on phi, delta, psi, 1e-2 rad/s on phidot,
            deltadot, psidot, thetaRdot and 1e-2 m/s on v; inputs exact.
        """
        chans = {name: Channel(std=1e-3) for name in ANGLES}
        chans.update({name: Channel(std=1e-2) for name in RATES})
        chans["v"] = Channel(std=1e-2)
        return cls(chans, rate, antialias)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> Sensors:
        """Inverse of :meth:`describe`.

        Parameters
        ----------
        d : mapping
            With optional keys ``rate`` [Hz], ``channels`` (name -> dict of ``std``,
            ``bias``, ``scale``, ``step``) and ``antialias`` (dict of ``cutoff`` [Hz],
            ``order``, or None).

        Returns
        -------
        Sensors
            The instruments described.

        Raises
        ------
        ValueError
            For an unknown top-level key or an invalid value (as the constructors).
        """
        unknown = set(d) - {"rate", "channels", "antialias"}
        if unknown:
            raise ValueError(f"unknown sensor settings {sorted(unknown)}")
        aa = d.get("antialias")
        return cls(
            {k: Channel(**v) for k, v in dict(d.get("channels", {})).items()},
            d.get("rate", 100.0),
            None if aa is None else AntiAlias(**aa),
        )

    def describe(self) -> dict[str, Any]:
        """JSON-serializable description (goes into run metadata).

        Returns
        -------
        dict
            ``rate`` [Hz], ``channels`` (name -> ``std``, ``bias``, ``scale``, ``step`` in
            the channel's units) and ``antialias`` (``cutoff`` [Hz], ``order``) or None.
        """
        return {
            "rate": self.rate,
            "channels": {
                k: {"std": c.std, "bias": c.bias, "scale": c.scale, "step": c.step}
                for k, c in self.channels.items()
            },
            "antialias": None
            if self.antialias is None
            else {"cutoff": self.antialias.cutoff, "order": self.antialias.order},
        }

    def with_effects(self, values: Mapping[str, float]) -> Sensors:
        """These instruments with the ``sensor``-layer effects of ``values`` applied.

        Each such registry entry (:mod:`bikeid.sim.effect_registry`) sets one field of one
        channel: its ``sensor_field`` (``bias`` or ``scale``) of channel ``sensor_channel``,
        e.g. ``roll_rate_bias`` b and ``roll_rate_scale`` s give phidot_m = s phidot + b.
        The channel's other fields (noise, quantization) are kept.

        Parameters
        ----------
        values : mapping of str to float
            Effect values by registry name, in the registry's units (bias: the channel's
            unit; scale: dimensionless).  Entries of other layers are skipped (the plant,
            the command or the parameters carry them); unknown names raise ValueError.

        Returns
        -------
        Sensors
            A new instrument set (this one is unchanged).
        """
        chans = dict(self.channels)
        for name, value in values.items():
            e = effect(name)
            if e.layer != "sensor":
                continue
            ch = chans.get(e.sensor_channel, _IDEAL)
            chans[e.sensor_channel] = replace(ch, **{e.sensor_field: float(value)})
        return Sensors(chans, self.rate, self.antialias)

    # -- use ------------------------------------------------------------------------
    @property
    def dt(self) -> float:
        """Sample period [s]."""
        return 1.0 / self.rate

    def channel(self, name: str) -> Channel:
        """The instrument model of channel ``name``.

        Parameters
        ----------
        name : str
            Channel name.

        Returns
        -------
        Channel
            Its model, or an ideal :class:`Channel` if none is listed.
        """
        return self.channels.get(name, _IDEAL)

    def decimation(self, fine_dt: float) -> int:
        """Fine-grid steps per sensor sample; ValueError unless an integer.

        Parameters
        ----------
        fine_dt : float
            Fine (simulation or controller) step [s].

        Returns
        -------
        int
            m = sensor period / ``fine_dt``, >= 1.

        Raises
        ------
        ValueError
            If the sensor period is not a whole multiple of ``fine_dt`` (to 1e-9
            relative).
        """
        m = self.dt / fine_dt
        k = round(m)
        if k < 1 or abs(m - k) > 1e-9 * max(1.0, m):
            raise ValueError(
                f"sensor period {self.dt} s is not a whole multiple of the simulation step "
                f"{fine_dt} s; choose a rate and step that divide"
            )
        return int(k)

    def measure(
        self, t: np.ndarray, truth: Mapping[str, np.ndarray], seed: int
    ) -> tuple[np.ndarray, dict[str, np.ndarray], dict[str, np.ndarray]]:
        """Sample the true signals ``truth`` given on the uniform fine grid ``t`` [s].

        Returns (t_s, measured, truth_s) at the sensor rate: the time base (every m-th fine
        sample, m = fine steps per sensor period, starting at t[0]), the measured signals
        (filtered, sampled, then corrupted) and the true signals sampled without filtering.

        Parameters
        ----------
        t : (N,) ndarray
            Uniform fine time grid [s], N >= 2.
        truth : mapping of str to (N,) ndarray
            True signals on ``t`` by channel name [SI units of the channel].
        seed : int
            Noise seed (:func:`channel_noise`).

        Returns
        -------
        t_s : (n,) ndarray
            Sensor instants [s], every m-th entry of ``t``.
        measured : dict of str to (n,) ndarray
            Measured signals [channel units].
        truth_s : dict of str to (n,) ndarray
            True signals at ``t_s``, unfiltered.

        Raises
        ------
        ValueError
            If ``t`` is not a uniform 1-D grid of at least 2 samples, the sensor period is
            not a whole multiple of its step, a signal's shape differs from ``t``'s, the
            anti-alias cutoff is not below the grid's Nyquist frequency, or ``seed`` is
            not a non-negative integer.
        """
        t = np.asarray(t, dtype=float)
        if t.ndim != 1 or t.size < 2:
            raise ValueError("sensor input time base must be 1-D with at least 2 samples")
        h = float(t[1] - t[0])
        if not np.allclose(np.diff(t), h, rtol=1e-9, atol=1e-12):
            raise ValueError("sensor input time base must be uniform")
        m = self.decimation(h)
        sel = slice(None, None, m)
        t_s = t[sel]
        measured, truth_s = {}, {}
        for name, x in truth.items():
            x = np.asarray(x, dtype=float)
            if x.shape != t.shape:
                raise ValueError(f"true signal {name!r} has shape {x.shape}, expected {t.shape}")
            truth_s[name] = x[sel].copy()
            ch = self.channel(name)
            xf = x if self.antialias is None else self.antialias.filter(x, 1.0 / h)
            w = channel_noise(seed, name, t_s.size) if ch.std > 0 else 0.0
            measured[name] = (
                x[sel].copy() if ch.ideal and self.antialias is None else ch.apply(xf[sel], w)
            )
        return t_s, measured, truth_s

    def chain(
        self, seed: int, n: int, names: tuple[str, ...] = MEASURED, fine_dt: float | None = None
    ) -> SensorChain:
        """A per-sample corrupter for use inside a control loop (see :class:`SensorChain`).

        Parameters
        ----------
        seed : int
            Noise seed (:func:`channel_noise`).
        n : int
            Number of sensor samples the chain can produce.
        names : tuple of str, optional
            Channel order of the vectors (default :data:`sim.conventions.MEASURED`).
        fine_dt : float, optional
            Step [s] at which :meth:`SensorChain.filter` is called; required with an
            anti-alias filter.

        Returns
        -------
        SensorChain
            The chain.

        Raises
        ------
        ValueError
            With an anti-alias filter: if ``fine_dt`` is missing, does not divide the
            sensor period, or puts the cutoff above its Nyquist frequency.
        """
        return SensorChain(self, seed, n, names, fine_dt)


_IDEAL = Channel()


class SensorChain:
    """Corrupts measurement vectors one sample at a time, inside a control loop.

    ``chain(k, y)`` returns the measured vector of sensor sample ``k`` (vector in
    ``names`` order, default ``MEASURED``) for the true vector ``y`` at that instant; the
    same (seed, k) always gives the same noise, equal to what :meth:`Sensors.measure` adds
    at sample k.  With an anti-alias filter, call :meth:`filter` with the true vector at
    every fine step (spacing ``fine_dt`` [s], e.g. the controller period) and pass its
    result to ``chain(k, ...)`` at the sensor instants; the filter is the same
    Butterworth as in :meth:`Sensors.measure`, run sample by sample (direct form II
    transposed), so it agrees with it to round-off, not bit for bit.

    Parameters
    ----------
    sensors : Sensors
        The instruments.
    seed : int
        Noise seed (:func:`channel_noise`), a non-negative integer.
    n : int
        Number of sensor samples k = 0..n-1 whose noise is drawn up front.
    names : tuple of str, optional
        Channel order of the vectors (default :data:`sim.conventions.MEASURED`).
    fine_dt : float, optional
        Fine step [s] of the :meth:`filter` calls; required with an anti-alias filter.

    Attributes
    ----------
    names : tuple of str
        Channel order.
    scale, bias, step : (m,) ndarray
        Per-channel gain [-], offset and quantization step [channel units].
    offset : (n, m) ndarray
        bias + std * w for every sensor sample [channel units].
    quantized : bool
        True if any channel quantizes.
    filtered : bool
        True if an anti-alias filter runs.

    Raises
    ------
    ValueError
        With an anti-alias filter: if ``fine_dt`` is missing, does not divide the sensor
        period, or puts the cutoff above its Nyquist frequency; or, when a channel is
        noisy, if ``seed`` is not a non-negative integer.
    """

    def __init__(
        self,
        sensors: Sensors,
        seed: int,
        n: int,
        names: tuple[str, ...] = MEASURED,
        fine_dt: float | None = None,
    ) -> None:
        self.names = tuple(names)
        chans = [sensors.channel(k) for k in self.names]
        self.scale = np.array([c.scale for c in chans])
        self.bias = np.array([c.bias for c in chans])
        self.step = np.array([c.step for c in chans])
        std = np.array([c.std for c in chans])
        w = np.zeros((n, len(self.names)))
        for j, name in enumerate(self.names):
            if std[j] > 0:
                w[:, j] = channel_noise(seed, name, n)
        self.offset = w * std + self.bias
        self.quantized = bool(np.any(self.step > 0))
        self.filtered = sensors.antialias is not None
        self._sos = None
        if self.filtered:
            if fine_dt is None:
                raise ValueError("an anti-alias filter in the loop needs the fine step fine_dt")
            sensors.decimation(fine_dt)  # the fine grid must divide the sensor period
            self._sos = sensors.antialias.sos(1.0 / fine_dt)
            self._z = None

    def filter(self, y_true: np.ndarray) -> np.ndarray:
        """Advance the anti-alias filter by one fine step; returns the filtered vector.

        The first call initializes the filter in steady state at its input.

        Parameters
        ----------
        y_true : (m,) ndarray
            True vector at this fine step, in ``names`` order [channel units].

        Returns
        -------
        (m,) ndarray
            Filtered vector (``y_true`` itself when there is no filter).
        """
        x = np.asarray(y_true, dtype=float)
        if not self.filtered:
            return x
        sos = self._sos
        if self._z is None:  # steady state at the first value (as sosfilt_zi)
            from scipy.signal import sosfilt_zi

            self._z = sosfilt_zi(sos)[:, :, None] * x[None, None, :]
        z = self._z
        for s in range(sos.shape[0]):
            b0, b1, b2, _, a1, a2 = sos[s]
            y = b0 * x + z[s, 0]
            z[s, 0] = b1 * x - a1 * y + z[s, 1]
            z[s, 1] = b2 * x - a2 * y
            x = y
        return x

    def __call__(self, k: int, y_true: np.ndarray) -> np.ndarray:
        y = self.scale * np.asarray(y_true, dtype=float) + self.offset[k]
        if self.quantized:
            q = self.step > 0
            y[q] = self.step[q] * np.round(y[q] / self.step[q])
        return y
