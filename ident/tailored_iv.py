"""Tailor-made ("simulated") instruments for the direct method on closed-loop data.

Why.  On closed-loop data with sensor noise, least squares on the canonical rows is biased
twice over: the noise sits in the regressors (errors in variables, reference F5), and the
controller feeds the same noise into the logged torque.  Instrumental variables built from
the external signals (dither, roll reference) are consistent, but a 2SLS first stage with
many lags of them overfits the sensor noise once the signals are low-pass filtered: after a
3 Hz zero-phase filter at 100 Hz a 50 s run holds only ~300 independent noise samples, so
tens of instruments per run put a sizeable share of the noise back into the fitted
regressors and the estimate slides towards least squares (docs/accuracy.md).

What.  Ljung's tailor-made IV (Ljung 1999, §15.3; "IV4"): the ideal instrument is the
noise-free part of the regressor that the external signals drive.  Per run:

1. estimate the controller from the run itself by an ARX least-squares fit of the logged
   controller output ``u = T_delta - dither`` on its own past and on the measured signals
   and the reference it acted on (:func:`fit_controller`).  The controller sees exactly the
   measured signals, so for a linear controller (PID, pole placement with integral action)
   this regression has no error at all: u[k] = sum a_i u[k-i] + sum b_j y[k-j] + sum c_j r[k-j];
2. simulate the linear closed loop of that controller and the current canonical model at
   the run's mean speed (zero-order hold at the run's sample time), driven only by the
   logged dither and reference, from rest (:func:`simulate_instruments`);
3. prepare the simulated run exactly as the data and use its regressors as instruments
   (``ident.direct.identify(method="iv", instruments="simulated")``): one instrument per
   free entry, pooled over all runs.

The instruments depend only on the external signals and on estimates, never on the sensor
noise of the sample, so the estimate is consistent whatever the noise colour; iterating
(model -> instruments -> model) moves the instruments towards the true noise-free
regressors (:func:`identify_tailored`).  A nonlinear controller (fuzzy, a rider) is replaced
by its best linear ARX fit: the instruments are then less correlated with the regressors
(less efficient) but still valid.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from bikeid.dataset.run import Run
from bikeid.ident.direct import DirectResult, identify
from bikeid.ident.signals import check_sampling
from bikeid.sim.errors import UntrustworthyResult
from bikeid.sim.linear import CanonicalMatrices, state_matrices
from bikeid.sim.sampling import zoh

__all__ = ["ControllerFit", "fit_controller", "identify_tailored", "simulate_instruments"]

#: Measured channels the controller is assumed to act on (bikeid state order).
STATE = ("phi", "delta", "phidot", "deltadot")


@dataclass(frozen=True)
class ControllerFit:
    """Linear ARX model of a controller, u = T_delta - dither [N m]::

        u[k] = sum_i a[i] u[k-1-i] + sum_j b[j] . y[k-j] + sum_j c[j] r[k-j] + const

    y = measured [phi, delta, phidot, deltadot] (rad, rad/s), r = roll reference [rad].
    ``a`` (na,), ``b`` (nb+1, 4), ``c`` (nb+1,); ``vaf`` = 1 - var(residual)/var(u) of the
    fit (1 for an exactly linear controller of these orders).

    Attributes
    ----------
    a : (na,) ndarray
        Coefficients of the past controller outputs u[k-1] .. u[k-na] (dimensionless).
    b : (nb + 1, 4) ndarray
        Row j: gains on y[k-j] = [phi, delta, phidot, deltadot] [N m/rad, N m s/rad].
    c : (nb + 1,) ndarray
        Gains on the roll reference r[k-j] [N m/rad].
    const : float
        Constant term [N m] (not used by :func:`simulate_instruments`).
    vaf : float
        Variance accounted for of the fit (dimensionless; NaN when u is constant).
    """

    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    const: float
    vaf: float


def _lagged(x: np.ndarray, lags: range, start: int) -> np.ndarray:
    return np.column_stack([x[start - j : x.size - j] for j in lags])


def fit_controller(run: Run, na: int = 1, nb: int = 1) -> ControllerFit:
    """ARX fit of the run's controller (see :class:`ControllerFit`) on the *raw* run.

    ``na`` >= 1 past outputs (one is enough for integral action: PID, pole placement with an
    integrator), ``nb`` >= 0 past inputs.  Needs a logged dither and reference.

    Parameters
    ----------
    run : Run
        Raw closed-loop run with ``T_delta`` [N m], the measured states [rad, rad/s], a
        logged dither [N m] and roll reference [rad].
    na : int, optional
        Number of past controller outputs, >= 1.
    nb : int, optional
        Largest lag [samples] of the measured states and reference, >= 0.

    Returns
    -------
    ControllerFit
        The least-squares ARX coefficients and the fit's VAF.

    Raises
    ------
    ValueError
        If the run has no logged dither or reference, the orders are out of range, or the
        run is too short (fewer than 10 samples per coefficient plus the lags).
    """
    if run.dither is None or run.reference is None:
        raise ValueError(
            "tailor-made instruments need runs with a logged dither and roll reference"
        )
    if na < 1 or nb < 0:
        raise ValueError(f"controller orders na={na}, nb={nb}: need na >= 1 and nb >= 0")
    s = max(na, nb)
    if run.n < 10 * (na + 5 * (nb + 1) + 1) + s:
        raise ValueError(f"run of {run.n} samples is too short for an ARX({na}, {nb}) controller")
    u = np.asarray(run["T_delta"], float) - run.dither
    y = [np.asarray(run[k], float) for k in STATE]
    cols = [_lagged(u, range(1, na + 1), s)]
    cols += [_lagged(x, range(nb + 1), s) for x in y]
    cols += [_lagged(np.asarray(run.reference, float), range(nb + 1), s)]
    X = np.column_stack([*cols, np.ones(run.n - s)])
    target = u[s:]
    scale = np.linalg.norm(X, axis=0)
    scale[scale == 0] = 1.0
    theta, *_ = np.linalg.lstsq(X / scale, target, rcond=None)
    theta = theta / scale
    res = target - X @ theta
    vaf = 1.0 - float(np.var(res) / np.var(target)) if np.var(target) > 0 else float("nan")
    k = nb + 1
    b = np.column_stack([theta[na + i * k : na + (i + 1) * k] for i in range(4)])
    c = theta[na + 4 * k : na + 5 * k]
    return ControllerFit(a=theta[:na], b=b, c=c, const=float(theta[-1]), vaf=vaf)


def _discretize(cm: CanonicalMatrices, v: float, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Zero-order-hold A_d, B_d (T_delta column) of the canonical model at speed v."""
    A, B = state_matrices(cm, v)
    Ad, Bd = zoh(A, B[:, 1:2], dt)
    return Ad, Bd[:, 0]


