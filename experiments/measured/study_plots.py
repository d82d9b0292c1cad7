"""Report of ``bikeid measured study``: Markdown tables in Moore & Hubbard's layout and figures.

:func:`write_study` writes ``report.md`` (runs x models tables of the equation VAF, simulation
VAF and decay error per split; identified entries beside the Whipple values with standard
errors, their Table 5; the grey-box conditioning; the effect translation), ``study.json``
and two PNG figures: eigenvalues against speed of every model with the measured weave of the
free decays (their Figs. 2-3) and the models' frequency responses beside the one measured in
the Bode runs (their Fig. 4).  Files are written atomically (:mod:`bikeid.dataset.files`).
"""

from __future__ import annotations

import math
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from bikeid.dataset.files import atomic_write_text
from bikeid.dataset.sbw_logs import SPEED_CALIBRATION
from bikeid.experiments.measured.study import MODEL_ORDER, Z_SIGNIFICANT
from bikeid.experiments.plots import display_scale, phases_on_one_branch, points_on_branch, save
from bikeid.ident.direct import parse_entry
from bikeid.ident.effects.before_after import verdict_text
from bikeid.sim.linear import canonical_matrices
from bikeid.sim.parameters import steer_by_wire
from bikeid.sim.textformats import dump_json

__all__ = ["closed_loop_weave", "headline", "write_study"]

#: The steer-into-lean law of the logs: T = K (V - v_sensor) phidot (data README).
LAW_K, LAW_V = 2.0, 6.5


def _f(x: float, fmt: str = ".3f") -> str:
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "n/a"
    if isinstance(x, float) and (math.isinf(x) or abs(x) >= 1e4):
        return "< -1e4" if x < 0 else "> 1e4"
    return format(x, fmt)


def closed_loop_weave(A: np.ndarray, b: np.ndarray, v: float) -> complex:
    """Weave eigenvalue of a plant closed by the logs' steer-into-lean law at treadmill speed v.

    Continuous, without the loop's sample delay: A + b K (V - v_sensor) e_phidot', with
    v_sensor from the source's calibration (:data:`bikeid.dataset.sbw_logs.SPEED_CALIBRATION`).

    Parameters
    ----------
    A : (4, 4) ndarray
        Plant state matrix, states [phi, delta, phidot, deltadot].
    b : (4,) ndarray
        Steer-torque column [per N m].
    v : float
        Treadmill speed [m/s].

    Returns
    -------
    complex
        The closed-loop eigenvalue with the largest imaginary part [1/s] (nan if none is
        oscillatory).
    """
    a, c = SPEED_CALIBRATION
    vs = a * v + c
    Acl = A + np.outer(b, [0.0, 0.0, LAW_K * (LAW_V - vs), 0.0])
    lam = np.linalg.eigvals(Acl)
    osc = lam[lam.imag > 1e-6]
    return complex(osc[np.argmax(osc.imag)]) if osc.size else complex(np.nan, np.nan)


def headline(study: dict) -> dict:
    """Which model predicts the held-out free decays best, per split (median decay error).

    Parameters
    ----------
    study : dict
        :func:`bikeid.experiments.measured.study.run_study`'s result.

    Returns
    -------
    dict
        Per split tag (e.g. ``"2.5+4.5"``): per model the median over held-out runs of the
        decay error, the best model and its ratio to the Whipple model's.
    """
    out = {}
    for s in study["splits"]:
        tag = "+".join(f"{v:g}" for v in s["fit_speeds"])
        med = {}
        for m in MODEL_ORDER:
            vals = [r[m]["decay_nrmse"] for r in s["runs"].values()
                    if m in r and "decay_nrmse" in r[m]]  # (not for undetermined models)
            if vals:
                med[m] = float(np.median(vals))
        finite = {k: v for k, v in med.items() if math.isfinite(v)}
        best = min(finite, key=finite.get)
        out[tag] = {"median_decay_nrmse": med, "best": best,
                    "ratio_to_whipple": finite[best] / med["whipple"]}  # fmt: skip
    return out


