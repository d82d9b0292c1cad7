"""The feedback share R^2 of static and low-order dynamic state laws, case by case.

    OPENBLAS_NUM_THREADS=1 python benchmarks/feedback_share.py [--data ../shared/data]
        [--seeds 2] [--json FILE]

The numbers of ``bikeid.ident.informativity.FEEDBACK_R2``'s source comment, which states
the rule (a run is feedback-only when the static law reproduces >= 98 % of its torque's
variance) and why no other threshold or law separates the 9 km/h push log.  Per case the
script prints the R^2 of three laws of the measured states, each fitted by least squares:

- ``static``: the law of :func:`bikeid.ident.informativity.feedback_share` (the four
  states, their products with the speed's deviation, the integrals of the angles), in
  sample (what the check uses) and on the held-out half (fitted on one half, judged on
  the other, both ways: min and max);
- ``lags``: the static law plus the four states lagged 1-3 samples (held-out half);
- ``filtered``: the static law plus the states and their speed products filtered by
  first-order lags of 0.02, 0.05, 0.1 and 0.2 s (in sample and held-out half).

Cases: the steer-by-wire push logs (``eigen``) and Bode logs (``bode-4mps``) through
``dataset.sbw_logs.settled`` (needs ``--data`` or ``$BIKEID_DATA``); the testbed's
dithered sweep runs (``experiments.testbed.sweep`` defaults: roll chirp and dither by speed
band) with the fuzzy, PID and pole-placement controllers at 1-10 m/s; the same loops with
the chirp but no dither, with neither (feedback only), and with one 0.7 Hz roll sinusoid;
the linear loop with a white dither held 1-20 samples.  Then two identifications that
show what the share does not measure: canonical PEM on the 9 km/h log, and on a PID loop
at 2.5 m/s with a small dither (0.3 and 0.15 N m, no reference, 100 s), each against the
Whipple model.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

STATES = ("phi", "delta", "phidot", "deltadot")
TAUS = (0.02, 0.05, 0.1, 0.2)


def _lag(x: np.ndarray, k: int) -> np.ndarray:
    return np.concatenate([np.full(k, x[0]), x[:-k]])


def _filtered(x: np.ndarray, a: float) -> np.ndarray:
    from scipy.signal import lfilter

    y, _ = lfilter([1 - a], [1, -a], x, zi=[a * x[0]])
    return y


def laws(run) -> dict[str, np.ndarray]:
    """Regressor matrices of the three laws (module docstring)."""
    from bikeid.ident.informativity import _law

    static = _law(run, "T_delta")
    lags = [static] + [_lag(np.asarray(run[s], float), k)[:, None] for s in STATES
                       for k in (1, 2, 3)]  # fmt: skip
    v = np.asarray(run["v"], float)
    dv = v - v.mean()
    filt = [static]
    for s in STATES:
        for tau in TAUS:
            f = _filtered(np.asarray(run[s], float), math.exp(-run.dt / tau))
            filt.append(f[:, None])
            if np.ptp(dv) > 0:
                filt.append((dv * f)[:, None])
    return {"static": static, "lags": np.hstack(lags), "filtered": np.hstack(filt)}


def r2_in_sample(X: np.ndarray, u: np.ndarray) -> float:
    """R^2 of the least-squares fit of ``u`` on ``X`` [-]."""
    c, *_ = np.linalg.lstsq(X, u, rcond=None)
    r = u - X @ c
    return float(1 - np.sum(r**2) / np.sum((u - u.mean()) ** 2))


def r2_held_out(X: np.ndarray, u: np.ndarray) -> tuple[float, float]:
    """(min, max) R^2 over fitting on one half and judging on the other, both ways [-]."""
    h = len(u) // 2
    out = []
    for a, b in ((slice(0, h), slice(h, None)), (slice(h, None), slice(0, h))):
        s = np.linalg.norm(X[a], axis=0)
        s[s == 0] = 1
        c, *_ = np.linalg.lstsq(X[a] / s, u[a], rcond=None)
        r = u[b] - (X[b] / s) @ c
        out.append(float(1 - np.sum(r**2) / np.sum((u[b] - u[b].mean()) ** 2)))
    return min(out), max(out)


def row(label: str, run) -> dict:
    """The three laws' R^2 on one run, printed and returned."""
    u = np.asarray(run["T_delta"], float)
    X = laws(run)
    out = {"case": label, "static": r2_in_sample(X["static"], u),
           "static_held_out": r2_held_out(X["static"], u),
           "lags_held_out": r2_held_out(X["lags"], u),
           "filtered": r2_in_sample(X["filtered"], u),
           "filtered_held_out": r2_held_out(X["filtered"], u)}  # fmt: skip
    print(f"{label:42s} static {out['static']:.4f} (held out {out['static_held_out'][0]:+.2f}.."
          f"{out['static_held_out'][1]:+.2f})  lags held out {out['lags_held_out'][0]:+.3f}.."
          f"{out['lags_held_out'][1]:+.3f}  filtered {out['filtered']:.3f} (held out "
          f"{out['filtered_held_out'][0]:+.2f}..{out['filtered_held_out'][1]:+.2f})",
          flush=True)  # fmt: skip
    return out


