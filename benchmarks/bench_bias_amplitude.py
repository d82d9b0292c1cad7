"""Weave bias of PEM against excitation amplitude, nonlinear vs linear plant, at 4.2 m/s.

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_bias_amplitude.py [--seeds 4]
        [--scales 1,0.5,0.25,0.125,0.0625] [--json FILE]

The Chen & Dao reproduction (docs/reproduce.md: fuzzy roll control at 4.2 m/s, 5 deg roll
chirp 0.05-0.5 Hz, uniform steer-torque dither +-1 N m held 0.01 s, default sensor noise,
50 s at 100 Hz) identifies a weave real part of ~0.069 1/s for a true +0.127 1/s.  Here the
whole excitation (chirp amplitude and dither amplitude together) is multiplied by a scale s
and the runs are identified (``ident.pem.fit``) with Chen & Dao's outputs (phi, delta) and
with all four measured states, on

- the nonlinear plant (``experiments.testbed.sweep.simulate_task``, the reproduction's runs at s =
1);
- the linear plant (``dataset.linear_loop.simulate``, same fuzzy controller, same chirp,
  dither and sensor-noise levels): the truth is exact there, so any bias it shows comes from
  the closed loop / noise model / output choice, not from the plant's nonlinearity.

Printed per (plant, outputs, s): the mean over seeds of the weave real-part error
(identified - true, paired by minimum distance), its standard error (sd over seeds /
sqrt(n)), the mean printed standard error (``ident.uncertainty.eigenvalue_intervals``), the
error divided by s^2 (constant if the bias is quadratic in amplitude), and the RMS roll and
steer angles.  If the amplitude is the cause, the nonlinear-plant error falls roughly as s^2
towards its standard error, while the linear plant stays unbiased at every s.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

SPEED = 4.2
CHIRP_DEG = 5.0
DITHER = 1.0
OUTPUT_SETS = {"phi,delta": ("phi", "delta"), "all4": ("phi", "phidot", "delta", "deltadot")}


def _nonlinear_run(scale: float, seed: int):
    from bikeid.experiments.testbed.sweep import SweepSpec, Task, simulate_task

    spec = SweepSpec("fuzzy", (SPEED,), (seed,), 50.0, bicycle="benchmark", reference="chirp",
                     chirp_amplitude=math.radians(CHIRP_DEG * scale), dither=DITHER * scale,
                     dither_hold=0.01, sensors="default", sample_time=0.01)  # fmt: skip
    return simulate_task(spec, Task(f"s{scale}_{seed}", SPEED, seed))


def _linear_run(scale: float, seed: int):
    from bikeid.controllers.excitation import ChirpReference
    from bikeid.controllers.registry import make
    from bikeid.dataset.linear_loop import simulate
    from bikeid.sim.parameters import benchmark

    p = benchmark()
    ref = ChirpReference(amplitude=math.radians(CHIRP_DEG * scale), f0=0.05, f1=0.5,
                         duration=50.0)  # fmt: skip
    return simulate(p, SPEED, duration=50.0, controller=make("fuzzy", p, sample_time=0.01),
                    seed=10_000 + seed, dither=DITHER * scale, dither_hold=1, reference=ref,
                    angle_noise=1e-3, rate_noise=1e-2)  # fmt: skip


def _weave(run, outputs, truth) -> dict[str, float]:
    from bikeid.ident import pem
    from bikeid.ident.uncertainty import eigenvalue_intervals
    from bikeid.sim.linear import match_eigenvalues

    model = pem.fit(run, outputs=outputs)
    ei = eigenvalue_intervals(model)
    targets = np.sort_complex(truth)
    _, col = match_eigenvalues(ei.values, targets, return_index=True)
    k = int(np.argmax(targets.imag))  # the weave root with positive frequency
    j = col[k]
    return {"re": float(ei.values[j].real), "im": float(abs(ei.values[j].imag)),
            "se_re": float(ei.std_real[j]), "true_re": float(targets[k].real),
            "true_im": float(targets[k].imag)}  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=4, help="seeds per scale (default 4)")
    ap.add_argument(
        "--scales",
        default="1,0.5,0.25,0.125,0.0625",
        help="excitation scales s (default 1,0.5,0.25,0.125,0.0625)",
    )
    ap.add_argument("--plants", default="nonlinear,linear")
    ap.add_argument("--json", metavar="FILE", help="also write every fit as JSON")
    args = ap.parse_args()
    from bikeid.sim.linear import eigenvalues
    from bikeid.sim.parameters import benchmark

    truth = eigenvalues(benchmark(), SPEED)
    scales = [float(s) for s in args.scales.split(",")]
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, python "
          f"{platform.python_version()}, numpy {np.__version__}")  # fmt: skip
    rows, records = [], []
    t0 = time.perf_counter()
    for plant in args.plants.split(","):
        make_run = _nonlinear_run if plant == "nonlinear" else _linear_run
        for s in scales:
            fits: dict[str, list[dict[str, float]]] = {k: [] for k in OUTPUT_SETS}
            rms = []
            for seed in range(args.seeds):
                run = make_run(s, seed)
                if run.meta.get("fell_at") is not None:
                    print(f"{plant} s={s} seed {seed}: fell at {run.meta['fell_at']} s; skipped")
                    continue
                rms.append((np.sqrt(np.mean(run.truth["phi"] ** 2)),
                            np.sqrt(np.mean(run.truth["delta"] ** 2))))  # fmt: skip
                for name, outs in OUTPUT_SETS.items():
                    try:
                        w = _weave(run, outs, truth)
                    except ValueError as exc:
                        print(f"{plant} s={s} seed {seed} {name}: {exc}")
                        continue
                    fits[name].append(w)
                    records.append({"plant": plant, "scale": s, "seed": seed, "outputs": name,
                                    **w})  # fmt: skip
            for name, ws in fits.items():
                if not ws:
                    continue
                err = np.array([w["re"] - w["true_re"] for w in ws])
                se_mean = (
                    float(np.std(err, ddof=1) / math.sqrt(err.size)) if err.size > 1 else math.nan
                )
                row = {"plant": plant, "outputs": name, "scale": s, "n": int(err.size),
                       "bias": float(err.mean()), "se_of_mean": se_mean,
                       "printed_se": float(np.mean([w["se_re"] for w in ws])),
                       "bias_over_s2": float(err.mean() / s**2),
                       "rms_phi_deg": float(np.degrees(np.mean([r[0] for r in rms]))),
                       "rms_delta_deg": float(np.degrees(np.mean([r[1] for r in rms]))),
                       }  # fmt: skip
                rows.append(row)
                print(f"{plant:9} {name:9} s={s:<7g} n={row['n']} bias {row['bias']:+.4f} +- "
                      f"{row['se_of_mean']:.4f} 1/s (printed SE {row['printed_se']:.4f}), "
                      f"bias/s^2 {row['bias_over_s2']:+.4f}, rms phi {row['rms_phi_deg']:.2f} "
                      f"deg, delta {row['rms_delta_deg']:.2f} deg", flush=True)  # fmt: skip
    print(
        f"true weave at {SPEED} m/s: {np.sort_complex(truth)[-1]:.4f} 1/s; "
        f"wall time {time.perf_counter() - t0:.0f} s"
    )
    print(
        "\n| plant | outputs | scale s | RMS roll, steer [deg] | weave Re error [1/s] "
        "(mean +- SE over seeds) | printed SE | error / s^2 |"
    )
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['plant']} | {r['outputs']} | {r['scale']:g} | {r['rms_phi_deg']:.2f}, "
              f"{r['rms_delta_deg']:.2f} | {r['bias']:+.4f} +- {r['se_of_mean']:.4f} | "
              f"{r['printed_se']:.4f} | {r['bias_over_s2']:+.4f} |")  # fmt: skip
    if args.json:
        from bikeid.dataset.files import atomic_write_text
        from bikeid.experiments.cli.args import dump_json

        atomic_write_text(args.json, dump_json({"summary": rows, "fits": records}) + "\n")


if __name__ == "__main__":
    main()
