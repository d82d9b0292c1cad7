"""The consistency study of the issue's "done when", at full size, with its CPU time.

    OPENBLAS_NUM_THREADS=1 nice python benchmarks/bench_consistency.py [--out DIR]
        [--workers 1] [--dask ADDRESS] [--json result.json]

Runs ``bikeid consistency --methods pem,pem:noise_model=none,direct --controller pid
--speeds 3,5,7 --durations 25,100,400 --seeds 12`` through the Python API
(:func:`bikeid.experiments.testbed.consistency.run_consistency`, efficiency reference
included) and prints the report, the verdicts and the CPU time of this process and its
workers (``resource.getrusage``).  With ``--out`` the finished fits are kept, so an
interrupted run resumes.  docs/consistency.md quotes its output with the machine and load.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from bikeid.experiments.testbed.consistency import run_consistency, table_text  # noqa: E402
from bikeid.experiments.testbed.scenario import Scenario  # noqa: E402

METHODS = ("pem", "pem:noise_model=none", "direct")


def _cpu() -> float:
    own = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=None, help="folder of finished fits (resumable)")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--dask", default=None)
    ap.add_argument("--json", default=None, help="write the result here")
    args = ap.parse_args()
    sc = Scenario(controller="pid", speeds=(3.0, 5.0, 7.0), durations=(25.0, 100.0, 400.0),
                  seeds=12)  # fmt: skip
    t0, c0 = time.perf_counter(), _cpu()
    res = run_consistency(list(METHODS), sc, out=args.out, workers=args.workers,
                          dask=args.dask)  # fmt: skip
    wall, cpu = time.perf_counter() - t0, _cpu() - c0
    print(table_text(res))
    print(f"jobs computed {res['jobs']['computed']}, reused {res['jobs']['reused']}; wall "
          f"{wall:.0f} s, CPU {cpu:.0f} s (this process and its local workers)")  # fmt: skip
    if args.json:
        with open(args.json, "w") as f:
            json.dump(res, f, indent=1)


if __name__ == "__main__":
    main()
