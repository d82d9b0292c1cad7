"""Identification performance targets (brief D): medians of repeats.

    OPENBLAS_NUM_THREADS=1 /work/venv/bin/python benchmarks/bench_ident.py [--repeats 3]

1. PEM at one speed, 50 s at 100 Hz (N = 5,000): target <= 1 s.
2. Speed-parameterized PEM over 29 speeds (1..15 m/s step 0.5, 50 s each): <= 10 s.
3. Subspace start (PBSID) at N = 50,000: <= 3 s and <= 500 MB (tracemalloc peak).
Data: linear closed loop (dataset.linear_loop), roll PID, dither 1 N m held 50 ms,
disturbance 0.5 N m, sensor noise 1e-3 rad / 1e-2 rad/s.  Single-threaded BLAS is
recommended: on a shared 2-core machine threaded BLAS made the 5,000-sample fit ~10x
slower.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time
import tracemalloc

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from bikeid.dataset.linear_loop import simulate  # noqa: E402
from bikeid.ident import pem  # noqa: E402
from bikeid.sim.parameters import benchmark  # noqa: E402

KW = dict(dither=1.0, dither_hold=5, disturbance=0.5, angle_noise=1e-3, rate_noise=1e-2)


def _median_time(f, repeats):
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        f()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    p = benchmark()
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"python {platform.python_version()}, numpy {np.__version__}")  # fmt: skip
    one = simulate(p, 4.0, duration=50, seed=1, **KW)
    pem.fit(one)  # compile numba kernels
    t1 = _median_time(lambda: pem.fit(one), args.repeats)
    print(f"1. PEM one speed, N=5000: median {t1:.3f} s (target 1 s)")
    speeds = np.arange(1.0, 15.01, 0.5)
    runs = [simulate(p, float(v), duration=50, seed=i, **KW) for i, v in enumerate(speeds)]
    t2 = _median_time(lambda: pem.fit_speed_model(runs), max(1, args.repeats - 2))
    print(f"2. speed-parameterized PEM, 29 speeds x 5000: median {t2:.2f} s (target 10 s)")
    big = simulate(p, 4.0, duration=500, seed=2, **KW)
    t3 = _median_time(lambda: pem.subspace_start([big]), args.repeats)
    tracemalloc.start()
    pem.subspace_start([big])
    peak = tracemalloc.get_traced_memory()[1] / 1e6
    tracemalloc.stop()
    print(
        f"3. subspace start, N=50000: median {t3:.2f} s, peak {peak:.0f} MB (targets 3 s, 500 MB)"
    )


if __name__ == "__main__":
    main()
