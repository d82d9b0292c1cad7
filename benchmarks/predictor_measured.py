"""The noise models of the canonical PEM fit on measured logs: the tutorial's steer-by-wire runs.

    python benchmarks/predictor_measured.py --data "$BIKEID_DATA" [--json FILE]

The TU Delft steer-by-wire bicycle on a treadmill at 4 m/s (``tudelft-sbw/bode-4mps``, read
by the one loader, ``dataset.logs.load_runs``, format ``sbw``): the tutorial's split, the
eleven runs at 1.0-2.05 Hz fitted and the five at 2.2-3.0 Hz held out (docs/tutorial.md).
Each noise model of ``ident.pem.fit`` (``kalman``: the Kalman gain of fitted noise
covariances, the default; ``gain``: free innovation-gain entries; ``none``: output error) is
fitted, and printed per model:

- the identified eigenvalues [1/s] beside this bicycle's Whipple model at 4 m/s
  (``sim.linear.eigenvalues(parameters.steer_by_wire(), 4)``, the nominal reference, not a
  truth: the real bicycle differs from it);
- the fit's one-step prediction-error criterion, log det of the innovations' sample
  covariance (lower is better; the likelihood of Gaussian innovations);
- the spectral radius of the one-step predictor Ad - K C and the noise parameters on a bound;
- the 10-step-ahead NRMSE fit [%] of each output on the held-out runs
  (``ident.validate.compare``, MATLAB ``compare``), the tutorial's validation figure;
- the CPU time of the fit (``time.process_time``).

docs/uncertainty.md ("A predictor stable by construction") quotes the output.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

FIT_HZ = ("1.0", "1.1", "1.2", "1.3", "1.4", "1.5", "1.6", "1.7", "1.8", "1.9", "2.05")
HELD_HZ = ("2.2", "2.4", "2.6", "2.8", "3.0")
VARIANTS = ("kalman", "gain", "none")


def _runs(folder: Path, hz: tuple[str, ...]) -> list:
    from bikeid.dataset.logs import LogOptions, load_runs

    files = [folder / f"bode_normal_4mps_{h}Hz.log.gz" for h in hz]
    return load_runs(files, LogOptions(format="sbw"), note=lambda msg: None)


def main() -> None:
    from bikeid.ident import pem
    from bikeid.ident.validate import compare
    from bikeid.sim.errors import UntrustworthyResult
    from bikeid.sim.linear import eigenvalues
    from bikeid.sim.parameters import steer_by_wire

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=os.environ.get("BIKEID_DATA"),
                    help="the data folder (default $BIKEID_DATA)")  # fmt: skip
    ap.add_argument("--json", help="also write the results to this JSON file")
    args = ap.parse_args()
    if not args.data:
        raise SystemExit("give --data or set BIKEID_DATA (the folder holding tudelft-sbw/)")
    folder = Path(args.data) / "tudelft-sbw" / "bode-4mps"
    fit_runs, held = _runs(folder, FIT_HZ), _runs(folder, HELD_HZ)
    whipple = np.sort_complex(eigenvalues(steer_by_wire(), 4.0))
    print("Whipple model of the steer-by-wire bicycle at 4 m/s: "
          + ", ".join(f"{z:.3f}" for z in whipple))  # fmt: skip
    out = {"whipple": [[z.real, z.imag] for z in whipple], "models": {}}
    for variant in VARIANTS:
        t0 = time.process_time()
        try:
            m = pem.fit(fit_runs, noise_model=variant)
        except ValueError as exc:
            print(f"{variant}: refused: {exc}")
            out["models"][variant] = {"error": str(exc)}
            continue
        cpu = time.process_time() - t0
        lam = np.sort_complex(np.linalg.eigvals(m.A))
        Ad, _, C, K = m.predictor()
        radius = float(np.max(np.abs(np.linalg.eigvals(Ad - K @ C))))
        logdet = float(np.linalg.slogdet(np.atleast_2d(m.noise_covariance))[1])
        try:
            held_fit = compare(held, m, horizon=10).fit
        except (ValueError, UntrustworthyResult) as exc:  # reported; the others still run
            held_fit = {"error": str(exc).splitlines()[0]}
        row = {"eigenvalues": [[z.real, z.imag] for z in lam], "logdet": logdet,
               "radius": radius, "noise_on_bound": list(m.noise_on_bound),
               "held_out_10_step_fit": held_fit, "cpu": cpu, "notes": list(m.notes)}  # fmt: skip
        out["models"][variant] = row
        fits = ", ".join(f"{k} {v:.1f}" for k, v in held_fit.items()) \
            if "error" not in held_fit else held_fit["error"]  # fmt: skip
        print(f"{variant}: eigenvalues " + ", ".join(f"{z:.3f}" for z in lam)
              + f"; log det {logdet:.2f}; predictor radius {radius:.4f}; held-out 10-step "
              f"fit [%] {fits}; CPU {cpu:.1f} s")  # fmt: skip
        print(f"    {m.notes[-1]}")
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