def measured(root) -> list[dict]:
    """Push and Bode logs of the steer-by-wire bicycle."""
    from bikeid.dataset.sbw_logs import find_logs, load_log, settled

    rows = []
    for kind in ("eigen", "bode"):
        for p in find_logs(root, kind):
            run = settled(load_log(p))
            rows.append(row(p.name.split(".log")[0], run))
            if kind == "eigen":
                from bikeid.ident.informativity import feedback_share

                ext = np.asarray(run["T_ext"], float)
                rows[-1]["sil_command_static"] = feedback_share(run, "sil_command")[0]
                rows[-1]["relayed_std"] = float(ext.std())
                rows[-1]["relayed_share_of_samples"] = float(np.mean(np.abs(ext) > 1e-6))
                if ext.std() > 0:
                    rows[-1]["relayed_vs_hand_torque"] = float(
                        np.corrcoef(ext, run["hand_torque"])[0, 1])
    return rows


def testbed(seeds: int) -> list[dict]:
    """The testbed's sweep runs with and without dither or reference; the linear loop."""
    from bikeid.dataset.linear_loop import simulate
    from bikeid.experiments.testbed.sweep import SweepSpec, Task, simulate_task
    from bikeid.sim.parameters import benchmark

    rows = []
    for ctrl in ("fuzzy", "pid", "pole"):
        for v in (1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0):
            for seed in range(seeds):
                spec = SweepSpec(controller=ctrl, speeds=(v,))
                rows.append(row(f"{ctrl} {v:g} m/s seed {seed} dithered",
                                simulate_task(spec, Task("x", v, seed))))  # fmt: skip
        for v in (2.0, 4.0, 6.0):
            for label, kw in (("chirp, no dither", {"dither": 0.0}),
                              ("no dither, no reference", {"dither": 0.0, "reference": "zero"})):
                spec = SweepSpec(controller=ctrl, speeds=(v,), **kw)
                rows.append(row(f"{ctrl} {v:g} m/s {label}", simulate_task(spec, Task("x", v, 0))))
    for hold in (1, 2, 5, 10, 20):
        for seed in (1, 2, 3):
            run = simulate(benchmark(), 5.0, duration=30.0, seed=seed, dither=1.0,
                           dither_hold=hold, rate_noise=1e-3, angle_noise=1e-4)  # fmt: skip
            rows.append(row(f"linear loop, dither held {hold}, seed {seed}", run))
    return rows


def sinusoids() -> list[dict]:
    """One 0.7 Hz roll sinusoid as the only excitation, each controller at 2, 4, 6 m/s."""
    from bikeid.controllers import make
    from bikeid.dataset.closed_loop import simulate_run
    from bikeid.experiments.testbed.sweep import excitation_for
    from bikeid.sim.parameters import benchmark

    rows = []
    for ctrl in ("fuzzy", "pid", "pole"):
        for v in (2.0, 4.0, 6.0):
            amp, _ = excitation_for(v)
            opts = {"design_speed": v} if ctrl == "pole" else {}
            run = simulate_run(benchmark(), make(ctrl, benchmark(), sample_time=0.01, **opts), v,
                               duration=50.0, seed=3,
                               reference=lambda t, a=amp: 0.3 * a * math.sin(2 * math.pi * 0.7 * t))
            rows.append(row(f"{ctrl} {v:g} m/s one 0.7 Hz sinusoid", run))
    return rows


def identifications(root) -> list[dict]:
    """Canonical PEM where the share does not tell: the 9 km/h log, small-dither loops."""
    from bikeid.experiments.testbed.sweep import SweepSpec, Task, simulate_task
    from bikeid.ident.informativity import feedback_share
    from bikeid.ident.methods import fit_pem
    from bikeid.sim import linear
    from bikeid.sim.parameters import benchmark, by_name

    out = []

    def show(label, run, p):
        eig = np.sort_complex(fit_pem([run], informativity="report").models[0].eigenvalues())
        truth = np.sort_complex(linear.eigenvalues(p, run.speed))
        d = {"case": label, "static": feedback_share(run)[0],
             "pem": [complex(z) for z in eig], "truth": [complex(z) for z in truth]}  # fmt: skip
        print(f"{label:42s} R^2 {d['static']:.4f}  PEM {np.round(eig, 2)}  Whipple "
              f"{np.round(truth, 2)}", flush=True)  # fmt: skip
        out.append(d)

    if root is not None:
        from bikeid.dataset.sbw_logs import load_log, settled

        run = settled(load_log(root / "eigen" / "eigen_normal_sil6.5n2_9kph.log.gz"))
        show("push log 9 km/h", run, by_name("steer-by-wire"))
    for amp in (0.3, 0.15):
        spec = SweepSpec(controller="pid", speeds=(2.5,), dither=amp, reference="zero",
                         duration=100.0)  # fmt: skip
        show(f"PID 2.5 m/s, dither {amp} N m, no reference", simulate_task(spec, Task("x", 2.5, 0)),
             benchmark())  # fmt: skip
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", default=os.environ.get("BIKEID_DATA"),
                    help="folder holding tudelft-sbw/ (default $BIKEID_DATA; none: skip the logs)")
    ap.add_argument("--seeds", type=int, default=2, help="seeds per dithered sweep cell")
    ap.add_argument("--json", default=None, help="write every row to this JSON file")
    args = ap.parse_args()
    root = None
    if args.data:
        from bikeid.dataset.sbw_logs import data_dir

        root = data_dir(args.data)
    print(f"# {platform.machine()}, Python {platform.python_version()}, numpy {np.__version__}")
    rows = (measured(root) if root is not None else []) + testbed(args.seeds) + sinusoids()
    rows += identifications(root)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=1, default=str)


if __name__ == "__main__":
    main()