def simulate_instruments(
    run: Run, model: CanonicalMatrices | DirectResult, controller: ControllerFit | None = None
) -> Run:
    """Noise-free closed-loop response to the run's dither and reference alone.

    The linear plant ``model`` at the run's mean measured speed (ZOH over the sample time)
    in a loop with ``controller`` (default: :func:`fit_controller` of the run), from rest.
    Returns a run on the same time grid whose signals are the simulated phi, delta, phidot,
    deltadot, T_delta (controller output + dither), constant v, and zero T_phi, F; dither and
    reference as the data's.  Raises ValueError if the simulated loop diverges (the model
    and controller do not form a stable loop).

    Parameters
    ----------
    run : Run
        Raw closed-loop run with a logged dither [N m], roll reference [rad] and speed
        ``v`` [m/s].
    model : CanonicalMatrices or DirectResult
        Linear plant (its steer-torque column is used).
    controller : ControllerFit, optional
        Controller of the loop; default :func:`fit_controller` of ``run``.

    Returns
    -------
    Run
        Simulated run on the same time grid: ``phi``, ``delta`` [rad], ``phidot``,
        ``deltadot`` [rad/s], ``T_delta`` [N m], ``v`` [m/s], ``T_phi`` [N m] and ``F``
        [N] zero; ``meta["instruments"]`` holds the controller VAF and the speed.

    Raises
    ------
    ValueError
        If the simulated loop diverges (non-finite or |phi| or |delta| above 10 rad), or
        the controller fit fails (:func:`fit_controller`).
    """
    cm = model.canonical() if isinstance(model, DirectResult) else model
    ctrl = controller if controller is not None else fit_controller(run)
    v = float(np.mean(run["v"]))
    Ad, Bd = _discretize(cm, v, run.dt)
    na, nb = ctrl.a.size, ctrl.b.shape[0] - 1
    n = run.n
    d, r = np.asarray(run.dither, float), np.asarray(run.reference, float)
    x = np.zeros((n, 4))
    u = np.zeros(n)
    xk = np.zeros(4)
    for k in range(n):
        x[k] = xk
        uk = 0.0
        for i in range(min(na, k)):
            uk += ctrl.a[i] * u[k - 1 - i]
        for j in range(min(nb, k) + 1):
            uk += ctrl.b[j] @ x[k - j] + ctrl.c[j] * r[k - j]
        u[k] = uk
        xk = Ad @ xk + Bd * (uk + d[k])
    scale = np.abs(x).max(axis=0)
    if not np.all(np.isfinite(x)) or scale[0] > 10.0 or scale[1] > 10.0:
        raise UntrustworthyResult(
            f"closed-loop simulation for the instruments diverges at {v:.3g} m/s: the model and "
            "the fitted controller do not form a stable loop; start from a better model"
        )
    sig = {k: x[:, i] for i, k in enumerate(STATE)}
    sig.update(v=np.full(n, v), T_delta=u + d, T_phi=np.zeros(n), F=np.zeros(n))
    meta = dict(run.meta)
    meta["instruments"] = {"controller_vaf": ctrl.vaf, "speed": v}
    return Run(t=run.t, signals=sig, dither=run.dither, reference=run.reference, meta=meta)


