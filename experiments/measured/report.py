"""``bikeid measured report``: report.md with before/after figures on the measured data.

Figures: free-decay overlays (measured, nominal, augmented), weave eigenvalue against
speed (fitted to the decays, nominal, augmented), and the Bode response at 4 m/s
(measured gain/phase per file at its excitation frequency against both models).
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from bikeid.dataset.decays import load_decays
from bikeid.dataset.files import atomic_write_text
from bikeid.dataset.sbw_logs import SPEED_CALIBRATION, data_dir, find_logs, load_log
from bikeid.dataset.windows import bode_window
from bikeid.experiments.plots import phases_on_one_branch, points_on_branch, save
from bikeid.ident.effects.before_after import verdict_text
from bikeid.ident.effects.experiment_model import ExperimentModel, with_nonlinear_correction
from bikeid.ident.effects.pipeline import DEFAULT_PLANT, evaluate_json, fit_model, model_from_json
from bikeid.ident.effects.weave import decay_eigenvalue
from bikeid.sim.textformats import dump_json


def sine_fit(y: np.ndarray, u: np.ndarray, freq: float, dt: float = 0.01) -> complex:
    """Complex ratio Y/U at ``freq`` [Hz] from least-squares sinusoid fits (with offset).

    Parameters
    ----------
    y, u : ndarray
        Output and input, sampled every ``dt`` [s].
    freq : float
        Frequency [Hz].
    dt : float, optional
        Sample time [s].

    Returns
    -------
    complex
        Y/U [unit of y per unit of u]; nan when u has no component at ``freq``.
    """
    t = np.arange(y.size) * dt
    basis = np.column_stack(
        [np.cos(2 * math.pi * freq * t), np.sin(2 * math.pi * freq * t), np.ones_like(t)]
    )
    cy, *_ = np.linalg.lstsq(basis, y, rcond=None)
    cu, *_ = np.linalg.lstsq(basis, u, rcond=None)
    cu_ = complex(cu[0], -cu[1])
    if abs(cu_) < 1e-6:
        return complex(np.nan, np.nan)  # no excitation at this frequency
    return complex(cy[0], -cy[1]) / cu_


def _asymmetry_lines(s: dict) -> list[str]:
    """Push-direction asymmetry of the error
    (``bikeid.ident.effects.diagnostics.push_asymmetry``)."""
    out = []
    for when in ("before", "after"):
        a = s.get(f"push_asymmetry_{when}")
        if a:
            out.append(
                f"Error by push direction, {when}: right {a['error_right']:.3f} "
                f"({a['n_right']} decays), left {a['error_left']:.3f} ({a['n_left']}), "
                f"ratio {a['ratio']:.2f}, Mann-Whitney p = {a['p_value']:.3g}."
            )
    if out:
        out.append(
            "(The model is mirror-symmetric; a difference between the directions points to a "
            "symmetry-breaking term: a sensor zero offset or a constant torque.)"
        )
    return out


def bode_points(root: str | Path) -> list[dict]:
    """Measured closed-loop response T_ext -> (roll rate, steer angle), one per Bode file.

    Parameters
    ----------
    root : str or Path
        Folder with ``bode*`` logs.

    Returns
    -------
    list of dict
        ``file``, ``freq`` [Hz], ``v_sensor`` [m/s] and the complex responses ``phidot``
        [rad/s per N m] and ``delta`` [rad per N m] at the file's frequency.
    """

    out = []
    for p in find_logs(root, "bode"):
        w = bode_window(load_log(p))
        if not abs(sine_fit(w.T_ext, w.T_ext, w.freq) - 1) < 1e-9:
            continue  # T_ext carries no component at the file's frequency
        out.append(
            {"file": p.name, "freq": w.freq, "v_sensor": float(np.mean(w.v_sensor)),
             "phidot": sine_fit(w.phidot, w.T_ext, w.freq),
             "delta": sine_fit(w.delta, w.T_ext, w.freq)}
        )  # fmt: skip
    return out


def write_report(out: str | Path, data: str | None, model_path: str | None) -> Path:
    """Write report.md, report.json and the figures into ``out``.

    Parameters
    ----------
    out : str or Path
        Output folder (created).
    data : str or None
        Data folder (None: ``$BIKEID_DATA``).
    model_path : str or None
        A model file of ``measured fit`` (None: fit on every other speed first).

    Returns
    -------
    Path
        The report.md written.
    """

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    allw = load_decays(data)
    speeds = sorted({round(w.speed, 1) for w in allw})
    if model_path:
        _, obj = model_from_json(model_path)
    else:
        fit_s = speeds[0::2]
        obj = fit_model([w for w in allw if round(w.speed, 1) in fit_s])
    held = [w for w in allw if round(w.speed, 2) not in obj.get("fit_speeds", [])] or allw
    ev = evaluate_json(obj, held)
    nom, aug = ExperimentModel(), ExperimentModel(effects=dict(obj["effects"]))

    # 1. decay overlays: first window of each speed
    firsts = [next(w for w in allw if round(w.speed, 1) == s) for s in speeds]
    fig, axes = plt.subplots(2, len(firsts), figsize=(3.2 * len(firsts), 5), squeeze=False,
                             layout="constrained")  # fmt: skip
    nonlinear = obj.get("plant", DEFAULT_PLANT) == "nonlinear"  # as measured fit
    firsts = [replace(w, correction=None) for w in firsts]
    s0 = nom.simulate(with_nonlinear_correction(firsts, nom) if nonlinear else firsts)
    s1 = aug.simulate(with_nonlinear_correction(firsts, aug) if nonlinear else firsts)
    for j, w in enumerate(firsts):
        t = np.arange(w.n) * 0.01
        for i, (c, lab) in enumerate((("phidot", "roll rate [deg/s]"), ("delta", "steer [deg]"))):
            ax = axes[i, j]  # bikeid's own logs: degrees in plots
            ax.plot(t, np.degrees(getattr(w, c)), "k", lw=1.2, label="measured")
            ax.plot(t, np.degrees(s0[j][c]), "tab:red", ls="--", label="nominal")
            ax.plot(t, np.degrees(s1[j][c]), "tab:blue", label="augmented")
            ax.set_ylabel(lab) if j == 0 else None
            ax.set_title(f"{w.speed:.2f} m/s") if i == 0 else ax.set_xlabel("t [s]")
    axes[0, 0].legend(fontsize=7)
    save(fig, out / "decays.png")

    # 2. weave eigenvalue against speed
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(6, 6), sharex=True, layout="constrained")
    vv = np.linspace(min(w.speed for w in allw) - 0.2, max(w.speed for w in allw) + 0.2, 40)
    a_cal, b_cal = SPEED_CALIBRATION
    vsens = a_cal * vv + b_cal
    for mdl, col, lab in ((nom, "tab:red", "nominal"), (aug, "tab:blue", "augmented")):
        # every oscillatory root of the sampled loop: below ~1.8 m/s the loop has two
        # oscillatory pairs, and the measured decays follow the faster one
        for k, (v, vs) in enumerate(zip(vv, vsens, strict=True)):
            lam = mdl.oscillatory_roots(vs)
            kw = {"label": lab} if k == 0 else {}
            a1.plot(np.full(lam.size, v), lam.real, ".", color=col, ms=3, **kw)
            a2.plot(np.full(lam.size, v), lam.imag, ".", color=col, ms=3)
    for w in allw:
        lam = decay_eigenvalue(w)
        a1.plot(w.speed, lam.real, "kx", ms=4)
        a2.plot(w.speed, lam.imag, "kx", ms=4)
    a1.plot([], [], "kx", label="measured decays")
    a1.set_ylabel("oscillatory roots: real part [1/s]")
    a2.set_ylabel("frequency [rad/s]")
    a2.set_xlabel("treadmill speed [m/s]")
    a1.legend()
    save(fig, out / "eigenvalues.png")

    # 3. Bode at 4 m/s
    root = data_dir(data)
    pts = bode_points(root)
    bode_rows = []
    if pts:
        vs = float(np.median([p["v_sensor"] for p in pts]))
        ff = np.linspace(0.8, 3.2, 100)
        fig, axes = plt.subplots(2, 2, figsize=(9, 6), sharex=True, layout="constrained")
        for j, c in enumerate(("phidot", "delta")):
            curves = [(mdl, col, lab, mdl.frequency_response(vs, ff)[:, j])
                      for mdl, col, lab in ((nom, "tab:red", "nominal"),
                                            (aug, "tab:blue", "augmented"))]  # fmt: skip
            # both models' phases on one branch, the measured points on the nominal's
            phases = phases_on_one_branch([(ff, H) for *_, H in curves])
            for (_, col, lab, H), ph in zip(curves, phases, strict=True):
                axes[0, j].plot(ff, 20 * np.log10(np.abs(H)), col, label=lab)
                axes[1, j].plot(ff, ph, col)
            fm = np.array([p["freq"] for p in pts])
            Hm = np.array([p[c] for p in pts])
            axes[0, j].plot(fm, 20 * np.log10(np.abs(Hm)), "ko", ms=4, label="measured")
            axes[1, j].plot(fm, points_on_branch(fm, Hm, ff, phases[0]), "ko", ms=4)
            axes[0, j].set_title(f"T_ext -> {c}")
            axes[1, j].set_xlabel("frequency [Hz]")
        axes[0, 0].set_ylabel("gain [dB]")
        axes[1, 0].set_ylabel("phase [deg]")
        axes[0, 0].legend(fontsize=7)
        save(fig, out / "bode.png")
        for p in pts:
            r = {"file": p["file"], "freq": p["freq"]}
            for lab, mdl in (("nominal", nom), ("augmented", aug)):
                H = mdl.frequency_response(p["v_sensor"], [p["freq"]])[0]
                r[lab] = float(np.mean([abs(H[j] - p[c]) / abs(p[c])
                                        for j, c in enumerate(("phidot", "delta"))]))  # fmt: skip
            bode_rows.append(r)

    s = ev["summary"]
    lines = [
        "# Steer-by-wire bicycle: nominal vs augmented experiment model", "",
        f"Fit speeds: {obj.get('fit_speeds')} m/s; evaluated on the others (held out).", "",
        f"Verdict: {obj.get('identification', {}).get('verdict')}; nominal plant: "
        f"{obj.get('plant', 'linear')}.", "",
        "| effect | value | std | unit |", "|---|---|---|---|",
        *[f"| {e['name']} | {e['value']:.4g} | {_fmt(e['std'])} | {e['unit']} |"
          for e in ev["effects"]],
        "", f"Metric: {ev['metric']}.", "",
        "| file | speed [m/s] | error before | error after | weave err before | after |",
        "|---|---|---|---|---|---|",
        *[f"| {f['file']} | {f['speed']:.2f} | {f['error_before']:.3f} | {f['error_after']:.3f} | "
          f"{f['weave_error_before']:.3f} | {f['weave_error_after']:.3f} |" for f in ev["files"]],
        "", f"Summary: error {s['error_before']:.3f} -> {s['error_after']:.3f} "
        f"(ratio {s['ratio']:.2f}); weave {s['weave_error_before']:.3f} -> "
        f"{s['weave_error_after']:.3f} (the measured weave itself is uncertain by "
        f"{s['weave_data_rel_std']:.3f}, bootstrap over the decays).", "",
        f"Before/after with its interval: {verdict_text(s)} "
        f"({s['interval']}).", "",
        *_asymmetry_lines(s), "",
        "![free decays](decays.png)", "", "![weave eigenvalue](eigenvalues.png)", "",
    ]  # fmt: skip
    if bode_rows:
        e0 = np.mean([r["nominal"] for r in bode_rows])
        e1 = np.mean([r["augmented"] for r in bode_rows])
        lines += [
            f"Bode at 4 m/s: mean relative complex error of T_ext -> (roll rate, steer) "
            f"{e0:.3f} (nominal) -> {e1:.3f} (augmented), {len(bode_rows)} files.", "",
            "![Bode at 4 m/s](bode.png)", "",
        ]  # fmt: skip
    atomic_write_text(out / "report.json", dump_json({"evaluation": ev, "bode": bode_rows}) + "\n")
    path = out / "report.md"
    atomic_write_text(path, "\n".join(lines) + "\n")
    return path


def _fmt(x) -> str:
    return "-" if x is None else f"{x:.3g}"
