"""The sign check of the loader on the steer-by-wire logs, as logged and with the roll axis
mirrored (dataset.signs): each log's roll- and steer-equation sign coefficients, their t
and verdicts.  The numbers quoted in the CHANGELOG and the closing notes come from here.

Usage::

    python benchmarks/sign_check_real_logs.py [--data FOLDER]   # default $BIKEID_DATA
"""

from __future__ import annotations

import argparse
import dataclasses

from bikeid.dataset.sbw_logs import data_dir, find_logs, load_log, settled
from bikeid.dataset.signs import sign_evidence
from bikeid.sim.parameters import steer_by_wire


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=None, help="folder holding tudelft-sbw/")
    args = ap.parse_args()
    p = steer_by_wire()
    ts: dict[str, list[float]] = {"as logged": [], "mirrored": []}
    for path in find_logs(data_dir(args.data)):
        run = settled(load_log(path))
        mirrored = dataclasses.replace(run, signals={
            **run.signals, "phi": -run.signals["phi"], "phidot": -run.signals["phidot"]})
        cells = []
        for label, r in (("as logged", run), ("mirrored", mirrored)):
            roll, *steer = sign_evidence([r], p)
            ts[label].append(roll.t)
            cells.append(f"{label}: roll {roll.coefficient:+.3f} (t {roll.t:+.1f}, "
                         f"{roll.verdict})" + (f", steer t {steer[0].t:+.1f}" if steer else ""))
        print(f"{path.name:40s} " + "; ".join(cells), flush=True)
    for label, t in ts.items():
        print(f"{label}: roll-equation t {min(t):+.1f} .. {max(t):+.1f} over {len(t)} logs")


if __name__ == "__main__":
    main()
