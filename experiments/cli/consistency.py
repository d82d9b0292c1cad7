"""``bikeid consistency``: is an estimator consistent in closed loop (anyone's estimator)?

Runs :func:`bikeid.experiments.testbed.consistency.run_consistency` for each controller:
bias, SD, RMSE of the weave, capsize and caster eigenvalues over seeds and record lengths,
the slope of log RMSE against log N, the coverage of the estimator's own intervals, and a
verdict (``refused``, ``inconclusive``, ``biased``, ``consistent with 1/sqrt(N)``).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from typing import Any

from bikeid.experiments.cli.args import MAX_WORKERS, dump_json, integer, number
from bikeid.experiments.parallel import DASK_HELP


def _list(kind: Callable[[str], Any], what: str) -> Callable[[str], list]:
    """An argparse ``type=``: comma-separated items, each checked by ``kind``, none twice."""

    def parse(text: str) -> list:
        items = [t.strip() for t in str(text).split(",") if t.strip()]
        if not items:
            raise argparse.ArgumentTypeError(f"give one or more comma-separated {what}")
        out = [kind(t) for t in items]  # kind raises ArgumentTypeError naming the item
        if len(set(out)) != len(out):
            raise argparse.ArgumentTypeError(f"{text!r}: give each of the {what} once")
        return out

    parse.__name__ = what
    return parse


def register(sub: argparse._SubParsersAction) -> None:
    from bikeid.experiments.testbed.coverage import DEFAULTS

    p = sub.add_parser(
        "consistency",
        help="is an estimator consistent in closed loop? bias, RMSE vs N, verdict",
        description=(
            "Simulate the closed loop (linear plant: exact truth; nonlinear: the "
            "linearization) for every record length and seed, fit each estimator and report "
            "bias, SD and RMSE of the weave, capsize and caster eigenvalues, the slope of "
            "log RMSE against log N with a seed-bootstrap interval, the coverage of the "
            "estimator's own intervals, and a verdict: refused (raised on > 10 %% of fits), "
            "inconclusive (< 8 seeds or < 3 lengths, or a slope interval too wide), biased "
            "(Hotelling T^2 at the largest N rejects at 0.01) or consistent with 1/sqrt(N) "
            "(slope interval below -0.25). Estimators: names of the method table with "
            "settings (pem, pem:noise_model=none, direct, direct_ls, greybox), the peer "
            "nfoursid, or module:function (called fn(runs, context), importable from the "
            "current folder or PYTHONPATH; docs/consistency.md)."
        ),
    )
    p.add_argument(
        "--methods",
        type=_list(str, "estimators"),
        default=["pem"],
        metavar="EST,...",
        help="estimators (default pem)",
    )
    p.add_argument(
        "--controller",
        type=_list(str, "controller names"),
        default=["pid"],
        metavar="NAME,...",
        help="controller(s) (controllers.registry; default pid); several give a list of studies",
    )
    p.add_argument(
        "--speeds",
        type=_list(number(0.1, 30.0, unit="m/s"), "speeds [m/s]"),
        default=[DEFAULTS["speed"]],
        metavar="V,...",
        help="speeds [m/s] fitted together (default 5)",
    )
    p.add_argument(
        "--durations",
        type=_list(number(0.5, 36000.0, unit="s"), "lengths [s]"),
        default=[25.0, 100.0, 400.0],
        metavar="T,...",
        help="record lengths [s] (default 25,100,400)",
    )
    p.add_argument(
        "--seeds", type=integer(1, 100000), default=12, help="seeds per length (default 12)"
    )
    p.add_argument("--first-seed", type=integer(0, 10**9), default=0, help="first seed")
    p.add_argument(
        "--plant",
        choices=("linear", "nonlinear"),
        default="linear",
        help="linear (exact truth, default) or nonlinear (truth: the "
        "linearization; no process noise)",
    )
    p.add_argument("--bicycle", default="benchmark", help="bicycle by name (default benchmark)")
    p.add_argument(
        "--dither",
        type=number(0.0, 50.0, unit="N m"),
        default=DEFAULTS["dither"],
        help=f"uniform steer-torque dither [N m] (default {DEFAULTS['dither']:g})",
    )
    p.add_argument(
        "--dither-hold",
        type=integer(1, 10000),
        default=int(DEFAULTS["dither_hold"]),
        help="samples each dither value is held (default 5)",
    )
    p.add_argument(
        "--disturbance",
        type=number(0.0, 100.0, unit="N m"),
        default=DEFAULTS["disturbance"],
        help="unlogged white steer torque SD [N m] (process noise; default 0.5)",
    )
    p.add_argument(
        "--roll-torque",
        type=number(0.0, 100.0, unit="N m"),
        default=0.0,
        help="unlogged white roll torque SD [N m] (default 0)",
    )
    p.add_argument(
        "--angle-noise",
        type=number(0.0, 1.0, unit="rad"),
        default=DEFAULTS["angle_noise"],
        help="angle sensor noise SD [rad]",
    )
    p.add_argument(
        "--rate-noise",
        type=number(0.0, 10.0, unit="rad/s"),
        default=DEFAULTS["rate_noise"],
        help="rate sensor noise SD [rad/s]",
    )
    p.add_argument(
        "--level",
        type=number(0.0, 1.0, lo_open=True, hi_open=True),
        default=0.95,
        help="nominal coverage of the intervals counted (default 0.95)",
    )
    p.add_argument(
        "--no-efficiency",
        action="store_true",
        help="skip the PEM reference fits of the efficiency figures",
    )
    p.add_argument(
        "--out",
        default=None,
        metavar="DIR",
        help="write each finished fit to DIR/jobs (a rerun skips them) and the "
        "result to DIR/consistency.json",
    )
    p.add_argument(
        "--plot",
        default=None,
        metavar="FILE",
        help="figure: RMSE against N on log axes with the -1/2 reference, and "
        "coverage per estimator (format from the suffix)",
    )
    p.add_argument(
        "--workers",
        type=integer(1, MAX_WORKERS),
        default=1,
        help="local worker processes (default 1)",
    )
    p.add_argument("--dask", metavar="ADDRESS", help=DASK_HELP)
    p.add_argument("--json", action="store_true", help="print JSON instead of the report")
    p.add_argument("--quiet", action="store_true", help="no progress on stderr")
    p.set_defaults(func=cmd_consistency)


def cmd_consistency(args: argparse.Namespace) -> int:
    from pathlib import Path

    from bikeid.experiments.cli.args import check_figure_path
    from bikeid.experiments.progress import terminal_progress
    from bikeid.experiments.testbed.consistency import run_consistency, table_text
    from bikeid.experiments.testbed.estimator import Estimator
    from bikeid.experiments.testbed.scenario import Scenario

    check_figure_path(args.plot, "--plot")
    estimators = [Estimator(m) for m in dict.fromkeys(args.methods)]  # refusals: one line
    scenarios = [
        Scenario(
            bicycle=args.bicycle,
            plant=args.plant,
            controller=c,
            speeds=tuple(args.speeds),
            dither=args.dither,
            dither_hold=args.dither_hold,
            disturbance=args.disturbance,
            roll_torque=args.roll_torque,
            angle_noise=args.angle_noise,
            rate_noise=args.rate_noise,
            durations=tuple(args.durations),
            seeds=args.seeds,
            first_seed=args.first_seed,
        )
        for c in dict.fromkeys(args.controller)
    ]
    studies = []
    for sc in scenarios:
        bar = terminal_progress(
            f"consistency {sc.controller}",
            json_output=args.json,
            unit="fit",
            quiet=args.quiet,
            lines=False,
        )
        res = run_consistency(
            estimators,
            sc,
            level=args.level,
            out=args.out,
            workers=args.workers,
            dask=args.dask,
            progress=bar,
            efficiency=not args.no_efficiency,
        )
        studies.append({"controller": sc.controller, **res})
    result = studies[0] if len(studies) == 1 else {"studies": studies}
    if args.out:
        from bikeid.dataset.files import atomic_write_text

        Path(args.out).mkdir(parents=True, exist_ok=True)
        atomic_write_text(Path(args.out) / "consistency.json", dump_json(result))
    if args.plot:
        from bikeid.experiments.testbed.consistency_plots import plot_consistency

        plot_consistency(studies, args.plot)
    if args.json:
        print(dump_json(result))
    else:
        for st in studies:
            print(table_text(st))
        if args.plot:
            print(f"wrote {args.plot}", file=sys.stderr)
    return 0
