"""Start-up and finish time of the quick commands (wall clock, fresh process each time).

    python benchmarks/bench_startup.py [--repeats 9]

Runs each command ``--repeats`` times in a new Python process (``python -m
bikeid.experiments.cli ...``, what the ``bikeid`` console script runs) and prints the
median, minimum and maximum wall time, with ``python -c pass`` as the interpreter's own
start-up in the same run for comparison.  The goal is that ``--help``, ``linearize``,
``critical-speeds`` and ``eig`` start and finish in under 0.5 s: a user calls them
interactively and in shell loops.  Where the time goes: ``python -X importtime -m
bikeid.experiments.cli critical-speeds``.  Timings depend on the machine and its load; run
it on an otherwise idle machine and quote the machine (docs/performance.md).
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import time

COMMANDS = {
    "python -c pass (interpreter only)": [sys.executable, "-c", "pass"],
    "bikeid --help": ["--help"],
    "bikeid linearize --speed 5": ["linearize", "--speed", "5"],
    "bikeid critical-speeds": ["critical-speeds"],
    "bikeid eig --speeds 0:10:0.5": ["eig", "--speeds", "0:10:0.5"],
}


def _time(cmd: list[str]) -> float:
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=9, help="runs per command (default 9)")
    args = ap.parse_args()
    if args.repeats < 1:
        ap.error("--repeats must be >= 1")
    print(f"{'command':36s} {'median':>8s} {'min':>8s} {'max':>8s}  [s, {args.repeats} runs]")
    for label, argv in COMMANDS.items():
        cmd = argv if argv[0] == sys.executable else [
            sys.executable, "-m", "bikeid.experiments.cli", *argv
        ]
        _time(cmd)  # warm the file cache (and numba's cache) once
        ts = [_time(cmd) for _ in range(args.repeats)]
        print(f"{label:36s} {statistics.median(ts):8.3f} {min(ts):8.3f} {max(ts):8.3f}")


if __name__ == "__main__":
    main()