def _runs_table(rows: dict, models: list[str], key) -> list[str]:
    lines = ["| run (speed) | " + " | ".join(models) + " |",
             "|---|" + "---|" * len(models)]  # fmt: skip
    for f, r in rows.items():
        cells = [("logs cannot determine it" if "undetermined" in r[m] else _f(key(r[m])))
                 if m in r else "-" for m in models]  # fmt: skip
        lines.append(f"| {f} ({r['speed']:g} m/s) | " + " | ".join(cells) + " |")
    return lines


def _entries_table(split: dict) -> list[str]:
    w = canonical_matrices(steer_by_wire())

    names = list(dict.fromkeys([*split["models"]["direct"]["free"],
                                *split["models"]["greybox"]["free"]]))  # fmt: skip
    lines = ["| entry | Whipple | direct (+- se) | z | grey-box (+- se) | z |",
             "|---|---|---|---|---|---|"]  # fmt: skip
    for n in names:
        m, i, j = parse_entry(n)
        wv = float(getattr(w, m)[i, j])
        cells = [n, _f(wv, ".4g")]
        for mod in ("direct", "greybox"):
            fr, se = split["models"][mod]["free"], split["models"][mod]["stderr"]
            if n in fr:
                z = (fr[n] - wv) / se[n]
                cells += [f"{fr[n]:.4g} +- {se[n]:.2g}", f"{z:+.1f}"]
            else:
                cells += ["fixed", ""]
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def _translation_lines(split: dict) -> list[str]:
    lib = set(split["models"]["effects"]["info"]["effects"])
    lines = []
    for mod, t in split["translation"].items():
        sig = t["significant"]
        lines.append(f"- **{mod}**: {len(sig)} of {len(t['deviations'])} entries with |z| > "
                     f"{Z_SIGNIFICANT:g} ({', '.join(sig) or 'none'}).")  # fmt: skip
        if not sig:
            lines.append("  No significant deviation: nothing to translate.")
            continue
        if t["effects"]:
            parts = [f"{n} {e['value']:.3g} +- {e['stderr']:.2g}"
                     + ("" if e["in_range"] else f" (outside plausible {e['plausible']})")
                     for n, e in t["effects"].items()]  # fmt: skip
            lines.append(f"  Effects fitted to the deviations: {'; '.join(parts)}; chi-square "
                         f"{t['chi2_before']:.3g} -> {t['chi2_after']:.3g} "
                         f"({len(t['deviations'])} entries).")  # fmt: skip
        else:
            lines.append("  No library effect lowers the chi-square significantly.")
        if t["unexplained"]:
            lines.append(f"  Still away from the fit (|z| > 3): {', '.join(t['unexplained'])}.")
        got = set(t["effects"])
        agree = sorted(got & lib)
        implausible = [n for n, e in t["effects"].items() if not e["in_range"]]
        verdict = (f"agrees with the effect library on {', '.join(agree)}" if agree
                   else "shares no effect with the effect library's selection "
                   f"({', '.join(sorted(lib))})")  # fmt: skip
        lines.append(f"  Compared with `measured fit`: the translation {verdict}"
                     + (f"; it needs implausible amounts of {', '.join(implausible)}"
                        if implausible else "") + ".")  # fmt: skip
    lines.append(
        "  What would decide it: the translation and the library read different data (the "
        "identified matrices vs the free-decay signals with the loop) and the matrices are "
        "fitted without the sensor, bias and delay terms the library also offers; an "
        "independent measurement of the steer assembly (bicycle lifted, a torque chirp on "
        "the fork motor: damping, stiffness, inertia) fixes the steer-row entries, after "
        "which the remaining deviations are attributable."
    )
    return lines


