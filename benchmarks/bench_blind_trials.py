"""Benchmark: blind effect-selection trials (an independent generator; four rates).

    python benchmarks/bench_blind_trials.py [--n 90 | --per-class none=24,outside=24]
        [--seed 0] [--processes 2] [--plant auto|nonlinear|linear] [--log blind.jsonl]
        [--resume blind.jsonl] [--min-heldout-gain G] [--min-improved F]
        [--unexplained-rule floor|coloured|residual] [--unexplained-threshold X]
        [--nominal-uncertainty default|none|inertia=F,trail=M] [--tradeoff] [--nominal-only]
        [--dask ADDRESS]

Draws ``n`` trials of :mod:`bikeid.experiments.measured.blind_trials` (effects cycle through six
library effects, two outside the library and none; every nuisance randomized), runs the
selection of ``bikeid measured fit`` on each (not told the effect) and prints, with exact
95 % intervals: right effect first with its value in band (library trials), trials with
extra effects and the mean number of extras, false positives on no-effect logs, and
outside-library effects misattributed to a library effect.  Trial i depends only on
(seed, i); ``--log`` appends each finished trial, ``--resume`` skips the trials already in the
log and summarizes all of them.  ``--per-class`` draws only chosen classes (``library``,
``outside``, ``none`` or one effect) in chosen numbers instead of the cycle of ``--n``
(:func:`bikeid.experiments.measured.blind_trials.draw_blind_classes`, reproducible by seed).
``--nominal-only`` runs no selection: it prints the nominal cost ratio (nonlinear / linear
plant) of every trial's fit decays and its range per truth plant and class, the calibration
of :data:`bikeid.ident.effects.selection.LINEAR_PLANT_MARGIN`.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from functools import partial

import numpy as np

from bikeid.experiments.cli.args import dump_json, to_jsonable
from bikeid.experiments.cli.measured import acceptance_rule, add_acceptance_options
from bikeid.experiments.measured.blind_trials import (
    draw_blind_classes,
    draw_blind_trials,
    nominal_comparison,
    parse_per_class,
    rescore_unexplained,
    run_blind_trial,
    summarize_blind,
)
from bikeid.experiments.parallel import DASK_HELP, imap, map_jobs
from bikeid.ident.effects.selection import LINEAR_PLANT_MARGIN


def _fmt(name: str, r: dict) -> str:
    lo, hi = r["ci95"]
    return f"{name:34s} {r['k']:3d}/{r['n']:<3d} = {r['rate']:.3f} (95 % CI {lo:.3f}-{hi:.3f})"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=90)
    ap.add_argument(
        "--per-class",
        type=_per_class_arg,
        metavar="CLASS=N,...",
        help="draw only these classes in these numbers (library, outside, none or an effect "
        "name), e.g. none=24,outside=24; replaces --n",
    )
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--processes", type=int, default=2)
    ap.add_argument("--dask", metavar="ADDRESS", help=DASK_HELP)
    ap.add_argument(
        "--plant",
        choices=("auto", "nonlinear", "linear"),
        default="auto",
        help="the pipeline's nominal plant (default auto, that of 'measured fit': linear only "
        "when its nominal cost is lower by more than LINEAR_PLANT_MARGIN)",
    )
    ap.add_argument(
        "--plant-margin",
        type=float,
        default=None,
        metavar="M",
        help="margin of --plant auto (default LINEAR_PLANT_MARGIN; 1 = the better-fitting "
        "plant, the auto of the runs before the margin)",
    )
    ap.add_argument(
        "--nominal-only",
        action="store_true",
        help="no selection: the nominal cost ratio of each trial and its range per truth "
        "plant and class (calibration of the plant margin)",
    )
    add_acceptance_options(ap)  # the options of bikeid measured fit, same defaults
    ap.add_argument(
        "--tradeoff",
        action="store_true",
        help="also print the rates for a grid of thresholds of each 'unexplained' rule "
        "(the accepted effects as selected: exact, no rerun)",
    )
    ap.add_argument("--log", help="append each finished trial to this JSON-lines file")
    ap.add_argument("--resume", help="reuse the finished trials of this JSON-lines log")
    args = ap.parse_args()
    print(
        f"machine: {platform.machine()}, {os.cpu_count()} cores, Python "
        f"{platform.python_version()}, load {os.getloadavg()[0]:.1f}",
        flush=True,
    )
    done = {}
    if args.resume and os.path.exists(args.resume):
        with open(args.resume) as fh:
            for line in fh:
                if line.strip():
                    r = json.loads(line)
                    done[r["index"]] = r
    drawn = (draw_blind_classes(args.per_class, args.seed) if args.per_class
             else draw_blind_trials(args.n, args.seed))  # fmt: skip
    if args.nominal_only:
        _nominal_only(drawn, args.processes, args.dask)
        return
    trials = [t for t in drawn if t.index not in done]
    rows = [done[i] for i in sorted(done) if i < len(drawn)]
    t0 = time.perf_counter()
    rule = acceptance_rule(args)
    job = partial(
        run_blind_trial, nonlinear="auto" if args.plant == "auto" else args.plant == "nonlinear",
        plant_margin=args.plant_margin, rule=rule,
    )  # fmt: skip
    for _, r in imap(job, trials, args.processes, args.dask, ordered=True):
        r = to_jsonable(r)
        rows.append(r)
        print(
            f"{r['index']:4d} {r['effect']:24s} {r['nuisance']['plant']:18s} -> "
            f"{r['verdict']} {r['seconds']:.1f} s",
            flush=True,
        )
        if args.log:
            with open(args.log, "a") as fh:
                fh.write(json.dumps(r) + "\n")
    s = summarize_blind(rows)
    print(
        f"{len(trials)} trials run in {time.perf_counter() - t0:.0f} s wall; "
        f"nominal plant {args.plant} (margin {args.plant_margin or LINEAR_PLANT_MARGIN}), "
        f"seed {args.seed}, "
        f"{'classes ' + str(args.per_class) if args.per_class else f'{args.n} trials'}, "
        f"acceptance rule {to_jsonable(rule.as_dict())}"
    )
    print(_fmt("right effect first, value in band", s["right_first"]))
    print(_fmt("library trials with extra effects", s["with_extras"]))
    me = s["mean_extras"]
    ci = "" if me["ci95"] is None else f" (95 % CI {me['ci95'][0]:.2f}-{me['ci95'][1]:.2f})"
    print(f"{'mean extra effects per library trial':34s} {me['mean']:.2f}{ci}")
    print(_fmt("false positive (no-effect logs)", s["false_positive"]))
    print(_fmt("outside library misattributed", s["misattributed"]))
    print(f"{'pipeline failures (counted as misses)':34s} {s['pipeline_errors']}")
    print(dump_json(s["per_plant"]))
    if args.tradeoff:
        _tradeoff(rows)


def _per_class_arg(text: str) -> dict[str, int]:
    try:
        return parse_per_class(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc).removeprefix("--per-class: ")) from None


def _nominal_only(trials: list, processes: int, dask: str | None = None) -> None:
    t0 = time.perf_counter()
    rows = map_jobs(nominal_comparison, trials, processes, dask)
    for r in rows:
        print(f"{r['index']:4d} {r['effect']:24s} {r['plant']:18s} linear {r['linear']:8.4g} "
              f"nonlinear {r['nonlinear']:8.4g} ratio {r['ratio']:8.4g}")  # fmt: skip
    print(f"{len(rows)} trials in {time.perf_counter() - t0:.0f} s wall; nominal cost ratio "
          "nonlinear / linear, min / 5 % / median / 95 % / max:")  # fmt: skip
    for plant in ("independent_linear", "bikeid_nonlinear"):
        for kind in ("none", "library", "outside", "all"):
            x = np.array([r["ratio"] for r in rows if r["plant"] == plant
                          and kind in ("all", r["kind"])])  # fmt: skip
            if x.size:
                q = np.quantile(x, [0.0, 0.05, 0.5, 0.95, 1.0])
                qs = " / ".join(f"{v:.3g}" for v in q)
                print(f"  {plant:18s} {kind:8s} n={x.size:3d}: {qs}")


def _tradeoff(rows: list[dict]) -> None:
    grid = {"floor": (0.5, 0.7, 0.8, 0.85, 0.9, 0.95), "coloured": (0.7, 0.8, 0.9, 0.95),
            "residual": (1.5, 1.8, 2.0, 2.5, 3.0, 4.0, 6.0)}  # fmt: skip
    print("unexplained rule, threshold: right first in band | misattributed | false positive")
    for rule, thresholds in grid.items():
        for thr in thresholds:
            s = summarize_blind(rescore_unexplained(rows, rule, thr))
            rf, mi, fp = s["right_first"], s["misattributed"], s["false_positive"]
            print(f"  {rule:9s} {thr:5.2f}: {rf['k']:2d}/{rf['n']} | {mi['k']}/{mi['n']} | "
                  f"{fp['k']}/{fp['n']}")  # fmt: skip


if __name__ == "__main__":
    main()
