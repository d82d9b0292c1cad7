"""Benchmark: one controller's full sweep (29 speeds 1:15:0.5 x 50 s, one seed) simulated
on the nonlinear model and written to HDF5.  Target: < 10 s on 2 cores.

    /work/venv/bin/python benchmarks/bench_sweep.py [--controller pid] [--workers 2] [--repeat 3]

Prints the wall time of each repetition (fresh output file each time, numba caches warm),
the median, the per-run cost with one worker, and the file size.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from bikeid.experiments.testbed.sweep import CONTROLLERS, SweepSpec, Task, run_sweep, simulate_task


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--controller", default="pid", choices=CONTROLLERS)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--duration", type=float, default=50.0)
    args = ap.parse_args()
    speeds = tuple(np.round(np.arange(1.0, 15.0 + 1e-9, 0.5), 12))
    spec = SweepSpec(args.controller, speeds, (0,), args.duration)
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"Python {platform.python_version()}")  # fmt: skip
    # warm-up: numba caches, imports (not timed)
    t0 = time.perf_counter()
    simulate_task(spec, Task("warm", 5.0, 0))
    print(f"warm-up run (imports, numba cache load): {time.perf_counter() - t0:.2f} s")
    one = []
    for v in (1.0, 8.0, 15.0):
        t0 = time.perf_counter()
        simulate_task(spec, Task("one", v, 0))
        one.append(time.perf_counter() - t0)
    print(
        f"one {args.duration:g} s run, in process: {statistics.median(one) * 1e3:.0f} ms (median)"
    )
    times = []
    with tempfile.TemporaryDirectory() as d:
        for i in range(args.repeat):
            out = Path(d) / f"sweep{i}.h5"
            t0 = time.perf_counter()
            report = run_sweep(spec, out, workers=args.workers, progress=False)
            times.append(time.perf_counter() - t0)
            size = out.stat().st_size
            print(f"  sweep {i}: {times[-1]:.2f} s ({report.total} runs, {len(report.fell)} fell)")
    print(
        f"{args.controller}: {len(speeds)} speeds x {args.duration:g} s, workers={args.workers}: "
        f"median {statistics.median(times):.2f} s (min {min(times):.2f}), file {size / 1e6:.1f} MB"
    )


if __name__ == "__main__":
    main()
