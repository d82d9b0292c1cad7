"""Chen & Dao (2010) on the testbed: Figs. 2, 3, 4-5, 7, eqs. 5-6, with the ground truth.

Ground truth is the linearization of the simulated plant (:mod:`sim.linear`, benchmark
bicycle).  Identification data (Fig. 2/3): nonlinear plant at held speed, fuzzy roll
controller (:mod:`controllers.fuzzy`), chirp roll reference, uniform dither <= 1 N m,
0.01 s sampling, default sensor noise (:meth:`dataset.sensors.Sensors.default`), built by
:func:`experiments.sweep.simulate_task` so the runs equal those of ``bikeid sweep``.
Identification: :func:`ident.pem.fit` (canonical PEM, innovations predictor, subspace start)
and, for the sweep summary, :func:`ident.direct.identify` (Moore & Hubbard's least squares
with the Whipple values for the fixed entries).

Every function returns plain dicts of numbers (for ``summary.json``) and writes its figures
into the output folder; :mod:`experiments.reproduce` assembles the report.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import linear_sum_assignment

from bikeid.sim.parameters import BicycleParameters

__all__ = [
    "PAPER",
    "critical_from_grid",
    "eigen_stderr",
    "fig2",
    "fig3",
    "fig7",
    "identify_speed",
    "k_step_prediction",
    "match_eigenvalues",
    "open_loop_simulation",
    "paper_eq5_reading",
    "transfer_functions",
]

#: Numbers printed in Chen & Dao (2010) (signs lost in the extracted text; see
#: :func:`paper_eq5_reading`).
PAPER = {
    "eq5_abs": {
        "a": [5.392, 0.432, 12.570, 3.177, 13.645, 20.944, 20.913, 17.000],
        "b": [19.711, 233.588],
    },
    "poles_abs": [15.101, 1.668, 0.331, 3.343],
    "den": [1.0, 17.431, 47.586, 205.934, 284.279],
    "num_phi_abs": [19.711, 1077.263, 2524.109],
    "num_delta_abs": [233.588, 311.882, 1528.374],
    "zeros_phi_abs": [52.199, 2.453],
    "zeros_delta_abs": [3.311, 1.976],
    "max_error_deg": {"phi": 0.231, "delta": 0.172},
    "critical": {"v_d": 1.465, "v_w": 3.994, "v_c": 10.525, "v_l": 3.152},
}

FIG2_SPEED = 4.2  # m/s
FIG7_SPEED = 15.0 / 3.6  # 15 km/h
CHIRP_DEG = 5.0  # roll reference amplitude of the identification runs (Fig. 2 shows +-6 deg)
#: Outputs fitted by PEM: Chen & Dao's (roll and steer angle).  ``ident.pem``'s default adds the
#: rates (more robust in closed loop) but is about 15x slower; see docs/reproduce.md.
OUTPUTS = ("phi", "delta")
PREDICTION_HORIZON = 1.0  # s, k-step prediction used when the identified model is unstable


# -- identification runs ---------------------------------------------------------------------
def _spec(controller: str, speeds: Sequence[float], duration: float, bicycle: str):
    from .sweep import SweepSpec

    return SweepSpec(
        controller=controller,
        speeds=tuple(speeds),
        seeds=(0,),
        duration=duration,
        bicycle=bicycle,
        reference="chirp",
        chirp_amplitude=math.radians(CHIRP_DEG),
        dither=1.0,
        dither_hold=0.01,
        sensors="default",
        sample_time=0.01,
    )


def eigen_stderr(theta: np.ndarray, cov: np.ndarray, step: float = 1e-6) -> np.ndarray:
    """Standard errors of Re and Im of the eigenvalues of the canonical A(theta), by first-order
    propagation of the parameter covariance (central differences); shape (4, 2), rows in the
    order of ``np.sort_complex(eig(A(theta)))``."""
    from bikeid.ident.canonical import canonical_ab

    base = np.sort_complex(np.linalg.eigvals(canonical_ab(theta)[0]))
    J = np.zeros((8, theta.size))
    for j in range(theta.size):
        h = step * max(1.0, abs(theta[j]))
        cols = []
        for s in (1, -1):
            th = theta.copy()
            th[j] += s * h
            ev = np.linalg.eigvals(canonical_ab(th)[0])
            _, col = linear_sum_assignment(np.abs(base[:, None] - ev[None, :]))
            cols.append(ev[col])
        d = (cols[0] - cols[1]) / (2 * h)
        J[:, j] = np.concatenate([d.real, d.imag])
    var = np.einsum("ij,jk,ik->i", J, cov, J)
    return np.sqrt(np.maximum(var, 0)).reshape(2, 4).T


def match_eigenvalues(ident: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """``ident`` reordered to pair with ``truth`` (minimum total distance)."""
    ident = np.asarray(ident, complex)
    _, col = linear_sum_assignment(np.abs(np.asarray(truth)[:, None] - ident[None, :]))
    return ident[col]


def identify_speed(args: tuple) -> dict[str, Any]:
    """One identification run: simulate, fit PEM (and the direct method); picklable worker.

    ``args`` = (controller, speed, duration, bicycle, methods).  Returns eigenvalues
    (identified, matched to the truth's order), their standard errors and run facts.
    """
    from bikeid.ident import pem
    from bikeid.sim.linear import eigenvalues
    from bikeid.sim.parameters import by_name

    from .sweep import Task, simulate_task

    controller, speed, duration, bicycle, methods = args
    spec = _spec(controller, [speed], duration, bicycle)
    task = Task(f"{controller}_{speed}", float(speed), 0)
    run = simulate_task(spec, task)
    p = by_name(bicycle)
    truth = np.sort_complex(eigenvalues(p, speed))
    out: dict[str, Any] = {
        "controller": controller,
        "speed": float(speed),
        "fell_at": run.meta.get("fell_at"),
        "seconds": float(run.t[-1]),
        "truth": truth,
        "methods": {},
    }
    if "pem" in methods:
        try:
            m = pem.fit(run, outputs=OUTPUTS)
            ev = np.sort_complex(m.eigenvalues())
            se = eigen_stderr(m.theta, m.covariance)
            _, col = linear_sum_assignment(np.abs(truth[:, None] - ev[None, :]))
            out["methods"]["pem"] = {
                "eig": ev[col],
                "stderr": se[col],
                "theta": m.theta,
                "error": None,
            }
        except (ValueError, np.linalg.LinAlgError) as exc:
            out["methods"]["pem"] = {"error": str(exc)}
    if "direct" in methods:
        from bikeid.ident.direct import identify
        from bikeid.ident.signals import prepare

        try:
            res = identify(prepare(run, derivative="forward"), reference=p)
            out["methods"]["direct"] = {
                "eig": match_eigenvalues(res.eigenvalues(speed), truth),
                "error": None,
            }
        except (ValueError, np.linalg.LinAlgError) as exc:
            out["methods"]["direct"] = {"error": str(exc)}
    return out


def run_jobs(jobs: Sequence[tuple], workers: int = 1) -> list[dict[str, Any]]:
    """:func:`identify_speed` for every job (one process pool for all), in job order."""
    if workers <= 1 or len(jobs) <= 1:
        return [identify_speed(j) for j in jobs]
    with ProcessPoolExecutor(max_workers=workers) as pool:
        return list(pool.map(identify_speed, jobs, chunksize=1))


# -- Fig. 2 / eqs. 5-6 -------------------------------------------------------------------------
def paper_eq5_reading() -> dict[str, Any]:
    """Signs of eq. 5 recovered from the paper's own eq. 6 and poles.

    Every sign pattern of a1..a8, b1, b2 is tried; kept are those whose characteristic
    polynomial and numerators reproduce eq. 6 (relative 1e-3).  Two A patterns survive;
    the one with the sign pattern of the physical model (a3, a4 < 0 < a5, a6, as in every
    Whipple linearization) is taken.  Its b = (+, -): opposite to the Meijaard sign of b
    (b2 = (M^-1)_dd > 0), i.e. the paper's torque (or angles) have the other sign; poles and
    zeros do not depend on that.
    """
    from scipy.signal import ss2tf

    from bikeid.ident.canonical import canonical_ab

    a, b = np.array(PAPER["eq5_abs"]["a"]), np.array(PAPER["eq5_abs"]["b"])
    den = np.array(PAPER["den"])
    nphi, ndel = np.array(PAPER["num_phi_abs"]), np.array(PAPER["num_delta_abs"])
    C = np.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0]])
    found = []
    for s in itertools.product((1.0, -1.0), repeat=10):
        th = np.concatenate([a * s[:8], b * s[8:]])
        A, B = canonical_ab(th)
        cp = np.poly(A)
        if np.max(np.abs(cp - den) / np.abs(den)) > 1e-3:
            continue
        n1 = ss2tf(A, B, C[:1], np.zeros((1, 1)))[0][0][-3:]
        n2 = ss2tf(A, B, C[1:], np.zeros((1, 1)))[0][0][-3:]
        if np.max(np.abs(np.abs(n1) - nphi) / nphi) > 1e-3 or n1[0] < 0:
            continue  # eq. 6 prints G_phi with a positive leading coefficient
        if np.max(np.abs(np.abs(n2) - ndel) / ndel) > 1e-3:
            continue
        found.append((th, cp, n1, n2))
    physical = [f for f in found if f[0][2] < 0 and f[0][3] < 0 and f[0][4] > 0 and f[0][5] > 0]
    th, cp, n1, n2 = physical[0]
    A, _ = canonical_ab(th)
    return {
        "theta": th,
        "candidates": len(found),
        "char_poly": cp,
        "num_phi": n1,
        "num_delta": n2,
        "poles": np.sort_complex(np.linalg.eigvals(A)),
        "zeros_phi": np.sort(np.roots(n1).real),
        "zeros_delta": np.sort(np.roots(n2).real),
        "char_poly_rel_error": float(np.max(np.abs(cp - den) / den)),
    }


def transfer_functions(A: np.ndarray, B: np.ndarray) -> dict[str, Any]:
    """G_phi = phi/T_delta and G_delta = delta/T_delta of a canonical model (python-control
    ``TransferFunction`` plus numerator/denominator coefficients and zeros)."""
    import control

    C = np.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0]])
    sys = control.ss(A, B, C, np.zeros((2, 1)))
    out = {}
    for i, name in enumerate(("phi", "delta")):
        siso = sys[i, 0]
        z = np.sort_complex(control.zeros(siso))
        from scipy.signal import ss2tf

        num, den = ss2tf(A, B, C[i : i + 1], np.zeros((1, 1)))
        num = np.trim_zeros(np.where(np.abs(num[0]) < 1e-9 * np.abs(num[0]).max(), 0, num[0]), "f")
        out[name] = {"tf": control.tf(num, den), "num": num, "den": den, "zeros": z}
    return out


def open_loop_simulation(Ad, Bd, C, u, y) -> tuple[np.ndarray, np.ndarray]:
    """Open-loop simulation driven by ``u`` with the initial state fitted by least squares to
    all of ``y`` (output error is affine in x0).  Returns (y_sim (N, 2), x0)."""
    N = u.size
    xf = np.zeros(4)
    forced = np.empty((N, C.shape[0]))
    Phi = np.empty((N, C.shape[0], 4))
    Ak = np.eye(4)
    for k in range(N):
        forced[k] = C @ xf
        Phi[k] = C @ Ak
        xf = Ad @ xf + Bd[:, 0] * u[k]
        Ak = Ad @ Ak
    x0, *_ = np.linalg.lstsq(Phi.reshape(-1, 4), (y - forced).ravel(), rcond=None)
    return forced + Phi @ x0, x0


def k_step_prediction(Ad, Bd, C, K, u, y, k: int) -> np.ndarray:
    """k-step-ahead prediction: the innovations predictor (a stabilizing observer) estimates
    the state up to t_{j-k}, then the model runs open loop on the measured torque for k
    samples.  The first k samples repeat the one-step prediction.  Returns (N, 2)."""
    N = u.size
    xh = np.zeros((N, 4))
    x = np.zeros(4)
    for j in range(N):
        xh[j] = x
        e = y[j] - C @ x
        x = Ad @ x + Bd[:, 0] * u[j] + K @ e
    pred = (xh @ C.T).copy()
    X = xh[: N - k].copy()
    for i in range(k):
        X = X @ Ad.T + np.outer(u[i : N - k + i], Bd[:, 0])
    pred[k:] = X @ C.T
    return pred


def fig2(p: BicycleParameters, out: Path, duration: float = 50.0) -> dict[str, Any]:
    """Identification at 4.2 m/s: data, model simulation, errors; eqs. 5-6 side by side."""
    from bikeid.ident import pem
    from bikeid.ident.canonical import theta_from_matrices
    from bikeid.sim.linear import canonical_matrices, eigenvalues, transfer_function

    from .plots import plt, save
    from .sweep import Task, simulate_task

    v = FIG2_SPEED
    run = simulate_task(_spec("fuzzy", [v], duration, p.name), Task("fig2", v, 0))
    model = pem.fit(run, outputs=OUTPUTS)
    Ad, Bd, C, K = model.predictor()
    u = run["T_delta"]
    outs = list(model.outputs)
    ya = np.column_stack([run[o] for o in outs])  # every output the model was fitted to
    sel = [outs.index("phi"), outs.index("delta")]
    y = ya[:, sel]
    stable = bool(np.all(model.eigenvalues().real < 0))
    y_ol = open_loop_simulation(Ad, Bd, C, u, ya)[0][:, sel]
    k = int(round(PREDICTION_HORIZON / run.dt))
    y_kp = k_step_prediction(Ad, Bd, C, K, u, ya, k)[:, sel]
    shown = y_ol if stable else y_kp
    how = (
        "open-loop simulation on the measured torque, initial state by least squares"
        if stable
        else f"{PREDICTION_HORIZON:g} s-ahead prediction: the identified model is unstable, so the "
        "state is estimated by the identified innovations predictor (a stabilizing "
        f"observer) up to t - {PREDICTION_HORIZON:g} s and the model then runs open loop on "
        "the measured torque"
    )
    err = y - shown
    fig, ax = plt.subplots(3, 1, figsize=(9, 8), sharex=True)
    ax[0].plot(run.t, u, lw=0.6, color="k", label="steer torque T_delta (incl. dither)")
    ax[0].set_ylabel("torque [N m]")
    ax[1].plot(run.t, np.degrees(y[:, 0]), color="tab:blue", lw=0.8, label="roll angle data")
    ax[1].plot(run.t, np.degrees(y[:, 1]), color="tab:red", lw=0.8, label="steer angle data")
    ax[1].plot(
        run.t,
        np.degrees(shown[:, 0]),
        "--",
        color="tab:cyan",
        lw=0.8,
        label="identified model, roll",
    )
    ax[1].plot(
        run.t,
        np.degrees(shown[:, 1]),
        "--",
        color="tab:orange",
        lw=0.8,
        label="identified model, steer",
    )
    ax[1].set_ylabel("angle [deg]")
    ax[2].plot(run.t, np.degrees(err[:, 0]), color="tab:blue", lw=0.6, label="roll angle error")
    ax[2].plot(run.t, np.degrees(err[:, 1]), color="tab:red", lw=0.6, label="steer angle error")
    ax[2].set_ylabel("error [deg]")
    ax[2].set_xlabel("time [s]")
    for a in ax:
        a.grid(alpha=0.3)
        a.legend(fontsize=7, loc="upper right", ncol=2)
    ax[0].set_title(
        f"Chen & Dao Fig. 2 analogue: identification at {v} m/s (fuzzy control, "
        "chirp + 1 N m dither)\nmodel: "
        + (
            "open-loop simulation"
            if stable
            else f"{PREDICTION_HORIZON:g} s-ahead prediction (identified model unstable)"
        ),
        fontsize=9,
    )
    save(fig, out / "cd_fig2_identification.png")

    cm = canonical_matrices(p)
    th_true = theta_from_matrices(cm, v)
    tfi = transfer_functions(model.A, model.B)
    tft = {n: transfer_function(p, v, n, "T_delta") for n in ("phi", "delta")}
    zt = {n: np.sort_complex(np.roots(np.asarray(tft[n].num[0][0]))) for n in tft}
    paper = paper_eq5_reading()
    rhp_id = [z.real for z in tfi["delta"]["zeros"] if z.real > 0 and abs(z.imag) < 1e-9]
    rhp_true = [z.real for z in zt["delta"] if z.real > 0 and abs(z.imag) < 1e-9]
    ev_true = np.sort_complex(eigenvalues(p, v))
    se = eigen_stderr(model.theta, model.covariance)
    ev_id = np.sort_complex(model.eigenvalues())
    _, col = linear_sum_assignment(np.abs(ev_true[:, None] - ev_id[None, :]))
    return {
        "speed": v,
        "duration": float(run.t[-1]),
        "fell_at": run.meta.get("fell_at"),
        "outputs_fitted": outs,
        "theta_identified": model.theta,
        "theta_stderr": np.sqrt(np.diag(model.covariance)),
        "theta_true": th_true,
        "theta_paper": paper["theta"],
        "paper_reading": {k: paper[k] for k in ("candidates", "char_poly_rel_error")},
        "poles_identified": ev_id[col],
        "poles_stderr": se[col],
        "poles_true": ev_true,
        "poles_paper": paper["poles"],
        "identified_stable": stable,
        "comparison": how,
        "max_error_deg": {
            "phi": float(np.degrees(np.abs(err[:, 0]).max())),
            "delta": float(np.degrees(np.abs(err[:, 1]).max())),
        },
        "max_error_open_loop_deg": {
            "phi": float(np.degrees(np.abs(y[:, 0] - y_ol[:, 0]).max())),
            "delta": float(np.degrees(np.abs(y[:, 1] - y_ol[:, 1]).max())),
        },
        "max_error_paper_deg": PAPER["max_error_deg"],
        **{
            f"G_{n}": {
                "num_identified": tfi[n]["num"],
                "den_identified": tfi[n]["den"],
                "num_true": np.asarray(tft[n].num[0][0]) / tft[n].den[0][0][0],
                "den_true": np.asarray(tft[n].den[0][0]) / tft[n].den[0][0][0],
                "num_paper": paper[f"num_{n}"],
                "den_paper": paper["char_poly"],
                "zeros_identified": tfi[n]["zeros"],
                "zeros_true": zt[n],
                "zeros_paper": paper[f"zeros_{n}"],
            }
            for n in ("phi", "delta")
        },
        "rhp_zero": {
            "identified": rhp_id[0] if rhp_id else None,
            "true": rhp_true[0] if rhp_true else None,
            "paper": float(max(paper["zeros_delta"])),
        },
        "figure": "cd_fig2_identification.png",
        "_model": model,
    }


# -- Fig. 3 ------------------------------------------------------------------------------------
def critical_from_grid(speeds: np.ndarray, eigs: np.ndarray) -> dict[str, float | None]:
    """Critical speeds read off identified eigenvalues on a speed grid (linear interpolation).

    ``eigs[k]`` holds the 4 eigenvalues at ``speeds[k]``.  v_w: lowest speed where the
    largest real part of a complex pair changes sign from + to -; v_c: lowest speed above
    v_w where the largest real eigenvalue of the real ones changes sign from - to + (the
    capsize root); v_d: midpoint between the last grid speed with only real eigenvalues and
    the next speed (None if a complex pair exists at the first speed).
    """
    speeds = np.asarray(speeds, float)
    has_pair = np.array([np.any(np.abs(e.imag) > 1e-9) for e in eigs])
    weave_re = np.array(
        [max((z.real for z in e if abs(z.imag) > 1e-9), default=np.nan) for e in eigs]
    )
    real_max = np.array(
        [max((z.real for z in e if abs(z.imag) <= 1e-9), default=np.nan) for e in eigs]
    )
    out: dict[str, float | None] = {"v_d": None, "v_w": None, "v_c": None}
    if not has_pair[0]:
        idx = np.where(~has_pair)[0]
        k = idx[-1]
        if k + 1 < speeds.size:
            out["v_d"] = float(0.5 * (speeds[k] + speeds[k + 1]))
    for k in range(speeds.size - 1):
        a, b = weave_re[k], weave_re[k + 1]
        if np.isfinite(a) and np.isfinite(b) and a > 0 >= b:
            out["v_w"] = float(speeds[k] + (speeds[k + 1] - speeds[k]) * a / (a - b))
            break
    start = out["v_w"] if out["v_w"] is not None else speeds[0]
    for k in range(speeds.size - 1):
        if speeds[k] < start:
            continue
        a, b = real_max[k], real_max[k + 1]
        if np.isfinite(a) and np.isfinite(b) and a < 0 <= b:
            out["v_c"] = float(speeds[k] + (speeds[k + 1] - speeds[k]) * (-a) / (b - a))
            break
    return out


def fig3(
    p: BicycleParameters,
    grid: list[dict[str, Any]],
    out: Path,
    zoom: list[dict[str, Any]] | None = None,
) -> dict[str, Any]:
    """Identified eigenvalues (PEM) against speed over the true linearization, ranges marked."""
    from bikeid.sim.linear import critical_speeds, eigenvalues_vs_speed

    from .plots import MODE_STYLE, plt, save

    ok = [g for g in grid if g["methods"].get("pem", {}).get("error") is None]
    speeds = np.array([g["speed"] for g in ok])
    eig = np.array([g["methods"]["pem"]["eig"] for g in ok])
    crit_true = critical_speeds(p)
    crit_id = critical_from_grid(speeds, eig)
    fine = np.linspace(min(1.0, speeds.min()), max(15.0, speeds.max()), 600)
    sw = eigenvalues_vs_speed(p, fine)

    def panel(axs, lo, hi, runs_sel, title):
        a1, a2 = axs
        seen = set()
        for j, lab in enumerate(sw.labels):
            c = MODE_STYLE.get(lab, "0.4")
            nm = f"true {lab}" if lab not in seen else None
            seen.add(lab)
            a1.plot(sw.speeds, sw.values[:, j].real, color=c, lw=1.0, label=nm)
            a2.plot(sw.speeds, np.abs(sw.values[:, j].imag), color=c, lw=1.0, label=nm)
        sp = np.array([g["speed"] for g in runs_sel])
        ev = np.array([g["methods"]["pem"]["eig"] for g in runs_sel])
        a1.plot(np.repeat(sp, 4), ev.real.ravel(), "kx", ms=4, label="identified (PEM), real part")
        a2.plot(
            np.repeat(sp, 4),
            np.abs(ev.imag).ravel(),
            "k*",
            ms=4,
            label="identified (PEM), |imag part|",
        )
        for a in (a1, a2):
            a.axhline(0, color="k", lw=0.5)
            a.set_xlim(lo - 0.02 * (hi - lo), hi + 0.02 * (hi - lo))
            a.grid(alpha=0.3)
            for key in ("v_d", "v_w", "v_c"):
                val = crit_true[key]
                if val is not None and lo <= val <= hi:
                    a.axvline(val, color="0.4", ls="--", lw=0.8)
            for val in crit_id.values():
                if val is not None and lo <= val <= hi:
                    a.axvline(val, color="m", ls=":", lw=1.0)
        ymin = max(-40.0, float(np.nanmin(ev.real)) - 2)
        a1.set_ylim(ymin, 8)
        a2.set_ylim(0, max(20.0, float(np.nanmax(np.abs(ev.imag))) + 1))
        for key in ("v_d", "v_w", "v_c"):
            val = crit_true[key]
            if val is not None and lo <= val <= hi:
                a1.annotate(
                    f"{key}={val:.3f}",
                    (val, 8),
                    fontsize=7,
                    ha="left",
                    va="top",
                    rotation=90,
                    color="0.3",
                )
        # ranges A-D of the truth
        edges = [lo] + [crit_true[k] for k in ("v_d", "v_w", "v_c")] + [hi]
        for name, a_, b_ in zip("ABCD", edges[:-1], edges[1:], strict=True):
            a_, b_ = max(a_, lo), min(b_, hi)
            if b_ > a_:
                a2.annotate(
                    name,
                    (0.5 * (a_ + b_), a2.get_ylim()[1] * 0.93),
                    ha="center",
                    fontsize=9,
                    color="0.3",
                )
        a1.set_ylabel("real part [1/s]")
        a2.set_ylabel("|imag part| [rad/s]")
        a2.set_xlabel(
            "speed v [m/s]   (grey dashed: true v_d, v_w, v_c; magenta dotted: identified)"
        )
        a1.set_title(title, fontsize=9)
        a1.legend(fontsize=6, loc="lower left", ncol=2)

    fig, axs = plt.subplots(2, 1, figsize=(9, 7.5), sharex=True)
    panel(
        axs,
        float(min(1.0, speeds.min())),
        float(max(15.0, speeds.max())),
        ok,
        "Chen & Dao Fig. 3(a) analogue: identified eigenvalues vs the true linearization "
        "(benchmark)",
    )
    save(fig, out / "cd_fig3a_eigenvalues.png")
    zoom_ok = [
        g
        for g in (zoom or []) + ok
        if 3.0 - 1e-9 <= g["speed"] <= 4.2 + 1e-9
        and g["methods"].get("pem", {}).get("error") is None
    ]
    if zoom_ok:
        fig, axs = plt.subplots(2, 1, figsize=(9, 7.5), sharex=True)
        panel(axs, 3.0, 4.2, zoom_ok, "Chen & Dao Fig. 3(b) analogue: zoom 3-4.2 m/s")
        axs[0].set_ylim(-16, 4)
        save(fig, out / "cd_fig3b_zoom.png")
    rows = []
    for g in sorted(ok + [z for z in zoom_ok if z not in ok], key=lambda g: g["speed"]):
        rows.append(
            {
                "speed": g["speed"],
                "identified": g["methods"]["pem"]["eig"],
                "stderr": g["methods"]["pem"]["stderr"],
                "true": g["truth"],
                "fell_at": g["fell_at"],
                "seconds": g["seconds"],
            }
        )
    return {
        "critical_true": {k: crit_true[k] for k in ("v_d", "v_w", "v_c")},
        "critical_identified": crit_id,
        "critical_paper": PAPER["critical"],
        "rows": rows,
        "failed": [
            {"speed": g["speed"], "error": g["methods"]["pem"]["error"]}
            for g in grid
            if g["methods"].get("pem", {}).get("error")
        ],
        "figures": ["cd_fig3a_eigenvalues.png"] + (["cd_fig3b_zoom.png"] if zoom_ok else []),
    }


# -- Fig. 7 ------------------------------------------------------------------------------------
def fig7(
    p: BicycleParameters,
    model,
    out: Path,
    duration: float = 50.0,
    poles: Sequence[complex] | None = None,
) -> dict[str, Any]:
    """Roll tracking at 15 km/h by pole placement with the paper's law (eq. 7, T = -K x + kI xi),
    gains placed on the identified model.  The paper does not give its poles; by default two
    poles sit on the identified model's roll zeros and three at -6, -8, -10 1/s
    (``controllers.pole_placement.tracking_poles``), so roll follows the same third-order
    response at every speed and the paper's "delay time" is the only tracking error."""
    from bikeid.controllers.excitation import ChirpReference
    from bikeid.controllers.pole_placement import (
        PolePlacement,
        augmented_system,
        to_bikeid_order,
        tracking_poles,
    )
    from bikeid.dataset.closed_loop import simulate_run
    from bikeid.dataset.sensors import Sensors
    from bikeid.sim.linear import state_matrices

    from .plots import plt, save

    v = FIG7_SPEED
    sys_id = model.state_space()
    if poles is None:
        A_id, B_id = to_bikeid_order(sys_id.A, sys_id.B, "chen_dao")
        poles = tracking_poles(A_id, B_id)
    poles = [complex(z) if abs(complex(z).imag) > 0 else float(complex(z).real) for z in poles]
    ctrl = PolePlacement(
        poles, model=sys_id, state_order="chen_dao", design_speed=v, sample_time=0.01,
        law="chen_dao",
    )  # fmt: skip
    ref = ChirpReference(amplitude=math.radians(15.0), f0=0.02, f1=0.3, duration=duration)
    # noise-free sensors and no dither, as the paper's tracking simulation
    run = simulate_run(p, ctrl, v, duration=duration, reference=ref, sensors=Sensors.ideal())
    g = np.array(ctrl.current_gains(v))
    A, B = state_matrices(p, v)
    Aa, Ba = augmented_system(A, B[:, 1:2])
    Ka = np.concatenate([g[:4], [-g[4]]])[None, :]
    achieved = np.sort_complex(np.linalg.eigvals(Aa - Ba @ Ka))
    phi, r = run.true("phi"), run.reference
    e = r - phi
    fig, ax = plt.subplots(3, 1, figsize=(9, 7.5), sharex=True)
    ax[0].plot(run.t, np.degrees(r), "k--", lw=0.9, label="reference")
    ax[0].plot(run.t, np.degrees(phi), color="tab:blue", lw=0.9, label="response (roll angle)")
    ax[0].plot(run.t, np.degrees(e), color="tab:red", lw=0.7, label="error")
    ax[0].set_ylabel("roll angle [deg]")
    ax[1].plot(run.t, np.degrees(run.true("delta")), color="tab:green", lw=0.8)
    ax[1].set_ylabel("steer angle [deg]")
    ax[2].plot(run.t, run.true("T_delta"), color="k", lw=0.7)
    ax[2].set_ylabel("steer torque [N m]")
    ax[2].set_xlabel("time [s]")
    for a in ax:
        a.grid(alpha=0.3)
    ax[0].legend(fontsize=7, loc="upper left", ncol=3)
    ax[0].set_title(
        f"Chen & Dao Fig. 7 analogue: roll tracking at 15 km/h, nonlinear plant, "
        f"poles {[round(float(np.real(z)), 2) for z in poles]} placed on the model identified at "
        f"{model.speed} m/s",
        fontsize=9,
    )
    save(fig, out / "cd_fig7_tracking.png")
    return {
        "speed": v,
        "poles_requested": list(poles),
        "gains": g,
        "poles_on_true_linearization": achieved,
        "design_model_speed": model.speed,
        "fell_at": run.meta.get("fell_at"),
        "rms_error_deg": float(np.degrees(np.sqrt(np.mean(e**2)))),
        "max_error_deg": float(np.degrees(np.abs(e).max())),
        "max_torque": float(np.abs(run.true("T_delta")).max()),
        "max_steer_deg": float(np.degrees(np.abs(run.true("delta")).max())),
        "reference": ref.describe(),
        "figure": "cd_fig7_tracking.png",
    }


def limit_cycle_study(
    p: BicycleParameters, out: Path, duration: float, log: Callable[[str], None] = lambda s: None
) -> dict[str, Any]:
    """Figs. 4-5: coasting runs from the paper's initial conditions + periodicity check."""
    from bikeid.sim.linear import critical_speeds, eigenvalues

    from . import limit_cycles as lc

    res: dict[str, Any] = {"speed": lc.SPEED, "duration": duration, "figures": []}
    for name, conds in (("fig4", lc.FIG4_CONDITIONS), ("fig5", lc.FIG5_CONDITIONS)):
        trajs = [lc.coast(p, ic, duration) for ic in conds]
        labels = [ic.label for ic in conds]
        res[name] = [
            lc.periodicity(tr, ic.label).as_dict() for tr, ic in zip(trajs, conds, strict=True)
        ]
        lc.plot_phase_portraits(
            trajs,
            labels,
            out / f"cd_{name}_phase.png",
            f"Chen & Dao {name[:3].title()}. {name[3]} analogue: coasting at "
            f"3.5 m/s, no steer torque, {duration:g} s (benchmark)",
        )
        lc.plot_energy_speed(
            trajs,
            labels,
            out / f"cd_{name}_energy_speed.png",
            f"{name[:3].title()}. {name[3]} runs: energy conservation and speed",
        )
        res["figures"] += [f"cd_{name}_phase.png", f"cd_{name}_energy_speed.png"]
        log(f"  {name}: " + ", ".join(f"{r['label']}: {r['verdict']}" for r in res[name]))
    ev = np.sort_complex(eigenvalues(p, lc.SPEED))
    res["linear_eigenvalues"] = ev
    res["critical_true"] = {k: critical_speeds(p)[k] for k in ("v_d", "v_w", "v_c")}
    return res
