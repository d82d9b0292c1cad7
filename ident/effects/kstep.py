"""The k-step prediction error: an error the logs determine without the controller law.

Replaying a logged steer torque open loop (``drive == "logged"``) through a bicycle that is
unstable without its controller gives an error that grows like exp(weave rate x window
length) for any model, true or not, and whatever slows that growth looks like an effect.
Here the model predicts each output from its own steady-state Kalman filter, k samples
ahead (``drive == "kstep"``):

    xhat[t+1] = Ad xhat[t] + Bd u[t] + K (y[t] - C xhat[t] - d),
    yhat[t]   = C Ad^(t-s) xhat[s] + (the known inputs over s..t-1) + d,  s = max(t - k + 1, 0),

with (Ad, Bd) the model's own zero-order-hold sampling (:meth:`ExperimentModel.discrete`:
its effects, delay, gain, lag, tyre relaxation), u the logged command through the input
path (delay, gain) and the constant laws, the sign laws evaluated on the propagated state,
and K the steady-state Kalman gain of the Riccati equation (:func:`bikeid.ident.predictor.
kalman_gain`, the same DARE as the prediction-error methods) with the process noise a
torque on each equation (:data:`PROCESS_TORQUE_STD`) and the measurement noise of each
channel estimated from the windows (second differences, :func:`measurement_variances`).
The recursion is :func:`bikeid.ident.predictor.kstep_kernel`.  The first k samples of a
window are its simulation from the measured start state (as the replay), and every later
sample is predicted k steps from the filter's estimate, so the error stays at the noise
level for the true model even where the bicycle is unstable.

The horizon k is one weave period of the stated bicycle at the window's speed, at most the
time its fastest unstable mode takes to grow e-fold (:func:`horizon`), fixed per window when
the windows are made (``meta["kstep_horizon"]``) so that every candidate model is scored on
the same horizon.  The nonlinear plant's defect
correction of a k-step window is taken over segments of k samples, each replayed from its
own measured start (:func:`bikeid.ident.effects.experiment_model.nonlinear_correction`), so
no segment runs long enough for the open-loop bicycle to fall.

:func:`kstep_error` is the public entry: a candidate model's normalized k-step residuals and
cost on a set of decay windows (the error the selection and the discovery of missing terms
score by).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from bikeid.dataset.windows import Window
from bikeid.ident.predictor import kalman_gain, kstep_kernel

__all__ = [
    "KSTEP",
    "GROWTH_CAP",
    "PROCESS_TORQUE_STD",
    "KStepError",
    "horizon",
    "kstep_error",
    "kstep_outputs",
    "measurement_variances",
    "with_horizon",
]

#: The drive of a window scored by the k-step error (:attr:`Window.drive`).
KSTEP = "kstep"

#: Standard deviation [N m] of the white torque on each equation (roll, steer) that the
#: Kalman filter assumes: the unmodelled torques of a rider-less bicycle on a treadmill
#: (belt, cables, the model's own errors) are a fraction of the decays' steer torques
#: (1-4 N m in the steer-by-wire logs); a larger value makes the filter follow the data
#: more closely (k-step error nearer the measurement noise for every model).
PROCESS_TORQUE_STD = 1.0

#: Largest growth of the plant's fastest unstable mode over the horizon: where the weave
#: period is longer than ln(GROWTH_CAP) / (its largest growth rate), the horizon is cut to
#: that time (at 1.5 m/s the steer-by-wire bicycle's weave period is 5.1 s at a growth rate
#: of 3.0 1/s: an estimation error would grow 4e6-fold over one period; cut to one e-fold,
#: 0.33 s, the true model's k-step cost on 3 s decays with the synthetic decays' noise was
#: 1.0-2.1 times the second-difference floor, against 5-15 times at a tenfold growth).
GROWTH_CAP = math.e

#: Horizon [s] used when the bicycle has no oscillatory (weave) root at a speed.
FALLBACK_HORIZON = 1.0


def horizon(model, v_sensor: float) -> int:
    """One weave period of ``model``'s uncontrolled bicycle at a sensor speed, in samples.

    Parameters
    ----------
    model : ExperimentModel
        The model (its bicycle, effects and sample period).
    v_sensor : float
        Sensor speed [m/s].

    Returns
    -------
    int
        round(T / dt) >= 2 with T = 2 pi / Im(lambda_weave), lambda_weave the oscillatory
        root of the open-loop plant with the largest real part (imaginary part below 0.8
        Nyquist), cut to ln(:data:`GROWTH_CAP`) / max Re(lambda) where the plant is unstable;
        :data:`FALLBACK_HORIZON` / dt without an oscillatory root.
    """
    A, _ = model.continuous(model.true_speed(v_sensor))
    lam = np.linalg.eigvals(A)
    osc = lam[(lam.imag > 1e-6) & (lam.imag < 0.8 * math.pi / model.dt)]
    if osc.size == 0:
        return max(2, int(round(FALLBACK_HORIZON / model.dt)))
    period = 2 * math.pi / osc[np.argmax(osc.real)].imag
    rate = float(np.max(lam.real))
    if rate > 0:  # no longer than a tenfold growth of the fastest unstable mode
        period = min(period, math.log(GROWTH_CAP) / rate)
    return max(2, int(round(period / model.dt)))


def with_horizon(windows: list[Window], model) -> list[Window]:
    """The windows scored by the k-step error, each with its horizon fixed at ``model``.

    Parameters
    ----------
    windows : list of Window
        Decays with their logged command (``T_logged``).
    model : ExperimentModel
        The stated nominal model (the horizon is one weave period of its bicycle).

    Returns
    -------
    list of Window
        New windows with ``drive == "kstep"``, ``meta["kstep_horizon"]`` [samples] and
        ``meta["kstep_gain"]``, the steady-state Kalman gain of ``model`` at the window's
        speed ((n, 4) for its n states).
    """
    out = []
    for w in windows:
        vs = float(np.mean(w.v_sensor))
        Ad, Bd = model.discrete(model.true_speed(vs))
        C = _output_matrix(model, Ad.shape[0])
        K = _gain(Ad, Bd, C, measurement_variances(w))
        out.append(replace(w, drive=KSTEP, meta={**w.meta, "kstep_horizon": horizon(model, vs),
                                                 "kstep_gain": K}))  # fmt: skip
    return out


def _output_matrix(model, npl: int) -> np.ndarray:
    C = np.zeros((4, npl))
    C[0, 0], C[1, 1], C[2, 2], C[3, 3] = 1.0, 1.0, model.e("roll_rate_scale"), 1.0
    return C


def measurement_variances(w: Window) -> np.ndarray:
    """Noise variance of each measured channel of a window, from second differences.

    sigma^2 = mean((y[k+1] - 2 y[k] + y[k-1])^2) / 6, exact for white noise on a locally
    linear signal; floored at 1e-12 of the channel's variance so that the Riccati equation
    stays regular on noise-free data.

    Parameters
    ----------
    w : Window
        The window.

    Returns
    -------
    (4,) ndarray
        [rad^2, rad^2, (rad/s)^2, (rad/s)^2] for phi, delta, phidot, deltadot.
    """
    out = []
    for y in (w.phi, w.delta, w.phidot, w.deltadot):
        y = np.asarray(y, float)
        s2 = float(np.mean(np.diff(y, 2) ** 2) / 6.0) if y.size > 2 else 0.0
        out.append(max(s2, 1e-12 * float(np.var(y)), 1e-16))
    return np.array(out)


def _inputs(model, w: Window, H: int, m: int, f: float):
    """Known inputs [u, w, T_phi] per sample: the logged command through the delay and
    gain, the constant laws (steer, roll) and the roll torque."""
    n = w.n
    if w.T_logged is None or np.size(w.T_logged) != n:
        raise ValueError(f"{w.file}@{w.start}: the k-step error needs the logged steer "
                         "command over the window (T_logged)")  # fmt: skip
    cmd = np.concatenate([w.command_history(H), np.asarray(w.T_logged, float)])
    k = np.arange(n)
    u = np.zeros((n, 3))
    u[:, 0] = model.e("command_gain") * ((1 - f) * cmd[H + k - m] + f * cmd[H + k - m - 1])
    if w.T_phi is not None:
        u[:, 2] = w.T_phi
    return u


def kstep_outputs(model, windows: list[Window], x0s: np.ndarray, eps: float,
                  k: int | None = None) -> list[dict]:  # fmt: skip
    """k-step predictions of each window's outputs (the ``simulate`` of a k-step window).

    Called by :meth:`ExperimentModel.simulate` for the windows with ``drive == "kstep"``.

    Parameters
    ----------
    model : ExperimentModel
        The candidate model.
    windows : list of Window
        Decays with ``T_logged``.
    x0s : (len(windows), 4) ndarray
        Measured start states [rad, rad, rad/s, rad/s]
        (:func:`bikeid.ident.effects.experiment_model.initial_states`).
    eps : float
        Smoothing of the sign laws [rad/s] (tanh(rate / eps)).
    k : int, optional
        Horizon [samples] for every window (default: each window's
        ``meta["kstep_horizon"]``, else :func:`horizon` at the window's speed).

    Returns
    -------
    list of dict of str to ndarray
        ``phi``, ``delta`` [rad], ``phidot``, ``deltadot`` [rad/s] predicted (sensor biases
        and scale applied, the window's defect correction added) and ``T`` [N m], the
        applied command, per window.

    Raises
    ------
    ValueError
        If a window has no logged command or ``k`` < 1.
    """
    if k is not None and k < 1:
        raise ValueError(f"k-step horizon must be >= 1 sample, got {k}")
    cms = model.canonical()
    m_, f = model._delay()
    H = max(m_ + 2, 2)
    s, brr = model.e("roll_rate_scale"), model.e("roll_rate_bias")
    bphi, bdel = model.e("roll_angle_bias"), model.e("steer_angle_bias")
    d = np.array([bphi, bdel, brr, 0.0])
    gains: dict = {}
    out = []
    for w, x0m in zip(windows, x0s, strict=True):
        vs = float(np.mean(w.v_sensor))
        v = model.true_speed(vs)
        Ad, Bd = model.discrete(v, None, cms)
        npl = Ad.shape[0]
        C = _output_matrix(model, npl)
        feq, fcode, fcoef = model.forcing_rows([v])
        u = _inputs(model, w, H, m_, f)
        for j in np.flatnonzero(fcode == 0):  # constants: known inputs
            u[:, 1 if feq[j] == 1 else 2] += fcoef[0, j]
        sg = np.flatnonzero(fcode != 0)  # signs of the roll (3) and steer (4) rates
        sidx = np.where(fcode[sg] == 3, 2, 3).astype(np.int64)
        scol = np.where(feq[sg] == 1, 1, 2).astype(np.int64)
        scoef = np.ascontiguousarray(fcoef[0, sg], dtype=float)
        y = np.column_stack([w.phi, w.delta, w.phidot, w.deltadot]).astype(float)
        if w.correction is not None:  # the linear-equivalent measurement
            for j, c in enumerate(("phi", "delta", "phidot", "deltadot")):
                y[:, j] -= w.correction[c]
        K = np.zeros((npl, 4))
        Kw = w.meta.get("kstep_gain")
        if Kw is not None:  # the stated nominal's filter, fixed with the window
            K[: min(npl, Kw.shape[0])] = Kw[:npl]
        if Kw is None or not np.max(np.abs(np.linalg.eigvals(Ad - K @ C))) < 1.0:
            key = (round(w.speed, 3), npl)  # the candidate's own filter, one per speed
            if key not in gains:
                gains[key] = _gain(Ad, Bd, C, measurement_variances(w))
            K = gains[key]
        x0 = np.zeros(npl)
        x0[0], x0[1] = x0m[0] - bphi, x0m[1] - bdel
        x0[2], x0[3] = (x0m[2] - brr) / s, x0m[3]
        if model.e("actuator_lag") > 0:
            x0[4] = u[0, 0]
        if model.e("tire_relaxation") > 0:
            x0[-1] = x0[1] - model.e("tire_relaxation") / v * x0[3]
        kw = int(k if k is not None else w.meta.get("kstep_horizon") or horizon(model, vs))
        Yh, _ = kstep_kernel(np.ascontiguousarray(Ad), np.ascontiguousarray(Bd), K, C, d,
                             u, y, x0, kw, sidx, scol, scoef, eps)  # fmt: skip
        o = {c: Yh[:, j].copy() for j, c in enumerate(("phi", "delta", "phidot", "deltadot"))}
        o["T"] = u[:, 0]
        if w.correction is not None:
            for c, dc in w.correction.items():
                o[c] = o[c] + dc
        out.append(o)
    return out


def _gain(Ad, Bd, C, r) -> np.ndarray:
    """Steady-state Kalman gain: torque noise on both equations, measured noise r."""
    return kalman_gain(Ad, Bd[:, 1:3], C, PROCESS_TORQUE_STD**2, r)


@dataclass
class KStepError:
    """A model's k-step prediction error on decay windows.

    Attributes
    ----------
    residuals : ndarray
        Stacked (prediction - measured) of roll rate and steer angle, each window and
        channel divided by its ||y - mean y|| (the residuals of the effect fits;
        dimensionless).
    per_window : (n_windows,) ndarray
        Each window's cost: the sum of its two channels' NRMSE^2.
    cost : float
        Sum of ``per_window``.
    horizons : list of int
        Each window's horizon k [samples].
    """

    residuals: np.ndarray
    per_window: np.ndarray
    cost: float
    horizons: list[int]


def kstep_error(model, windows: list[Window], k: int | None = None) -> KStepError:
    """The k-step prediction error of a candidate model on decay windows.

    Parameters
    ----------
    model : ExperimentModel
        The candidate model (its effects and bicycle).
    windows : list of Window
        Decays with their logged steer command (any drive: they are scored k steps ahead).
    k : int, optional
        Horizon [samples] for every window (default: one weave period, :func:`horizon`, or
        the window's own ``meta["kstep_horizon"]``).

    Returns
    -------
    KStepError
        The normalized residuals, per-window costs, total cost and horizons.
    """
    ws = [w if w.drive == KSTEP and k is None else
          replace(w, drive=KSTEP, meta={**w.meta, **({} if k is None else {"kstep_horizon": k})})
          for w in windows]  # fmt: skip
    parts = []
    for w, o in zip(ws, model.simulate(ws), strict=True):
        for c in ("phidot", "delta"):
            y = getattr(w, c)
            parts.append((o[c] - y) / max(np.linalg.norm(y - y.mean()), 1e-12))
    r = np.concatenate(parts)
    sizes = np.cumsum([0] + [2 * w.n for w in ws])
    per = np.array([float(r[a:b] @ r[a:b]) for a, b in zip(sizes[:-1], sizes[1:], strict=True)])
    ks = [int(w.meta.get("kstep_horizon") or horizon(model, float(np.mean(w.v_sensor))))
          for w in ws]  # fmt: skip
    return KStepError(r, per, float(per.sum()), ks)
