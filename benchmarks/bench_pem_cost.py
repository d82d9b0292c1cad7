"""CPU of the PEM fits, to run side by side with another checkout of bikeid.

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=CHECKOUT python benchmarks/bench_pem_cost.py one [--fits 10]
    OPENBLAS_NUM_THREADS=1 PYTHONPATH=CHECKOUT python benchmarks/bench_pem_cost.py speed
    OPENBLAS_NUM_THREADS=1 PYTHONPATH=CHECKOUT python benchmarks/bench_pem_cost.py profile

``one``: the fixed-speed fit of benchmark 1 of ``bench_ident.py`` (``ident.pem.fit`` with its
defaults, 50 s at 100 Hz, N = 5,000, linear closed loop under the roll PID at 4 m/s), one
warm-up fit (compiled kernels loaded), then ``--fits`` fits.  ``speed``: benchmark 2, the
speed-parameterized fit over 29 speeds (1..15 m/s step 0.5) x 50 s, ``pem.fit_speed_model``
with its defaults (the joint Kalman gain), after one warm-up fixed-speed fit.  Each prints
the CPU seconds of its fits (``time.process_time``, this process: single-threaded BLAS) and
the estimates, so two checkouts' results can be compared.  ``profile``: cProfile of three
fixed-speed fits, by own and by cumulative time (where the time goes).

PYTHONPATH picks the checkout (the directory holding the ``bikeid`` package), so the same
command times an older commit against this one in the same run: the ratios of such pairs,
not absolute times, are what a shared machine can give (docs/performance.md).
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from bikeid.dataset.linear_loop import simulate  # noqa: E402
from bikeid.ident import pem  # noqa: E402
from bikeid.sim.parameters import benchmark  # noqa: E402

KW = dict(dither=1.0, dither_hold=5, disturbance=0.5, angle_noise=1e-3, rate_noise=1e-2)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("what", choices=("one", "speed", "profile"))
    ap.add_argument("--fits", type=int, default=10, help="fixed-speed fits timed ('one')")
    args = ap.parse_args()
    p = benchmark()
    one = simulate(p, 4.0, duration=50, seed=1, **KW)
    pem.fit(one)  # warm-up: compiled kernels loaded
    if args.what == "profile":
        import cProfile
        import pstats

        prof = cProfile.Profile(time.process_time)
        prof.runcall(lambda: [pem.fit(one) for _ in range(3)])
        pstats.Stats(prof).sort_stats("tottime").print_stats(15)
        pstats.Stats(prof).sort_stats("cumulative").print_stats(30)
        return
    if args.what == "one":
        t0 = time.process_time()
        for _ in range(args.fits):
            m = pem.fit(one)
        cpu = (time.process_time() - t0) / args.fits
        print(f"fixed-speed fit, N=5000: {cpu:.4f} s CPU per fit ({args.fits} fits)")
        print("theta", np.array2string(m.theta, precision=10, max_line_width=200))
        print("se   ", np.array2string(np.sqrt(np.diag(m.covariance)), precision=6,
                                       max_line_width=200))  # fmt: skip
        return
    speeds = np.arange(1.0, 15.01, 0.5)
    runs = [simulate(p, float(v), duration=50, seed=i, **KW) for i, v in enumerate(speeds)]
    t0 = time.process_time()
    m = pem.fit_speed_model(runs)
    cpu = time.process_time() - t0
    print(f"speed-parameterized fit, 29 speeds x 5000: {cpu:.2f} s CPU, nfev {m.nfev}")
    print("params", np.array2string(m.params, precision=10, max_line_width=200))
    print("se    ", np.array2string(np.sqrt(np.diag(m.covariance)), precision=6,
                                    max_line_width=200))  # fmt: skip


if __name__ == "__main__":
    main()
