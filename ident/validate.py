"""Validation of identified models: compare, resid, goodness of fit, poles and zeros.

Semantics follow MATLAB's System Identification Toolbox (reference §2):
``compare`` simulates (horizon ``None`` = infinite) or k-step predicts each run and
reports the NRMSE fit 1 - ||y - yhat|| / ||y - mean(y)|| per output (a fraction;
MATLAB prints it x100) and the variance VAF beside it; ``ic="estimate"`` picks
the initial state that minimizes the error (MATLAB ``InitialCondition 'e'``).
``resid`` computes one-step residuals and their autocorrelation and the
residual-input cross-correlation at lags -25..25 with the 99 % band
2.576 / sqrt(N) (MATLAB ``resid`` defaults).  In closed loop, correlation at
negative lags (input lagging the residual) reflects feedback, not a model error;
judge positive lags, or use the dither as the input.

Models: a :class:`ident.pem.CanonicalModel` (its innovation gain K is used for
prediction), or any continuous python-control ``StateSpace`` whose outputs are
named after run signals and whose inputs are run signals (K = 0 then).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import control
import numpy as np
from scipy.linalg import expm

from bikeid.dataset.run import Run

from .direct import vaf_variance

__all__ = [
    "CompareResult",
    "ResidResult",
    "compare",
    "goodness_of_fit",
    "poles",
    "resid",
    "transfer_functions",
    "zeros",
]


def goodness_of_fit(y: np.ndarray, yhat: np.ndarray) -> dict[str, float]:
    """MSE, NRMSE fit (1 - ||y - yhat|| / ||y - mean y||), NMSE fit (squared ratio), VAF."""
    y, yhat = np.asarray(y, float), np.asarray(yhat, float)
    err = np.linalg.norm(y - yhat)
    den = np.linalg.norm(y - y.mean())
    return {
        "mse": float(np.mean((y - yhat) ** 2)),
        "nrmse_fit": float(1 - err / den) if den > 0 else float("nan"),
        "nmse_fit": float(1 - (err / den) ** 2) if den > 0 else float("nan"),
        "vaf": vaf_variance(y, yhat),
    }


def _sampled(model, dt: float):
    """(Ad, Bd, C, K, outputs, inputs) at dt."""
    if hasattr(model, "predictor") and hasattr(model, "outputs"):
        if abs(model.dt - dt) > 1e-12:
            raise ValueError(f"model identified at dt={model.dt} s, data at dt={dt} s")
        Ad, Bd, C, K = model.predictor()
        return Ad, Bd, C, K, tuple(model.outputs), ("T_delta",)
    if isinstance(model, control.StateSpace):
        if not control.isctime(model):
            raise ValueError("pass a continuous-time StateSpace (it is sampled at the data's dt)")
        A, B, C = (np.asarray(m, float) for m in (model.A, model.B, model.C))
        if np.any(np.asarray(model.D)):
            raise ValueError("models with direct feedthrough (D != 0) are not supported")
        n, m = B.shape
        Z = np.zeros((n + m, n + m))
        Z[:n, :n], Z[:n, n:] = A * dt, B * dt
        E = expm(Z)
        K = np.zeros((n, C.shape[0]))
        return E[:n, :n], E[:n, n:], C, K, tuple(model.output_labels), tuple(model.input_labels)
    raise ValueError("model must be an ident.pem.CanonicalModel or a control.StateSpace")


@dataclass(frozen=True)
class CompareResult:
    """``yhat[i]`` (N_i, n_outputs) per run; ``fit``/``vaf`` per output over all runs;
    ``x0[i]`` the initial state used; ``outputs`` names; ``horizon`` (None = simulation)."""

    yhat: tuple[np.ndarray, ...]
    fit: dict[str, float]
    vaf: dict[str, float]
    x0: tuple[np.ndarray, ...]
    outputs: tuple[str, ...]
    horizon: int | None


def _forced(Ad, Bd, C, U, F):
    """Response with x0 = 0 of x+ = F x + Bd u (+ K y terms folded in U)."""
    n = Ad.shape[0]
    x = np.zeros(n)
    out = np.empty((U.shape[0], C.shape[0]))
    for k in range(U.shape[0]):
        out[k] = C @ x
        x = F @ x + U[k]
    return out


def compare(
    runs: Run | Sequence[Run],
    model,
    horizon: int | None = None,
    ic: str | np.ndarray = "estimate",
) -> CompareResult:
    """Simulation (``horizon=None``) or ``horizon``-step prediction of each run.

    ``ic``: "estimate" (least squares on the run, per run), "zero", or a state vector.
    A simulation of an unstable model over a long run raises ValueError: use a
    finite horizon or a shorter window (``Run.window``), as Moore's 8 s windows.
    """
    runs = [runs] if isinstance(runs, Run) else list(runs)
    if horizon is not None and horizon < 1:
        raise ValueError(f"horizon={horizon}: need an integer >= 1 or None (simulation)")
    yh_all, x0_all, ys = [], [], []
    outputs = None
    for run in runs:
        Ad, Bd, C, K, outputs, inputs = _sampled(model, run.dt)
        n = Ad.shape[0]
        U = np.column_stack([run[i] for i in inputs])
        Y = np.column_stack([run[o] for o in outputs])
        N = run.n
        if horizon is None:
            growth = np.max(np.abs(np.linalg.eigvals(Ad))) ** N
            if growth > 1e12:
                raise ValueError(
                    f"the model is unstable and the run has {N} samples (growth {growth:.2g}): "
                    "use horizon=k (k-step prediction) or a shorter window (Run.window)"
                )
            F, drive = Ad, U @ Bd.T
        else:
            F, drive = Ad - K @ C, U @ Bd.T + Y @ K.T
        base = _forced(Ad, Bd, C, drive, F)
        Phi = np.empty((N, C.shape[0], n))  # response to each unit initial state
        Fk = np.eye(n)
        for k in range(N):
            Phi[k] = C @ Fk
            Fk = F @ Fk
        if isinstance(ic, str):
            if ic == "estimate":
                x0, *_ = np.linalg.lstsq(Phi.reshape(-1, n), (Y - base).ravel(), rcond=None)
            elif ic == "zero":
                x0 = np.zeros(n)
            else:
                raise ValueError(f"ic={ic!r}: use 'estimate', 'zero' or a state vector")
        else:
            x0 = np.asarray(ic, float).reshape(n)
        if horizon is None:
            yhat = base + (Phi.reshape(-1, n) @ x0).reshape(N, -1)
        else:
            # one-step predictor states, then horizon-1 open-loop steps
            xs = np.empty((N, n))
            x = x0.copy()
            for k in range(N):
                xs[k] = x
                x = F @ x + drive[k]
            Xp = xs.copy()
            Ub = U @ Bd.T
            for _ in range(horizon - 1):
                Xn = np.empty_like(Xp)
                Xn[1:] = Xp[:-1] @ Ad.T + Ub[:-1]
                Xn[0] = Xp[0]
                Xp = Xn
            yhat = Xp @ C.T
        yh_all.append(yhat)
        x0_all.append(x0)
        ys.append(Y)
    Yc, Yh = np.vstack(ys), np.vstack(yh_all)
    fit = {o: goodness_of_fit(Yc[:, j], Yh[:, j])["nrmse_fit"] for j, o in enumerate(outputs)}
    vaf = {o: vaf_variance(Yc[:, j], Yh[:, j]) for j, o in enumerate(outputs)}
    return CompareResult(tuple(yh_all), fit, vaf, tuple(x0_all), tuple(outputs), horizon)


@dataclass(frozen=True)
class ResidResult:
    """Residual analysis.  ``lags`` = -max_lag..max_lag; ``autocorr[o]`` (normalized,
    lags 0..max_lag); ``crosscorr[o]`` with the input over ``lags`` (positive lag tau:
    residual at k vs input at k - tau); ``band`` = 2.576 / sqrt(N);
    ``fraction_outside[o]`` over lags 1..max_lag of the autocorrelation;
    ``cross_outside[o]`` over lags 0..max_lag of the cross-correlation."""

    residuals: tuple[np.ndarray, ...]
    lags: np.ndarray
    autocorr: dict[str, np.ndarray]
    crosscorr: dict[str, np.ndarray]
    band: float
    fraction_outside: dict[str, float]
    cross_outside: dict[str, float]


def _xcorr(a: np.ndarray, b: np.ndarray, lag: int) -> float:
    """sum_k a[k] b[k - lag] / sqrt(sum a^2 sum b^2)."""
    if lag >= 0:
        s = np.dot(a[lag:], b[: len(b) - lag])
    else:
        s = np.dot(a[: len(a) + lag], b[-lag:])
    return float(s / np.sqrt(np.dot(a, a) * np.dot(b, b)))


def resid(
    runs: Run | Sequence[Run],
    model,
    input: str = "T_delta",
    max_lag: int = 25,
    confidence: float = 0.99,
) -> ResidResult:
    """One-step residuals and their whiteness / input-independence statistics.

    ``input`` names the signal for the cross-correlation: "T_delta" or, in closed
    loop, "dither" (the run's logged dither).
    """
    from scipy.stats import norm

    runs = [runs] if isinstance(runs, Run) else list(runs)
    pred = compare(runs, model, horizon=1)
    res, uin = [], []
    for run, yh in zip(runs, pred.yhat, strict=True):
        Y = np.column_stack([run[o] for o in pred.outputs])
        res.append(Y - yh)
        if input == "dither":
            if run.dither is None:
                raise ValueError("input='dither' needs runs with a logged dither")
            uin.append(run.dither)
        else:
            uin.append(run[input])
    E = np.vstack(res)
    u = np.concatenate(uin)
    u = u - u.mean()
    N = E.shape[0]
    band = float(norm.ppf(0.5 + confidence / 2) / np.sqrt(N))
    lags = np.arange(-max_lag, max_lag + 1)
    auto, cross, frac, xfrac = {}, {}, {}, {}
    for j, o in enumerate(pred.outputs):
        e = E[:, j] - E[:, j].mean()
        auto[o] = np.array([_xcorr(e, e, k) for k in range(max_lag + 1)])
        cross[o] = np.array([_xcorr(e, u, int(k)) for k in lags])
        frac[o] = float(np.mean(np.abs(auto[o][1:]) > band))
        xfrac[o] = float(np.mean(np.abs(cross[o][max_lag:]) > band))
    return ResidResult(tuple(res), lags, auto, cross, band, frac, xfrac)


def _ss(model) -> control.StateSpace:
    return model.state_space() if hasattr(model, "state_space") else model


def poles(model) -> np.ndarray:
    """Poles [1/s] of an identified model (``CanonicalModel`` or ``StateSpace``)."""
    return np.asarray(control.poles(_ss(model)))


def zeros(model, output: str = "phi", input: str = "T_delta") -> np.ndarray:
    """Transmission zeros [1/s] of one SISO channel."""
    return np.asarray(control.zeros(transfer_functions(model)[(output, input)]))


def transfer_functions(model) -> dict[tuple[str, str], control.TransferFunction]:
    """SISO transfer functions keyed by (output, input)."""
    sys = _ss(model)
    out = {}
    for i, o in enumerate(sys.output_labels):
        for j, u in enumerate(sys.input_labels):
            tf = control.ss2tf(sys[i, j])
            num, den = np.asarray(tf.num[0][0], float), np.asarray(tf.den[0][0], float)
            scale = np.abs(num).max() if num.size else 0.0
            lead = np.argmax(np.abs(num) > 1e-9 * scale) if scale > 0 else len(num) - 1
            out[(o, u)] = control.tf(num[lead:], den)  # drop round-off leading terms
    return out


# -- correlation tests of one residual sequence (resid's tests, also used by the effect
# diagnostics of the measured data) ---------------------------------------------------------
__all__ += ["cross_correlation", "whiteness"]


def _band(n: int, confidence: float) -> float:
    from scipy.stats import norm

    return float(norm.ppf(0.5 + confidence / 2) / np.sqrt(n))


def whiteness(e: np.ndarray, max_lag: int = 25, confidence: float = 0.99) -> dict:
    """Autocorrelation test of one residual sequence (the test of :func:`resid`).

    Parameters
    ----------
    e : (N,) array_like
        Residuals (any unit; the mean is removed).
    max_lag : int, optional
        Largest lag [samples].
    confidence : float, optional
        Level of the band (0.99: +-2.576 / sqrt(N)).

    Returns
    -------
    dict
        ``acf``: normalized autocorrelation at lags 1..max_lag; ``band``; and
        ``fraction_outside``: the fraction of ``acf`` outside +-band.
    """
    e = np.asarray(e, float) - np.mean(e)
    r = np.array([_xcorr(e, e, k) for k in range(1, max_lag + 1)])
    band = _band(e.size, confidence)
    return {"acf": r, "band": band, "fraction_outside": float(np.mean(np.abs(r) > band))}


def cross_correlation(
    e: np.ndarray, u: np.ndarray, max_lag: int = 25, confidence: float = 0.99
) -> dict:
    """Residual-input cross-correlation test (that of :func:`resid`).

    Parameters
    ----------
    e, u : (N,) array_like
        Residual and input (means removed).
    max_lag : int, optional
        Lags -max_lag..max_lag [samples]; lag tau pairs e[k] with u[k - tau].
    confidence : float, optional
        Level of the band (0.99: +-2.576 / sqrt(N)).

    Returns
    -------
    dict
        ``lags``; ``ccf``: normalized cross-correlation at ``lags``; ``band``;
        ``fraction_outside``: the fraction of ``ccf`` outside +-band (all lags).
    """
    e = np.asarray(e, float) - np.mean(e)
    u = np.asarray(u, float) - np.mean(u)
    lags = np.arange(-max_lag, max_lag + 1)
    r = np.array([_xcorr(e, u, int(k)) for k in lags])
    band = _band(e.size, confidence)
    return {"lags": lags, "ccf": r, "band": band,
            "fraction_outside": float(np.mean(np.abs(r) > band))}  # fmt: skip
