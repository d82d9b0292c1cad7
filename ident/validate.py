"""Validation of identified models: compare, resid, goodness of fit, poles and zeros.

Semantics follow MATLAB's System Identification Toolbox (reference §2):
``compare`` simulates (horizon ``None`` = infinite) or k-step predicts each run and
reports the NRMSE fit 100 (1 - ||y - yhat|| / ||y - mean(y)||) per output in percent (as
MATLAB prints it, and as ``bikeid validate`` and ``validation.json`` give it) and the
variance VAF beside it, also in percent; ``ic="estimate"`` picks
the initial state that minimizes the error (MATLAB ``InitialCondition 'e'``).
``resid`` computes one-step residuals and their autocorrelation and the
residual-input cross-correlation at lags -25..25 with the 99 % band
2.576 / sqrt(N) (MATLAB ``resid`` defaults).  In closed loop, correlation at
negative lags (input lagging the residual) reflects feedback, not a model error;
judge positive lags, or use the dither as the input.  Beside the band, ``resid`` gives
verdicts computed from the data: the chi-squared whiteness test N sum r(k)^2 ~ chi^2(M)
(:func:`portmanteau`) and the independence test N r' R_u^-1 r ~ chi^2(M) on lags 1..M
(:func:`independence_test`), both at level 1 - confidence (Ljung, sec. 16.6).

Models (:func:`sampled_model`): a :class:`ident.pem.CanonicalModel` (its innovation gain K
is used for prediction), a ``SpeedCanonicalModel`` or a ``DirectResult`` (taken at each
run's speed; K = 0 for the direct method's model), or any continuous python-control
``StateSpace`` whose outputs are named after run signals and whose inputs are run signals
(K = 0 then), sampled exactly (``sim.sampling.zoh``).  The computations behind ``compare``
take discrete matrices and arrays and are public: :func:`simulation` (open-loop simulation, initial
state by least squares) and :func:`k_step_prediction` (innovations predictor, then k
open-loop steps); the reproductions of Chen & Dao and Moore & Hubbard use them.
Moore & Hubbard's VAF measures live here too: eq. 6 (:func:`vaf_moore`, the variance form
:func:`vaf_variance`) and its windowed simulation form (:func:`windowed_simulation_vaf`,
used by the reproduction's Table 4 and the measured-data study); and the exact
(Clopper-Pearson) interval of a rate (:func:`binomial_interval`) that the coverage and
trial studies report.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numba
import numpy as np
from scipy.stats import binomtest

from bikeid.dataset.run import Run
from bikeid.ident.direct import DirectResult, vaf_moore, vaf_variance
from bikeid.ident.linear_model import LinearModel, SpeedDependentModel
from bikeid.sim.errors import InputError, UntrustworthyResult
from bikeid.sim.sampling import zoh

if TYPE_CHECKING:
    import control

__all__ = [
    "CompareResult",
    "ResidResult",
    "compare",
    "goodness_of_fit",
    "k_step_prediction",
    "poles",
    "resid",
    "sampled_model",
    "simulation",
    "transfer_functions",
    "zeros",
]


def goodness_of_fit(y: np.ndarray, yhat: np.ndarray) -> dict[str, float]:
    """MSE, NRMSE fit (1 - ||y - yhat|| / ||y - mean y||), NMSE fit (squared ratio), VAF.

    Parameters
    ----------
    y : array_like
        Measured signal (any unit, any shape; norms and means over all entries).
    yhat : array_like
        Simulated or predicted signal, same shape and unit as ``y``.

    Returns
    -------
    dict of str to float
        ``"mse"`` (unit of ``y`` squared); ``"nrmse"`` = ||y - yhat|| / ||y - mean y||
        (0 = perfect; the error of ``bikeid measured evaluate``,
        :func:`bikeid.ident.effects.experiment_model.window_errors`); ``"nrmse_fit"`` = 1 - nrmse
        (MATLAB ``compare``'s fit, as a fraction), ``"nmse_fit"`` = 1 - nrmse^2 and
        ``"vaf"`` = 1 - var(y - yhat) / var(y) (:func:`ident.direct.vaf_variance`), all
        dimensionless, NaN when ``y`` is constant.
    """
    y, yhat = np.asarray(y, float), np.asarray(yhat, float)
    err = np.linalg.norm(y - yhat)
    den = np.linalg.norm(y - y.mean())
    ratio = float(err / den) if den > 0 else float("nan")
    return {
        "mse": float(np.mean((y - yhat) ** 2)),
        "nrmse": ratio,
        "nrmse_fit": 1 - ratio,
        "nmse_fit": 1 - ratio**2,
        "vaf": vaf_variance(y, yhat),
    }


def sampled_model(model, dt: float, v: float | None = None):
    """The discrete innovations predictor of a model at the data's sample period.

    Parameters
    ----------
    model : CanonicalModel, SpeedCanonicalModel, DirectResult, GreyboxModel or control.StateSpace
        A ``CanonicalModel`` gives its own predictor (its ``dt`` must equal ``dt``); a
        ``SpeedCanonicalModel`` its fixed-speed model at ``v`` (:meth:`at`: K of the
        nearest fitted speed); a ``DirectResult`` its state space at ``v`` with inputs
        T_phi, T_delta and F (a run without T_phi or F has them zero), all four states
        measured and K = 0; a ``GreyboxModel`` its canonical model at ``v``
        (:meth:`~bikeid.ident.greybox.GreyboxModel.at`: the matrices' theta(v) with the
        innovation gain of the nearest fitted speed, input T_delta); a continuous
        ``StateSpace`` (D = 0) is sampled exactly (zero-order hold) with K = 0.
    dt : float
        Sample period of the data [s].
    v : float, optional
        Forward speed [m/s]; required for models defined over speed.

    Returns
    -------
    Ad, Bd, C, K : ndarray
        x[k+1] = Ad x[k] + Bd u[k] + K (y[k] - C x[k]) (state units of the model; outputs
        in rad and rad/s, inputs in N m).
    outputs, inputs : tuple of str
        Output and input signal names, in the order of the rows of C and columns of Bd.

    Raises
    ------
    ValueError
        If the model's sample period differs from ``dt``, a model over speed gets no
        ``v``, a state space is discrete or has D != 0, or the model is of another type.
    """
    if isinstance(model, DirectResult) or hasattr(model, "at"):  # defined over speed
        if v is None:
            raise ValueError(
                f"a {type(model).__name__} is defined over speed: pass the speed, v=... [m/s]"
            )
        if isinstance(model, DirectResult):  # all its inputs (zero when a run lacks them)
            model = model.state_space(v)
        else:
            model = model.at(v)
    if hasattr(model, "predictor") and hasattr(model, "outputs"):
        if abs(model.dt - dt) > 1e-12:
            raise ValueError(
                f"model identified at dt={model.dt} s, data at dt={dt} s: give data logged "
                "at the model's sample period (or identify again at the data's)"
            )
        Ad, Bd, C, K = model.predictor()
        return Ad, Bd, C, K, tuple(model.outputs), ("T_delta",)
    ctl = sys.modules.get("control")  # a StateSpace exists only once python-control is loaded
    if ctl is not None and isinstance(model, ctl.StateSpace):
        if not ctl.isctime(model):
            raise ValueError("pass a continuous-time StateSpace (it is sampled at the data's dt)")
        A, B, C = (np.asarray(m, float) for m in (model.A, model.B, model.C))
        if np.any(np.asarray(model.D)):
            raise ValueError("models with direct feedthrough (D != 0) are not supported")
        Ad, Bd = zoh(A, B, dt)
        K = np.zeros((A.shape[0], C.shape[0]))
        return Ad, Bd, C, K, tuple(model.output_labels), tuple(model.input_labels)
    raise ValueError(
        "model must be an ident.pem.CanonicalModel, SpeedCanonicalModel, "
        "ident.direct.DirectResult, ident.greybox.GreyboxModel or a control.StateSpace"
    )


@dataclass(frozen=True)
class CompareResult:
    """``yhat[i]`` (N_i, n_outputs) per run; ``fit``/``vaf`` per output over all runs;
    ``x0[i]`` the initial state used; ``outputs`` names; ``horizon`` (None = simulation).

    Attributes
    ----------
    yhat : tuple of (N_i, p) ndarray
        Simulated or predicted outputs per run, columns in ``outputs`` order (rad, rad/s).
    fit : dict of str to float
        NRMSE fit per output over all runs stacked [%] (100 = perfect; MATLAB's ``compare``).
    vaf : dict of str to float
        Variance accounted for per output over all runs stacked [%].
    x0 : tuple of (n,) ndarray
        Initial state used per run (the model's state order and units).
    outputs : tuple of str
        Output names.
    horizon : int or None
        Prediction horizon [samples]; None for simulation.
    """

    yhat: tuple[np.ndarray, ...]
    fit: dict[str, float]
    vaf: dict[str, float]
    x0: tuple[np.ndarray, ...]
    outputs: tuple[str, ...]
    horizon: int | None


def _as_columns(u: np.ndarray) -> np.ndarray:
    """Inputs as an (N, m) array (a 1-D signal is one column)."""
    u = np.asarray(u, dtype=float)
    return u.reshape(u.shape[0], -1)


def _f64(a) -> np.ndarray:
    """A C-contiguous float64 copy or view (the compiled loops' argument type)."""
    return np.ascontiguousarray(a, dtype=np.float64)


@numba.njit(cache=True)
def _forced_and_free(Ad, Bd, C, U):
    """Outputs of x[k+1] = Ad x[k] + Bd u[k] from x = 0 (N, p) and C Ad^k (N, p, n)."""
    N, n, ny = U.shape[0], Ad.shape[0], C.shape[0]
    xf = np.zeros(n)
    forced = np.empty((N, ny))
    Phi = np.empty((N, ny, n))  # response to each unit initial state
    Ak = np.eye(n)
    for k in range(N):
        forced[k] = C @ xf
        Phi[k] = C @ Ak
        xf = Ad @ xf + Bd @ U[k]
        Ak = Ad @ Ak
    return forced, Phi


@numba.njit(cache=True)
def _predictor_states(Ad, Bd, C, K, U, y, x0):
    """States xhat[j] (N, n) of xhat[j+1] = Ad xhat[j] + Bd u[j] + K (y[j] - C xhat[j])."""
    N = U.shape[0]
    xh = np.zeros((N, Ad.shape[0]))
    x = x0.copy()
    for j in range(N):
        xh[j] = x
        e = y[j] - C @ x
        x = Ad @ x + Bd @ U[j] + K @ e
    return xh


def simulation(
    Ad: np.ndarray,
    Bd: np.ndarray,
    C: np.ndarray,
    u: np.ndarray,
    y: np.ndarray | None = None,
    ic: str | np.ndarray = "estimate",
) -> tuple[np.ndarray, np.ndarray]:
    """Open-loop simulation of x[k+1] = Ad x[k] + Bd u[k], y[k] = C x[k].

    The output is affine in the initial state, yhat = forced + Phi x0, so ``ic="estimate"``
    fits x0 by linear least squares to all of ``y`` (MATLAB ``compare`` with
    ``InitialCondition 'e'``).

    Parameters
    ----------
    Ad : (n, n) ndarray
        Discrete state matrix [-] (one sample of the model's period).
    Bd : (n, m) ndarray
        Discrete input matrix [state units per input unit].
    C : (p, n) ndarray
        Output matrix [-] (selects/combines states; outputs in state units).
    u : (N,) or (N, m) ndarray
        Input samples (units of the model's inputs, e.g. N m for T_delta).
    y : (N, p) ndarray, optional
        Measured outputs (units of the outputs, e.g. rad, rad/s); needed for
        ``ic="estimate"``.
    ic : {"estimate", "zero"} or (n,) array_like
        Initial state: least squares on ``y``, zero, or the given state (state units).

    Returns
    -------
    yhat : (N, p) ndarray
        Simulated outputs (units of ``y``).
    x0 : (n,) ndarray
        The initial state used (state units).
    """
    U = _as_columns(u)
    n = Ad.shape[0]
    forced, Phi = _forced_and_free(_f64(Ad), _f64(Bd), _f64(C), _f64(U))
    if isinstance(ic, str):
        if ic == "estimate":
            if y is None:
                raise ValueError("ic='estimate' needs the measured outputs y")
            x0, *_ = np.linalg.lstsq(Phi.reshape(-1, n), (y - forced).ravel(), rcond=None)
        elif ic == "zero":
            x0 = np.zeros(n)
        else:
            raise ValueError(f"ic={ic!r}: use 'estimate', 'zero' or a state vector")
    else:
        x0 = np.asarray(ic, float).reshape(n)
    return forced + Phi @ x0, x0


def k_step_prediction(
    Ad: np.ndarray,
    Bd: np.ndarray,
    C: np.ndarray,
    K: np.ndarray,
    u: np.ndarray,
    y: np.ndarray,
    k: int,
    x0: np.ndarray | None = None,
    head: str = "one-step",
) -> np.ndarray:
    """Prediction k samples beyond the innovations predictor's one-step state estimate.

    The predictor xhat[j+1] = Ad xhat[j] + Bd u[j] + K (y[j] - C xhat[j]) (a stabilizing
    observer when Ad - K C is stable) gives xhat[j] from the data up to j - 1; the model
    then runs open loop on the measured input for k samples, so yhat[j] = C (state at j
    predicted from xhat[j - k]).  ``k = 0`` is the one-step prediction; MATLAB's
    ``compare(..., h)`` is ``k = h - 1`` with ``head="open-loop"``.

    Parameters
    ----------
    Ad, Bd, C : ndarray
        Discrete model, as in :func:`simulation`.
    K : (n, p) ndarray
        Discrete innovation (observer) gain [state units per output unit].
    u : (N,) or (N, m) ndarray
        Input samples (model input units).
    y : (N, p) ndarray
        Measured outputs (output units).
    k : int
        Open-loop steps after the state estimate, >= 0 [samples].
    x0 : (n,) ndarray, optional
        Initial state of the predictor (state units); zero by default.
    head : {"one-step", "open-loop"}
        The first k samples, which have no estimate k samples back: the one-step
        prediction, or ``x0`` run open loop.

    Returns
    -------
    (N, p) ndarray
        Predicted outputs (units of ``y``).
    """
    if k < 0:
        raise ValueError(f"k={k}: need k >= 0")
    if head not in ("one-step", "open-loop"):
        raise ValueError(f"head={head!r}: use 'one-step' or 'open-loop'")
    U = _as_columns(u)
    N, n = U.shape[0], Ad.shape[0]
    x = np.zeros(n) if x0 is None else np.asarray(x0, float).reshape(n)
    xh = _predictor_states(_f64(Ad), _f64(Bd), _f64(C), _f64(K), _f64(U), _f64(y), _f64(x))
    pred = (xh @ C.T).copy()
    if k < N:
        X = xh[: N - k].copy()
        for i in range(k):
            X = X @ Ad.T + U[i : N - k + i] @ Bd.T
        pred[k:] = X @ C.T
    if head == "open-loop":
        z = xh[0].copy()
        for j in range(min(k, N)):
            pred[j] = C @ z
            z = Ad @ z + Bd @ U[j]
    return pred


def _data_first(runs, model, name: str) -> list[Run]:
    """The runs as a list, refusing a model given first (the order is data, then model,
    as MATLAB's ``compare(data, model)`` and ``resid(data, model)``)."""

    def is_runs(x) -> bool:
        return isinstance(x, Run) or (
            isinstance(x, (list, tuple)) and len(x) > 0 and all(isinstance(r, Run) for r in x)
        )

    if not is_runs(runs):
        if is_runs(model):
            raise InputError(
                f"{name}(model, runs): the arguments are swapped; the data come first, as in "
                f"MATLAB: {name}(runs, model)"
            )
        if isinstance(runs, (list, tuple)) and not runs:
            raise InputError(f"{name}: no runs given; pass a Run or a list of Runs first")
        raise InputError(
            f"{name}: the first argument is a {type(runs).__name__}, not a Run or a list of "
            f"Runs; call {name}(runs, model)"
        )
    return [runs] if isinstance(runs, Run) else list(runs)


def compare(
    runs: Run | Sequence[Run],
    model,
    horizon: int | None = None,
    ic: str | np.ndarray = "estimate",
) -> CompareResult:
    """Simulation (``horizon=None``) or ``horizon``-step prediction of each run.

    Parameters
    ----------
    runs : Run or sequence of Run
        The data (signals named after the model's inputs and outputs).
    model : CanonicalModel, SpeedCanonicalModel, DirectResult or control.StateSpace
        The model, made discrete at each run's dt and speed by :func:`sampled_model`.
    horizon : int or None
        None: simulation (:func:`simulation`); h >= 1: h-step-ahead prediction by the
        model's innovations predictor (:func:`k_step_prediction` with k = h - 1 and the
        first samples run open loop from the initial state, as MATLAB).
    ic : {"estimate", "zero"} or (n,) array_like
        Initial state: least squares per run (of the simulation, or of the one-step
        predictor), zero, or the given state vector (state units).

    Returns
    -------
    CompareResult
        Predictions per run and NRMSE fit and VAF per output [%].

    Raises
    ------
    ValueError
        UntrustworthyResult (a ValueError) for a simulation of an unstable model over a long
        run (growth of the largest discrete eigenvalue over the run above 1e12): use a finite
        horizon or a shorter window (``Run.window``), as Moore's 8 s windows; likewise for a
        prediction whose predictor Ad - K C is unstable (K = 0 and an unstable model).
    InputError
        If ``runs`` is not a Run or a non-empty list of Runs, e.g. the arguments swapped
        (``compare(model, runs)``; the data come first, as MATLAB's ``compare(data, model)``).
    """
    runs = _data_first(runs, model, "compare")
    if horizon is not None and horizon < 1:
        raise ValueError(f"horizon={horizon}: need an integer >= 1 or None (simulation)")
    yh_all, x0_all, ys = [], [], []
    outputs = None
    for run in runs:
        Ad, Bd, C, K, outputs, inputs = sampled_model(model, run.dt, run.speed)
        U = np.column_stack([run[i] for i in inputs])
        Y = np.column_stack([run[o] for o in outputs])
        N = run.n
        if horizon is None:
            growth = np.max(np.abs(np.linalg.eigvals(Ad))) ** N
            if growth > 1e12:
                raise UntrustworthyResult(
                    f"the model is unstable and the run has {N} samples (growth {growth:.2g}): "
                    "use horizon=k (k-step prediction) or a shorter window (Run.window)"
                )
            yhat, x0 = simulation(Ad, Bd, C, U, Y, ic)
        else:
            growth = np.max(np.abs(np.linalg.eigvals(Ad - K @ C))) ** N
            if growth > 1e12:
                raise UntrustworthyResult(
                    f"the model's predictor is unstable (Ad - K C; K = 0 for a model without "
                    f"a noise model) and the run has {N} samples (growth {growth:.2g}): use a "
                    "shorter window (Run.window) or a model with an innovation gain (pem)"
                )
            # the one-step predictor is a simulation of x+ = (Ad - K C) x + [Bd K] [u; y]
            _, x0 = simulation(Ad - K @ C, np.hstack([Bd, K]), C, np.hstack([U, Y]), Y, ic)
            yhat = k_step_prediction(Ad, Bd, C, K, U, Y, horizon - 1, x0, head="open-loop")
        yh_all.append(yhat)
        x0_all.append(x0)
        ys.append(Y)
    Yc, Yh = np.vstack(ys), np.vstack(yh_all)
    fit = {o: 100 * goodness_of_fit(Yc[:, j], Yh[:, j])["nrmse_fit"]
           for j, o in enumerate(outputs)}  # fmt: skip
    vaf = {o: 100 * vaf_variance(Yc[:, j], Yh[:, j]) for j, o in enumerate(outputs)}
    return CompareResult(tuple(yh_all), fit, vaf, tuple(x0_all), tuple(outputs), horizon)


@dataclass(frozen=True)
class ResidResult:
    """Residual analysis.  ``lags`` = -max_lag..max_lag; ``autocorr[o]`` (normalized,
    lags 0..max_lag); ``crosscorr[o]`` with the input over ``lags`` (positive lag tau:
    residual at k vs input at k - tau); ``band`` = 2.576 / sqrt(N);
    ``fraction_outside[o]`` over lags 1..max_lag of the autocorrelation;
    ``cross_outside[o]`` over lags 0..max_lag of the cross-correlation.

    Attributes
    ----------
    residuals : tuple of (N_i, p) ndarray
        One-step prediction errors per run (output units: rad, rad/s).
    lags : (2 max_lag + 1,) int ndarray
        Lags -max_lag..max_lag [samples] of ``crosscorr``.
    autocorr : dict of str to (max_lag + 1,) ndarray
        Normalized residual autocorrelation per output at lags 0..max_lag (1 at lag 0).
    crosscorr : dict of str to (2 max_lag + 1,) ndarray
        Normalized residual-input cross-correlation per output at ``lags``.
    band : float
        Half-width of the confidence band, z / sqrt(N) (N all samples stacked).
    fraction_outside : dict of str to float
        Fraction of autocorrelation lags 1..max_lag outside +-band, per output.
    cross_outside : dict of str to float
        Fraction of cross-correlation lags 0..max_lag outside +-band, per output.
    whiteness_test : dict of str to dict
        Per output the chi-squared whiteness test of the autocorrelation at lags
        1..max_lag (:func:`portmanteau`: ``statistic``, ``dof``, ``p_value``, ``passed``).
    independence_test : dict of str to dict
        Per output the chi-squared test of independence from the input at lags 1..max_lag
        (:func:`independence_test`), same keys.
    input : str
        The signal the cross-correlation used (``"T_delta"``, ``"dither"``, ...).
    """

    residuals: tuple[np.ndarray, ...]
    lags: np.ndarray
    autocorr: dict[str, np.ndarray]
    crosscorr: dict[str, np.ndarray]
    band: float
    fraction_outside: dict[str, float]
    cross_outside: dict[str, float]
    whiteness_test: dict[str, dict] = field(default_factory=dict)
    independence_test: dict[str, dict] = field(default_factory=dict)
    input: str = "T_delta"


def _xcorr(a: np.ndarray, b: np.ndarray, lags) -> np.ndarray:
    """sum_k a[k] b[k - lag] / sqrt(sum a^2 sum b^2) at each of ``lags`` (|lag| < N).

    All lags from one FFT product of the zero-padded signals (length >= 2N, so the circular
    correlation is the linear one): O(N log N) instead of a dot product per lag; it equals
    the per-lag sums to rounding (about 1e-15 of sqrt(sum a^2 sum b^2)).
    """
    a, b = np.asarray(a, float), np.asarray(b, float)
    lags = np.asarray(list(lags), int)
    nfft = 1 << int(2 * len(a) - 1).bit_length()
    c = np.fft.irfft(np.fft.rfft(a, nfft) * np.conj(np.fft.rfft(b, nfft)), nfft)
    return c[lags % nfft] / np.sqrt(np.dot(a, a) * np.dot(b, b))


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

    Parameters
    ----------
    runs : Run or sequence of Run
        The data; residuals of all runs are stacked for the statistics.
    model : CanonicalModel, SpeedCanonicalModel, DirectResult or control.StateSpace
        The model, as in :func:`compare` (one-step prediction, ``horizon=1``).
    input : str, optional
        Run signal for the cross-correlation, or ``"dither"``.
    max_lag : int, optional
        Largest lag [samples].
    confidence : float, optional
        Level of the band (0.99: z = 2.576).

    Returns
    -------
    ResidResult
        Residuals, their correlation statistics and the chi-squared whiteness and
        independence tests at level 1 - ``confidence``.

    Raises
    ------
    ValueError
        If ``input="dither"`` and a run has no logged dither, or :func:`compare` raises
        (InputError for arguments swapped: ``resid(runs, model)``).
    """
    from scipy.stats import norm

    runs = _data_first(runs, model, "resid")
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
    u_acf = _acf(u, range(max_lag))
    auto, cross, frac, xfrac, wtest, itest = {}, {}, {}, {}, {}, {}
    for j, o in enumerate(pred.outputs):
        e = E[:, j] - E[:, j].mean()
        auto[o] = _acf(e, range(max_lag + 1))
        cross[o] = _xcorr(e, u, lags)
        frac[o] = float(np.mean(np.abs(auto[o][1:]) > band))
        xfrac[o] = float(np.mean(np.abs(cross[o][max_lag:]) > band))
        wtest[o] = portmanteau(auto[o][1:], N, confidence)
        itest[o] = independence_test(cross[o][max_lag + 1 :], u_acf, N, confidence)
    return ResidResult(tuple(res), lags, auto, cross, band, frac, xfrac, wtest, itest, input)


def _ss(model, v: float | None = None) -> control.StateSpace:
    # poles, zeros and transfer functions do not depend on the state order; the canonical
    # model's own (Chen & Dao) order is used, as the identification computed it
    if not isinstance(model, LinearModel):
        return model
    if isinstance(model, SpeedDependentModel) and v is None:
        raise ValueError(
            f"a {type(model).__name__} is defined over speed: pass the speed, v=... [m/s]"
        )
    # (a model with Chen & Dao's matrices, ident.pem.CanonicalModel, by what it has: this
    # module is below ident.pem, whose fit runs the structure check built on it)
    order = "chen_dao" if hasattr(model, "A_chen_dao") else "bikeid"
    return model.state_space(v if isinstance(model, SpeedDependentModel) else None, order=order)


def poles(model, v: float | None = None) -> np.ndarray:
    """Poles [1/s] of an identified model (``CanonicalModel`` or ``StateSpace``).

    Parameters
    ----------
    model : ident.pem.CanonicalModel, SpeedCanonicalModel, DirectResult or control.StateSpace
        Continuous-time model.
    v : float, optional
        Speed [m/s], required for models defined over speed (``SpeedCanonicalModel``,
        ``DirectResult``).

    Returns
    -------
    (n,) complex ndarray
        Poles [1/s] (independent of the state order).
    """
    import control

    return np.asarray(control.poles(_ss(model, v)))


def zeros(model, output: str = "phi", input: str = "T_delta", v: float | None = None) -> np.ndarray:
    """Transmission zeros [1/s] of one SISO channel.

    Parameters
    ----------
    model : ident.pem.CanonicalModel, SpeedCanonicalModel, DirectResult or control.StateSpace
        Continuous-time model.
    output : str, optional
        Output name, e.g. ``"phi"`` or ``"delta"``.
    input : str, optional
        Input name, e.g. ``"T_delta"``.
    v : float, optional
        Speed [m/s], required for models defined over speed.

    Returns
    -------
    complex ndarray
        Zeros [1/s] of the transfer function from ``input`` to ``output``.

    Raises
    ------
    KeyError
        If the model has no such (output, input) channel.
    """
    import control

    return np.asarray(control.zeros(transfer_functions(model, v)[(output, input)]))


def transfer_functions(
    model, v: float | None = None
) -> dict[tuple[str, str], control.TransferFunction]:
    """SISO transfer functions keyed by (output, input).

    Parameters
    ----------
    model : ident.pem.CanonicalModel, SpeedCanonicalModel, DirectResult or control.StateSpace
        Continuous-time model.
    v : float, optional
        Speed [m/s], required for models defined over speed.

    Returns
    -------
    dict of (str, str) to control.TransferFunction
        One transfer function per output/input pair (e.g. ``("phi", "T_delta")`` in
        rad/(N m)), numerator leading coefficients below 1e-9 of its largest dropped as
        round-off.
    """
    import control

    ss = _ss(model, v)
    out = {}
    for i, o in enumerate(ss.output_labels):
        for j, u in enumerate(ss.input_labels):
            tf = control.ss2tf(ss[i, j])
            num, den = np.asarray(tf.num[0][0], float), np.asarray(tf.den[0][0], float)
            scale = np.abs(num).max() if num.size else 0.0
            lead = np.argmax(np.abs(num) > 1e-9 * scale) if scale > 0 else len(num) - 1
            out[(o, u)] = control.tf(num[lead:], den)  # drop round-off leading terms
    return out


# -- correlation tests of one residual sequence (resid's tests, also used by the effect
# diagnostics of the measured data) ---------------------------------------------------------
__all__ += ["cross_correlation", "independence_test", "portmanteau", "whiteness"]


def _band(n: int, confidence: float) -> float:
    from scipy.stats import norm

    return float(norm.ppf(0.5 + confidence / 2) / np.sqrt(n))


def portmanteau(acf: np.ndarray, n: int, confidence: float = 0.99) -> dict:
    """Whiteness test on an autocorrelation: zeta = N sum_k r(k)^2 against chi^2(M).

    Under the hypothesis that the residual is white, sqrt(N) r(k) for k = 1..M are
    asymptotically independent standard normal, so zeta is chi-squared with M degrees of
    freedom (Ljung, *System Identification*, 2nd ed., sec. 16.6; Box & Pierce 1970).

    Parameters
    ----------
    acf : (M,) array_like
        Normalized autocorrelation at lags 1..M (dimensionless).
    n : int
        Number of samples the autocorrelation was computed from.
    confidence : float, optional
        The test's level is 1 - confidence (0.99: a white residual fails 1 % of the time).

    Returns
    -------
    dict
        ``statistic`` zeta, ``dof`` M, ``p_value`` (chi^2 survival function of zeta) and
        ``passed`` (p_value >= 1 - confidence).
    """
    from scipy.stats import chi2

    r = np.asarray(acf, float)
    stat = float(n * np.sum(r**2))
    p = float(chi2.sf(stat, r.size))
    return {"statistic": stat, "dof": int(r.size), "p_value": p, "passed": p >= 1 - confidence}


def independence_test(
    ccf: np.ndarray, input_acf: np.ndarray, n: int, confidence: float = 0.99
) -> dict:
    """Residual-input independence test: zeta = N r' R^-1 r against chi^2(M).

    ``r`` is the normalized residual-input cross-correlation at lags 1..M (the residual at k
    against the input at k - 1 .. k - M: what a correct predictor leaves independent of past
    inputs, in open and in closed loop), ``R`` the Toeplitz matrix of the input's normalized
    autocorrelation at lags 0..M-1.  Under the hypothesis (white residual independent of the
    input), sqrt(N) r is asymptotically normal with covariance R (Ljung, sec. 16.6), so zeta
    is chi-squared with M degrees of freedom (fewer when R is singular: the rank, from its
    eigenvalues above 1e-10 of the largest).

    Parameters
    ----------
    ccf : (M,) array_like
        Cross-correlation at lags 1..M (dimensionless).
    input_acf : (M,) array_like
        Input autocorrelation at lags 0..M-1 (1 at lag 0).
    n : int
        Number of samples.
    confidence : float, optional
        The test's level is 1 - confidence.

    Returns
    -------
    dict
        ``statistic``, ``dof``, ``p_value`` and ``passed`` (p_value >= 1 - confidence).
    """
    from scipy.linalg import toeplitz
    from scipy.stats import chi2

    r = np.asarray(ccf, float)
    w, V = np.linalg.eigh(toeplitz(np.asarray(input_acf, float)))
    keep = w > 1e-10 * w.max()
    z = V[:, keep].T @ r
    stat = float(n * np.sum(z**2 / w[keep]))
    dof = int(keep.sum())
    p = float(chi2.sf(stat, dof))
    return {"statistic": stat, "dof": dof, "p_value": p, "passed": p >= 1 - confidence}


def _acf(x: np.ndarray, lags) -> np.ndarray:
    """Normalized autocorrelation of a mean-removed signal at ``lags``."""
    return _xcorr(x, x, lags)


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
        ``acf``: normalized autocorrelation at lags 1..max_lag; ``band``;
        ``fraction_outside``: the fraction of ``acf`` outside +-band; and ``test``: the
        chi-squared whiteness test of :func:`portmanteau` at level 1 - confidence.
    """
    e = np.asarray(e, float) - np.mean(e)
    r = _acf(e, range(1, max_lag + 1))
    band = _band(e.size, confidence)
    return {"acf": r, "band": band, "fraction_outside": float(np.mean(np.abs(r) > band)),
            "test": portmanteau(r, e.size, confidence)}  # fmt: skip


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
        ``fraction_outside``: the fraction of ``ccf`` outside +-band (all lags); ``test``:
        the chi-squared independence test of :func:`independence_test` on lags 1..max_lag
        at level 1 - confidence.
    """
    e = np.asarray(e, float) - np.mean(e)
    u = np.asarray(u, float) - np.mean(u)
    lags = np.arange(-max_lag, max_lag + 1)
    r = _xcorr(e, u, lags)
    band = _band(e.size, confidence)
    test = independence_test(r[max_lag + 1 :], _acf(u, range(max_lag)), e.size, confidence)
    return {"lags": lags, "ccf": r, "band": band,
            "fraction_outside": float(np.mean(np.abs(r) > band)), "test": test}  # fmt: skip


# -- Moore & Hubbard's VAF measures and the binomial interval of a rate ---------------------
__all__ += ["binomial_interval", "vaf_moore", "vaf_variance", "windowed_simulation_vaf"]


def windowed_simulation_vaf(
    Ad: np.ndarray,
    Bd: np.ndarray,
    y: np.ndarray,
    u: np.ndarray,
    window: int,
    initial: str = "measured",
    names: Sequence[str] = ("phi", "delta", "phidot", "deltadot"),
) -> dict[str, float]:
    """Moore & Hubbard's simulation VAF: eq. 6 (:func:`vaf_moore`) on open-loop
    simulations of the model over consecutive windows of the record.

    The models are open-loop unstable, so each window of ``window`` samples is simulated
    on its own (:func:`simulation`, all states observed: C = I) from an initial state that
    is either the measured state at its first sample (``initial="measured"``) or the least
    squares fit to the window's measured outputs (``"estimate"``).

    Parameters
    ----------
    Ad : (4, 4) ndarray
        Discrete state matrix of the model at the record's sample period [-].
    Bd : (4, m) ndarray
        Discrete input matrix [state units per input unit].
    y : (N, 4) ndarray
        Measured states, in the order of ``names`` (e.g. rad, rad/s).
    u : (N,) or (N, m) ndarray
        Inputs driving the model (e.g. the logged T_delta [N m], F [N]).
    window : int
        Window length [samples], >= 2 (the last window may be shorter).
    initial : {"measured", "estimate"}, optional
        Initial state of each window.
    names : sequence of str, optional
        Names of the states (keys of the result).

    Returns
    -------
    dict of str to float
        Per state, eq. 6 over all windows, dimensionless (1: exact); ``-inf`` where the
        simulation overflowed (a model far from the data).

    Raises
    ------
    ValueError
        If ``window`` < 2, ``initial`` is unknown, or the shapes disagree.
    """
    y = np.asarray(y, dtype=float)
    U = _as_columns(u)
    n = int(window)
    if n < 2:
        raise ValueError(f"window={window}: need at least 2 samples per window")
    if initial not in ("measured", "estimate"):
        raise ValueError(f"initial={initial!r}: use 'measured' or 'estimate'")
    if y.ndim != 2 or y.shape[1] != Ad.shape[0] or U.shape[0] != y.shape[0]:
        raise ValueError(f"y {y.shape} and u {U.shape}: need (N, {Ad.shape[0]}) and (N, m)")
    if len(names) != y.shape[1]:
        raise ValueError(f"{len(names)} names for {y.shape[1]} states")
    C = np.eye(Ad.shape[0])
    sim = np.empty_like(y)
    with np.errstate(over="ignore", invalid="ignore"):
        for s in range(0, y.shape[0], n):
            sl = slice(s, min(s + n, y.shape[0]))
            ic = y[s] if initial == "measured" else "estimate"
            sim[sl], _ = simulation(Ad, Bd, C, U[sl], y[sl], ic=ic)
    return {
        nm: vaf_moore(y[:, j], sim[:, j]) if np.all(np.isfinite(sim[:, j])) else -np.inf
        for j, nm in enumerate(names)
    }


def binomial_interval(k: int, n: int, level: float = 0.95) -> tuple[float, float]:
    """Exact (Clopper-Pearson) interval of a success probability from ``k`` of ``n``.

    Parameters
    ----------
    k : int
        Successes, 0 <= k <= n.
    n : int
        Trials, >= 0.
    level : float, optional
        Confidence level, 0 < level < 1 (default 0.95).

    Returns
    -------
    (float, float)
        Lower and upper bound of the probability; (0, 1) when ``n`` is 0 (no trials, no
        information).

    Raises
    ------
    ValueError
        If ``k`` or ``n`` is not a whole number with 0 <= k <= n, or ``level`` is not in
        (0, 1).
    """
    if int(k) != k or int(n) != n or not 0 <= k <= n:
        raise ValueError(f"{k} successes of {n} trials: need whole numbers 0 <= k <= n")
    if not 0 < level < 1:
        raise ValueError(f"level={level}: need 0 < level < 1")
    if n == 0:
        return (0.0, 1.0)
    ci = binomtest(int(k), int(n)).proportion_ci(confidence_level=level, method="exact")
    return (float(ci.low), float(ci.high))
