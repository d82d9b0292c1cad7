"""Eigenvalue intervals without identification: is a shortfall the covariance or the curvature?

One 50 s closed-loop PEM fit of the linear benchmark at 5 m/s (``bikeid coverage``'s default
experiment, seed 0) gives a covariance P.  Then, with no further fits, theta is drawn D times
from N(theta_true, P), each draw is given P as its covariance (what a calibrated fit would
report), and the first-order and profile intervals of each eigenvalue part
(``ident.uncertainty.eigenvalue_intervals(method="delta" | "profile")``) are checked against
the exact benchmark eigenvalues.  P is exactly right here by construction, so a coverage
below 95 % can only come from the interval's construction (the eigenvalues' curvature in
theta).  The script also prints the correlation matrix of the fit's weighted innovations,
which the sandwich covariance of ``pem.fit`` accounts for.

    python benchmarks/bench_interval_curvature.py --draws 4000

Prints per eigenvalue part the coverage of both intervals with its exact 95 % interval.
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=int, default=1000, help="parameter draws D (default 1000)")
    ap.add_argument("--seed", type=int, default=5, help="seed of the draws (default 5)")
    args = ap.parse_args()
    if args.draws < 2:
        ap.error("--draws must be at least 2")

    from bikeid.controllers.registry import make
    from bikeid.dataset.linear_loop import simulate
    from bikeid.experiments.testbed.coverage import DEFAULTS, binomial_verdict
    from bikeid.ident import pem
    from bikeid.ident.canonical import theta_from_matrices
    from bikeid.ident.uncertainty import eigenvalue_intervals
    from bikeid.sim.linear import canonical_matrices, eigenvalues
    from bikeid.sim.parameters import benchmark

    p, v = benchmark(), DEFAULTS["speed"]
    run = simulate(
        p, v, duration=DEFAULTS["duration"], controller=make("pid", p, sample_time=0.01),
        seed=0, dither=DEFAULTS["dither"], dither_hold=int(DEFAULTS["dither_hold"]),
        disturbance=DEFAULTS["disturbance"], angle_noise=DEFAULTS["angle_noise"],
        rate_noise=DEFAULTS["rate_noise"],
    )  # fmt: skip
    fit = pem.fit(run)
    theta = theta_from_matrices(canonical_matrices(p), v)
    truth = eigenvalues(p, v)
    L = np.linalg.cholesky(fit.covariance)
    rng = np.random.default_rng(args.seed)
    hits = {"delta": np.zeros(4, int), "profile": np.zeros(4, int)}
    for _ in range(args.draws):
        m = dataclasses.replace(fit, theta=theta + L @ rng.standard_normal(10))
        for method, h in hits.items():
            h += eigenvalue_intervals(m, method=method).contains(truth)[0]
    names = {}
    for k in np.argsort(truth.real):  # caster, weave (two members), capsize
        names.setdefault(
            "caster" if truth[k].real < -5 else "weave" if truth[k].imag else "capsize", k
        )
    print(f"{args.draws} draws from N(theta_true, P), P of the 50 s fit at {v:g} m/s")
    print(f"{'real part':<10} {'first order':>31} {'profile':>31}")
    for name, k in names.items():
        cells = []
        for method in ("delta", "profile"):
            c = int(hits[method][k])
            lo, hi, verdict = binomial_verdict(c, args.draws)
            cells.append(f"{c / args.draws:.3f} [{lo:.3f}, {hi:.3f}] {verdict:<10}")
        print(f"{name:<10} {cells[0]:>31} {cells[1]:>31}")
    e = fit.noise_covariance
    d = np.sqrt(np.diag(e))
    print("innovation correlation (outputs " + ", ".join(fit.outputs) + "):")
    print(np.array2string(e / np.outer(d, d), precision=3, suppress_small=True))


if __name__ == "__main__":
    main()
