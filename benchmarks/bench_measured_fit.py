"""Where ``bikeid measured fit`` spends its time, and how long it takes (CPU seconds).

Runs the command's own code (:func:`bikeid.experiments.cli.main`) on the steer-by-wire logs of
``--speeds`` (default all four shared speeds) in this process and prints the CPU time of this
process (user + system, so other engineers' load on a shared machine does not count), the
effects selected, and with ``--profile N`` the N functions with the most CPU time of their own
(cProfile with a CPU clock; profiling slows the run by about 2x).

    python benchmarks/bench_measured_fit.py --data ../shared/data
    python benchmarks/bench_measured_fit.py --data ../shared/data --speeds 4.5 --profile 25

Numbers are in docs/performance.md ("measured fit").
"""

from __future__ import annotations

import argparse
import contextlib
import cProfile
import io
import json
import os
import pstats
import resource
import sys
import tempfile
import time
from pathlib import Path


def _cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def run(data: str | None, speeds: str | None, profile: int = 0) -> dict:
    """One ``measured fit``; returns CPU seconds, wall seconds, effects and the profile text."""
    from bikeid.experiments.cli import main

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "model.json"
        argv = ["measured", "fit", "--out", str(out)]
        argv += ["--data", data] if data else []
        argv += ["--speeds", speeds] if speeds else []
        prof = cProfile.Profile(time.process_time) if profile else None
        c0, w0 = _cpu(), time.perf_counter()
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            if prof:
                prof.enable()
            code = main(argv)
            if prof:
                prof.disable()
        cpu, wall = _cpu() - c0, time.perf_counter() - w0
        if code != 0:
            raise SystemExit(f"measured fit failed (exit {code})")
        effects = json.loads(out.read_text())["model"]["effects"]
    text = ""
    if prof:
        s = io.StringIO()
        pstats.Stats(prof, stream=s).sort_stats("tottime").print_stats(profile)
        text = s.getvalue()
    return {"cpu_seconds": cpu, "wall_seconds": wall, "effects": effects, "profile": text}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=os.environ.get("BIKEID_DATA"), help="data folder")
    ap.add_argument("--speeds", default=None, help="fit speeds, e.g. 2.5,4.5 (default all)")
    ap.add_argument("--profile", type=int, default=0, metavar="N", help="print the top N")
    a = ap.parse_args(argv)
    r = run(a.data, a.speeds, a.profile)
    print(f"measured fit --speeds {a.speeds or 'all'}: {r['cpu_seconds']:.1f} s CPU "
          f"({r['wall_seconds']:.1f} s wall); effects {r['effects']}")  # fmt: skip
    if r["profile"]:
        print(r["profile"], file=sys.stdout)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
