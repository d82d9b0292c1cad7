"""Clean free decays per log of the closure's generator: the fixed 1 s window against the
window that follows the decay (dataset.decays.detect_decays).

Each seed draws the closure's trials (experiments.measured.blind_trials.draw_blind_trials over
CLOSURE_EFFECTS), writes the chosen effect's two fit-speed logs as CSV
(``write_trial_logs``), reads them as ``bikeid measured fit`` does (the one loader,
``dataset.logs.load_runs``, with the trials' ``log_options``) and counts the decays each
detector keeps, the pushes it counts (kept + rejected; the generator makes 8 per log) and
the window lengths.  A trial whose two logs hold fewer than MIN_FIT_DECAYS decays is one
``measured fit`` refuses.  No fits: a few seconds per trial.

Usage::

    python benchmarks/bench_decay_counts.py [--effect input_delay] [--seeds 8]
        [--first-seed 0] [--truth independent_linear|bikeid_nonlinear]
"""

from __future__ import annotations

import argparse
import tempfile

from bikeid.dataset.decays import MIN_FIT_DECAYS, detect_decays
from bikeid.dataset.logs import load_runs
from bikeid.experiments.measured.blind_trials import (
    CLOSURE_EFFECTS,
    PLANTS,
    draw_blind_trials,
    log_options,
    write_trial_logs,
)

DETECTORS = {"fixed 1 s": {"max_length": None}, "follows the decay": {}}


def count(trial, truth: str) -> dict:
    """Per detector: decays kept, pushes counted and window lengths [s] over a trial's logs."""
    with tempfile.TemporaryDirectory() as d:
        files = write_trial_logs(trial, d, truth)
        runs = load_runs(files, log_options(), note=lambda _msg: None)
    out = {}
    for name, kw in DETECTORS.items():
        kept, pushes, lengths = 0, 0, []
        for run in runs:
            rejected: list = []
            segs = detect_decays(run, rejected=rejected, **kw)
            kept += len(segs)
            pushes += len(segs) + len(rejected)
            lengths += [(s.end - s.start) * run.dt for s in segs]
        out[name] = {"kept": kept, "pushes": pushes, "lengths": lengths}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--effect", choices=CLOSURE_EFFECTS, default="input_delay")
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--truth", choices=PLANTS, default="independent_linear")
    args = ap.parse_args()
    refused = dict.fromkeys(DETECTORS, 0)
    for s in range(args.first_seed, args.first_seed + args.seeds):
        trial = next(t for t in draw_blind_trials(len(CLOSURE_EFFECTS), s, CLOSURE_EFFECTS)
                     if t.effect == args.effect)  # fmt: skip
        res = count(trial, args.truth)
        parts = []
        for name, r in res.items():
            refused[name] += r["kept"] < MIN_FIT_DECAYS
            ls = r["lengths"]
            span = f", windows {min(ls):.2f}-{max(ls):.2f} s" if ls else ""
            parts.append(f"{name}: {r['kept']} kept of {r['pushes']} pushes{span}")
        print(f"seed {s} {args.effect} {trial.value:g}: " + "; ".join(parts), flush=True)
    print(f"refused (< {MIN_FIT_DECAYS} decays): "
          + ", ".join(f"{name} {k}/{args.seeds}" for name, k in refused.items()))  # fmt: skip


if __name__ == "__main__":
    main()
