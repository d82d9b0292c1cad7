"""Are the grey-box standard errors honest?  z-scores of ``ident.greybox.fit`` over seeds.

Linear closed loop of the benchmark bicycle (``dataset.linear_loop``: default PID, dither
1 N m held 50 ms, unlogged steer disturbance 0.5 N m, sensor noise 1e-3 rad / 1e-2 rad/s),
30 s at 2, 4, 6 and 8 m/s per replicate (the setting of ``tests/ident/test_greybox.py``), Moore &
Hubbard's free set fitted jointly.  Prints, per free entry, the spread of the estimates over
the replicates divided by their mean standard error (1 if the standard errors are honest;
the ratio itself is uncertain by about 1/sqrt(2 (n - 1))), the mean z-score (bias in
standard errors), and the RMS and largest |z| over all entries and replicates.

    OPENBLAS_NUM_THREADS=1 python benchmarks/greybox_calibration.py --replicates 10
"""

from __future__ import annotations

import argparse

import numpy as np

from bikeid.dataset.linear_loop import simulate
from bikeid.ident import greybox
from bikeid.sim.linear import canonical_matrices
from bikeid.sim.parameters import benchmark

SPEEDS = (2.0, 4.0, 6.0, 8.0)


def main() -> None:
    """Run the replicates and print the calibration summary."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--replicates", type=int, default=10)
    ap.add_argument("--seed", type=int, default=100, help="first seed (seeds seed + 10 r + i)")
    args = ap.parse_args()
    p = benchmark()
    cm = canonical_matrices(p)
    z, se, est = [], [], []
    names: list[str] = []
    for r in range(args.replicates):
        runs = [simulate(p, v, duration=30, seed=args.seed + 10 * r + i, dither=1.0,
                         dither_hold=5, disturbance=0.5, angle_noise=1e-3, rate_noise=1e-2)
                for i, v in enumerate(SPEEDS)]  # fmt: skip
        m = greybox.fit(runs, reference=p)
        names = list(m.free)
        e = np.array([m.free[n] for n in names])
        s = np.array([m.stderr[n] for n in names])
        truth = np.array([_true(cm, n) for n in names])
        z.append((e - truth) / s)
        se.append(s)
        est.append(e)
    Z, SE, EST = np.array(z), np.array(se), np.array(est)
    ratio = EST.std(axis=0, ddof=1) / SE.mean(axis=0)
    print(f"{args.replicates} replicates, entries {names}")
    pairs = zip(names, ratio, Z.mean(axis=0), strict=True)
    print("per entry: sd(estimate) / mean(stderr), mean z")
    print("  " + ", ".join(f"{n} {q:.2f} {mz:+.2f}" for n, q, mz in pairs))
    print(f"RMS z {np.sqrt(np.mean(Z**2)):.2f}, max |z| {np.abs(Z).max():.2f}")


def _true(cm, name: str) -> float:
    from bikeid.ident.direct import parse_entry

    m, r, c = parse_entry(name)
    return float(getattr(cm, m)[r, c])


if __name__ == "__main__":
    main()
