"""``bikeid coverage``: how often PEM's 95 % intervals contain the truth over seeds.

On the linear plant (exact truth; ``--critical`` for v_w and v_c) or, with ``--plant``, on
the README's default path.
"""

from __future__ import annotations

import argparse
import sys

from bikeid.experiments.cli.args import MAX_WORKERS, dump_json, integer, number, quantity
from bikeid.experiments.parallel import DASK_HELP

#: ``--level``: a nominal coverage strictly between 0 and 1.
_level = number(0.0, 1.0, lo_open=True, hi_open=True)


def register(sub: argparse._SubParsersAction) -> None:
    from bikeid.experiments.testbed.coverage import DEFAULT_PATH, DEFAULTS

    p = sub.add_parser(
        "coverage",
        help="coverage of PEM's 95 %% intervals over seeds (linear loop; --plant: default path)",
        description=(
            "Simulate N closed-loop runs of the linear benchmark bicycle (exact truth), "
            "identify each with canonical PEM and count how often the intervals of the "
            "parameters and eigenvalues contain the truth (Clopper-Pearson interval of the "
            "count, verdict). Calibrates the intervals on the linear plant only "
            "(docs/uncertainty.md); --plant runs the README's default path instead. A 50 s "
            "run costs ~0.35 s of CPU (200 seeds: 310 s wall on the shared 2-core VM)."
        ),
    )
    p.add_argument("--seeds", type=integer(2, 100000), default=200, help="runs N (default 200)")
    p.add_argument(
        "--speed", type=quantity("m/s", 1.0, 15.0), default=DEFAULTS["speed"],
        help=f"forward speed [m/s, or with a unit: 18km/h], 1-15 (default {DEFAULTS['speed']:g})",
    )  # fmt: skip
    p.add_argument(
        "--duration", type=number(1.0, 3600.0, unit="s"), default=DEFAULTS["duration"],
        help=f"run length [s] (default {DEFAULTS['duration']:g})",
    )  # fmt: skip
    p.add_argument(
        "--dither", type=number(0.0, 50.0, lo_open=True, unit="N m"), default=None,
        help=f"dither amplitude [N m] (default {DEFAULTS['dither']:g}; "
        f"{DEFAULT_PATH['dither']:g} with --plant)",
    )  # fmt: skip
    p.add_argument(
        "--plant", choices=("nonlinear", "linear"), default=None,
        help="instead: the README's default path (closed_loop.simulate_run on this plant, "
        "roll PID, uniform dither, no disturbance, pem.fit, eigenvalue_intervals), counting "
        "the caster, weave and capsize intervals over all fits and apart for the fits that "
        "end on the predictor's stability boundary (refused by "
        "ident.uncertainty.check_predictor_interior); --controller is then ignored",
    )  # fmt: skip
    p.add_argument(
        "--noise-model", choices=("free", "kalman", "gain", "none"), default="free",
        help="with --plant: pem.fit's noise model (default free, pem.FREE_NOISE_MODEL = kalman, "
        "the Kalman gain of fitted noise; gain = the free innovation gain; none = output "
        "error)",
    )  # fmt: skip
    p.add_argument(
        "--restart", action="store_true",
        help="with --plant: also fit from the true parameters and count lower optima",
    )  # fmt: skip
    p.add_argument("--controller", choices=("pid", "pole"), default="pid")
    p.add_argument(
        "--level", type=_level, default=0.95,
        help="nominal coverage of each interval, 0 < level < 1 (default 0.95)",
    )  # fmt: skip
    p.add_argument(
        "--covariance-scale", type=number(0.0, 1e6, lo_open=True), default=1.0,
        help="factor on each fitted covariance (0.1 shows the verdict failing); default 1",
    )  # fmt: skip
    p.add_argument(
        "--critical", action="store_true",
        help="instead: v_w and v_c intervals of speed-parameterized fits over runs at 2, 3, "
        "..., 8 m/s (~3 s of CPU per seed: 100 seeds ~5 min; --speed and --controller are "
        "then ignored)",
    )  # fmt: skip
    p.add_argument("--json", action="store_true", help="print JSON instead of the table")
    p.add_argument(
        "--workers", type=integer(1, MAX_WORKERS), default=1,
        help="local worker processes, one seed each (default 1; same numbers for any value)",
    )  # fmt: skip
    p.add_argument("--dask", metavar="ADDRESS", help=DASK_HELP)
    p.add_argument(
        "--estimator", default="pem", metavar="EST",
        help="the estimator whose intervals are counted (linear-plant study): a name of the "
        "method table with settings, or module:function returning a canonical model with "
        "covariance (default pem)",
    )  # fmt: skip
    p.set_defaults(func=cmd_coverage)


def cmd_coverage(args: argparse.Namespace) -> int:
    import os

    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    from bikeid.experiments.testbed import coverage as cov

    run_coverage, run_critical_coverage, table_text = (
        cov.run_coverage, cov.run_critical_coverage, cov.table_text)  # fmt: skip
    if args.plant is not None and args.critical:
        raise ValueError("--plant and --critical are separate studies; drop one of them")
    if args.plant is None and (args.noise_model != "free" or args.restart):
        raise ValueError("--noise-model and --restart apply to --plant (the default-path "
                         "study); add --plant nonlinear or --plant linear")  # fmt: skip
    if args.estimator != "pem" and (args.plant is not None or args.critical):
        raise ValueError("--estimator applies to the linear-plant study; drop --plant or "
                         "--critical, or --estimator")  # fmt: skip
    if args.plant is not None:
        if args.covariance_scale != 1.0:
            raise ValueError("--covariance-scale is not used with --plant; drop one of them")
        res = cov.run_default_path_coverage(
            args.seeds, duration=args.duration, plant=args.plant, speed=args.speed,
            dither=cov.DEFAULT_PATH["dither"] if args.dither is None else args.dither,
            noise_model=args.noise_model, restart=args.restart, level=args.level,
            workers=args.workers, dask=args.dask,
        )  # fmt: skip
        if len(res["rows"]) < 2:
            why = (
                f" (seed {res['failed'][0]['seed']}: {res['failed'][0]['error']})"
                if res["failed"]
                else ""
            )
            raise ValueError(
                f"only {len(res['rows'])} of {args.seeds} fits succeeded{why}; "
                "give the fits more information (longer --duration)"
            )
        print(dump_json(res) if args.json else cov.default_path_table(res), file=sys.stdout)
        return 0
    if args.dither is None:
        args.dither = cov.DEFAULTS["dither"]
    if args.critical:
        result = run_critical_coverage(
            args.seeds, duration=args.duration, dither=args.dither, level=args.level,
            covariance_scale=args.covariance_scale, workers=args.workers, dask=args.dask,
        )  # fmt: skip
    else:
        result = run_coverage(
            args.seeds, speed=args.speed, duration=args.duration, dither=args.dither,
            controller=args.controller, level=args.level,
            covariance_scale=args.covariance_scale, workers=args.workers, dask=args.dask,
            estimator=args.estimator,
        )  # fmt: skip
    if result.n < 2:
        why = f" (seed {result.failed[0][0]}: {result.failed[0][1]})" if result.failed else ""
        raise ValueError(f"only {result.n} of {args.seeds} fits succeeded{why}; give the fits "
                         "more information (longer --duration, larger --dither)")  # fmt: skip
    print(dump_json(result.to_json()) if args.json else table_text(result), file=sys.stdout)
    return 0
