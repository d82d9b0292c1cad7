"""Fit fixed sets of library effects to the measured decays and report held-out errors.

The pipeline (``bikeid measured fit``) *chooses* effects; this script answers the
complementary question "how well would this set of effects do?", for the comparison
tables of docs/measured.md.  Each set is fitted jointly (output error, nonlinear nominal
by defect correction re-attached at the fitted model twice, as in the pipeline's final
fit) on the decays of the fit speeds and evaluated on the other speeds with the same
metrics as ``bikeid measured evaluate``.  Any experiment-model effect can be named, also those
kept out of the library (``tire_twist_stiffness``, ``roll_stiffness``, ...).  ``--per-file``
instead fits each set to each file alone (the spread of the values across speeds tests
whether an effect is a constant) and reports the in-sample weave error of that fit against
the weave's measurement uncertainty (can the set reproduce this speed's weave at all?).

    python benchmarks/measured_effect_sets.py --data ../shared/data \\
        --sets "steer_viscous_damping;steer_viscous_damping,steer_stiffness,steer_angle_bias"
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from bikeid.dataset.decays import load_decays
from bikeid.ident.effects.diagnostics import evaluate
from bikeid.ident.effects.experiment_model import ExperimentModel
from bikeid.ident.effects.pipeline import fit_effect_set
from bikeid.sim.effect_registry import EFFECTS


def lean_check(windows, data: str) -> None:
    """Per speed: the logged lean angle (Kalman estimate) against the integrated roll rate
    (gyro) in each decay, phi[k] ~ g * int(phidot)[k + s] + a + b t; median g and shift s.
    Then per log the means over the whole file (straight running between pushes): steer
    angle, lean angle, lean rate and steer command."""
    from scipy.integrate import cumulative_trapezoid

    from bikeid.dataset.decays import iter_decays
    from bikeid.dataset.sbw_logs import data_dir

    rows = []
    for w in windows:
        ip = cumulative_trapezoid(w.phidot, dx=0.01, initial=0.0)
        t = np.arange(w.n) * 0.01
        best = None
        for sh in range(-15, 16):
            k0, k1 = max(0, -sh), min(w.n, w.n - sh)
            A = np.c_[ip[k0 + sh : k1 + sh], np.ones(k1 - k0), t[k0:k1]]
            c, *_ = np.linalg.lstsq(A, w.phi[k0:k1], rcond=None)
            e = float(np.mean((A @ c - w.phi[k0:k1]) ** 2))
            if best is None or e < best[0]:
                best = (e, sh, c[0])
        rows.append((w.speed, best[1], best[2]))
    r = np.array(rows)
    for v in sorted({round(x, 1) for x in r[:, 0]}):
        sel = r[np.abs(r[:, 0] - v) < 0.1]
        print(f"{v:.1f} m/s ({len(sel)} decays): lean angle = {np.median(sel[:, 2]):.3f} x "
              f"integrated roll rate, shifted {np.median(sel[:, 1]):+.0f} samples")  # fmt: skip
    for run, _segs in iter_decays(data_dir(data)):
        m = {k: float(np.mean(run[k])) for k in ("delta", "phi", "phidot", "T_delta")}
        print(f"{run.meta.get('file')}: whole-log means: steer {m['delta']:+.4f} rad, lean "
              f"{m['phi']:+.4f} rad, lean rate {m['phidot']:+.4f} rad/s, command "
              f"{m['T_delta']:+.4f} N m")  # fmt: skip


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", required=True, help="folder containing tudelft-sbw/")
    ap.add_argument("--sets", default="", help="effect sets: 'a,b;c,d' (';' between sets)")
    ap.add_argument(
        "--lean-check", action="store_true", help="lean angle vs integrated roll rate, per speed"
    )
    ap.add_argument("--splits", default="2.5,4.5/1.5,3.5", help="fit speeds, '/' between")
    ap.add_argument("--per-file", action="store_true", help="fit each file alone instead")
    ap.add_argument("--linear", action="store_true", help="linear nominal (no correction)")
    a = ap.parse_args(argv)
    sets = [[n.strip() for n in s.split(",") if n.strip()] for s in a.sets.split(";")]
    bad = sorted({n for s in sets for n in s} - set(EFFECTS))
    if bad:
        raise SystemExit(f"unknown effects {bad}; the registry has {sorted(EFFECTS)}")
    allw = load_decays(a.data)
    if a.lean_check:
        lean_check(allw, a.data)
        return 0
    if not sets or not sets[0]:
        raise SystemExit("give --sets (or --lean-check)")
    nl = not a.linear
    if a.per_file:
        files = sorted(
            {w.file for w in allw}, key=lambda f: next(w.speed for w in allw if w.file == f)
        )
        for names in sets:
            print(", ".join(names))
            for f in files:
                ws = [w for w in allw if w.file == f]
                r = fit_effect_set(ws, names, nl)
                vals = "  ".join(f"{n} {r.values[n]:.3f} +- {r.std[n]:.3f}" for n in names)
                print(f"  {ws[0].speed:.2f} m/s ({len(ws)} decays): cost {r.cost:.3f}  {vals}")
                fe = evaluate(ExperimentModel(), r.model, ws, nonlinear=nl)["files"][0]
                print(f"      in-sample weave error {fe['weave_error_before']:.3f} -> "
                      f"{fe['weave_error_after']:.3f} (the data resolve the weave to "
                      f"{fe['weave_data_rel_std']:.3f}); weave data {fe['weave_data']:.2f}, "
                      f"model {fe['weave_after']:.2f} 1/s")  # fmt: skip
        return 0
    for split in a.splits.split("/"):
        sp = [float(x) for x in split.split(",")]
        fw = [w for w in allw if min(abs(w.speed - s) for s in sp) < 0.25]
        hw = [w for w in allw if w not in fw]
        for names in sets:
            t0 = time.perf_counter()
            r = fit_effect_set(fw, names, nl)
            s = evaluate(ExperimentModel(), r.model, hw, nonlinear=nl)["summary"]
            vals = ", ".join(f"{n} {r.values[n]:.3f} +- {r.std[n]:.3f}" for n in names)
            print(f"fit {split:9s} [{vals}]\n    held out: error {s['error_before']:.3f} -> "
                  f"{s['error_after']:.3f} ({s['ratio']:.2f}), weave {s['weave_error_before']:.3f}"
                  f" -> {s['weave_error_after']:.3f} ({s['weave_ratio']:.2f})"
                  f"  [{time.perf_counter() - t0:.0f} s]", flush=True)  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