def _decay_direct_line(dd: dict) -> str:
    """The direct method on the decay windows: each entry with its z against Whipple."""

    w = canonical_matrices(steer_by_wire())
    parts = []
    for n, v in dd["free"].items():
        m, i, j = parse_entry(n)
        z = (v - float(getattr(w, m)[i, j])) / dd["stderr"][n]
        parts.append(f"{n} {v:.3g} +- {dd['stderr'][n]:.2g} (z {z:+.1f})")
    return (
        "Direct method on the free-decay windows only (no push inside): " + ", ".join(parts) + "."
    )


def _before_after_line(ba: dict | None) -> str:
    """The split's held-out decay error, Whipple -> Whipple + effects, with its interval."""
    if not ba:
        return ""
    if "undefined" in ba:
        return f"Held-out decay error before/after the effects: undefined ({ba['undefined']})."
    return ("Held-out decay error, Whipple -> Whipple + effects (mean over files, "
            f"{ba['decays']} decays): {verdict_text(ba)}; {ba['interval']}.")


def write_study(study: dict, out: str | Path) -> Path:
    """Write ``report.md``, ``study.json`` and the figures of a study into ``out``.

    Parameters
    ----------
    study : dict
        :func:`bikeid.experiments.measured.study.run_study`'s result (with ``_models``).
    out : str or Path
        Output folder (created).

    Returns
    -------
    Path
        The ``report.md`` written.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    figs = []
    figs.append(_eigen_figure(study, out / "eigenvalues_vs_speed.png"))
    if study.get("bode", {}).get("frf"):
        figs.append(_bode_figure(study["bode"]["frf"], out / "bode_4mps.png"))
    head = headline(study)
    js = {k: v for k, v in study.items() if k != "_models"}
    js["headline"] = head
    atomic_write_text(out / "study.json", dump_json(js) + "\n")
    L = ["# Moore & Hubbard's study on the real steer-by-wire bicycle", "",
         f"Data: `{study['data']}`; eigen runs at {study['speeds']} m/s. Command: "
         "`bikeid measured study`.", ""]  # fmt: skip
    for k, v in study["definitions"].items():
        L.append(f"- **{k}**: {v}")
    L.append("")
    for s in study["splits"]:
        tag = "+".join(f"{v:g}" for v in s["fit_speeds"])
        h = head[tag]
        models = [m for m in MODEL_ORDER if any(m in r for r in s["runs"].values())]
        L += [f"## Split: fit {tag} m/s, held out {s['held_out_speeds']} m/s", "",
              f"Effects model: {s['effects_source']}: "
              + ", ".join(f"{n} {v:g}" for n, v in
                          s["models"]["effects"]["info"]["effects"].items()) + ".",
              f"Best on the held-out decays (median decay error): **{h['best']}**, "
              f"{h['ratio_to_whipple']:.2f} x the Whipple model's "
              f"({', '.join(f'{m} {v:.3g}' for m, v in h['median_decay_nrmse'].items())}).",
              _before_after_line(s.get("before_after")),
              "", "Equation VAF, steer row (Tables 2-3 analogue):", ""]  # fmt: skip
        L += _runs_table(s["runs"], models, lambda r: r["equation_vaf"]["steer"])
        L += ["", "Equation VAF, roll row:", ""]
        L += _runs_table(s["runs"], models, lambda r: r["equation_vaf"]["roll"])
        L += ["", "Simulation VAF, mean of phi, delta, phidot, deltadot (Table 4 analogue):", ""]
        L += _runs_table(s["runs"], models, lambda r: r["simulation_vaf"]["mean"])
        L += ["", "Decay error (NRMSE, logged command replayed; lower is better):", ""]
        L += _runs_table(s["runs"], models, lambda r: r["decay_nrmse"])
        gi = s["models"]["greybox"]["info"]
        di = s["models"]["direct"]["info"]
        L += ["", "Identified entries beside the Whipple values (Table 5 analogue):", ""]
        L += _entries_table(s)
        L += ["", f"Conditioning on this data set: grey-box (Moore & Hubbard's free set) "
              f"condition number {gi['condition']:.3g}, dropped {gi['dropped'] or 'none'}, "
              "largest inflation "
              + ", ".join(f"{k} {v:.2g}" for k, v in
                          sorted(gi["inflation"].items(), key=lambda kv: -kv[1])[:3])
              + f"; direct regression condition numbers roll {di['condition']['roll']:.3g}, "
              f"steer {di['condition']['steer']:.3g}.", "",
              "Effect translation of the significant deviations:", ""]  # fmt: skip
        L[-2:-2] = [_decay_direct_line(s["direct_decays"]), ""]
        L += _translation_lines(s)
        L.append("")
    b = study.get("bode")
    if b and "runs" in b:
        models = b["models"]
        L += [
            "## Bode runs at 4 m/s",
            "",
            f"Canonical PEM fitted on {len(b['fit_files'])} runs (even-numbered); the speed "
            "models ([0] = fit 2.5+4.5, [1] = fit 1.5+3.5 m/s) were fitted on the eigen runs, "
            "so 4 m/s is held out for all. Simulation VAF (mean of 4 outputs):",
            "",
        ]
        L += _runs_table(b["runs"], models, lambda r: r["simulation_vaf"]["mean"])
        g4 = b["greybox_4mps"]["info"]
        L += ["", f"Conditioning of Moore & Hubbard's free set on the 4 m/s runs (one speed): "
              f"dropped {', '.join(g4['dropped']) or 'none'} (fixed at Whipple), condition "
              f"number {g4['condition']:.3g} after dropping."]  # fmt: skip
        L += ["", "Equation VAF, steer row:", ""]
        L += _runs_table(b["runs"], models, lambda r: r["equation_vaf"]["steer"])
        L.append("")
        fr = b["frf"]
        L += ["Frequency response T_delta -> (phi, delta) measured in the Bode runs (one point "
              "per run at its excitation frequency, T_ext as the reference): median relative "
              "complex error |H_model - H| / |H| per model:", "",
              "| model | phi | delta |", "|---|---|---|"]  # fmt: skip
        for n, m in fr["models"].items():
            e = m.get("median_rel_error", {})
            L.append(f"| {n} | {_f(e.get('phi', math.nan))} | {_f(e.get('delta', math.nan))} |")
        L.append("")
    sc = study.get("signal_consistency", {})
    if sc:
        L += [
            "## Sensor consistency (eigen runs)",
            "",
            "Differentiated angle against the measured rate: shift maximizing the "
            "cross-correlation [samples of 0.01 s; positive = the angle lags] and gain.",
            "",
            "| run | roll lag | roll gain | steer lag | steer gain |",
            "|---|---|---|---|---|",
        ]
        for f, c in sc.items():
            L.append(
                f"| {f} | {c['roll']['lag']} | {c['roll']['gain']:.3f} | "
                f"{c['steer']['lag']} | {c['steer']['gain']:.3f} |"
            )
        L.append("")
    L += ["## Figures", ""] + [f"![{p.stem}]({p.name})" for p in figs]
    path = out / "report.md"
    atomic_write_text(path, "\n".join(L) + "\n")
    return path


def _speed_models(study: dict) -> dict:
    sm = study["_models"]["splits"]
    out = {"whipple": sm[0]["whipple"]}
    for k, ms in enumerate(sm):
        tag = "+".join(f"{v:g}" for v in study["splits"][k]["fit_speeds"])
        for n in ("effects", "direct", "greybox"):
            out[f"{n} ({tag})"] = ms[n]
    return out


def _eigen_figure(study: dict, path: Path) -> Path:
    v = np.linspace(0.5, 6.0, 111)
    fig, ax = plt.subplots(1, 3, figsize=(15, 4.5), layout="constrained")
    for i, (name, m) in enumerate(_speed_models(study).items()):
        lam = np.array([np.linalg.eigvals(m.ab(x)[0]) for x in v])
        col = f"C{i}"
        ax[0].plot(v, lam.real, ".", ms=2, color=col)
        ax[0].plot([], [], ".", color=col, label=name)
        ax[1].plot(v, np.abs(lam.imag), ".", ms=2, color=col)
        w = np.array([closed_loop_weave(*m.ab(x), x) for x in v])
        ax[2].plot(v, w.real, "-", color=col)
        ax[2].plot(v, w.imag, "--", color=col)
    for k, m in study["_models"]["pem"].items():
        lam = np.linalg.eigvals(m.ab(k)[0])
        ax[0].plot([k] * 4, lam.real, "kx")
        ax[1].plot([k] * 4, np.abs(lam.imag), "kx")
        w = closed_loop_weave(*m.ab(k), k)
        ax[2].plot([k, k], [w.real, w.imag], "kx")
    ax[0].plot([], [], "kx", label="canonical PEM per speed")
    for wv in study["weave"].values():
        lam, u = complex(wv["eigenvalue"]), wv["rel_uncertainty"] * abs(complex(wv["eigenvalue"]))
        u = 0.0 if not math.isfinite(u) else u
        ax[2].errorbar([wv["speed"]] * 2, [lam.real, lam.imag], yerr=u, fmt="ko", mfc="none")
    ax[2].plot([], [], "ko", mfc="none", label="measured weave (free decays)")
    ax[0].set(xlabel="speed [m/s]", ylabel="Re(eigenvalue) [1/s]", title="open loop: real parts",
              ylim=(-15, 10))  # fmt: skip
    ax[1].set(xlabel="speed [m/s]", ylabel="|Im(eigenvalue)| [rad/s]", title="open loop: imag")
    ax[2].set(xlabel="speed [m/s]", ylabel="[1/s] (solid Re, dashed Im)",
              title="closed loop (steer-into-lean, no delay): weave")  # fmt: skip
    ax[0].legend(fontsize=6)
    ax[2].legend(fontsize=7)
    for a in ax:
        a.grid(True, alpha=0.3)
    return save(fig, path)


def _bode_figure(frf: dict, path: Path) -> Path:
    """Models' and measured Bode plots (degrees; phases on the first model curve's branch)."""
    outs = list(frf["outputs"])
    fig, ax = plt.subplots(2, len(outs), figsize=(6 * len(outs), 6), squeeze=False,
                           layout="constrained")  # fmt: skip
    for j, o in enumerate(outs):
        scale, unit = display_scale(o)  # bikeid's own logs: degrees in plots
        drawn = [(i, n, m) for i, (n, m) in enumerate(frf["models"].items()) if o in m]
        # every model curve on the first one's branch (they agree at the lowest frequency)
        phases = phases_on_one_branch([(m["f"], np.asarray(m[o])) for _, _, m in drawn])
        for (i, n, m), ph in zip(drawn, phases, strict=True):
            ax[0, j].loglog(m["f"], scale * np.abs(np.asarray(m[o])), color=f"C{i}", label=n)
            ax[1, j].semilogx(m["f"], ph, color=f"C{i}")
        e = frf["outputs"][o]
        if len(e["f"]):
            H = np.asarray(e["H"])
            ax[0, j].errorbar(e["f"], scale * np.abs(H),
                              yerr=scale * np.abs(H) * np.asarray(e["rel_error"]),
                              fmt="ko", ms=3, label="measured (Bode runs)")  # fmt: skip
            ph_e = (points_on_branch(e["f"], H, drawn[0][2]["f"], phases[0]) if drawn
                    else np.degrees(np.angle(H)))  # fmt: skip
            ax[1, j].plot(e["f"], ph_e, "ko", ms=3)
        ax[0, j].set(title=f"T_delta -> {o} at {frf['speed']:g} m/s",
                     ylabel=f"|H| [{unit}/(N m)]")  # fmt: skip
        ax[1, j].set(xlabel="frequency [Hz]", ylabel="phase [deg]")
    ax[0, 0].legend(fontsize=6)
    return save(fig, path)
