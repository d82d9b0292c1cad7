"""The closure's rates on logs of another lab's format, from a generator that does not share
the pipeline's nominal plant.

Each seed draws one blind trial (experiments.measured.blind_trials) per hidden effect of
CLOSURE_EFFECTS: viscous steer damping, an input delay, an actuator gain, roll damping
(outside the library) and none.  Its two fit speeds are written as CSV logs (time in ms,
degrees, deg/s, km/h, roll positive to the left) and fitted by ``bikeid measured fit`` with
identify's import options and the default pipeline (``--plant auto``: the selection with both
nominal plants, the plant chosen after it by the final models' out-of-fold costs; the default
acceptance rule).  The truth's plant is the independent linear one (Moore's canonical matrices from
bicycleparameters, perturbed within the stated uncertainty) unless ``--truth`` says
otherwise.  Prints each trial's outcome (with the plant test's out-of-fold cost ratio
nonlinear / linear, its p-value and whether the two selections agree, and the nominal cost
ratio before any effect) and, per effect, the rate of right answers with its
exact (Clopper-Pearson) 95 % interval (:func:`blind_trials.closure_rates`: a library effect
named alone with its value within 35 %; an outside effect answered ``unexplained`` alone,
counted only when every no-effect log of the run said nothing; no effect: nothing said);
``--json`` writes all rows and the summary.

Usage::

    python benchmarks/bench_closure_rates.py --seeds 8 [--first-seed 0] [--processes 1]
        [--truth independent_linear|bikeid_nonlinear|trial] [--fit-plant auto|linear|nonlinear]
        [--drive loop|kstep] [--torque-only] [--effects none,input_delay]
        [--unexplained-rule instruments] [--json rates.json]

``--torque-only`` reads the logs as a stranger's (no controller law: the k-step error);
``--drive kstep`` with the law scores the same logs by the k-step error instead of the loop
simulation (the comparison of docs/measured.md).
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

from bikeid.experiments.measured.blind_trials import (
    CLOSURE_EFFECTS,
    LOG_OUTCOMES,
    PLANTS,
    VALUE_TOLERANCE,
    closure_rates,
    draw_blind_trials,
    run_log_trial,
)
from bikeid.experiments.parallel import imap


def _job(args: tuple) -> dict:
    trial, truth, fit_plant, drive, torque_only, unexplained_rule = args
    t0 = time.process_time()
    extra = () if fit_plant == "auto" else ("--plant", fit_plant)
    extra += () if drive is None else ("--drive", drive)
    extra += () if unexplained_rule is None else ("--unexplained-rule", unexplained_rule)
    with tempfile.TemporaryDirectory() as d:
        row = run_log_trial(trial, d, None if truth == "trial" else truth, extra, torque_only)
        model = Path(d) / "model.json"
        res = json.loads(model.read_text())["results"] if row["rc"] == 0 else {}
    check = res.get("plant_check")
    ident = res.get("identification") or {}
    ev = ident.get("evidence") or {}
    keep = ("fit_gain", "heldout_gain", "heldout_windows_improved", "heldout_windows", "p_adjusted")
    row["evidence"] = {"explained": (ev.get("unexplained") or {}).get("explained"),
                       "effects": {n: {k: e.get(k) for k in keep}
                                   for n, e in (ev.get("effects") or {}).items()}}  # fmt: skip
    test = (check or {}).get("test") or {}
    row["plant_test"] = {k: test.get(k) for k in ("ratio", "p_value", "separated")} if test \
        else None  # fmt: skip
    row["plant_agree"] = None if check is None else check["agree"]
    row["cpu_s"] = time.process_time() - t0
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=4, help="grid seeds (one trial per effect)")
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--processes", type=int, default=1)
    ap.add_argument("--truth", choices=(*PLANTS, "trial"), default="independent_linear",
                    help="the truth's plant (trial: the trial's own draw, 3/4 linear)")
    ap.add_argument("--fit-plant", choices=("auto", "linear", "nonlinear"), default="auto",
                    help="measured fit's --plant (auto: the default, with the plant check; "
                    "nonlinear with a linear truth: the mismatch the check is for)")
    ap.add_argument("--drive", choices=("loop", "kstep"), default=None,
                    help="measured fit's --drive (default: loop with the law, kstep without)")
    ap.add_argument("--torque-only", action="store_true",
                    help="read the logs without the controller law (the logged torque only)")
    ap.add_argument("--unexplained-rule", default=None,
                    help="measured fit's --unexplained-rule (default: its default)")
    ap.add_argument("--effects", default=None,
                    help="comma-separated subset of the hidden effects (default: all)")
    ap.add_argument("--json", help="write rows and summary to this file")
    args = ap.parse_args()
    keep = set(args.effects.split(",")) if args.effects else set(CLOSURE_EFFECTS)
    trials = [t for s in range(args.first_seed, args.first_seed + args.seeds)
              for t in draw_blind_trials(len(CLOSURE_EFFECTS), s, CLOSURE_EFFECTS)
              if t.effect in keep]  # fmt: skip
    rows = []
    jobs = [(t, args.truth, args.fit_plant, args.drive, args.torque_only, args.unexplained_rule)
            for t in trials]  # fmt: skip
    for _, r in imap(_job, jobs, args.processes, None, ordered=True):
        rows.append(r)
        t = r["plant_test"]
        after = "" if not t else (f" (after selection: out-of-fold ratio {t['ratio']:.3g}, p "
                                  f"{t['p_value']:.2g}, selections "
                                  f"{'agree' if r['plant_agree'] else 'disagree'})")
        ratio = "-" if r["plant_ratio"] is None else f"{r['plant_ratio']:.3g}"
        print(f"seed-trial {r['seed']} {r['effect']:22s} {r['outcome']:18s} verdict "
              f"{r['verdict']} plant {r['plant']}{after} nominal ratio {ratio} cpu "
              f"{r['cpu_s']:.1f} s", flush=True)  # fmt: skip
    s = closure_rates(rows)
    for eff, v in s.items():
        if not isinstance(v, dict) or "ci95" not in v:
            continue
        lo, hi = v["ci95"]
        extra = "" if "value_ok" not in v else (
            f", named first alone {v['named_first']}/{v['n']}, value within "
            f"{VALUE_TOLERANCE:.0%}: {v['value_ok']}/{v['n']}")
        print(f"{eff:22s} right {v['right']}/{v['n']} (95 % CI {lo:.2f}-{hi:.2f}); "
              f"outcomes {v['outcomes']}{extra}")
    sn = s["silent_none"]
    print(f"no-effect logs silent {sn['k']}/{sn['n']}: `unexplained` on outside effects is "
          f"{'' if s['unexplained_is_evidence'] else 'not '}counted as evidence")
    print(f"outcomes: {', '.join(LOG_OUTCOMES)}; CPU {sum(r['cpu_s'] for r in rows):.0f} s")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"args": vars(args), "rows": rows, "summary": s}, fh, indent=1,
                      default=float)  # fmt: skip


if __name__ == "__main__":
    main()
