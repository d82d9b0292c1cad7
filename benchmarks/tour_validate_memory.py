"""Benchmark: peak memory of ``bikeid validate`` on the README's tour as written (145 runs).

    python benchmarks/tour_validate_memory.py [--work DIR] [--seeds 0:4]

Runs the README's three tour commands in DIR (a new folder by default):
``bikeid sweep --controller pid --speeds 1:15:0.5 --duration 50 --seeds 0:4 --out pid.h5``,
``bikeid identify pid.h5 --speed-parameterized --out model.json`` and
``bikeid validate --model model.json pid.h5 --out val/``, then prints validate's peak resident
memory (``os.wait4``'s resource usage of that child alone, Linux kB -> MB), its CPU time and
exit status, with the machine and load (a DIR of an earlier run reuses its sweep and model
and rewrites val/).  The goal the docs state: under 500 MB.
"""

from __future__ import annotations

import argparse
import os
import platform
import subprocess
import sys
import tempfile
from pathlib import Path


def _bikeid(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "bikeid.experiments.cli", *args]
    return subprocess.run(cmd, cwd=cwd, capture_output=True, text=True)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", help="folder for pid.h5, model.json and val/ (default: a new one)")
    ap.add_argument("--seeds", default="0:4", help="sweep seeds (the README's: 0:4, 145 runs)")
    args = ap.parse_args()
    work = Path(args.work or tempfile.mkdtemp(prefix="tour_validate_"))
    work.mkdir(parents=True, exist_ok=True)
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, Python "
          f"{platform.python_version()}, load {os.getloadavg()[0]:.1f}; folder {work}")  # fmt: skip
    steps = [
        ("sweep", "--controller", "pid", "--speeds", "1:15:0.5", "--duration", "50",
         "--seeds", args.seeds, "--out", "pid.h5"),
        ("identify", "pid.h5", "--speed-parameterized", "--out", "model.json"),
    ]  # fmt: skip
    for step in steps:
        if not (work / step[-1]).exists():
            p = _bikeid(*step, cwd=work)
            print(f"bikeid {' '.join(step)}: exit {p.returncode}", flush=True)
            if p.returncode != 0:
                print(p.stderr.strip().splitlines()[-1], file=sys.stderr)
                return 1
    # os.wait4 gives the resource usage of this one child (validate), not the largest of
    # all children (RUSAGE_CHILDREN would report identify's larger peak)
    cmd = [sys.executable, "-m", "bikeid.experiments.cli", "validate", "--model", "model.json",
           "pid.h5", "--out", "val/"]  # fmt: skip
    with open(work / "validate.out", "w") as out:
        p = subprocess.Popen(cmd, cwd=work, stdout=out, stderr=subprocess.STDOUT)
        _, status, usage = os.wait4(p.pid, 0)
    code = os.waitstatus_to_exitcode(status)
    if code != 0:  # its one-line error, as the steps above print theirs
        lines = (work / "validate.out").read_text().strip().splitlines()
        print(lines[-1] if lines else "(no output)", file=sys.stderr)
    print(f"bikeid validate: exit {code}, peak RSS {usage.ru_maxrss / 1024:.0f} MB, CPU "
          f"{usage.ru_utime:.1f} s user")  # fmt: skip
    return 0 if code == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