def _entry(model: DirectResult | CanonicalMatrices, name: str) -> float:
    if isinstance(model, DirectResult):
        return model.entry(name)
    m, r, c = name[:-2], "pd".index(name[-2]), "pd".index(name[-1])
    return float(getattr(model, m)[r, c])


def identify_tailored(
    runs: Sequence[Run],
    reference,
    free_roll: Sequence[str] | None = None,
    free_steer: Sequence[str] | None = None,
    *,
    prepare: Callable[[Run], Run],
    start: DirectResult | CanonicalMatrices | str = "external",
    iterations: int = 3,
    na: int = 1,
    nb: int = 1,
    **kwargs,
) -> DirectResult:
    """Direct identification with tailor-made instruments, iterated.

    Each iteration simulates noise-free instruments through each run's fitted controller
    and the current model (:func:`simulate_instruments`), prepares them like the data and
    solves :func:`ident.direct.identify` with ``instruments="simulated"``.  The result's
    ``notes`` record the iterations and the worst controller-fit VAF.

    Parameters
    ----------
    runs : sequence of Run
        *Raw* closed-loop runs with a logged dither [N m] and roll reference [rad] (the
        controller fit and the simulation need the signals the controller saw).
    reference : BicycleParameters or CanonicalMatrices
        Values of the fixed entries (as :func:`ident.direct.identify`).
    free_roll, free_steer : sequence of str, optional
        Entries to estimate (default Moore & Hubbard's sets).
    prepare : callable
        Maps a raw run to the signals the regression uses (e.g.
        ``experiments.testbed.accuracy.direct_prepare``); applied alike to data and simulated
        instruments.
    start : {"external", "ls"} or DirectResult or CanonicalMatrices, optional
        First model for the instruments: "external" (default: ``identify(...,
        method="iv", instruments="external", lags=40)`` on the prepared runs), "ls" (least
        squares), or a model (e.g. the Whipple model of the reference,
        ``canonical_matrices(reference)``).  It only shapes the first instruments: the
        estimate stays consistent, and the iterations remove its influence.
    iterations : int, optional
        Instrument/model refinements, >= 1.
    na, nb : int, optional
        Controller ARX orders (:func:`fit_controller`).
    **kwargs
        Other keywords go to :func:`ident.direct.identify` (not ``method``,
        ``instruments``, ``instrument_runs``).

    Returns
    -------
    DirectResult
        The last iteration's estimate, ``method="iv (tailor-made)"``, with a note giving
        the relative entry change of each iteration and the worst controller VAF.

    Raises
    ------
    ValueError
        If ``iterations`` < 1, no runs are given, a run breaks the sampling contract
        (``ident.signals.check_sampling``), ``start`` is an unknown string, or a
        controller fit, instrument simulation or :func:`ident.direct.identify` raises.
    """
    if iterations < 1:
        raise ValueError(f"iterations={iterations}: need at least 1")
    runs = list(runs)
    if not runs:
        raise ValueError("no runs given")
    check_sampling(runs, "tailored_iv.identify_tailored")
    prepared = [prepare(r) for r in runs]
    controllers = [fit_controller(r, na, nb) for r in runs]
    if isinstance(start, str):
        if start not in ("external", "ls"):
            raise ValueError(f"start {start!r}: choose 'external', 'ls' or pass a model")
        iv = {"method": "iv", "instruments": "external", "lags": 40} if start == "external" else {}
        model = identify(prepared, reference, free_roll, free_steer, **iv, **kwargs)
    else:
        model = start
    steps = []
    for _ in range(iterations):
        inst = [prepare(simulate_instruments(r, model, c)) for r, c in zip(runs, controllers,
                                                                          strict=True)]  # fmt: skip
        new = identify(prepared, reference, free_roll, free_steer, method="iv",
                       instruments="simulated", instrument_runs=inst, **kwargs)  # fmt: skip
        old = {k: _entry(model, k) for k in new.free}
        change = max(abs(new.free[k] - old[k]) / max(abs(old[k]), 1e-12) for k in new.free)
        steps.append(change)
        model = new
    worst = min(c.vaf for c in controllers)
    note = (f"tailor-made IV: {iterations} iterations, relative entry changes "
            + ", ".join(f"{s:.2g}" for s in steps)
            + f"; worst controller ARX({na},{nb}) VAF {worst:.4f}")  # fmt: skip
    return replace(model, notes=(*model.notes, note), method="iv (tailor-made)")
