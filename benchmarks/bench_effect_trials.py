"""Benchmark: the randomized undeclared-effect grid on the nonlinear plant.

    python benchmarks/bench_effect_trials.py [--n 160] [--seed 1]
        [--processes 2] [--log trials.jsonl] [--resume trials.jsonl]

Runs ``experiments.measured.effect_trials.run_trials`` (the same as ``bikeid measured trials``),
printing each trial as it finishes and the rates with 95 % Clopper-Pearson intervals at the
end (per effect: what was named first).  ``--resume`` summarizes an existing JSON-lines log
(e.g. of an interrupted run) without simulating: trial i depends only on (seed, i), so the
first k trials of a log are the grid of size k.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time

from bikeid.experiments.cli.args import to_jsonable
from bikeid.experiments.cli.measured import parse_weave_weight
from bikeid.experiments.measured.effect_trials import format_summary, run_trials, summarize


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=160)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--processes", type=int, default=2)
    ap.add_argument("--log", help="append each finished trial to this JSON-lines file")
    ap.add_argument("--resume", help="only summarize this JSON-lines log")
    ap.add_argument(
        "--weave-weight",
        default="auto",
        type=parse_weave_weight,
        help="as for 'bikeid measured fit'",
    )
    args = ap.parse_args()
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"Python {platform.python_version()}, load {os.getloadavg()[0]:.1f}")  # fmt: skip
    if args.resume:
        with open(args.resume) as fh:
            rows = [json.loads(line) for line in fh if line.strip()]
        print(format_summary(summarize(rows)))
        return

    def progress(r):
        line = (
            f"{r['index']:4d} {r['effect']:24s} {r['value']:8.4g} -> {r['verdict']} "
            f"est {r['estimate']} ratio {r['error_ratio']:.2f} {r['seconds']:.1f} s"
        )
        print(line, flush=True)
        if args.log:
            with open(args.log, "a") as fh:
                fh.write(json.dumps(to_jsonable(r)) + "\n")

    t0 = time.perf_counter()
    out = run_trials(
        args.n, args.seed, args.processes, progress=progress, weave_weight=args.weave_weight
    )
    print(f"{args.n} trials in {time.perf_counter() - t0:.0f} s wall")
    print(format_summary(out["summary"]))


if __name__ == "__main__":
    main()
