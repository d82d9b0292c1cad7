"""Coverage of the default path's eigenvalue intervals at short and long records, and why.

The default path (README): the nonlinear benchmark bicycle under the roll PID at 5 m/s with
a 1 N m uniform dither, ``pem.fit`` and ``ident.uncertainty.eigenvalue_intervals``.  Each
case counts how often the 95 % profile intervals of the caster, weave and capsize real
parts contain the linearized truth over seeds 0..N-1
(``experiments.testbed.coverage.run_default_path_coverage``), over all fits, over the fits
inside the one-step predictor's stability boundary and over those on it (which
``check_predictor_interior`` refuses), with Clopper-Pearson intervals; the scatter of the
estimates over seeds against the median printed standard error; and, where asked, how often
a start at the truth reaches a lower cost (local optima).  The cases separate the three
candidate causes: record length (30, 60, 90, 120, 300 s), the plant's nonlinearity (the
exact linear plant, same controller and dither objects), the noise model (output error,
``noise_model="none"``) and the excitation (3 N m).

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_default_path_coverage.py --seeds 20

(about 6 min wall on the shared 2-core VM with --workers 2; docs/uncertainty.md quotes it.)
"""

from __future__ import annotations

import argparse
import json
import os
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from bikeid.experiments.testbed.coverage import default_path_table, run_default_path_coverage

#: (label, keyword arguments of run_default_path_coverage)
CASES = (
    ("30 s", {"duration": 30.0, "restart": True}),
    ("60 s", {"duration": 60.0}),
    ("90 s", {"duration": 90.0}),
    ("120 s", {"duration": 120.0, "restart": True}),
    ("300 s", {"duration": 300.0}),
    ("30 s, linear plant", {"duration": 30.0, "plant": "linear"}),
    ("30 s, output error", {"duration": 30.0, "noise_model": "none"}),
    ("120 s, output error", {"duration": 120.0, "noise_model": "none"}),
    ("30 s, dither 3 N m", {"duration": 30.0, "dither": 3.0}),
)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--only", help="run only the cases whose label contains this text")
    ap.add_argument("--json", help="also write all results to this JSON file")
    args = ap.parse_args()
    out = {}
    for label, kw in CASES:
        if args.only and args.only not in label:
            continue
        t0 = time.perf_counter()
        res = run_default_path_coverage(args.seeds, workers=min(args.workers, 2), **kw)
        print(f"== {label} ({time.perf_counter() - t0:.0f} s wall)")
        print(default_path_table(res), flush=True)
        out[label] = res
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(out, fh, indent=1, default=float)


if __name__ == "__main__":
    main()
