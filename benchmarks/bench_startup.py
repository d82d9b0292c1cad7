"""Start-up and finish time of the quick commands (fresh process each time).

    python benchmarks/bench_startup.py [--repeats 9]

Runs each command ``--repeats`` times in a new Python process (``python -m
bikeid.experiments.cli ...``, what the ``bikeid`` console script runs) and prints the
median, minimum and maximum wall time and the median CPU time (user + system of the child
process, which a busy machine inflates much less than the wall time), with ``python -c
pass`` as the interpreter's own start-up in the same run for comparison, and the load
average before and after.  The goal is that ``--help``, ``linearize``, ``critical-speeds``
and ``eig`` start and finish in under 0.5 s: a user calls them interactively and in shell
loops.  Where the time goes: ``python -X importtime -m bikeid.experiments.cli
critical-speeds``; tests/experiments/cli/test_startup.py checks that these commands import none of
the
heavy modules.  Timings depend on the machine and its load; run it on an otherwise idle
machine and quote the machine (docs/performance.md).
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
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


def _children_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _time(cmd: list[str]) -> tuple[float, float]:
    """Wall and CPU time [s] of one run of ``cmd``."""
    c0, t0 = _children_cpu(), time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - t0, _children_cpu() - c0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=9, help="runs per command (default 9)")
    args = ap.parse_args()
    if args.repeats < 1:
        ap.error("--repeats must be >= 1")
    print(
        f"{platform.machine()}, {os.cpu_count()} cores, python {platform.python_version()}; "
        f"load average {os.getloadavg()[0]:.2f} at the start"
    )
    print(
        f"{'command':36s} {'median':>8s} {'min':>8s} {'max':>8s} {'CPU':>8s}"
        f"  [s, {args.repeats} runs; CPU: median user+sys]"
    )
    for label, argv in COMMANDS.items():
        cmd = argv if argv[0] == sys.executable else [
            sys.executable, "-m", "bikeid.experiments.cli", *argv
        ]  # fmt: skip
        _time(cmd)  # warm the file cache (and numba's cache) once
        runs = [_time(cmd) for _ in range(args.repeats)]
        wall = [w for w, _ in runs]
        cpu = statistics.median(c for _, c in runs)
        print(
            f"{label:36s} {statistics.median(wall):8.3f} {min(wall):8.3f} {max(wall):8.3f} "
            f"{cpu:8.3f}"
        )
    print(f"load average {os.getloadavg()[0]:.2f} at the end")


if __name__ == "__main__":
    main()
