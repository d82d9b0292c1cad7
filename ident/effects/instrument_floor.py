"""The noise floor of the instruments: the cost a right model leaves on the logs.

``unexplained`` should mean that the model leaves structure which the instruments cannot
explain.  The second-difference floor (:func:`bikeid.ident.effects.fit.noise_floor`) counts
only white sensor noise, so coloured sensor noise, quantization, drift and the treadmill's
speed wander, which every log carries, read as structure.  :func:`instrument_floor` measures
the nuisances on the windows themselves and asks what cost they alone give the model:

- **sensor noise** (coloured, quantization included) and **drift**, from the log's quietest
  stretch (:func:`quiet_noise`: the second of upright running with the least roll-rate
  motion, between or before the pushes, where the signal is small and the nuisances are
  what is left): per channel an AR(1) noise (variance and lag-one coefficient of the
  detrended stretch) and the roll-rate gyro's offset and drift rate (the stretch's mean and
  slope: the rider-less bicycle's mean roll rate is zero).  ``decays_from_logs`` attaches
  it to each window (``meta["instrument_noise"]``); a window without it falls back to the
  AR(1) fit of its own spaced second differences
  (:func:`bikeid.ident.effects.fit.coloured_noise`), which confounds strongly coloured
  noise with the decay's smooth signal and over-estimates it (measured 3x at a = 0.8 on
  2 s decays);
- **speed wander**: the model is scored at the window's mean sensor speed; the cost of a
  speed error of one standard deviation of the window's own sensor speed is added.

The model's error on a window is linear in its measured signals and its logged command
(the k-step predictor, the replay and the loop simulation alike, for the linear laws), so
the error of the right model on signal + noise is its error on the noise alone: draws of the
fitted noise, scored by the same error as the fit (:meth:`ExperimentModel.simulate`, each
window's ``drive``), normalized by the real windows' ||y - mean y||, give the floor.  The
sign and constant laws and the sensor offsets, not linear in the signals, are left out of
this part.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from bikeid.dataset.windows import Window
from bikeid.ident.effects.fit import _norms, coloured_noise, output_residuals

__all__ = ["INSTRUMENT_DRAWS", "QUIET_SECONDS", "instrument_floor", "quiet_noise", "with_noise"]

#: Length [s] of the quiet stretch :func:`quiet_noise` looks for.
QUIET_SECONDS = 1.0

CHANNELS = ("phi", "delta", "phidot", "deltadot")

#: Noise draws averaged for the floor (the floor's relative spread over draws was under 5 %
#: with 16 windows on the closure benchmark's logs).
INSTRUMENT_DRAWS = 4

_OFFSETS = ("roll_rate_bias", "roll_angle_bias", "steer_angle_bias")


def quiet_noise(signals: dict, dt: float, seconds: float = QUIET_SECONDS) -> dict | None:
    """The instruments' nuisances measured on a log's quietest stretch.

    Parameters
    ----------
    signals : dict of str to ndarray
        The log's ``phi``, ``delta`` [rad], ``phidot``, ``deltadot`` [rad/s], equal lengths.
    dt : float
        Sample period [s].
    seconds : float, optional
        Length of the stretch [s].

    Returns
    -------
    dict or None
        Per channel ``[s2, a]`` (AR(1) variance [unit^2] and lag-one coefficient in
        [0, 0.98] of the linearly detrended stretch), ``gyro_offset`` [rad/s] and
        ``gyro_drift`` [rad/s^2] (mean and slope of the stretch's roll rate), ``start``
        (its first sample); None for a log shorter than two stretches.
    """
    n = int(round(seconds / dt))
    y = np.asarray(signals["phidot"], float)
    if n < 10 or y.size < 2 * n:
        return None
    t = np.arange(n) * dt
    X = np.column_stack([np.ones(n), t - t.mean()])
    P = X @ np.linalg.pinv(X)

    def rough(a):  # roll-rate motion left after the offset and drift
        r = y[a : a + n] - P @ y[a : a + n]
        return float(r @ r)

    start = min(range(0, y.size - n + 1, max(n // 4, 1)), key=rough)
    out: dict = {"start": int(start)}
    for c in CHANNELS:
        seg = np.asarray(signals[c], float)[start : start + n]
        r = seg - P @ seg
        s2 = float(r @ r) / (n - 2)
        a = float(r[1:] @ r[:-1] / max(r @ r, 1e-300))
        out[c] = [s2, float(np.clip(a, 0.0, 0.98))]
    coef = np.linalg.pinv(X) @ y[start : start + n]
    out["gyro_offset"], out["gyro_drift"] = float(coef[0]), float(coef[1])
    return out


def with_noise(windows: list[Window], runs) -> list[Window]:
    """The windows with their log's quiet-stretch nuisances (``meta["instrument_noise"]``).

    Parameters
    ----------
    windows : list of Window
        Decays; each window's ``file`` names its run.
    runs : sequence of bikeid.dataset.run.Run
        The logs (``meta["file"]``, ``dt`` and the four signals).

    Returns
    -------
    list of Window
        New windows (a window whose log has no quiet stretch is returned as it is).
    """
    by_file = {}
    for r in runs:
        f = str(r.meta.get("file", "run"))
        by_file[f] = quiet_noise({c: r[c] for c in CHANNELS}, r.dt)
    return [replace(w, meta={**w.meta, "instrument_noise": by_file[w.file]})
            if by_file.get(w.file) else w for w in windows]  # fmt: skip


def _ar1(rng, n: int, s2: float, a: float) -> np.ndarray:
    e = rng.normal(0.0, np.sqrt(s2 * (1 - a * a)), n)
    x = np.empty(n)
    x[0] = rng.normal(0.0, np.sqrt(s2))
    for k in range(1, n):
        x[k] = a * x[k - 1] + e[k]
    return x


def _linear_part(model):
    """The model without its sign and constant laws and its sensor offsets."""
    keep = {n: v for n, v in model.effects.items() if n not in _OFFSETS}
    for e, _value in model.law_effects():
        if e.law.kind in ("constant", "sign"):
            keep.pop(e.name, None)
    return replace(model, effects=keep)


def instrument_floor(model, windows: list[Window], draws: int = INSTRUMENT_DRAWS,
                     seed: int = 0) -> dict:  # fmt: skip
    """Expected cost of ``model`` on ``windows`` from the instruments alone.

    Parameters
    ----------
    model : ExperimentModel
        The model whose cost is compared with the floor (its own error, each window's
        drive: loop, kstep or logged).
    windows : list of Window
        The decays.
    draws : int, optional
        Noise draws averaged.
    seed : int, optional
        Seed of the draws (the floor is a fixed function of the data and the seed).

    Returns
    -------
    dict
        ``floor`` (dimensionless, comparable with the sum of squares of
        :func:`bikeid.ident.effects.fit.output_residuals`), its parts ``sensor_noise`` and
        ``speed_wander``, and ``draws``.
    """
    rng = np.random.default_rng(seed)
    norms = _norms(windows)
    lin = _linear_part(model)
    fits, gyro = [], []
    for w in windows:
        q = w.meta.get("instrument_noise")
        fits.append([tuple(q[c]) if q else coloured_noise(np.asarray(getattr(w, c), float))
                     for c in CHANNELS])  # fmt: skip
        gyro.append((q["gyro_offset"], q["gyro_drift"]) if q else (0.0, 0.0))
    noise = 0.0
    for _ in range(draws):
        fake = []
        for w, f, (b0, b1) in zip(windows, fits, gyro, strict=True):
            sig = {c: _ar1(rng, w.n, s2, a) for c, (s2, a) in zip(CHANNELS, f, strict=True)}
            t = np.arange(w.n) * model.dt  # the gyro: an offset and a drift of the measured size
            sig["phidot"] += rng.normal(0.0, abs(b0)) + rng.normal(0.0, abs(b1)) * t
            z = np.zeros(w.n)
            fake.append(replace(w, **sig, T_ext=z, T_phi=None, hist=np.zeros_like(w.hist),
                                T_logged=z.copy(), correction=None))  # fmt: skip
        r = output_residuals(lin, fake, norms)
        noise += float(r @ r) / draws
    base = output_residuals(model, windows, norms)
    moved = [replace(w, v_sensor=np.asarray(w.v_sensor) + np.std(w.v_sensor)) for w in windows]
    wander = output_residuals(model, moved, norms) - base
    return {"floor": noise + float(wander @ wander), "sensor_noise": noise,
            "speed_wander": float(wander @ wander), "draws": draws}  # fmt: skip
